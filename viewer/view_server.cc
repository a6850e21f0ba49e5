// libtandem_view.so: the viewer's HTTP server (view_server.h), a module of its own loaded by
// ViewServer::Start (view_loader.cc), so that only a program that serves the page loads
// cpp-httplib and the OpenSSL and Brotli it links.
#include "tandem/viewer/view_server.h"

#include <httplib.h>

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <sstream>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "tandem/net/http_guard.h"

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

// Event streams hold a worker each while open; the others stay for the page's requests.
constexpr int kWorkers = 16;
constexpr int kMaxEventStreams = kWorkers - 4;

net::HttpLimits ViewLimits() {
  net::HttpLimits limits;
  limits.workers = kWorkers;
  return limits;
}

// A fresh random value, for the cookie a browser that showed the token gets.
std::string RandomHex() {
  std::random_device random;
  std::string out;
  for (int i = 0; i < 4; ++i) absl::StrAppend(&out, absl::Hex(random(), absl::kZeroPad8));
  return out;
}

// The value of cookie `name` in a Cookie header ("" when absent).
std::string CookieValue(const std::string& header, const std::string& name) {
  for (absl::string_view part : absl::StrSplit(header, ';')) {
    part = absl::StripAsciiWhitespace(part);
    if (absl::ConsumePrefix(&part, name) && absl::ConsumePrefix(&part, "=")) {
      return std::string(part);
    }
  }
  return "";
}

struct Impl {
  ViewOptions options;
  std::string assets, three, host;
  int port = 0;
  // With a token: the cookie a request that showed it gets, so that the page's scripts,
  // styles and three.js (loaded without ?token=) pass too. Named after the port (cookies
  // are per host, not per port: two viewers must not overwrite each other's); its value is
  // not the token.
  std::string cookie_value;
  net::GuardedHttpServer http{ViewLimits()};
  std::atomic<bool> stopping{false};
  std::atomic<int64_t> connections{0};
  std::atomic<int> event_streams{0};  // open now

  mutable absl::Mutex mu;
  int64_t version ABSL_GUARDED_BY(mu) = 0;
  json state ABSL_GUARDED_BY(mu);
  std::vector<std::shared_ptr<const std::string>> chunks ABSL_GUARDED_BY(mu);
  // Each surface's latest band, by the version that names it (versions count over all
  // surfaces, so that /band/V.drc needs no surface).
  struct Band {
    int64_t version = 0;
    std::shared_ptr<const std::string> bytes;
  };
  std::vector<Band> bands ABSL_GUARDED_BY(mu);
  int64_t band_version ABSL_GUARDED_BY(mu) = 0;
  std::optional<absl::Time> finishing_since ABSL_GUARDED_BY(mu);
  std::map<std::string, std::shared_ptr<const std::string>> files ABSL_GUARDED_BY(mu);

  void ChangedLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu) {
    ++version;
    state["version"] = version;
  }
  // The state as sent: the finishing time counted up to now (the page counts on from there).
  std::string DumpLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu) {
    if (finishing_since && state["finishing"].is_object()) {
      state["finishing"]["elapsed_s"] = absl::ToDoubleSeconds(absl::Now() - *finishing_since);
    }
    return state.dump();
  }
  std::string StateText() {
    absl::MutexLock lock(&mu);
    return DumpLocked();
  }
  // The slot of `surface` in the per-surface arrays, grown to hold it.
  void GrowSurfacesLocked(int surface) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu) {
    while (static_cast<int>(bands.size()) <= surface) {
      bands.emplace_back();
      state["bands"].push_back(nullptr);
    }
  }
  // Responses that never change: cached for good, by the browser only when they need the
  // token (a shared cache would hand them out without it).
  const char* Immutable() const {
    return options.token.empty() ? "public, max-age=31536000, immutable"
                                 : "private, max-age=31536000, immutable";
  }
  // The token check (every path, the page's files included): ?token=, Authorization:
  // Bearer, or the cookie.
  bool Authorized(const httplib::Request& req, httplib::Response& res) const {
    if (options.token.empty()) return true;
    const std::string cookie_name = absl::StrCat("tandem_view_", req.local_port);
    if (req.get_param_value("token") == options.token) {
      if (req.path == "/") {  // the page: what it loads next comes without the query
        res.set_header("Set-Cookie", absl::StrCat(cookie_name, "=", cookie_value,
                                                  "; Path=/; HttpOnly; SameSite=Strict"));
      }
      return true;
    }
    if (req.get_header_value("Authorization") == "Bearer " + options.token ||
        CookieValue(req.get_header_value("Cookie"), cookie_name) == cookie_value) {
      return true;
    }
    res.status = 401;
    res.set_content("this viewer needs its token (?token=... or Authorization: Bearer ...)\n",
                    "text/plain");
    return false;
  }
  void Routes();
  // A 404 that says what is missing (not with a Range header: cpp-httplib would cut the text
  // by it). The text names no more of the request than its number.
  static void NotFound(const httplib::Request& req, httplib::Response& res,
                       const std::string& text) {
    res.status = 404;
    if (req.ranges.empty()) res.set_content(text, "text/plain; charset=utf-8");
  }
};

