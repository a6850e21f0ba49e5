#include "testutil/testutil.h"

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <vector>

#include <unistd.h>

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

}  // namespace tandem::testing
