// The live browser viewer's HTTP side: a small cpp-httplib server that serves the page
// (viewer/web), three.js and its Draco decoder (from the npm install, node_modules/three),
// and what a session has produced so far, as immutable resources plus one event stream:
//   GET /                  the page (index.html, viewer.js, viewer.css)
//   GET /three/...         three.js (build/ and examples/jsm/ only)
//   GET /state.json        the state below, now
//   GET /events            server-sent events: the state again each time it changes
//   GET /chunk/N.drc       sealed chunk N (Draco; never changes: cached for good)
//   GET /band/V.drc        a surface's unsealed band (or its whole partial or final mesh),
//                          version V (versions count over all surfaces)
//   GET /file/NAME         a finished mesh file (tandem view FILE)
// State (JSON): {version, session, description, nz, slices_sent, slices_meshed,
// slices_on_disk, triangles_held, triangles_sealed, surfaces [{label}], chunks,
// chunk_triangles [], chunk_surfaces [], bands [per surface: null or {version, triangles,
// slice, band_only}], files [{name, format}], finishing (null or {triangles, estimate_s,
// elapsed_s}), finished, error, metrics (an object, or one per surface)}.
// A page that reloads, or a browser that connects late, reads the state and fetches every
// chunk by index: nothing is pushed but the small state. No gRPC, Protobuf or Draco here:
// the bytes are served as they came, the browser decodes them.
// With a token (--view-token-file, $TANDEM_VIEW_TOKEN), every request, the page's own files
// included, needs `Authorization: Bearer TOKEN`, `?token=TOKEN` (EventSource cannot set
// headers; the page forwards its own URL's token) or the cookie the page got with it (for
// the scripts, styles and three.js it loads). The HTTP rules of tandem/net/http_guard.h apply:
// GET/HEAD only, no request body, one range, the Host header checked, slow clients cut off.
#ifndef TANDEM_VIEWER_VIEW_SERVER_H_
#define TANDEM_VIEWER_VIEW_SERVER_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace tandem::viewer {

struct ViewOptions {
  std::string listen = "127.0.0.1:8080";  // HOST:PORT (port 0: any free port)
  std::string token;                      // "" = no check
  // Where the page and three.js are (empty: next to the binary, then the source tree).
  std::string assets_dir, three_dir;
};

// Where the page's files are found: `dir`, else share/tandem/viewer next to the running
// binary (installed), else the source tree. Same for three.js (node_modules/three).
std::string FindAssets(const std::string& dir);
std::string FindThree(const std::string& dir);

// "127.0.0.1:8080" → host and port; an error names the text.
absl::Status ParseListen(const std::string& listen, std::string* host, int* port);
// True for 127.0.0.0/8, ::1 and "localhost".
bool IsLoopback(const std::string& host);

// The server lives in a module of its own, libtandem_view.so (view_server.cc), loaded by
// Start: cpp-httplib links OpenSSL and Brotli, whose loading would cost every start of the
// CLI and the client, viewer or not (docs/decisions.md 43). The programs see only this
// interface.
// Where the scan is (ViewServer::SetProgress).
struct ViewProgress {
  int64_t slices_sent = 0, slices_meshed = 0;
  int64_t slices_on_disk = -1;  // following a scan of unknown depth: slices seen so far
  int64_t triangles_held = 0, triangles_sealed = 0;
};

class ViewServer {
 public:
  // Loads the module (the first time), binds (an error names the address: "the viewer
  // cannot listen on 127.0.0.1:8080: port 8080 is in use by another process; ...") and
  // serves on threads of its own until destroyed. Without the module, FailedPrecondition
  // naming the places searched.
  static absl::StatusOr<std::unique_ptr<ViewServer>> Start(const ViewOptions& options);
  virtual ~ViewServer() = default;
  virtual std::string url() const = 0;  // http://HOST:PORT/ (with ?token= when one is set)

  // What the page shows; any thread. `surface` counts from 0 (the first --iso).
  virtual void SetSession(const std::string& id, const std::string& description, int64_t nz) = 0;
  // One label per surface ("iso 500"), in surface order; none = one unnamed surface.
  // `colors`: none (the page's palette), or a CSS colour ("#rrggbb") per surface, the one it
  // is drawn in (a label session's labels).
  virtual void SetSurfaces(const std::vector<std::string>& labels,
                           const std::vector<std::string>& colors = {}) = 0;
  virtual void SetProgress(const ViewProgress& progress) = 0;
  virtual void AddChunk(std::string draco, int64_t triangles, int surface) = 0;
  // A surface's unsealed band (band_only) or its whole partial (or final) mesh.
  virtual void SetBand(int surface, std::string draco, int64_t triangles, int64_t slice,
                       bool band_only) = 0;
  virtual void ClearBands() = 0;
  // Every slice is in: the session simplifies and encodes what it holds, for about
  // estimate_s seconds (elapsed_s in the state counts from this call).
  virtual void SetFinishing(int64_t triangles_held, double estimate_s) = 0;
  // A finished mesh file, served as /file/NAME (its format from the extension).
  virtual void AddFile(const std::string& name, std::string bytes) = 0;
  // The end: metrics as a JSON text, an object or an array of one per surface ("" = none),
  // or an error message.
  virtual void Finish(const std::string& metrics_json, const std::string& error) = 0;

  virtual int64_t connections() const = 0;  // event streams opened so far (tests and logs)
};

// The module's table (view_server.cc; view_loader.cc loads it).
inline constexpr int kViewModuleAbi = 3;
struct ViewModule {
  int abi;
  absl::StatusOr<std::unique_ptr<ViewServer>> (*start)(const ViewOptions& options);
};
extern "C" using ViewModuleEntry = const ViewModule * ();
inline constexpr const char kViewModuleEntryName[] = "tandem_view_module";
inline constexpr const char kViewModuleName[] = "libtandem_view.so";

}  // namespace tandem::viewer

#endif  // TANDEM_VIEWER_VIEW_SERVER_H_
