#include "live_view.h"

#include <array>
#include <atomic>
#include <csignal>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/common/wire.h"
#include "tandem/eval/label_metrics.h"
#include "tandem/eval/report.h"
#include "tandem/labels.h"
#include "tandem/status_macros.h"

namespace tandem::client {
namespace {

std::atomic<bool> g_quit{false};
void OnQuit(int) { g_quit = true; }

}  // namespace

double FinishingEstimateSeconds(int64_t triangles_held) {
  // The finishing pass, the sag correction, the encoding and the client's decoding and
  // writing each take about a microsecond a triangle held on one core, plus a fixed part.
  return 0.05 + 3e-6 * static_cast<double>(triangles_held);
}

// The stream's source, watched for its end (OutOfRange): a scan of unknown depth says only
// there that it is over.
class LiveView::EndTracker final : public SliceSource {
 public:
  EndTracker(SliceSource* inner, LiveView* view) : inner_(inner), view_(view) {}
  const VolumeInfo& info() const override { return inner_->info(); }
  int64_t next_slice() const override { return inner_->next_slice(); }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    return Noted(inner_->ReadSlice(bytes));
  }
  absl::Status ViewSlice(const uint8_t** data) override { return Noted(inner_->ViewSlice(data)); }

 private:
  absl::Status Noted(absl::Status st) {
    if (absl::IsOutOfRange(st)) view_->SourceEnded(inner_->next_slice());
    return st;
  }
  SliceSource* inner_;
  LiveView* view_;
};

void LiveView::AddFlags(cli::FlagSet& flags, const std::string& listen) {
  listen_ = listen;
  flags.AddString("view", &listen_, "HOST:PORT",
                  "show the session live in a browser: serve the viewer page on this address "
                  "(e.g. 127.0.0.1:8080; port 0 = any free one); the page draws the mesh as it "
                  "grows (sealed chunks and band, or the previews), then the final mesh");
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
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<viewer::ViewServer> server,
                          viewer::ViewServer::Start(options));
  server_ = std::move(server);
  description_ = description;
  nz_ = nz;
  {
    absl::MutexLock lock(&mu_);
    expected_ = nz;
  }
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

void LiveView::SetIsos(const std::vector<std::string>& isos) {
  if (!server_) return;
  std::vector<std::string> labels;
  for (const std::string& iso : isos) labels.push_back(absl::StrCat("iso ", iso));
  server_->SetSurfaces(labels);
  labeled_ = true;
}

void LiveView::SetLabels(const io::LabelNames* names) {
  label_session_ = true;
  label_names_ = names;
  labeled_ = true;
}

int LiveView::SurfaceOfLabel(LabelId id) {
  auto [it, added] = label_surface_.try_emplace(id, static_cast<int>(label_order_.size()));
  if (added) label_order_.push_back(id);
  return it->second;
}

void LiveView::PublishLabels() {
  if (labels_published_ == label_order_.size()) return;
  labels_published_ = label_order_.size();
  std::vector<std::string> names, colors;
  for (size_t k = 0; k < label_order_.size(); ++k) {
    const LabelId id = label_order_[k];
    std::string name = absl::StrCat("label ", id);
    if (label_names_ != nullptr) {
      if (auto it = label_names_->find(id); it != label_names_->end()) {
        name = absl::StrCat(it->second.name, " (", id, ")");
      }
    }
    names.push_back(std::move(name));
    const std::array<uint8_t, 4> c = io::LabelColor(id, k, label_names_);
    colors.push_back(absl::StrFormat("#%02x%02x%02x", c[0], c[1], c[2]));
  }
  server_->SetSurfaces(names, colors);
}

