// TandemSession: extraction and simplification in lock-step (Attali, Cohen-Steiner,
// Edelsbrunner, "Extraction and Simplification of Iso-surfaces in Tandem", SGP 2005).
//
// The contract in one place: the session below, what it is asked to do (SessionOptions,
// options.h), what it hands back (IndexedMesh and SealedChunk, mesh.h) and what it measured
// (SessionStats, stats.h). The engine behind it is internal (core/src/).
//
// Push model: the caller feeds slices 0, 1, ... with AddSlice and calls Finish once; the
// session does no I/O (RunSession, tandem_io's run_session.h, is the driver for a
// SliceSource). Per slice k it runs the paper's EXTRACT(k) and, for the tandem schedules, the
// SIMPLIFY step behind the sweep (SessionOptions::schedule). E0 is in the volume's physical
// units.
//
// Slabs: the grid may be split along x into slabs (SessionOptions::parts) run side by side; the
// vertices on the planes between slabs wait until Finish, which merges the slabs and goes on
// from the seams. The split is part of the result (parts = 1 is the paper's algorithm, nothing
// deferred); threads are not: a pipelined and a sequential run give identical meshes.
//
// Threads: a session runs its work on the Executor it is given (executor.h: the built-in pool
// or one the caller implements), never on threads of its own, apart from the caller's: with
// SessionOptions::pipeline, AddSlice may queue the slice for the executor and return. Many
// sessions on one executor share its threads.
//
// Memory: a session given a MemoryBudget (budget.h) checks it where its arrays grow, inside
// its steps, and fails with RESOURCE_EXHAUSTED (naming the budget and the bytes) before it
// outgrows it by more than a grain of each part's figure; the budget's Cancel stops it
// (CANCELLED).
// Destroying a session stops its queued work at once: steps not started never run, a running
// one returns at its next check, and the destructor returns once they have let go.
#ifndef TANDEM_TANDEM_H_
#define TANDEM_TANDEM_H_

#include <cstdint>
#include <exception>
#include <memory>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/executor.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"
#include "tandem/options.h"
#include "tandem/stats.h"
#include "tandem/volume.h"

namespace tandem {

class MemoryBudget;  // budget.h

// Coordinates: the engine works in a frame of its own, relative to the grid: voxel (i, j, k)
// at (i*sx, j*sy, k*sz) / s, with s the power of two nearest below the smallest spacing. The
// origin drops out (a scan at origin 1e5 mm simplifies as one at 0, moved, with the same
// topology and error bound; the vertices' float32 positions hold fewer digits far off) and
// the unit's size does not matter (spacing 1e-12 works as spacing 1). A
// change of unit by a power of two (spacing, origin and E0 all times 2^k) gives the same mesh
// times 2^k, bit for bit, because the frame sees the same numbers; any other factor (mm to m)
// rounds the frame's numbers differently, which can reorder contractions of equal cost: the
// mesh keeps its guarantees (topology, Error(K) <= E0) but not its exact triangles.
// Everything the session hands out is in world coordinates.
//
// Failures: no input ends the process. Every exception thrown inside a session (an
// allocation that fails, on any thread working for it) becomes the status of the call that
// ran into it (RESOURCE_EXHAUSTED for memory, INTERNAL otherwise), and every later AddSlice or
// Finish returns the same status: the session is then unusable, the process is fine.
//
// Observers (Snapshot, stats, ...) first wait for the slices AddSlice queued; a failure of
// those is reported by the next AddSlice or Finish.
class TandemSession {
 public:
  // ---- The session: slices in, a mesh out ----

  // `grid`: nx, ny (>= 2), nz (0 if unknown), spacing, origin. `executor`: the threads to use
  // (null: Executor::Shared()); it must outlive the session. `budget`: the memory it may hold,
  // shared with other sessions or not (null: no limit).
  static absl::StatusOr<std::unique_ptr<TandemSession>> Create(
      const VolumeInfo& grid, const SessionOptions& options, Executor* executor = nullptr,
      std::shared_ptr<MemoryBudget> budget = nullptr);
  ~TandemSession();
  TandemSession(const TandemSession&) = delete;
  TandemSession& operator=(const TandemSession&) = delete;

