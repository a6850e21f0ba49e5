// --view for tandem-client stream and watch: the live browser viewer (tandem/viewer/view_server.h)
// fed from the stream's callbacks, kept up after the end until Ctrl-C (or --view-linger).
// The page always has the growing mesh to draw: every surface's sealed chunks and band, or
// (unsealed) the whole partial meshes the previews bring, then the final meshes; the
// progress follows the slices meshed, then a finishing state from the last slice to the end.
#ifndef TANDEM_APPS_TANDEM_CLIENT_LIVE_VIEW_H_
#define TANDEM_APPS_TANDEM_CLIENT_LIVE_VIEW_H_

#include <atomic>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "apps/common/flags.h"
#include "tandem/client/stream_client.h"
#include "tandem/io/labels_io.h"
#include "tandem/viewer/view_server.h"
#include "tandem/volume.h"

namespace tandem::client {

// The preview cadence --view asks for when the user set none: a preview at every slice, at
// most one per this many milliseconds (the server bounds their share of the time as well).
inline constexpr int64_t kViewPreviewMs = 500;

// Seconds the end of a stream is expected to take after its last slice, for
// `triangles_held` triangles to simplify, encode, send, decode and write: a rough figure
// for the page's finishing state.
double FinishingEstimateSeconds(int64_t triangles_held);

class LiveView {
 public:
  // --view ADDR, --view-token (or --view-token-file, $TANDEM_VIEW_TOKEN), --view-linger.
  // `listen`: the default address ("" = off; when set, --listen is accepted as another name
  // of --view).
  void AddFlags(cli::FlagSet& flags, const std::string& listen = "");
  bool on() const { return !listen_.empty(); }
  // Starts serving (when on) and prints the address on stderr, with a warning when it is
  // not loopback and has no token. The error names the address (a busy port). `nz`: the
  // slices expected, 0 = unknown.
  absl::Status Start(const std::string& description, int64_t nz);
  // The surfaces' iso-values as the user wrote them, for the page's legend and table.
  void SetIsos(const std::vector<std::string>& isos);
  // A label session: each label is a surface of the page's, in a colour of its own (the
  // table's, with `names`; else LabelColor's hue, in the order the labels first showed), the
  // previews cut by label, and the final table has a row per label. `names` (or null) must
  // outlive the view.
  void SetLabels(const io::LabelNames* names);
  // A watcher: the names of the labels, should the session turn out to be a label session
  // (its messages say so: then as SetLabels).
  void SetLabelNames(const io::LabelNames* names) { label_names_ = names; }
  // Following a scan of unknown depth: the slices on disk so far, the progress's measure.
  void SetOnDisk(const std::atomic<int64_t>* on_disk) { on_disk_ = on_disk; }
  // The source to stream from: `source`, watched for its end (a scan of unknown depth is
  // over when it says so), so that the page can tell "finishing" from "waiting for slices".
  SliceSource* Track(SliceSource* source);
  // Publishes what `callbacks` receive to the page as well (call after setting them).
  void Wire(StreamCallbacks* callbacks);
  // Publishes the end (every surface's final mesh of an unsealed stream, the metrics, or the
  // error), then keeps the page up for --view-linger seconds (default: until SIGINT /
  // SIGTERM).
  void Finish(const absl::StatusOr<StreamResult>& result);

 private:
  class EndTracker;
  void SourceEnded(int64_t slices);
  // Enters the finishing state once every slice is in and consumed (once).
  void MaybeFinishingLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Label sessions (on the stream's thread): the page's surface of label `id` (a new one is
  // added, published by PublishLabels), and a preview cut into one band per label.
  int SurfaceOfLabel(LabelId id);
  void PublishLabels();
  void ShowLabelPreview(const v1::Preview& preview);
  // A chunk of label pairs: each label's part on that label's surface.
  void ShowLabelChunk(const v1::SealedChunk& chunk);

  std::string listen_, token_;
  double linger_s_ = -1;
  std::string description_;
  int64_t nz_ = 0;
  const std::atomic<int64_t>* on_disk_ = nullptr;
  std::unique_ptr<viewer::ViewServer> server_;
  std::unique_ptr<SliceSource> tracker_;
  bool labeled_ = false;  // the surfaces have their labels (a watcher's come with the metrics)
  std::string session_id_;
  bool label_session_ = false;
  const io::LabelNames* label_names_ = nullptr;
  std::map<LabelId, int> label_surface_;
  std::vector<LabelId> label_order_;  // by surface
  size_t labels_published_ = 0;

  absl::Mutex mu_;
  int64_t slices_total_ ABSL_GUARDED_BY(mu_) = -1;  // the source's end, once reached
  int64_t consumed_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t expected_ ABSL_GUARDED_BY(mu_) = 0;  // the session's depth (watch: from Progress)
  int64_t held_ ABSL_GUARDED_BY(mu_) = 0;
  bool finishing_ ABSL_GUARDED_BY(mu_) = false;
};

}  // namespace tandem::client

#endif  // TANDEM_APPS_TANDEM_CLIENT_LIVE_VIEW_H_
