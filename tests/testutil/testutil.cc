#include "testutil/testutil.h"

#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <vector>

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
  }
}

double LoadValue(DType t, const uint8_t* p) {
  float f[1];
  ConvertToFloat(t, p, 1, f);
  return f[0];
}

SliceFn PatternSlices(const VolumeInfo& info) {
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
