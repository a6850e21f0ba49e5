// TandemSession: extraction and simplification in lock-step (Attali, Cohen-Steiner,
// Edelsbrunner, "Extraction and Simplification of Iso-surfaces in Tandem", SGP 2005).
//
// Push model: the caller feeds slices 0, 1, ... with AddSlice and calls Finish once; the
// session does no I/O and owns no threads. Per slice k, with the paper's names:
//   classical:   EXTRACT(k)                       ... Finish: INSERT(all); SIMPLIFY(E0)
//   tandem:      EXTRACT(k); INSERT(k-1); SIMPLIFY(E0)   (the newest layer is never touched)
//   tandem-lag:  EXTRACT(k); DELAY(k); ACTIVATE(k); SIMPLIFY(E0)
//                                                  ... Finish: ACTIVATE(∞); SIMPLIFY(E0)
// `tandem` is the waiting queue keyed by layer + 1, `tandem-lag` keyed by the reach of the
// contracted vertex (simplifier.h). E0 is in the volume's physical units.
#ifndef TANDEM_TANDEM_H_
#define TANDEM_TANDEM_H_

#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/layer_extractor.h"
#include "tandem/mesh.h"
#include "tandem/mesh_store.h"
#include "tandem/simplifier.h"
#include "tandem/volume.h"

namespace tandem {

enum class Schedule : uint8_t { kNone, kClassical, kTandem, kTandemLag };
std::string_view ScheduleName(Schedule s);  // "none", "classical", "tandem", "tandem-lag"
absl::StatusOr<Schedule> ParseSchedule(std::string_view name);

struct SessionOptions {
  double iso = 0;
  Schedule schedule = Schedule::kTandemLag;  // kNone = full resolution, no simplification
  double error = 0;             // E0 (physical units); required > 0 unless kNone
  double alpha = 0;             // isotropy parameter in [0, 1]
  int64_t target_triangles = 0; // > 0: after SIMPLIFY(E0), keep contracting (beyond E0 if
                                // need be) until at most this many triangles remain
  bool pipeline = true;         // use a second thread (identical results either way):
                                // EXTRACT(k) while layer k-1 is simplified (tandem
                                // schedules), and half of every large batch of edge
                                // evaluations (DELAY, ACTIVATE)
  absl::Status Validate() const;
};

struct PhaseTimes {
  double extract_s = 0, simplify_s = 0;  // CPU-side time of each phase
  double total_s = 0;  // wall time spent inside AddSlice/Finish (< the sum when pipelined)
};

struct SessionStats {
  int64_t slices = 0;
  int64_t crossed_cubes = 0;
  int64_t triangles_extracted = 0;  // full-resolution triangle count
  int64_t peak_triangles = 0;       // most triangles held at once
  std::vector<int64_t> trace;       // triangles after every EXTRACT and every SIMPLIFY
  PhaseTimes time;
  RefusalCounts refusals;
  int64_t contractions = 0;
  double max_reach_over_front = 0;  // <= 0: no contraction's reach exceeded the front
  double max_layer_over_front = 0;  // <= -1: no contraction touched the newest layer
};

class TandemSession {
 public:
  // `grid`: nx, ny (>= 2), nz (0 if unknown), spacing, origin. Check Create's status.
  static absl::StatusOr<std::unique_ptr<TandemSession>> Create(const VolumeInfo& grid,
                                                                const SessionOptions& options);

  // Consumes the next slice (nx*ny floats): EXTRACT(k), and for the tandem schedules the
  // SIMPLIFY step of layer k-1, which is deferred to here so that it overlaps EXTRACT(k)
  // (SessionOptions::pipeline). A rejected slice leaves the mesh as it was, apart from
  // that deferred step, which the sequential order would have run already.
  absl::Status AddSlice(const float* values);
  // Same, from raw voxels of the given type in host byte order.
  absl::Status AddSliceBytes(DType dtype, const uint8_t* bytes);
  // Ends the stream: at least 2 slices (and nz if it was declared) must have been added.
  absl::Status Finish();

  // Compacted copy of the current (partial or final) mesh.
  IndexedMesh Snapshot() const { return store_.Snapshot(); }
  int64_t num_triangles() const { return static_cast<int64_t>(store_.num_triangles()); }
  const SessionStats& stats() const;
  double MaxShapeError() const;  // Error(K)
  size_t MemoryBytes() const;    // mesh store + queues + extractor caches
  const VolumeInfo& grid() const { return grid_; }
  const SessionOptions& options() const { return options_; }
  bool finished() const { return finished_; }

 private:
  TandemSession(const VolumeInfo& grid, const SessionOptions& options);
  void Record();
  bool tandem_schedule() const {
    return options_.schedule == Schedule::kTandem || options_.schedule == Schedule::kTandemLag;
  }
  // DELAY(k); ACTIVATE(k); SIMPLIFY(E0) for the last committed layer k.
  void SimplifyStep();

  VolumeInfo grid_;
  SessionOptions options_;
  MeshStore store_;
  LayerExtractor extractor_;
  Simplifier simplifier_;
  std::vector<TriId> new_tris_;
  std::vector<VertexId> new_verts_;
  std::vector<float> convert_;
  mutable SessionStats stats_;
  bool finished_ = false;
  bool simplify_pending_ = false;  // the last committed layer awaits its SIMPLIFY step
  int64_t pending_front_ = 0;
};

// Convenience: runs a whole slice source through a session (progress callback optional,
// called after every slice with (done, total)).
absl::StatusOr<std::unique_ptr<TandemSession>> RunSession(
    SliceSource& source, const SessionOptions& options,
    const std::function<void(int64_t, int64_t)>& progress = nullptr);

}  // namespace tandem

#endif  // TANDEM_TANDEM_H_
