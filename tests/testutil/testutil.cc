#include "testutil/testutil.h"

#include <atomic>
#include <filesystem>
#include <unistd.h>

namespace tandem::testing {

std::string SharedDataPath(const std::string& name) {
  std::filesystem::path p = std::filesystem::path(TANDEM_SHARED_DATA_DIR) / name;
  std::error_code ec;
  return std::filesystem::exists(p, ec) ? p.string() : std::string();
}

std::string MakeTempDir() {
  static std::atomic<int> counter{0};
  auto base = std::filesystem::temp_directory_path() /
              ("tandem_test_" + std::to_string(getpid()) + "_" + std::to_string(counter++));
  std::filesystem::remove_all(base);
  std::filesystem::create_directories(base);
  return base.string();
}

std::string BinPath(const std::string& name) {
  return (std::filesystem::path(TANDEM_BIN_DIR_PATH) / name).string();
}

}  // namespace tandem::testing
