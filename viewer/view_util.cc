#include <filesystem>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "tandem/viewer/view_server.h"

#ifndef TANDEM_SOURCE_DIR
#define TANDEM_SOURCE_DIR "."
#endif

// What both the programs and the module (view_server.cc) use: the places of the page and
// three.js, and the address.
namespace tandem::viewer {
namespace fs = std::filesystem;

namespace {

std::string ExeDir() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  return ec ? std::string() : exe.parent_path().string();
}

std::string FirstExisting(const std::vector<std::string>& candidates, const std::string& probe) {
  for (const std::string& c : candidates) {
    std::error_code ec;
    if (!c.empty() && fs::exists(fs::path(c) / probe, ec)) return c;
  }
  return "";
}

}  // namespace

namespace {
// `dir` if given, else share/tandem/<installed> next to the running binary, else the
// source tree's <source>, whichever holds `probe`.
std::string FindData(const std::string& dir, const std::string& installed,
                     const std::string& source, const std::string& probe) {
  if (!dir.empty()) return dir;
  const std::string exe = ExeDir();
  return FirstExisting({exe + "/../share/tandem/" + installed, exe + "/" + installed,
                        std::string(TANDEM_SOURCE_DIR) + "/" + source},
                       probe);
}
}  // namespace

std::string FindAssets(const std::string& dir) {
  return FindData(dir, "viewer", "viewer/web", "index.html");
}

std::string FindThree(const std::string& dir) {
  return FindData(dir, "three", "node_modules/three", "build/three.module.js");
}

absl::Status ParseListen(const std::string& listen, std::string* host, int* port) {
  const size_t colon = listen.rfind(':');
  int p = -1;
  if (colon == std::string::npos || colon == 0 ||
      !absl::SimpleAtoi(listen.substr(colon + 1), &p) || p < 0 || p > 65535) {
    return absl::InvalidArgumentError(
        absl::StrCat("expected HOST:PORT (e.g. 127.0.0.1:8080), got '", listen, "'"));
  }
  *host = listen.substr(0, colon);
  if (host->size() > 2 && host->front() == '[' && host->back() == ']') {
    *host = host->substr(1, host->size() - 2);
  }
  *port = p;
  return absl::OkStatus();
}

bool IsLoopback(const std::string& host) {
  return host == "localhost" || host == "::1" || absl::StartsWith(host, "127.");
}

}  // namespace tandem::viewer
