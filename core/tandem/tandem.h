// TandemSession: extraction and simplification in lock-step (Attali, Cohen-Steiner,
// Edelsbrunner, "Extraction and Simplification of Iso-surfaces in Tandem", SGP 2005).
//
// Push model: the caller feeds slices 0, 1, ... with AddSlice and calls Finish once; the
// session does no I/O. Per slice k, with the paper's names:
//   classical:   EXTRACT(k)                       ... Finish: INSERT(all); SIMPLIFY(E0)
//   tandem:      EXTRACT(k); INSERT(k-1); SIMPLIFY(E0)   (the newest layer is never touched)
//   tandem-lag:  EXTRACT(k); DELAY(k); ACTIVATE(k); SIMPLIFY(E0)
//                                                  ... Finish: ACTIVATE(∞); SIMPLIFY(E0)
// `tandem` is the waiting queue keyed by layer + 1, `tandem-lag` keyed by the reach of the
// contracted vertex (simplifier.h). E0 is in the volume's physical units.
//
// Parts: the grid can be split along x into slabs ("parts", SessionOptions::parts), each with
// its own extractor, mesh store and queues, run side by side (by a pool of worker threads
// when pipelined: AddSlice then queues the slice and returns). The vertices on the grid
// edges of a plane between two parts belong to both (kSeam) and are never contracted while
// the stream lasts, so every contraction inside a
// part is exactly a contraction of the whole mesh (same stars, same link condition). Finish
// merges the parts, welds the seam copies (their quadrics add up to the whole one) and runs
// SIMPLIFY(E0) once more from the edges at the seam. The split is part of the result (a run
// with parts = 1 is the paper's algorithm, nothing deferred); threads are not: a pipelined
// and a sequential run give identical meshes.
#ifndef TANDEM_TANDEM_H_
#define TANDEM_TANDEM_H_

#include <array>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "layer_extractor.h"
#include "tandem/mesh.h"
#include "tandem/options.h"
#include "tandem/stats.h"
#include "mesh_store.h"
#include "sealer.h"
#include "simplifier.h"
#include "tandem/volume.h"

namespace tandem {

// Coordinates: the engine (extractor, mesh store, quadrics, queues) works in a frame of its
// own, relative to the grid: voxel (i, j, k) at (i*sx, j*sy, k*sz) / s, with s the power of
// two nearest below the smallest spacing. The origin drops out (a scan placed at 1e9 mm
// simplifies exactly as one at 0) and so does the unit (spacing 1e-300 or 1e12 behaves as
// spacing 1), while the scaling by a power of two is exact, so a grid with origin 0 gives
// bit for bit the mesh it gave in world coordinates. Snapshot() and MaxShapeError() answer
// in world coordinates.
//
// Failures: no input ends the process. Every exception thrown inside a session (an
// allocation that fails, on any of its threads) becomes the status of the call that ran
// into it (RESOURCE_EXHAUSTED for memory, INTERNAL otherwise), and every later AddSlice or
// Finish returns the same status: the session is then unusable, the process is fine.
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

  // Compacted copy of the current (partial or final) mesh, in world coordinates; with
  // sealing, of the part not sealed yet (empty after Finish).
  IndexedMesh Snapshot() const;  // the parts' meshes welded at their seams
  // Sealing: moves everything sealed since the last call into one chunk, in world
  // coordinates (false: nothing new). Finish seals the rest.
  bool TakeSealed(SealedChunk* out);
  int64_t sealed_pending() const;  // triangles TakeSealed would hand out now
  int64_t num_triangles() const;  // held by the session (with sealing: not sealed yet)
  int num_parts() const { return static_cast<int>(parts_.size()); }  // after Finish: 1
  const SessionStats& stats() const;
  double MaxShapeError() const;  // Error(K), in world units
  size_t MemoryBytes() const;    // mesh store + queues + extractor caches
  const VolumeInfo& grid() const { return grid_; }
  const SessionOptions& options() const { return options_; }
  bool finished() const { return finished_; }

 private:
  // One slab of the grid: columns x0 .. x0 + nx - 1 of the whole grid (neighbours share the
  // boundary column).
  struct Part {
    Part(const ExtractorConfig& ec, const SimplifierOptions& so)
        : extractor(ec, &store), simplifier(&store, so) {}
    MeshStore store;
    LayerExtractor extractor;
    Simplifier simplifier;
    std::unique_ptr<Sealer> sealer;  // SessionOptions::seal
    int64_t x0 = 0;
    size_t index = 0;  // in parts_
    std::vector<TriId> new_tris;
    std::vector<VertexId> new_verts;
    std::array<std::vector<VertexId>, 2> seam_log;  // not yet paired, in order, per seam face
    std::vector<int64_t> trace;                     // this part's triangles, per step
    PhaseTimes time;
    int64_t triangles_extracted = 0;
    bool simplify_pending = false;  // the last committed layer awaits its SIMPLIFY step
    int64_t pending_front = 0;
    // Pipelined split sessions, guarded by mu_: slices (indices into ring_) waiting for
    // this part, whether a worker is on it, and how many it has done.
    std::deque<int> queue;
    bool busy = false;
    int64_t steps = 0;
    absl::Status error;  // the first failure of a queued step (none expected)
  };
  // A slice shared by the parts' queues, free again when no part still needs it.
  struct RingSlot {
    std::vector<float> values;
    int pending = 0;  // parts that have not finished with it
  };
  static constexpr int kRingSlots = 4;  // slices in flight, at most