  // Consumes the next slice (nx*ny floats, x fastest; a label session refuses floats). A rejected
  // slice (non-finite values, past nz) leaves the mesh as it was, apart from the deferred SIMPLIFY
  // step of the slice before, which the sequential order would have run already.
  absl::Status AddSlice(const float* values);
  // Same, from raw voxels of the given type in host byte order. A label session
  // (SessionOptions::labels) takes its slices here, in an integer type (each value a label;
  // a negative one is refused, naming the voxel).
  absl::Status AddSliceBytes(DType dtype, const uint8_t* bytes);
  // Ends the stream: at least 2 slices (and nz if it was declared) must have been added.
  absl::Status Finish();

  // Compacted copy of the current (partial or final) mesh, the slabs welded at their seams;
  // with sealing, of the part not sealed yet (empty after Finish).
  IndexedMesh Snapshot() const;
  // A label session's current mesh (the same as Snapshot, in the same order) with the pair
  // of labels each triangle separates (labels.h; SplitByLabel makes one surface per label).
  // Empty for an iso-surface session.
  LabeledMesh SnapshotLabeled() const;
  const SessionStats& stats() const;
  double MaxShapeError() const;  // Error(K), in world units
  const VolumeInfo& grid() const;
  const SessionOptions& options() const;
  bool finished() const;

  // ---- Sealing (SessionOptions::seal): the final mesh handed out in pieces as it settles ----

  // Moves everything sealed since the last call into one chunk (false: nothing new), first
  // waiting for every slab step still queued. Finish seals the rest.
  bool TakeSealed(SealedChunk* out);
  int64_t sealed_pending() const;  // triangles TakeSealed would hand out now
  // Sealing without draining the pipeline: moves what the steps of slices up to `slice` sealed
  // (and not taken yet) into one chunk, waiting for those steps only, never for later ones
  // (false: nothing). Each slab step's share is cut as the step ends, so taking slice k after
  // AddSlice of slice k + kSlicesInFlight never waits, and gives the chunk that TakeSealed
  // after AddSlice of slice k gives. A caller taking after every slice uses this one: with
  // TakeSealed a split session's slabs would run in lock-step.
  bool TakeSealedThrough(int64_t slice, SealedChunk* out);
  // A split session steps its slabs up to this many slices behind AddSlice: once AddSlice of
  // slice k returns, every step of slice k - kSlicesInFlight has finished.
  static constexpr int64_t kSlicesInFlight = 4;

  // ---- Introspection (a server's budget, progress and accounting) ----

  int64_t num_triangles() const;  // held by the session (with sealing: not sealed yet)
  int num_parts() const;          // slabs; after Finish: 1
  // Mesh store + queues (at their fullest in the last step) + extractor caches + slice buffers.
  size_t MemoryBytes() const;
  // The observers of this class first wait for every slab step still queued (a split session
  // runs its slabs' steps up to kSlicesInFlight slices behind AddSlice). A caller that looks
  // after every slice would drain that pipeline each time and leave cores idle. Peek does not
  // wait: it gives the figures as each slab's last finished step left them, exact when no
  // step is in flight (one slab, or after Finish).
  struct Gauge {
    int64_t triangles = 0;       // num_triangles()
    int64_t peak_triangles = 0;  // stats().peak_triangles, with `triangles`
    size_t memory_bytes = 0;     // MemoryBytes()
    // Sealing: the last slice whose steps every slab finished, and the triangles
    // TakeSealedThrough(sealed_through) would hand out now (what Finish seals, only
    // TakeSealed hands out).
    int64_t sealed_through = -1;
    int64_t sealed_pending = 0;
  };
  Gauge Peek() const;
  // What Finish is doing, asked from any thread while it runs (the session's own thread is
  // inside it), for a status line after the last slice: the step, how much of the step's
  // work lies behind it (`share`, 0..1, by the queue of edges the step began with; -1 for a
  // step without such a measure) and the wall seconds spent in the step and in Finish.
  struct Finishing {
    bool running = false;  // Finish has started and not returned
    const char* step = "";
    double share = -1;
    double step_seconds = 0, seconds = 0;
  };
  Finishing FinishProgress() const;

 private:
  struct Impl;  // session_impl.h
  explicit TandemSession(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// How often a status line asks FinishProgress while Finish runs (the CLI and the server alike).
inline constexpr double kFinishingEvery = 0.2;

// The status an exception caught by a barrier becomes: RESOURCE_EXHAUSTED for a failed
// allocation (bad_alloc, length_error), INTERNAL with what() otherwise. The session's
// barrier uses it, and so do the server's worker and the CLI around everything else.
absl::Status StatusOfException(std::exception_ptr e);

}  // namespace tandem

#endif  // TANDEM_TANDEM_H_
