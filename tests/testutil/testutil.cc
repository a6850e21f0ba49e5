#include "testutil/testutil.h"

#include <sys/wait.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <sstream>
#include <vector>

#include "absl/strings/str_cat.h"
#include "tandem/io/series.h"

namespace tandem::testing {

std::string SharedDataPath(const std::string& name) {
  std::filesystem::path p = std::filesystem::path(TANDEM_SHARED_DATA_DIR) / name;
  std::error_code ec;
  return std::filesystem::exists(p, ec) ? p.string() : std::string();
}

namespace {

// Temp dirs made by this process, removed when it exits (set TANDEM_KEEP_TEMP=1 to keep).
std::mutex temp_mu;
std::vector<std::filesystem::path>* temp_dirs = nullptr;

void RemoveTempDirs() {
  if (std::getenv("TANDEM_KEEP_TEMP")) return;
  std::lock_guard<std::mutex> lock(temp_mu);
  for (const auto& p : *temp_dirs) {
    std::error_code ec;
    std::filesystem::remove_all(p, ec);
  }
}

}  // namespace

std::string MakeTempDir() {
  static std::atomic<int> counter{0};
  auto base = std::filesystem::temp_directory_path() /
              ("tandem_test_" + std::to_string(getpid()) + "_" + std::to_string(counter++));
  std::filesystem::remove_all(base);
  std::filesystem::create_directories(base);
  std::lock_guard<std::mutex> lock(temp_mu);
  if (!temp_dirs) {
    temp_dirs = new std::vector<std::filesystem::path>;
    std::atexit(RemoveTempDirs);
  }
  temp_dirs->push_back(base);
  return base.string();
}

std::string BinPath(const std::string& name) {
  return (std::filesystem::path(TANDEM_BIN_DIR_PATH) / name).string();
}

int64_t ResidentBytes(int pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) {
      std::istringstream fields(line.substr(6));
      int64_t kib = -1;
      fields >> kib;
      return kib < 0 ? -1 : kib * 1024;
    }
  }
  return -1;
}

CommandOutput RunCommand(const std::string& command) {
  const std::string cmd = command + " 2>&1";
  CommandOutput out;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return out;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) out.text.append(buf, n);
  const int status = pclose(p);
  out.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return out;
}

double PatternValue(DType t, int64_t i, int64_t j, int64_t k) {
  switch (t) {
    case DType::kUInt8:
      return static_cast<double>((i * 7 + j * 13 + k * 29) % 256);
    case DType::kUInt16:
      return static_cast<double>((40000 + i * 301 + j * 17 + k * 1009) % 65536);
    case DType::kInt16:
      return static_cast<double>(-20000 + i * 311 + j * 977 + k * 1001);
    case DType::kFloat32:
      return -3.25 + i * 0.5 + j * 1.125 + k * 100.0625;
    case DType::kInt8:
      return static_cast<double>((i * 7 + j * 13 + k * 29) % 256 - 128);
    case DType::kUInt32:
      return 3e9 + static_cast<double>(i * 65537 + j * 4099 + k * 1000003);
    case DType::kInt32:
      return -2e9 + static_cast<double>(i * 65537 + j * 4099 + k * 1000003);
    case DType::kUInt64:  // every byte used, and exact in a double (below 2^53)
      return 0x1f00000000000p0 + static_cast<double>(i * 65537 + j * 4099 + k * 1000003);
    case DType::kInt64:
      return -0x1f00000000000p0 + static_cast<double>(i * 65537 + j * 4099 + k * 1000003);
  }
  return 0;
}

void StoreValue(DType t, double v, uint8_t* dst) {
  switch (t) {
    case DType::kUInt8:
      *dst = static_cast<uint8_t>(v);
      break;
    case DType::kUInt16: {
      const uint16_t x = static_cast<uint16_t>(v);
      std::memcpy(dst, &x, 2);
      break;
    }
    case DType::kInt16: {
      const int16_t x = static_cast<int16_t>(v);
      std::memcpy(dst, &x, 2);
      break;
    }
    case DType::kFloat32: {
      const float x = static_cast<float>(v);
      std::memcpy(dst, &x, 4);
      break;
    }
    case DType::kInt8: {
      const int8_t x = static_cast<int8_t>(v);
      std::memcpy(dst, &x, 1);
      break;
    }
    case DType::kUInt32: {
      const uint32_t x = static_cast<uint32_t>(v);
      std::memcpy(dst, &x, 4);
      break;
    }
    case DType::kInt32: {
      const int32_t x = static_cast<int32_t>(v);
      std::memcpy(dst, &x, 4);
      break;
    }
    case DType::kUInt64: {
      const uint64_t x = static_cast<uint64_t>(v);
      std::memcpy(dst, &x, 8);
      break;
    }
    case DType::kInt64: {
      const int64_t x = static_cast<int64_t>(v);
      std::memcpy(dst, &x, 8);
      break;
    }
  }
}