  TandemSession(const VolumeInfo& grid, const SessionOptions& options, int parts);
 public:
  ~TandemSession();
  TandemSession(const TandemSession&) = delete;
  TandemSession& operator=(const TandemSession&) = delete;

 private:
  void Record();
  // Runs f (AddSlice's or Finish's body) behind the session's barrier: an exception becomes
  // failed_, returned now and by every later call.
  template <typename F>
  absl::Status Guarded(F&& f);
  // AddSlice (values) and AddSliceBytes (dtype, bytes: converted straight into the ring).
  absl::Status AddSliceImpl(const float* values, DType dtype, const uint8_t* bytes);
  absl::Status FinishImpl();
  void AppendPartSnapshots(IndexedMesh* out) const;  // Snapshot of a split session
  // Engine frame -> world, in place (a mirrored frame also reverses the triangles' winding).
  void ToWorld(std::vector<Vec3>* positions, std::vector<uint32_t>* indices) const;
  bool tandem_schedule() const {
    return options_.schedule == Schedule::kTandem || options_.schedule == Schedule::kTandemLag;
  }
  // Runs f(part) for every part: on one thread each when pipelined, else in order.
  void ForEachPart(const std::function<void(Part&)>& f);
  // Pipelined split sessions: slices go through ring_ to the parts' queues; a pool of
  // workers (one per core, at most one per part) takes the next step of whichever idle part
  // is furthest behind, so a part whose slab holds most of the surface for a while gets the
  // cores while the others wait. A part's steps run in order, one at a time, so the result
  // does not depend on the number of workers. Sync waits until every queued slice is done,
  // then pairs the new seam vertices and folds the traces (it only fills caches: const
  // callers may use it).
  void StartWorkers();
  void Work(size_t worker);
  // mu_ held; nullptr when no part can step now. Each worker has home parts (index %
  // workers == worker), whose data stay in its core's caches; it takes another's only
  // when none of its own can step.
  Part* NextPart(size_t worker) const;
  void StopWorkers();
  absl::Status Sync() const;
  void SimplifyStep(Part& p);
  absl::Status PartStep(Part& p, const float* values);  // SIMPLIFY(k-1), EXTRACT(k)
  void FinishPart(Part& p);
  void FoldTraces() const;  // appends the parts' new trace entries, summed, to stats_.trace
  absl::Status PairSeams() const;  // moves the parts' seam logs into seams_
  void MergeParts();  // into parts_[0], then SIMPLIFY(E0) from the seam edges

  VolumeInfo grid_;
  SessionOptions options_;
  double scale_ = 1;   // engine frame -> world: world = engine * scale_ + grid_.origin
  absl::Status failed_;  // set by an exception: the session is unusable
  std::vector<std::unique_ptr<Part>> parts_;
  // seams_[s]: (vertex in part s, its copy in part s+1), per shared grid edge.
  mutable std::vector<std::vector<std::pair<VertexId, VertexId>>> seams_;
  mutable size_t folded_ = 0;  // entries of the parts' traces already in stats_.trace
  int64_t slices_added_ = 0;
  bool workers_ = false;
  bool stop_ = false;
  std::vector<std::thread> threads_;
  size_t workers_planned_ = 1;
  mutable std::mutex mu_;
  mutable std::condition_variable cv_;
  std::array<RingSlot, kRingSlots> ring_;
  int ring_next_ = 0;
  // Of the parts merged away by Finish.
  int64_t merged_crossed_cubes_ = 0, merged_triangles_extracted_ = 0;
  PhaseTimes merged_time_;
  std::vector<float> convert_;
  mutable SessionStats stats_;
  bool finished_ = false;
};

// The status an exception caught by a barrier becomes: RESOURCE_EXHAUSTED for a failed
// allocation (bad_alloc, length_error), INTERNAL with what() otherwise. The session's
// barrier uses it, and so do the server's worker and the CLI around everything else.
absl::Status StatusOfException(std::exception_ptr e);

// Runs a session over every slice of `source`. With sealing (SessionOptions::seal), the
// sealed chunks are taken after every slice and handed to on_chunk (required then); a
// non-OK status from it ends the run.
absl::StatusOr<std::unique_ptr<TandemSession>> RunSession(
    SliceSource& source, const SessionOptions& options,
    const std::function<void(int64_t, int64_t)>& progress = nullptr,
    const std::function<absl::Status(SealedChunk)>& on_chunk = nullptr);

// Several surfaces in one pass (e.g. skin and bone, one iso-value each): one session per
// options entry, all fed from a single read of each slice and run side by side. Each
// session's mesh is the one RunSession would give with its options alone. on_chunk gets the
// index of the options entry the chunk belongs to.
absl::StatusOr<std::vector<std::unique_ptr<TandemSession>>> RunSessions(
    SliceSource& source, const std::vector<SessionOptions>& options,
    const std::function<void(int64_t, int64_t)>& progress = nullptr,
    const std::function<absl::Status(size_t, SealedChunk)>& on_chunk = nullptr);

}  // namespace tandem

#endif  // TANDEM_TANDEM_H_
