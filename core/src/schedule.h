// The paper's schedules, one slab at a time (Attali, Cohen-Steiner, Edelsbrunner, SGP 2005).
// Per slice k, with the paper's names:
//   classical:   EXTRACT(k)                              ... Finish: INSERT(all); SIMPLIFY(E0)
//   tandem:      EXTRACT(k); INSERT(k-1); SIMPLIFY(E0)   (the newest layer is never touched)
//   tandem-lag:  EXTRACT(k); DELAY(k); ACTIVATE(k); SIMPLIFY(E0)
//                                                        ... Finish: ACTIVATE(∞); SIMPLIFY(E0)
// `tandem` is the waiting queue keyed by layer + 1, `tandem-lag` keyed by the reach of the
// contracted vertex (simplifier.h); none = EXTRACT only (the full-resolution surface).
//
// Threads are not the schedule's business: the SIMPLIFY step of layer k is run at the start of
// the next step, through `overlap`, beside EXTRACT(k+1) (which reads only the extractor's own
// buffers, while the simplifier never touches the front), so an executor may run the two side by
// side; either way the store sees the same mutations in the same order.
#ifndef TANDEM_SCHEDULE_H_
#define TANDEM_SCHEDULE_H_

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

#include "absl/status/status.h"
#include "slabs.h"
#include "tandem/options.h"

namespace tandem {

// Runs first() and second(), possibly side by side, and returns when both are done; run one
// after the other, first() goes first.
using Overlap = std::function<void(const std::function<void()>& first,
                                   const std::function<void()>& second)>;

// How far E0 rises next toward a target count, from how the last rise went.
struct RiseState {
  double boost = 1;    // doubles after each rise that removed next to nothing
  int idle = 0;        // x4 rises in a row that removed next to nothing
  bool floor = false;  // so many: no contraction is left to find
  // The factor for E0 when `count` triangles should become about `goal`.
  double Step(double count, double goal, double min_step) const;
  // After a rise by `step` removed `removed` triangles of the `wanted`.
  void After(double step, double removed, double wanted);
};

// A target triangle count N (SessionOptions::target_triangles) for the lock-step. E0 starts
// small (StartError) and rises as the mesh grows: a coarser E0 can contract the finished
// part further, nothing can refine it, so a rise must leave more than N triangles behind.
// E0 is the whole mesh's, shared by the slabs: each slab reports its count after every
// SIMPLIFY step; once every slab has reported step j, the counts decide E0 for step j (the
// rule: TargetControl::Decide), and every slab applies that decision at its step
// j + kLag, in whatever order the slabs ran, so the result does not depend on the threads.
class TargetControl {
 public:
  static constexpr int64_t kLag = 1;
  TargetControl(int64_t target, size_t slabs, double start_error);
  int64_t target() const { return target_; }
  // A slab after its SIMPLIFY step of layer j (each slab's steps in order): its triangles,
  // of those about `unsettled` in layers the lock-step cannot reach yet, how many the
  // step's rise of E0 removed, and its Simplifier::NextCost. Returns true when it was the last report of step j: the
  // decision is made (slabs waiting for it may go on).
  bool Report(int64_t step, int64_t triangles, int64_t unsettled, int64_t removed,
              double next_cost);
  // Whether the decision a slab needs at step j is known (steps below kLag need none).
  bool Ready(int64_t step) const;
  // E0 (engine units) for the step j SIMPLIFY, once Ready(j).
  double ErrorAt(int64_t step) const;

 private:
  struct Step {  // the sums of a step's reports
    int reports = 0;
    double triangles = 0, unsettled = 0, removed = 0;
    double next_cost = std::numeric_limits<double>::infinity();
  };
  double Decide(double error, int64_t step, const Step& r);
  mutable std::mutex mu_;
  int64_t target_;
  size_t slabs_;
  std::vector<Step> steps_;        // reports per step
  std::vector<double> decided_;    // decided_[j]: E0 after step j, for step j + kLag
  int64_t last_rise_ = -(int64_t{1} << 40);
  double settled_at_rise_ = 0;  // triangles less unsettled ones, when E0 last rose
  double last_step_ = 1;        // and by how much
  RiseState rise_;
  double start_error_;
};

// The end of a target count N for the whole mesh (merged from slabs, if split, with their
// queues): E0 rises until N remains.
void ReachTarget(Slab& whole, int64_t target);

// Before a split session's merge, with a target count N: the finished slabs come down
// together toward 1.05 N plus their seams' triangles, one shared E0 rise at a time, on both
// cores, each slab's SIMPLIFY stopping at its share of N at the latest (its count's part of
// the whole), so no rise leaves fewer than N. Without it the lock-step ended
// at up to 1.5 N (it rises only while more than that is settled, for the layers to come),
// and ReachTarget took the rest alone after the merge. for_each(f) runs f on every slab,
// side by side or not. After any rise, each slab's trace gets its count.
void ApproachTarget(std::span<const std::unique_ptr<Slab>> slabs, int64_t target,
                    const std::function<void(const std::function<void(Slab&)>&)>& for_each);

// E0 in the engine frame (physical units over `scale`, as the slabs' coordinates): what
// every slab comes down to by the end (FinishAtError).
double FinalError(const SessionOptions& options, double scale);
// E0 in the engine frame at the start of a session: FinalError, or below it the
// finishing pass's lock-step E0 (SessionOptions::lockstep_error; FinishAtError brings it up
// at the end); with a target triangle count, which E0 must reach from below, at most 1/1000
// of the smallest spacing: a larger start can keep fewer than a smooth surface's target
// (docs/decisions.md 23). A target above what the start keeps needs a smaller --error.
double StartError(const VolumeInfo& grid, const SessionOptions& options, double scale);

// The finishing pass of an E0 run (SessionOptions::lockstep_error): once every slab is
// finished at the lock-step's share of E0, each comes down to `error` (the engine frame's
// E0) in one cost order, side by side (for_each as in ApproachTarget), before the merge;
// the seams follow after it at `error` (FinishWhole). Slabs already at `error` are left
// as they are; each slab's trace gets its count.
void FinishAtError(std::span<const std::unique_ptr<Slab>> slabs, double error,
                   const std::function<void(const std::function<void(Slab&)>&)>& for_each);

// One slice through one slab. A refused slice (non-finite values, past nz) leaves the slab as it
// was, apart from the deferred SIMPLIFY step, which the sequential order would have run already.
absl::Status StepSlab(Slab& slab, SliceValues values, Schedule schedule, const Overlap& overlap);

// The end of the stream for one slab: its last SIMPLIFY step, the top of the box, and for the
// classical schedule INSERT(all); then ACTIVATE(∞); SIMPLIFY(E0).
void FinishSlab(Slab& slab, Schedule schedule);

// The end for the whole mesh, once the slabs are merged into `whole`: SIMPLIFY(E0) from the
// welded seam vertices (null: there was one slab); toward the target triangle count if asked; then the sag correction
// (sealing: the last seal, sag included), in ranges on `executor` if one is given. Returns the
// vertices the sag correction moved.
int64_t FinishWhole(Slab& whole, const SessionOptions& options,
                    const std::vector<VertexId>* seam_vertices, Executor* executor = nullptr);

}  // namespace tandem

#endif  // TANDEM_SCHEDULE_H_