double LoadValue(DType t, const uint8_t* p) {
  float f[1];
  ConvertToFloat(t, p, 1, f);
  return f[0];
}

std::string WriteLocalizer(const std::string& dir, const VolumeInfo& info, bool flagged) {
  io::DicomWriteOptions o;
  o.series_description = "Scout";
  o.series_uid = flagged ? "1.2.826.0.1.3680043.2.1125.77.1" : "1.2.826.0.1.3680043.2.1125.77.2";
  if (flagged) o.image_type = "ORIGINAL\\PRIMARY\\LOCALIZER";
  o.float_max = 1.0f;
  for (int image = 0; image < 2; ++image) {
    const VolumeInfo grid = io::LocalizerGrid(info, image);
    absl::StatusOr<io::DicomSliceWriter> w = io::DicomSliceWriter::Create(grid, o);
    EXPECT_TRUE(w.ok()) << w.status();
    if (!w.ok()) break;
    const std::vector<uint8_t> zeros(grid.slice_bytes(), 0);
    absl::Status st =
        w->Write(absl::StrCat(dir, "/scout", flagged ? "" : "_unflagged", image + 1, ".dcm"), 0,
                 zeros, image + 1);
    EXPECT_TRUE(st.ok()) << st;
  }
  return o.series_uid;
}

std::string FileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void WriteDoseReport(const std::string& path, const std::string& series_uid) {
  // Explicit VR little endian elements (UI padded with a zero byte, text with a space).
  auto element = [](uint16_t group, uint16_t elem, const char* vr, std::string value) {
    if (value.size() % 2 == 1) value.push_back(std::string(vr) == "UI" ? '\0' : ' ');
    std::string e;
    for (uint16_t v : {group, elem})
      e.append({static_cast<char>(v & 0xff), static_cast<char>(v >> 8)});
    e.append(vr, 2);
    const size_t n = value.size();
    e.append({static_cast<char>(n & 0xff), static_cast<char>(n >> 8)});
    return e + value;
  };
  const std::string sop_class = "1.2.840.10008.5.1.4.1.1.88.67";  // X-Ray Radiation Dose SR
  const std::string sop = series_uid + ".1";
  std::string meta = element(0x0002, 0x0002, "UI", sop_class) + element(0x0002, 0x0003, "UI", sop) +
                     element(0x0002, 0x0010, "UI", "1.2.840.10008.1.2.1");
  std::string length;
  for (int shift = 0; shift < 32; shift += 8)
    length.push_back(static_cast<char>(meta.size() >> shift));
  std::string file(128, '\0');
  file += "DICM";
  file += std::string("\x02\x00\x00\x00UL\x04\x00", 8) + length + meta;
  file += element(0x0008, 0x0016, "UI", sop_class) + element(0x0008, 0x0018, "UI", sop) +
          element(0x0008, 0x0060, "CS", "SR") + element(0x0008, 0x103e, "LO", "Dose Report") +
          element(0x0020, 0x000e, "UI", series_uid);
  std::ofstream(path, std::ios::binary) << file;
}

io::SliceFn PatternSlices(const VolumeInfo& info) {
  return [info](int64_t k, std::vector<uint8_t>* bytes) {
    const size_t es = DTypeSize(info.dtype);
    bytes->resize(info.slice_bytes());
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        StoreValue(info.dtype, PatternValue(info.dtype, i, j, k),
                   bytes->data() + (j * info.nx + i) * es);
      }
    }
    return absl::OkStatus();
  };
}

void WriteBareTiffStack(const std::string& path, int nx, int ny, int nz) {
  TIFF* tif = TIFFOpen(path.c_str(), "w");
  ASSERT_NE(tif, nullptr) << path;
  const double r = 0.35 * std::min({nx, ny, nz});
  std::vector<uint8_t> row(static_cast<size_t>(nx));
  for (int z = 0; z < nz; ++z) {
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, nx);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, ny);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 8);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
    TIFFSetField(tif, TIFFTAG_SUBFILETYPE, FILETYPE_PAGE);
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        const double dx = x - (nx - 1) / 2.0, dy = y - (ny - 1) / 2.0, dz = z - (nz - 1) / 2.0;
        row[static_cast<size_t>(x)] = dx * dx + dy * dy + dz * dz < r * r ? 200 : 0;
      }
      ASSERT_EQ(TIFFWriteScanline(tif, row.data(), static_cast<uint32_t>(y), 0), 1);
    }
    ASSERT_EQ(TIFFWriteDirectory(tif), 1);
  }
  TIFFClose(tif);
}

}  // namespace tandem::testing