void Impl::Routes() {
  http.set_gate([this](const httplib::Request& req, httplib::Response& res) {
    return Authorized(req, res);
  });
  auto serve_file = [this](const fs::path& path, httplib::Response& res, bool immutable) {
    std::string bytes;
    if (!ReadWhole(path, &bytes)) {
      res.status = 404;
      return;
    }
    if (immutable) res.set_header("Cache-Control", Immutable());
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
    size_t index = 0, count = 0;
    std::shared_ptr<const std::string> bytes;
    {
      absl::MutexLock lock(&mu);
      count = chunks.size();
      if (absl::SimpleAtoi(std::string(req.matches[1]), &index) && index < count) {
        bytes = chunks[index];
      }
    }
    if (!bytes) {
      NotFound(req, res,
               absl::StrCat("no chunk ", std::string(req.matches[1]), ": this session has ", count,
                            count == 1 ? " chunk" : " chunks",
                            count > 0 ? absl::StrCat(" (0 to ", count - 1, ")") : "", " so far\n"));
      return;
    }
    res.set_header("Cache-Control", Immutable());
    res.set_content(*bytes, "application/octet-stream");
  });
  http.Get(R"(/band/(\d+)\.drc)", [this](const httplib::Request& req, httplib::Response& res) {
    int64_t v = -1;
    std::shared_ptr<const std::string> bytes;
    if (absl::SimpleAtoi(std::string(req.matches[1]), &v)) {
      absl::MutexLock lock(&mu);
      for (const Band& band : bands) {
        if (band.bytes && band.version == v) bytes = band.bytes;
      }
    }
    if (!bytes) {
      NotFound(req, res,
               absl::StrCat("no band version ", std::string(req.matches[1]),
                            ": superseded or never made (state.json names the current ones)\n"));
      return;
    }
    res.set_header("Cache-Control", Immutable());
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
      NotFound(req, res, "no such file here (state.json lists the files)\n");
      return;
    }
    res.set_content(*bytes, ContentType(std::string(req.matches[1])));
  });
  http.Get("/events", [this](const httplib::Request&, httplib::Response& res) {
    if (event_streams.fetch_add(1) >= kMaxEventStreams) {
      event_streams.fetch_sub(1);
      res.status = 503;
      res.set_header("Retry-After", "5");
      res.set_content("too many viewer pages are open at once\n", "text/plain");
      return;
    }
    connections.fetch_add(1);
    res.set_header("Cache-Control", "no-store");
    auto sent = std::make_shared<int64_t>(-1);
    res.set_chunked_content_provider(
        "text/event-stream", [this, sent](size_t, httplib::DataSink& sink) {
          // One event per call: the state when it changed, or a comment every 15 s (keeps
          // proxies from closing an idle stream). A page that left is noticed within a
          // second (is_writable turns false), so that its worker is free again.
          const absl::Time keep_alive = absl::Now() + absl::Seconds(15);
          std::string text;
          while (text.empty()) {
            {
              absl::MutexLock lock(&mu);
              auto changed = [this, sent]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu) {
                return version != *sent || stopping.load();
              };
              mu.AwaitWithTimeout(absl::Condition(&changed), absl::Seconds(1));
              if (stopping.load()) return false;
              if (version != *sent) {
                *sent = version;
                text = absl::StrCat("data: ", DumpLocked(), "\n\n");
              }
            }
            if (text.empty() && !sink.is_writable()) return false;
            if (text.empty() && absl::Now() >= keep_alive) text = ": keep-alive\n\n";
          }
          return sink.write(text.data(), text.size());
        },
        [this](bool) { event_streams.fetch_sub(1); });
  });
}

