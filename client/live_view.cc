#include "client/live_view.h"

#include <atomic>
#include <csignal>

#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "common/wire.h"
#include "tandem/report.h"

namespace tandem::client {
namespace {

std::atomic<bool> g_quit{false};
void OnQuit(int) { g_quit = true; }

}  // namespace

void LiveView::AddFlags(cli::FlagSet& flags, const std::string& listen) {
  listen_ = listen;
  flags.AddString("view", &listen_, "HOST:PORT",
                  "show the session live in a browser: serve the viewer page on this address "
                  "(e.g. 127.0.0.1:8080; port 0 = any free one)");
  if (!listen.empty()) {  // tandem-client view: the address is what it is for
    flags.AddString("listen", &listen_, "HOST:PORT", "the same as --view");
  }
  flags.AddSecret("view-token", &token_, "TOKEN", "TANDEM_VIEW_TOKEN",
                  "--view: the page and its data need ?token=TOKEN (for an address other "
                  "than loopback, which has no other protection)");
  flags.AddDouble("view-linger", &linger_s_,
                  "--view: keep the page up this many seconds after the end (default: until "
                  "Ctrl-C)");
}

absl::Status LiveView::Start(const std::string& description, int64_t nz) {
  if (!on()) return absl::OkStatus();
  viewer::ViewOptions options;
  options.listen = listen_;
  options.token = token_;
  absl::StatusOr<std::unique_ptr<viewer::ViewServer>> server = viewer::ViewServer::Start(options);
  if (!server.ok()) return server.status();
  server_ = *std::move(server);
  description_ = description;
  nz_ = nz;
  server_->SetSession("", description, nz);
  std::string host;
  int port = 0;
  if (viewer::ParseListen(listen_, &host, &port).ok() && !viewer::IsLoopback(host) &&
      token_.empty()) {
    absl::FPrintF(stderr,
                  "tandem-client: warning: the viewer on %s has no authentication: anyone who "
                  "can reach it sees the mesh (add --view-token-file FILE or "
                  "$TANDEM_VIEW_TOKEN)\n",
                  listen_);
  }
  absl::FPrintF(stderr, "tandem-client: viewer at %s\n", server_->url());
  return absl::OkStatus();
}

void LiveView::Wire(StreamCallbacks* callbacks) {
  if (!server_) return;
  viewer::ViewServer* view = server_.get();
  auto progress = callbacks->on_progress;
  callbacks->on_progress = [this, view, progress](const v1::Progress& p, int64_t sent) {
    if (!p.session_id().empty()) view->SetSession(p.session_id(), description_, nz_);
    view->SetProgress(sent, p.slices_consumed(), p.triangles(), p.sealed_triangles());
    if (progress) progress(p, sent);
  };
  auto preview = callbacks->on_preview;
  callbacks->on_preview = [view, preview](const v1::Preview& p, int64_t sent) {
    // Several surfaces: the page draws every surface's chunks, and the first one's band.
    if (p.surface() == 0) view->SetBand(p.draco(), p.triangles(), p.slice(), p.band_only());
    if (preview) preview(p, sent);
  };
  auto chunk = callbacks->on_chunk;
  callbacks->on_chunk = [view, chunk](const v1::SealedChunk& c) {
    view->AddChunk(c.draco(), c.triangles());
    if (chunk) chunk(c);
  };
}

void LiveView::Finish(const absl::StatusOr<StreamResult>& result) {
  if (!server_) return;
  if (result.ok()) {
    if (result->sealed_session) {
      server_->ClearBand();  // the chunks are the whole mesh
    } else {
      server_->SetBand(result->draco, result->triangles, result->metrics.slices(), false);
    }
    MetricsReport report = wire::ReportFromProto(result->metrics);
    server_->Finish(ReportToJson(report), "");
  } else {
    server_->Finish("", result.status().ToString());
  }
  std::signal(SIGINT, OnQuit);
  std::signal(SIGTERM, OnQuit);
  if (linger_s_ < 0) {
    absl::FPrintF(stderr, "tandem-client: the viewer stays at %s (Ctrl-C to quit)\n",
                  server_->url());
  }
  const absl::Time until =
      linger_s_ < 0 ? absl::InfiniteFuture() : absl::Now() + absl::Seconds(linger_s_);
  while (!g_quit && absl::Now() < until) absl::SleepFor(absl::Milliseconds(100));
  server_.reset();
}

}  // namespace tandem::client
