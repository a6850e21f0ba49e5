// tandem view: a finished mesh or folder of sealed chunks, shown in the browser viewer.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "apps/common/flags.h"
#include "command.h"
#include "tandem/viewer/view_server.h"

namespace tandem::app {

namespace {

constexpr char kViewUsage[] =
    R"(usage: tandem view MESH | DIR [flags]
Shows a finished result in a browser: serves the viewer page (the one tandem-client
stream/watch --view shows live) on HOST:PORT (default 127.0.0.1:8080; port 0 = any free
one) and prints its address. MESH is a .ply, .obj, .stl, .glb or .drc file; DIR a folder of
sealed chunks (chunk_000000.drc, ... as tandem-client --chunks saves them), drawn chunk by
chunk. Runs until Ctrl-C, or for --linger S seconds.)";

std::atomic<bool> g_view_quit{false};

}  // namespace

int ViewCommand(int argc, char** argv) {
  std::string listen = "127.0.0.1:8080", token;
  double linger_s = -1;
  cli::FlagSet flags(kViewUsage);
  flags.AddString("view", &listen, "HOST:PORT", "where the page is served (port 0 = any free one)");
  flags.AddSecret("view-token", &token, "TOKEN", "TANDEM_VIEW_TOKEN",
                  "the page and its data need ?token=TOKEN (for an address other than "
                  "loopback, which has no other protection)");
  flags.AddDouble("linger", &linger_s,
                  "serve for this many seconds, then exit (< 0 = until Ctrl-C)", false, "S");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (flags.positional().size() != 1) {
    return Usage(absl::InvalidArgumentError("expected one mesh file or folder of chunks to show"));
  }
  const std::string path = flags.positional()[0];
  std::vector<std::string> chunks;
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    for (const auto& e : std::filesystem::directory_iterator(path, ec)) {
      const std::string name = e.path().filename().string();
      if (absl::StartsWith(name, "chunk_") && absl::EndsWith(name, ".drc")) {
        chunks.push_back(e.path().string());
      }
    }
    std::sort(chunks.begin(), chunks.end());
    if (chunks.empty()) {
      return Fail(absl::NotFoundError(absl::StrCat(path, ": no chunk_*.drc files in this folder")));
    }
  } else {
    const std::string ext = absl::AsciiStrToLower(std::filesystem::path(path).extension().string());
    if (ext != ".ply" && ext != ".obj" && ext != ".stl" && ext != ".glb" && ext != ".drc") {
      return Usage(absl::InvalidArgumentError(absl::StrCat(
          path, ": expected a .ply, .obj, .stl, .glb or .drc file, or a folder of chunks")));
    }
  }
  auto read = [](const std::string& file) -> absl::StatusOr<std::string> {
    std::ifstream in(file, std::ios::binary);
    if (!in) return absl::NotFoundError(absl::StrCat(file, ": cannot open"));
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  viewer::ViewOptions options;
  options.listen = listen;
  options.token = token;
  auto server = viewer::ViewServer::Start(options);
  if (!server.ok()) return FailWriting(server.status());
  (*server)->SetSession("", std::filesystem::path(path).filename().string(), 0);
  if (chunks.empty()) {
    auto bytes = read(path);
    if (!bytes.ok()) return Fail(bytes.status());
    (*server)->AddFile(std::filesystem::path(path).filename().string(), *std::move(bytes));
  } else {
    for (const std::string& c : chunks) {
      auto bytes = read(c);
      if (!bytes.ok()) return Fail(bytes.status());
      (*server)->AddChunk(*std::move(bytes), -1, 0);
    }
  }
  (*server)->Finish("", "");
  std::string host;
  int port = 0;
  if (viewer::ParseListen(options.listen, &host, &port).ok() && !viewer::IsLoopback(host) &&
      options.token.empty()) {
    std::fprintf(stderr,
                 "tandem view: warning: %s has no authentication: anyone who can reach "
                 "it sees the mesh (add --view-token-file FILE or $TANDEM_VIEW_TOKEN)\n",
                 options.listen.c_str());
  }
  std::fprintf(stderr, "tandem view: %s at %s%s\n", path.c_str(), (*server)->url().c_str(),
               linger_s < 0 ? " (Ctrl-C to quit)" : "");
  std::signal(SIGINT, [](int) { g_view_quit = true; });
  std::signal(SIGTERM, [](int) { g_view_quit = true; });
  const auto until =
      std::chrono::steady_clock::now() +
      std::chrono::milliseconds(static_cast<int64_t>(std::max(0.0, linger_s) * 1000));
  while (!g_view_quit && (linger_s < 0 || std::chrono::steady_clock::now() < until)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return 0;
}

}  // namespace tandem::app