// The server (view_server.h), behind the interface the programs see.
class HttpViewServer final : public ViewServer {
 public:
  explicit HttpViewServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
  ~HttpViewServer() override;
  std::string url() const override;
  void SetSession(const std::string& id, const std::string& description, int64_t nz) override;
  void SetSurfaces(const std::vector<std::string>& labels,
                   const std::vector<std::string>& colors) override;
  void SetProgress(const ViewProgress& progress) override;
  void AddChunk(std::string draco, int64_t triangles, int surface) override;
  void SetBand(int surface, std::string draco, int64_t triangles, int64_t slice,
               bool band_only) override;
  void ClearBands() override;
  void SetFinishing(int64_t triangles_held, double estimate_s) override;
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
    impl->state = json{{"version", 0},
                       {"session", ""},
                       {"description", ""},
                       {"nz", 0},
                       {"slices_sent", 0},
                       {"slices_meshed", 0},
                       {"slices_on_disk", -1},
                       {"triangles_held", 0},
                       {"triangles_sealed", 0},
                       {"surfaces", json::array()},
                       {"chunks", 0},
                       {"chunk_triangles", json::array()},
                       {"chunk_surfaces", json::array()},
                       {"bands", json::array()},
                       {"files", json::array()},
                       {"finishing", nullptr},
                       {"finished", false},
                       {"error", ""},
                       {"metrics", nullptr}};
  }
  impl->cookie_value = RandomHex();
  impl->Routes();
  absl::StatusOr<int> port = impl->http.Start(impl->host, impl->port);
  if (!port.ok()) {
    return absl::UnavailableError(absl::StrCat("the viewer ", port.status().message(),
                                               "; choose another with --view HOST:PORT"));
  }
  impl->port = *port;
  return std::unique_ptr<ViewServer>(new HttpViewServer(std::move(impl)));
}

HttpViewServer::~HttpViewServer() {
  impl_->stopping = true;
  {
    absl::MutexLock lock(&impl_->mu);  // wakes the event streams
    impl_->ChangedLocked();
  }
  impl_->http.Stop();
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

void HttpViewServer::SetSurfaces(const std::vector<std::string>& labels,
                                 const std::vector<std::string>& colors) {
  absl::MutexLock lock(&impl_->mu);
  json surfaces = json::array();
  for (size_t i = 0; i < labels.size(); ++i) {
    json s{{"label", labels[i]}};
    if (i < colors.size()) s["color"] = colors[i];
    surfaces.push_back(std::move(s));
  }
  impl_->state["surfaces"] = std::move(surfaces);
  if (!labels.empty()) impl_->GrowSurfacesLocked(static_cast<int>(labels.size()) - 1);
  impl_->ChangedLocked();
}

void HttpViewServer::SetProgress(const ViewProgress& p) {
  absl::MutexLock lock(&impl_->mu);
  json& s = impl_->state;
  s["slices_sent"] = p.slices_sent;
  s["slices_meshed"] = p.slices_meshed;
  s["slices_on_disk"] = p.slices_on_disk;
  s["triangles_held"] = p.triangles_held;
  s["triangles_sealed"] = p.triangles_sealed;
  impl_->ChangedLocked();
}

void HttpViewServer::AddChunk(std::string draco, int64_t triangles, int surface) {
  auto bytes = std::make_shared<const std::string>(std::move(draco));
  surface = std::max(surface, 0);
  absl::MutexLock lock(&impl_->mu);
  impl_->GrowSurfacesLocked(surface);
  impl_->chunks.push_back(std::move(bytes));
  impl_->state["chunks"] = impl_->chunks.size();
  impl_->state["chunk_triangles"].push_back(triangles);
  impl_->state["chunk_surfaces"].push_back(surface);
  impl_->ChangedLocked();
}

void HttpViewServer::SetBand(int surface, std::string draco, int64_t triangles, int64_t slice,
                             bool band_only) {
  auto bytes = std::make_shared<const std::string>(std::move(draco));
  surface = std::max(surface, 0);
  absl::MutexLock lock(&impl_->mu);
  impl_->GrowSurfacesLocked(surface);
  Impl::Band& band = impl_->bands[surface];
  band.bytes = std::move(bytes);
  band.version = ++impl_->band_version;
  impl_->state["bands"][surface] = json{{"version", band.version},
                                        {"triangles", triangles},
                                        {"slice", slice},
                                        {"band_only", band_only}};
  impl_->ChangedLocked();
}

void HttpViewServer::ClearBands() {
  absl::MutexLock lock(&impl_->mu);
  for (size_t i = 0; i < impl_->bands.size(); ++i) {
    impl_->bands[i] = Impl::Band();
    impl_->state["bands"][i] = nullptr;
  }
  impl_->ChangedLocked();
}

void HttpViewServer::SetFinishing(int64_t triangles_held, double estimate_s) {
  absl::MutexLock lock(&impl_->mu);
  impl_->finishing_since = absl::Now();
  impl_->state["finishing"] =
      json{{"triangles", triangles_held}, {"estimate_s", estimate_s}, {"elapsed_s", 0.0}};
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
  if (impl_->finishing_since) {  // the time it took, frozen
    impl_->state["finishing"]["elapsed_s"] =
        absl::ToDoubleSeconds(absl::Now() - *impl_->finishing_since);
    impl_->finishing_since.reset();
  }
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
