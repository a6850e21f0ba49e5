// libtandem_view.so: the viewer's HTTP server (view_server.h), a module of its own loaded by
// ViewServer::Start (view_loader.cc), so that only a program that serves the page loads
// cpp-httplib and the OpenSSL and Brotli it links.
#include "viewer/view_server.h"

#include <httplib.h>
#include <netdb.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"

namespace tandem::viewer {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

bool ReadWhole(const fs::path& path, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::ostringstream ss;
  ss << in.rdbuf();
  *out = ss.str();
  return true;
}

const char* ContentType(const std::string& path) {
  static const std::map<std::string, const char*> kTypes = {
      {".html", "text/html; charset=utf-8"}, {".js", "text/javascript; charset=utf-8"},
      {".mjs", "text/javascript; charset=utf-8"}, {".css", "text/css; charset=utf-8"},
      {".wasm", "application/wasm"}, {".json", "application/json"},
      {".png", "image/png"}, {".drc", "application/octet-stream"},
      {".ply", "application/octet-stream"}, {".obj", "text/plain"},
      {".stl", "application/octet-stream"}, {".glb", "model/gltf-binary"}};
  const std::string ext = fs::path(path).extension().string();
  auto it = kTypes.find(ext);
  return it == kTypes.end() ? "application/octet-stream" : it->second;
}

// A relative path inside a served folder: no "..", no absolute path, no hidden file.
bool SafeRelative(const std::string& rel) {
  if (rel.empty() || rel[0] == '/' || absl::StrContains(rel, "..") ||
      absl::StrContains(rel, "/.") || rel[0] == '.') {
    return false;
  }
  return true;
}

// Whether nobody listens on host:port. cpp-httplib binds with SO_REUSEPORT, which lets a
// second server bind a port another one listens on (and then shares its connections), so
// the port is tried first with a plain socket.
bool PortFree(const std::string& host, int port) {
  addrinfo hints{};
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE;
  addrinfo* found = nullptr;
  if (getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &found) != 0) return true;
  bool free = true;
  for (addrinfo* a = found; a != nullptr && free; a = a->ai_next) {
    const int fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    if (bind(fd, a->ai_addr, a->ai_addrlen) != 0 && errno == EADDRINUSE) free = false;
    close(fd);
  }
  freeaddrinfo(found);
  return free;
}

struct Impl {
  ViewOptions options;
  std::string assets, three, host;
  int port = 0;
  httplib::Server http;
  std::thread thread;
  std::atomic<bool> stopping{false};
  std::atomic<int64_t> connections{0};

  mutable absl::Mutex mu;
  int64_t version ABSL_GUARDED_BY(mu) = 0;
  json state ABSL_GUARDED_BY(mu);
  std::vector<std::shared_ptr<const std::string>> chunks ABSL_GUARDED_BY(mu);
  std::shared_ptr<const std::string> band ABSL_GUARDED_BY(mu);
  int64_t band_version ABSL_GUARDED_BY(mu) = 0;
  std::map<std::string, std::shared_ptr<const std::string>> files ABSL_GUARDED_BY(mu);

  void ChangedLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu) {
    ++version;
    state["version"] = version;
  }
  std::string StateText() const {
    absl::MutexLock lock(&mu);
    return state.dump();
  }
  bool Authorized(const httplib::Request& req) const {
    if (options.token.empty()) return true;
    if (req.get_param_value("token") == options.token) return true;
    return req.get_header_value("Authorization") == "Bearer " + options.token;
  }
  void Routes();
};