void LiveView::ShowLabelPreview(const v1::Preview& p) {
  std::vector<uint32_t> group;
  absl::StatusOr<IndexedMesh> mesh = codec::DecodeDraco(p.draco(), &group);
  if (!mesh.ok() || group.size() != mesh->positions.size()) return;  // best effort
  const auto n = static_cast<uint32_t>(p.labels_size());
  std::vector<IndexedMesh> parts(n);
  std::vector<uint32_t> local(mesh->positions.size());
  for (size_t v = 0; v < group.size(); ++v) {
    if (group[v] >= n) continue;
    local[v] = static_cast<uint32_t>(parts[group[v]].positions.size());
    parts[group[v]].positions.push_back(mesh->positions[v]);
  }
  for (size_t k = 0; k + 2 < mesh->indices.size(); k += 3) {
    const uint32_t* t = &mesh->indices[k];
    const uint32_t g = group[t[0]];
    if (g >= n || group[t[1]] != g || group[t[2]] != g) continue;
    for (int c = 0; c < 3; ++c) parts[g].indices.push_back(local[t[c]]);
  }
  codec::DracoOptions fast;
  fast.compression_level = 0;  // the page decodes it at once; size matters little on loopback
  for (uint32_t g = 0; g < n; ++g) {
    absl::StatusOr<std::string> bytes = codec::EncodeDraco(parts[g], fast);
    if (!bytes.ok()) continue;
    server_->SetBand(SurfaceOfLabel(p.labels(static_cast<int>(g))), *std::move(bytes),
                     static_cast<int64_t>(parts[g].num_triangles()), p.slice(), false);
  }
  PublishLabels();
}

void LiveView::ShowLabelChunk(const v1::SealedChunk& c) {
  SealedChunk chunk;
  LabelId background = 0;
  absl::StatusOr<IndexedMesh> mesh = codec::DecodeDraco(c.draco(), &chunk.ids);
  if (!mesh.ok() ||
      !common::LabelPairsFromProto(c.label_pairs(), mesh->num_triangles(), &chunk, &background)
           .ok()) {
    return;  // the stream reports it
  }
  chunk.positions = std::move(mesh->positions);
  chunk.indices = std::move(mesh->indices);
  codec::DracoOptions fast;
  fast.compression_level = 0;  // the page decodes it at once; size matters little on loopback
  for (const auto& [label, part] : SplitLabeledChunk(chunk, background)) {
    IndexedMesh one;
    one.positions = part.positions;
    one.indices = part.indices;
    absl::StatusOr<std::string> bytes = codec::EncodeDraco(one, fast, part.ids);
    if (!bytes.ok()) continue;
    server_->AddChunk(*std::move(bytes), static_cast<int64_t>(part.num_triangles()),
                      SurfaceOfLabel(label));
  }
  PublishLabels();
}

SliceSource* LiveView::Track(SliceSource* source) {
  if (!server_) return source;
  tracker_ = std::make_unique<EndTracker>(source, this);
  return tracker_.get();
}

void LiveView::SourceEnded(int64_t slices) {
  absl::MutexLock lock(&mu_);
  slices_total_ = slices;
  MaybeFinishingLocked();
}

void LiveView::MaybeFinishingLocked() {
  if (finishing_ || !server_) return;
  const int64_t total = expected_ > 0 ? expected_ : slices_total_;
  if (total < 0 || consumed_ < total) return;
  finishing_ = true;
  server_->SetFinishing(held_, FinishingEstimateSeconds(held_));
}

