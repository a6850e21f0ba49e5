// TandemSession's inside: the slabs, the slices on their way to them, and the executor that
// steps them. The schedule itself is in schedule.h, the slabs in slabs.h, the ring and the
// queued steps in slab_pipeline.h.
#ifndef TANDEM_SESSION_IMPL_H_
#define TANDEM_SESSION_IMPL_H_

#include <array>
#include <chrono>
#include <deque>
#include <memory>
#include <mutex>
#include <unordered_set>
#include <vector>

#include "absl/status/status.h"
#include "meter.h"
#include "schedule.h"
#include "slab_pipeline.h"
#include "slabs.h"
#include "tandem/task_group.h"
#include "tandem/tandem.h"

namespace tandem {

struct TandemSession::Impl {
  Impl(const VolumeInfo& grid, const SessionOptions& options, int slabs, Executor* executor,
       std::shared_ptr<MemoryBudget> budget);
  ~Impl();

  // AddSlice and Finish run behind the session's barrier: an exception becomes `failed`,
  // returned now and by every later call.
  template <typename F>
  absl::Status Guarded(F&& f);
  // values (host floats) or dtype + bytes (integers stay as they are, in the ring too: the
  // extractors convert them as they scan; SliceValues).
  absl::Status AddSlice(const float* values, DType dtype, const uint8_t* bytes);
  absl::Status StepSlice(const float* values, DType dtype, const uint8_t* bytes);  // unqueued
  absl::Status QueueSlice(const float* values, DType dtype, const uint8_t* bytes);  // the ring
  absl::Status CheckSliceIndex() const;  // the next slice lies within nz
  absl::Status NonFiniteError(const float* values) const;  // names the first bad voxel
  // A split label session's slice (bytes of dtype; null: floats) holds only labels, checked
  // before any slab moves (one slab's extractor checks as it scans).
  absl::Status CheckLabels(const uint8_t* bytes, DType dtype) const;
  absl::Status Finish();
  // Waits for the queued slab steps, then pairs the new seam vertices and folds the traces.
  // It only fills caches, so the const observers use it.
  absl::Status Sync();
  void FoldTraces();  // appends the slabs' new trace entries, summed, to stats.trace
  void Record();      // the whole mesh's count, after Finish
  // Runs f(slab) for every slab: side by side on the executor when pipelined, else in order.
  // `balanced`: at most as many at once as the executor has threads (the caller counting as
  // one), each taking the next slab when it is done, for long steps of similar size.
  void ForEachSlab(const std::function<void(Slab&)>& f, bool balanced = false);
  // Engine frame -> world, in place (a mirrored frame also reverses the triangles' winding).
  void ToWorld(std::vector<Vec3>* positions, std::vector<uint32_t>* indices) const;
  const SessionStats& Stats();
  size_t MemoryBytes();
  TandemSession::Gauge Peek();
  // One slab's share of MemoryBytes and of the gauge: read by the task that stepped it, at
  // the end of each queued step (its own data, then), or by the caller between steps.
  struct SlabGauge {
    int64_t triangles = 0;
    size_t bytes = 0;
  };
  SlabGauge Measure(const Slab& slab) const;  // reads only the slab and the grid
  size_t BufferBytes() const;  // the slice buffers and the seams' pairs

  // Queued slices (a pipelined split session, slab_pipeline.h): each slice is copied once
  // into the ring and queued for every slab.
  static constexpr int kRingSlots = static_cast<int>(kSlicesInFlight);  // slices in flight
  void StepQueued(size_t slab);  // one queued step of a slab (a task)
  absl::Status QueuedFailure();  // mu held

  VolumeInfo grid;
  SessionOptions options;
  double scale = 1;  // engine frame -> world: world = engine * scale + grid.origin
  Executor* executor;
  // The budget and the stop of every step (meter.h); before the slabs, which report to it.
  Meter meter;
  Meter::Account buffers{&meter};  // BufferBytes (the caller's thread)
  Meter::Account cut_account{&meter};  // cut_bytes (under mu)
  Overlap overlap;   // how a slab overlaps EXTRACT(k) with SIMPLIFY(k-1)
  absl::Status failed;
  std::vector<std::unique_ptr<Slab>> slabs;
  std::unique_ptr<TargetControl> target;  // SessionOptions::target_triangles > 0
  void WakeParked();  // a target decision was made: parked slabs go on
  Seams seams;
  size_t folded = 0;  // entries of the slabs' traces already in stats.trace
  int64_t slices_added = 0;
  bool queued = false;  // slices go through the ring to tasks
  std::mutex mu;        // guards queues and the ring slots' pending counts
  std::vector<SlabQueue> queues;
  std::vector<SlabGauge> gauges;  // each slab's, at the end of its last queued step
  std::array<RingSlot, kRingSlots> ring;
  int ring_next = 0;
  std::unique_ptr<TaskGroup> steps;  // the queued slab steps
  MergedCounts merged;               // of the slabs merged away by Finish
  // float32 bytes not aligned for float (one part or unqueued); voxels of a type the
  // extractor does not read as it is (SliceValues::ScannedAsIs), converted
  std::vector<float> convert;
  SessionStats stats;
  int64_t chunks_taken = 0;  // TakeSealed: the next chunk's index
  // Sealing: each slab step's share of the sealed mesh, cut as the step ends (CutSealed), by
  // slab (the slabs as created: they outlive the merge); the front of each is slice
  // cut_taken's. Guarded by mu, with cut_bytes (their memory).
  std::vector<std::deque<SealedChunk>> cuts;
  int64_t cut_taken = 0;
  size_t cut_bytes = 0;
  void CutSealed(Slab& slab);  // the slab's step ended (takes mu)
  int64_t CutThrough() const;  // mu held: the last slice every slab's share is cut for
  // mu held: moves the shares of slices up to `through` (<= CutThrough()) into *pieces,
  // slice by slice, each in slab order.
  void TakeCuts(int64_t through, std::vector<SealedChunk>* pieces);
  int64_t CutTriangles(int64_t through) const;  // mu held: in the shares TakeCuts would take
  // One chunk of the pieces taken (false: no triangle and no retired id), in world units.
  bool JoinTaken(std::vector<SealedChunk> pieces, SealedChunk* out);
  // Sealing with slabs: seam vertices frozen in both slabs (SettleSeams), and those of them
  // one copy of which was retired so far (the id is retired with the second).
  int64_t seam_ids = 0;
  std::unordered_set<uint32_t> half_retired;
  static constexpr int64_t kSettleEvery = 16;  // slices between SettleSeams
  void MaybeSettleSeams();  // before slice slices_added is stepped
  bool finished = false;
  // FinishProgress: the step Finish is in and the simplifiers it runs (tracked), under
  // finish_mu; a reader takes the lock, the simplifiers' counters are atomic.
  void BeginFinishStep(const char* step, std::vector<Simplifier*> simplifiers);
  TandemSession::Finishing FinishProgress() const;
  mutable std::mutex finish_mu;
  const char* finish_step = nullptr;  // null: Finish is not running
  std::vector<Simplifier*> tracked;
  std::chrono::steady_clock::time_point finish_start, step_start;
};

}  // namespace tandem

#endif  // TANDEM_SESSION_IMPL_H_
