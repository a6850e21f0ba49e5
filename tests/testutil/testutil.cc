#include "testutil/testutil.h"

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <mutex>
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

}  // namespace tandem::testing