void LiveView::Wire(StreamCallbacks* callbacks) {
  if (!server_) return;
  viewer::ViewServer* view = server_.get();
  auto progress = callbacks->on_progress;
  callbacks->on_progress = [this, view, progress](const v1::Progress& p, int64_t sent) {
    if (p.labels()) SetLabels(label_names_);  // a watcher learns it so
    if (!p.session_id().empty()) {
      session_id_ = p.session_id();
      view->SetSession(session_id_, description_, nz_);
    }
    viewer::ViewProgress shown;
    shown.slices_sent = sent;
    shown.slices_meshed = p.slices_consumed();
    shown.triangles_held = p.triangles();
    shown.triangles_sealed = p.sealed_triangles();
    if (on_disk_ != nullptr && nz_ == 0) shown.slices_on_disk = on_disk_->load();
    {
      absl::MutexLock lock(&mu_);
      if (nz_ == 0 && p.slices_expected() > 0 && expected_ != p.slices_expected()) {
        expected_ = p.slices_expected();  // a watcher learns the depth from the session
        view->SetSession(session_id_, description_, expected_);
      }
      consumed_ = p.slices_consumed();
      held_ = p.triangles();
      view->SetProgress(shown);
      MaybeFinishingLocked();
    }
    if (progress) progress(p, sent);
  };
  auto preview = callbacks->on_preview;
  callbacks->on_preview = [this, view, preview](const v1::Preview& p, int64_t sent) {
    if (label_session_ || p.labels_size() > 0) {
      ShowLabelPreview(p);
    } else {
      view->SetBand(p.surface(), p.draco(), p.triangles(), p.slice(), p.band_only());
    }
    if (preview) preview(p, sent);
  };
  auto chunk = callbacks->on_chunk;
  callbacks->on_chunk = [this, view, chunk](const v1::SealedChunk& c) {
    // A label's chunks say their label, not their surface (known at End only).
    if (c.has_label_pairs()) {
      ShowLabelChunk(c);
    } else if (c.has_label()) {
      view->AddChunk(c.draco(), c.triangles(), SurfaceOfLabel(c.label()));
      PublishLabels();
    } else {
      view->AddChunk(c.draco(), c.triangles(), c.surface());
    }
    if (chunk) chunk(c);
  };
}

void LiveView::Finish(const absl::StatusOr<StreamResult>& result) {
  if (!server_) return;
  if (result.ok() && (label_session_ || result->labels)) {
    // Each label's final mesh on its surface, and a row of figures per label.
    std::vector<eval::LabelMetrics> rows;
    for (size_t i = 0; i < result->num_labels(); ++i) {
      const SurfaceResult& surface = result->surface(i);
      const int k = SurfaceOfLabel(surface.metrics.label());
      if (!result->sealed_session) {  // sealed, the chunks are the whole mesh
        server_->SetBand(k, surface.draco, surface.triangles, result->session_metrics.slices(),
                         false);
      }
      if (rows.size() <= static_cast<size_t>(k)) rows.resize(static_cast<size_t>(k) + 1);
      rows[static_cast<size_t>(k)] = common::LabelMetricsFromProto(surface.metrics);
      if (label_names_ != nullptr) {
        if (auto it = label_names_->find(surface.metrics.label()); it != label_names_->end()) {
          rows[static_cast<size_t>(k)].name = it->second.name;
        }
      }
    }
    for (size_t k = 0; k < label_order_.size(); ++k) {  // shown live, gone at the end
      if (k >= rows.size() || rows[k].label != label_order_[k]) {
        if (rows.size() <= k) rows.resize(k + 1);
        rows[k].label = label_order_[k];
        server_->SetBand(static_cast<int>(k), codec::EncodeDraco(IndexedMesh{}).value_or(""), 0,
                         result->session_metrics.slices(), false);
      }
    }
    if (result->sealed_session) server_->ClearBands();
    PublishLabels();
    server_->Finish(eval::LabelMetricsToJson(rows), "");
  } else if (result.ok()) {
    std::vector<std::string> labels;
    std::string metrics = "[";
    for (size_t i = 0; i < result->num_surfaces(); ++i) {
      const SurfaceResult& surface = result->surface(i);
      labels.push_back(absl::StrCat("iso ", absl::StrFormat("%g", surface.metrics.iso())));
      if (!result->sealed_session) {  // the final mesh, whole
        server_->SetBand(static_cast<int>(i), surface.draco, surface.triangles,
                         surface.metrics.slices(), false);
      }
      absl::StrAppend(&metrics, i == 0 ? "" : ",",
                      eval::ReportToJson(common::ReportFromProto(surface.metrics)));
    }
    absl::StrAppend(&metrics, "]");
    if (result->sealed_session) server_->ClearBands();  // the chunks are the whole mesh
    if (!labeled_) server_->SetSurfaces(labels);
    server_->Finish(result->num_surfaces() == 1
                        ? eval::ReportToJson(common::ReportFromProto(result->metrics))
                        : metrics,
                    "");
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