void Impl::Routes() {
  http.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    // The page and three.js are public code; the session's data needs the token.
    const bool data = req.path == "/state.json" || req.path == "/events" ||
                      absl::StartsWith(req.path, "/chunk/") ||
                      absl::StartsWith(req.path, "/band/") || absl::StartsWith(req.path, "/file/");
    if (!data || Authorized(req)) return httplib::Server::HandlerResponse::Unhandled;
    res.status = 401;
    res.set_content("this viewer needs its token (?token=... or Authorization: Bearer ...)\n",
                    "text/plain");
    return httplib::Server::HandlerResponse::Handled;
  });
  auto serve_file = [](const fs::path& path, httplib::Response& res, bool immutable) {
    std::string bytes;
    if (!ReadWhole(path, &bytes)) {
      res.status = 404;
      return;
    }
    if (immutable) res.set_header("Cache-Control", "public, max-age=31536000, immutable");
    res.set_content(std::move(bytes), ContentType(path.string()));
  };
  http.Get("/", [this, serve_file](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-cache");
    serve_file(fs::path(assets) / "index.html", res, false);
  });
  http.Get(R"(/(viewer\.js|viewer\.css))",
           [this, serve_file](const httplib::Request& req, httplib::Response& res) {
             res.set_header("Cache-Control", "no-cache");
             serve_file(fs::path(assets) / std::string(req.matches[1]), res, false);
           });
  http.Get(R"(/three/((build|examples/jsm)/.+))",
           [this, serve_file](const httplib::Request& req, httplib::Response& res) {
             const std::string rel = req.matches[1];
             if (!SafeRelative(rel)) {
               res.status = 404;
               return;
             }
             serve_file(fs::path(three) / rel, res, true);
           });
  http.Get("/state.json", [this](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    res.set_content(StateText(), "application/json");
  });
  http.Get(R"(/chunk/(\d+)\.drc)", [this](const httplib::Request& req, httplib::Response& res) {
    size_t index = 0;
    std::shared_ptr<const std::string> bytes;
    if (absl::SimpleAtoi(std::string(req.matches[1]), &index)) {
      absl::MutexLock lock(&mu);
      if (index < chunks.size()) bytes = chunks[index];
    }
    if (!bytes) {
      res.status = 404;
      return;
    }
    res.set_header("Cache-Control", "public, max-age=31536000, immutable");
    res.set_content(*bytes, "application/octet-stream");
  });
  http.Get(R"(/band/(\d+)\.drc)", [this](const httplib::Request& req, httplib::Response& res) {
    int64_t v = -1;
    std::shared_ptr<const std::string> bytes;
    if (absl::SimpleAtoi(std::string(req.matches[1]), &v)) {
      absl::MutexLock lock(&mu);
      if (v == band_version) bytes = band;
    }
    if (!bytes) {
      res.status = 404;  // superseded: the state names the current one
      return;
    }
    res.set_header("Cache-Control", "public, max-age=31536000, immutable");
    res.set_content(*bytes, "application/octet-stream");
  });
  http.Get(R"(/file/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    std::shared_ptr<const std::string> bytes;
    {
      absl::MutexLock lock(&mu);
      auto it = files.find(std::string(req.matches[1]));
      if (it != files.end()) bytes = it->second;
    }
    if (!bytes) {
      res.status = 404;
      return;
    }
    res.set_content(*bytes, ContentType(std::string(req.matches[1])));
  });
  http.Get("/events", [this](const httplib::Request&, httplib::Response& res) {
    connections.fetch_add(1);
    res.set_header("Cache-Control", "no-store");
    auto sent = std::make_shared<int64_t>(-1);
    res.set_chunked_content_provider(
        "text/event-stream", [this, sent](size_t, httplib::DataSink& sink) {
          // One event per call: the state when it changed, or a comment every 15 s (keeps
          // proxies from closing an idle stream and notices a browser that left).
          std::string text;
          {
            absl::MutexLock lock(&mu);
            auto changed = [this, sent]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu) {
              return version != *sent || stopping.load();
            };
            mu.AwaitWithTimeout(absl::Condition(&changed), absl::Seconds(15));
            if (stopping.load()) return false;
            if (version != *sent) {
              *sent = version;
              text = absl::StrCat("data: ", state.dump(), "\n\n");
            }
          }
          if (text.empty()) text = ": keep-alive\n\n";
          return sink.write(text.data(), text.size());
        });
  });
}

// The server (view_server.h), behind the interface the programs see.
class HttpViewServer final : public ViewServer {
 public:
  explicit HttpViewServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
  ~HttpViewServer() override;
  std::string url() const override;
  void SetSession(const std::string& id, const std::string& description, int64_t nz) override;
  void SetProgress(int64_t slices_sent, int64_t slices_meshed, int64_t triangles_held,
                   int64_t triangles_sealed) override;
  void AddChunk(std::string draco, int64_t triangles) override;
  void SetBand(std::string draco, int64_t triangles, int64_t slice, bool band_only) override;
  void ClearBand() override;
  void AddFile(const std::string& name, std::string bytes) override;
  void Finish(const std::string& metrics_json, const std::string& error) override;
  int64_t connections() const override { return impl_->connections.load(); }

 private:
  std::unique_ptr<Impl> impl_;
};

absl::StatusOr<std::unique_ptr<ViewServer>> Start(const ViewOptions& options) {
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  if (absl::Status st = ParseListen(options.listen, &impl->host, &impl->port); !st.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("--view ", st.message()));
  }
  impl->assets = FindAssets(options.assets_dir);
  impl->three = FindThree(options.three_dir);
  if (impl->assets.empty() || !fs::exists(fs::path(impl->assets) / "index.html")) {
    return absl::NotFoundError(
        "the viewer's page is not installed (share/tandem/viewer next to the binaries, or "
        "viewer/web in the source tree)");
  }
  if (impl->three.empty()) {
    return absl::NotFoundError(
        "three.js is not installed: run deploy/install-web.sh (npm ci) in the source tree, or "
        "install the binaries with cmake --install");
  }
  {
    absl::MutexLock lock(&impl->mu);
    impl->state = json{{"version", 0},          {"session", ""},         {"description", ""},
                       {"nz", 0},               {"slices_sent", 0},      {"slices_meshed", 0},
                       {"triangles_held", 0},   {"triangles_sealed", 0}, {"chunks", 0},
                       {"chunk_triangles", json::array()},
                       {"band", nullptr},       {"files", json::array()},
                       {"finished", false},     {"error", ""},           {"metrics", nullptr}};
  }
  // Event streams hold a thread each while open; 16 is plenty for a few browsers.
  impl->http.new_task_queue = [] { return new httplib::ThreadPool(16); };
  impl->Routes();
  int port = impl->port;
  if (port == 0) {
    port = impl->http.bind_to_any_port(impl->host);
    if (port < 0) port = 0;
  } else if (!PortFree(impl->host, port) || !impl->http.bind_to_port(impl->host, port)) {
    port = 0;
  }
  if (port == 0) {
    return absl::UnavailableError(absl::StrCat(
        "cannot serve the viewer on ", options.listen, ": ",
        impl->port != 0 ? absl::StrCat("port ", impl->port, " is in use (another viewer?) or ")
                        : "",
        "the address is not this machine's; choose another with --view HOST:PORT"));
  }
  impl->port = port;
  Impl* raw = impl.get();
  impl->thread = std::thread([raw] { raw->http.listen_after_bind(); });
  // Until the loop runs, stop() would not reach it (and the destructor would wait forever).
  for (int i = 0; i < 500 && !impl->http.is_running(); ++i) absl::SleepFor(absl::Milliseconds(10));
  return std::unique_ptr<ViewServer>(new HttpViewServer(std::move(impl)));
}

