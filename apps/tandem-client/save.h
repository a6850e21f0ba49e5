// What stream and watch share after the flags: their output folders, the sealed-chunk
// callback, the Draco flags' check, and saving each surface's mesh and metrics.
#ifndef TANDEM_APPS_TANDEM_CLIENT_SAVE_H_
#define TANDEM_APPS_TANDEM_CLIENT_SAVE_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "apps/common/cli_util.h"
#include "tandem/client/chunk_store.h"
#include "tandem/client/stream_client.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/io/labels_io.h"
#include "tandem/v1/tandem.pb.h"

namespace tandem::client_app {

// Creates an output directory a flag names (--chunks, --partials).
absl::Status MakeOutputDir(const char* flag, const std::string& dir);

// The chunk callback of stream and watch: a line with --verbose; with `store` (watch
// --chunks; stream's are saved by StreamVolume) DIR/chunk_<index>.drc of session `session`,
// the first write error kept in *error.
std::function<void(const tandem::v1::SealedChunk&)> ChunkSaver(tandem::client::ChunkStore* store,
                                                               const std::string& session,
                                                               const bool& verbose,
                                                               absl::Status* error);

// How stream and watch save what they received.
struct SaveOptions {
  bool seal = false;  // the mesh came as sealed chunks
  std::string out_pattern, metrics_path;
  tandem::codec::DracoOptions draco;  // .drc re-encoding of sealed chunks; --glb-draco
  bool glb_draco = false;
  std::string input, frame_text;  // for the report (the frame itself comes with the metrics)
  std::vector<tandem::cli::IsoValue> isos;  // as the user wrote them ({iso} names), or none
  const char* wall_label = "stream wall time";
  bool quiet = false;
  // A label session: --out is a folder (label_extension the per-label files' ".ply", ...) or,
  // with label_extension empty, one .glb; the names and colours of --label-names, or null.
  std::string label_extension;
  const tandem::io::LabelNames* label_names = nullptr;
};

// Every surface of a stream or a watch: to the names `out_pattern` gives (with {iso} when
// there are several), the metrics to `metrics_path` (one file per surface with {iso}, else
// one report, or a JSON array of them in surface order). 0 or the exit status of the failure.
int SaveResult(tandem::client::StreamResult& result, const SaveOptions& o);

// A label session's surfaces, as `tandem extract --labels` writes them (tandem/io/labels_io.h:
// one file per label and labels.glb, or one .glb), and its metrics (the session's report with
// the labels' figures). 0 or the exit status of the failure.
int SaveLabels(tandem::client::StreamResult& result, const SaveOptions& o);

}  // namespace tandem::client_app

#endif  // TANDEM_APPS_TANDEM_CLIENT_SAVE_H_