HttpViewServer::~HttpViewServer() {
  impl_->stopping = true;
  {
    absl::MutexLock lock(&impl_->mu);  // wakes the event streams
    impl_->ChangedLocked();
  }
  impl_->http.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

std::string HttpViewServer::url() const {
  const bool v6 = absl::StrContains(impl_->host, ':');
  std::string host = impl_->host == "0.0.0.0" ? "127.0.0.1" : impl_->host;
  if (v6) host = absl::StrCat("[", host, "]");
  return absl::StrCat("http://", host, ":", impl_->port, "/",
                      impl_->options.token.empty() ? "" : "?token=" + impl_->options.token);
}

void HttpViewServer::SetSession(const std::string& id, const std::string& description, int64_t nz) {
  absl::MutexLock lock(&impl_->mu);
  impl_->state["session"] = id;
  impl_->state["description"] = description;
  impl_->state["nz"] = nz;
  impl_->ChangedLocked();
}

void HttpViewServer::SetProgress(int64_t slices_sent, int64_t slices_meshed, int64_t triangles_held,
                             int64_t triangles_sealed) {
  absl::MutexLock lock(&impl_->mu);
  json& s = impl_->state;
  s["slices_sent"] = slices_sent;
  s["slices_meshed"] = slices_meshed;
  s["triangles_held"] = triangles_held;
  s["triangles_sealed"] = triangles_sealed;
  impl_->ChangedLocked();
}

void HttpViewServer::AddChunk(std::string draco, int64_t triangles) {
  auto bytes = std::make_shared<const std::string>(std::move(draco));
  absl::MutexLock lock(&impl_->mu);
  impl_->chunks.push_back(std::move(bytes));
  impl_->state["chunks"] = impl_->chunks.size();
  impl_->state["chunk_triangles"].push_back(triangles);
  impl_->ChangedLocked();
}

void HttpViewServer::SetBand(std::string draco, int64_t triangles, int64_t slice, bool band_only) {
  auto bytes = std::make_shared<const std::string>(std::move(draco));
  absl::MutexLock lock(&impl_->mu);
  impl_->band = std::move(bytes);
  ++impl_->band_version;
  impl_->state["band"] = json{{"version", impl_->band_version},
                              {"triangles", triangles},
                              {"slice", slice},
                              {"band_only", band_only}};
  impl_->ChangedLocked();
}

void HttpViewServer::ClearBand() {
  absl::MutexLock lock(&impl_->mu);
  impl_->band.reset();
  impl_->state["band"] = nullptr;
  impl_->ChangedLocked();
}

void HttpViewServer::AddFile(const std::string& name, std::string bytes) {
  auto shared = std::make_shared<const std::string>(std::move(bytes));
  absl::MutexLock lock(&impl_->mu);
  impl_->files[name] = std::move(shared);
  std::string format = fs::path(name).extension().string();
  if (!format.empty()) format = format.substr(1);
  for (char& c : format) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  impl_->state["files"].push_back(json{{"name", name}, {"format", format}});
  impl_->ChangedLocked();
}

void HttpViewServer::Finish(const std::string& metrics_json, const std::string& error) {
  absl::MutexLock lock(&impl_->mu);
  impl_->state["finished"] = true;
  impl_->state["error"] = error;
  if (!metrics_json.empty()) {
    impl_->state["metrics"] = json::parse(metrics_json, nullptr, /*allow_exceptions=*/false);
  }
  impl_->ChangedLocked();
}

const ViewModule kModule{kViewModuleAbi, &Start};

}  // namespace
}  // namespace tandem::viewer

// The module's only exported symbol (the rest is hidden: CXX_VISIBILITY_PRESET).
extern "C" __attribute__((visibility("default"))) const tandem::viewer::ViewModule*
tandem_view_module() {
  return &tandem::viewer::kModule;
}
