#include "schedule.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>

#include "thread_clock.h"

namespace tandem {
namespace {

// A phase's time is CPU time: the phase's own thread's, and what the work it handed to the
// executor (batch evaluations, the final sag correction's ranges) took on other threads
// (Simplifier::TakeHelperSeconds).
class PhaseClock {
 public:
  explicit PhaseClock(Simplifier& s) : s_(s), t0_(ThreadCpuSeconds()) {
    (void)s_.TakeHelperSeconds();  // spent outside any phase
  }
  double Seconds() const { return ThreadCpuSeconds() - t0_ + s_.TakeHelperSeconds(); }

 private:
  Simplifier& s_;
  double t0_;
};

bool Lockstep(Schedule s) { return s == Schedule::kTandem || s == Schedule::kTandemLag; }

// A rise aims at kGoal N with the model count ~ E0^-kExponent, which under-estimates how fast
// the count falls (measured: the exponent is 1.1-1.3 on the CTs), so it lands above the goal
// rather than below N, and steps by kMinStep..kMaxStep.
constexpr double kGoal = 1.2, kExponent = 1.5, kMinStep = 1.25, kMaxStep = 4;
// E0 rises while the lock-step holds more than kHigh N triangles besides the unsettled ones:
// those of the last kRecentLayers layers as extracted (partly simplified already), and about
// two per seam vertex. Few recent layers leave more to the parallel lock-step
// (docs/decisions.md 23).
constexpr double kHigh = 1.5;
constexpr size_t kRecentLayers = 3;
// Where a rise starts: from the least cost above E0, when there is one (a small first E0
// can sit far below every cost).
double From(double error, double next_cost) {
  return std::isfinite(next_cost) ? std::max(error, next_cost) : error;
}

}  // namespace

double RiseState::Step(double count, double goal, double min_step) const {
  return std::clamp(boost * std::pow(count / goal, 1 / kExponent), min_step, kMaxStep);
}

void RiseState::After(double step, double removed, double wanted) {
  // A rise that removed under 1 % of what it aimed at doubles the next one: a CT's costs can
  // sit far above a small E0 (docs/decisions.md 23). After
  // kGiveUp x4 rises in a row that removed next to nothing, the surface is at its floor
  // (components and handles no contraction may remove, as on a head MR at a few hundred
  // triangles).
  constexpr int kGiveUp = 8;
  const bool effective = removed >= 0.01 * wanted;
  boost = effective ? 1 : 2 * boost;
  idle = effective ? 0 : idle + (step >= kMaxStep);
  floor = idle >= kGiveUp;
}

namespace {

// After a SIMPLIFY step of the lock-step, with the layer it delayed: the decision of step
// j - kLag, then this step's report.
void FollowTarget(Slab& s) {
  TargetControl& t = *s.target;
  const int64_t step = s.pending_front;
  int64_t removed = 0;  // by the rise
  if (const double e = t.ErrorAt(step); e > s.simplifier.error()) {
    const auto before = static_cast<int64_t>(s.store.num_triangles());
    s.simplifier.RaiseError(e);
    s.simplifier.Simplify();
    removed = before - static_cast<int64_t>(s.store.num_triangles());
  }
  s.recent_layers.push_back(static_cast<int64_t>(s.new_tris.size()));
  if (s.recent_layers.size() > kRecentLayers) s.recent_layers.erase(s.recent_layers.begin());
  // Seam vertices wait for the merge, and so do the triangles around them: about two each
  // once the rest is coarse.
  int64_t unsettled = 2 * s.seam_vertices;
  for (int64_t n : s.recent_layers) unsettled += n;
  if (t.Report(step, static_cast<int64_t>(s.store.num_triangles()), unsettled, removed,
               s.simplifier.NextCost()) &&
      s.waker) {
    s.waker();
  }
}

// DELAY(k); ACTIVATE(k); SIMPLIFY(E0) for the layer extracted last, whose top plane is the
// front; sealing: then everything the front has left behind for good.
void SimplifyLayer(Slab& s) {
  const PhaseClock clock(s.simplifier);
  const double front = static_cast<double>(s.pending_front);
  s.simplifier.Delay(s.new_tris, s.new_edges);
  s.simplifier.Activate(front);
  s.simplifier.Simplify();
  if (s.target) FollowTarget(s);
  if (s.sealer) s.sealer->Seal(front);
  s.time.simplify_s += clock.Seconds();
  s.trace.push_back(static_cast<int64_t>(s.store.num_triangles()));
  s.CheckHolding("simplifying slice", s.pending_front);
}

// The second half of EXTRACT(k): the staged layer joins the store, its triangles' quadrics
// their vertices.
void InsertLayer(Slab& s, Schedule schedule) {
  s.new_tris.clear();
  s.new_edges.clear();
  s.new_verts.clear();
  const size_t seam_before = s.seam_log[0].size() + s.seam_log[1].size();
  s.extractor.CommitLayer(&s.new_tris, &s.new_verts, &s.seam_log, &s.new_edges);
  s.seam_vertices += static_cast<int64_t>(s.seam_log[0].size() + s.seam_log[1].size() - seam_before);
  s.triangles_extracted += static_cast<int64_t>(s.new_tris.size());
  if (schedule != Schedule::kNone) s.simplifier.AddTriangles(s.new_tris, s.new_verts);
  if (s.sealer) {
    s.extractor.CompactLabelPairs();
    s.sealer->AddVertices(s.new_verts);
    // Full resolution: nothing will change below the front plane.
    if (schedule == Schedule::kNone) s.sealer->Seal(static_cast<double>(s.extractor.slices_done() - 1));
  }
}

}  // namespace

TargetControl::TargetControl(int64_t target, size_t slabs, double start_error)
    : target_(target), slabs_(slabs), start_error_(start_error) {}

bool TargetControl::Report(int64_t step, int64_t triangles, int64_t unsettled, int64_t removed,
                           double next_cost) {
  std::lock_guard<std::mutex> lock(mu_);
  const auto j = static_cast<size_t>(step);
  if (steps_.size() <= j) steps_.resize(j + 1);
  Step& r = steps_[j];
  r.triangles += static_cast<double>(triangles);
  r.unsettled += static_cast<double>(unsettled);
  r.removed += static_cast<double>(removed);
  r.next_cost = std::min(r.next_cost, next_cost);
  if (++r.reports < static_cast<int>(slabs_)) return false;
  // Steps end in order in every slab, so step j - 1 was decided before.
  assert(decided_.size() == j);
  const double before = j == 0 ? start_error_ : decided_.back();
  decided_.push_back(Decide(before, step, r));
  return true;
}

double TargetControl::Decide(double error, int64_t step, const Step& r) {
  const auto n = static_cast<double>(target_);
  const double settled = r.triangles - r.unsettled;
  // A rise shows kLag steps later; at the floor, rising on would only crush the layers to
  // come, and N cannot be reached anyway (ReachTarget still tries at the end).
  if (step == last_rise_ + kLag) rise_.After(last_step_, r.removed, settled_at_rise_ - kGoal * n);
  if (step < last_rise_ + kLag || rise_.floor || settled <= kHigh * n) return error;
  last_rise_ = step;
  settled_at_rise_ = settled;
  last_step_ = rise_.Step(settled, kGoal * n, kMinStep);
  return From(error, r.next_cost) * last_step_;
}

bool TargetControl::Ready(int64_t step) const {
  std::lock_guard<std::mutex> lock(mu_);
  return step < kLag || static_cast<int64_t>(decided_.size()) > step - kLag;
}

double TargetControl::ErrorAt(int64_t step) const {
  std::lock_guard<std::mutex> lock(mu_);
  if (step < kLag) return start_error_;
  assert(static_cast<int64_t>(decided_.size()) > step - kLag);
  return decided_[static_cast<size_t>(step - kLag)];
}

void ReachTarget(Slab& s, int64_t target) {
  // The whole mesh is settled: E0 rises in steps, each SIMPLIFY stopping at N, so that no
  // step can overshoot (a flat face may fall at once when E0 passes its cost), and within a
  // step the contractions still go in cost order.
  const auto n = static_cast<double>(target);
  constexpr double kFinalStep = 1.05;
  s.simplifier.Simplify(target);
  RiseState rise;
  double useful = s.simplifier.error();  // E0 after the last rise that removed something
  while (!rise.floor && static_cast<int64_t>(s.store.num_triangles()) > target) {
    const auto count = static_cast<double>(s.store.num_triangles());
    const double step = rise.Step(count, n, kFinalStep);
    s.simplifier.RaiseError(From(s.simplifier.error(), s.simplifier.NextCost()) * step);
    s.simplifier.Simplify(target);
    rise.After(step, count - static_cast<double>(s.store.num_triangles()), count - n);
    if (rise.idle == 0 && rise.boost == 1) useful = s.simplifier.error();
  }
  if (static_cast<int64_t>(s.store.num_triangles()) > target) {
    // The checks refuse what is left at every E0 (not seen): past E0, without the guard.
    s.simplifier.RequeueAll();
    s.simplifier.Simplify(target, /*past_error=*/true);
  }
  // At the floor E0 ran up by 4^8 for nothing: the sag correction and the report take the E0
  // that last did some good.
  if (rise.floor) s.simplifier.LowerErrorAfterSimplify(useful);
}

void ApproachTarget(std::span<const std::unique_ptr<Slab>> slabs, int64_t target,
                    const std::function<void(const std::function<void(Slab&)>&)>& for_each) {
  // The last few percent and the seams' triangles are left to ReachTarget's one cost order.
  constexpr double kNear = 1.05, kFinalStep = 1.05;
  // The seams stay at full resolution until the merge (about two triangles a seam vertex,
  // as in FollowTarget): the parts come down to N besides them, not to N with them, or E0
  // would climb past what the whole needs.
  double seams = 0;
  for (const auto& s : slabs) seams += 2.0 * static_cast<double>(s->seam_vertices);
  const double goal = kNear * static_cast<double>(target) + seams;
  auto count = [&] {
    double n = 0;
    for (const auto& s : slabs) n += static_cast<double>(s->store.num_triangles());
    return n;
  };
  RiseState rise;
  double now = count();
  std::vector<int64_t> share(slabs.size());
  bool rose = false;
  // Until a rise removes next to nothing: where the parts cannot come down (the seams' full
  // resolution, a floor) E0 would double on for nothing, and the sag correction follows E0.
  while (rise.boost == 1 && now > goal) {
    double error = 0, next = std::numeric_limits<double>::infinity();
    for (const auto& slab : slabs) {
      Slab& s = *slab;
      error = std::max(error, s.simplifier.error());
      next = std::min(next, s.simplifier.NextCost());
      // A floor only, summing to N: a rise can land below the goal, never below N. Each
      // part contracts what costs at most E0, as one SIMPLIFY(E0) of the whole would.
      share[s.index] = static_cast<int64_t>(
          std::ceil(static_cast<double>(target) * static_cast<double>(s.store.num_triangles()) / now));
    }
    const double step = rise.Step(now, goal, kFinalStep);
    const double e = From(error, next) * step;
    for_each([&](Slab& s) {
      const PhaseClock clock(s.simplifier);
      s.simplifier.RaiseError(e);
      s.simplifier.Simplify(share[s.index]);
      s.time.simplify_s += clock.Seconds();
    });
    const double after = count();
    rise.After(step, now - after, now - goal);
    now = after;
    rose = true;
  }
  if (rose) {
    for (const auto& s : slabs) s->trace.push_back(static_cast<int64_t>(s->store.num_triangles()));
  }
}

double FinalError(const SessionOptions& options, double scale) { return options.error / scale; }

double StartError(const VolumeInfo& grid, const SessionOptions& options, double scale) {
  const double spacing = std::min({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  double start = options.error;  // physical units
  if (options.target_triangles > 0) {
    start = spacing / 1000;
  } else if (Lockstep(options.schedule) && !options.seal) {
    start = std::max(options.lockstep_error * options.error,
                     SessionOptions::kDefaultErrorVoxels * spacing);
  }
  return std::min(FinalError(options, scale), start / scale);
}

void FinishAtError(std::span<const std::unique_ptr<Slab>> slabs, double error,
                   const std::function<void(const std::function<void(Slab&)>&)>& for_each) {
  // One rise, straight to E0: rises of x1.3 gave no better a mesh for its count (link-256 at
  // E0 0.975, F = 0.3: 638 triangles at RMS 0.575 against 662 at 0.551) and evaluate every
  // edge again at each rise (no dropped-edge lists in E0 runs: docs/decisions.md).
  for_each([error](Slab& s) {
    if (s.simplifier.error() < error) {
      const PhaseClock clock(s.simplifier);
      s.simplifier.RaiseError(error);
      s.simplifier.Simplify();
      s.time.simplify_s += clock.Seconds();
    }
  });
  for (const auto& s : slabs) s->trace.push_back(static_cast<int64_t>(s->store.num_triangles()));
}

absl::Status StepSlab(Slab& s, SliceValues values, Schedule schedule, const Overlap& overlap) {
  s.meter->CheckStop();  // a stopped session's step does not start
  absl::Status extracted;
  double extract_s = 0;
  auto extract = [&] {  // the first half of EXTRACT(k): reads the extractor's own state only
    const double t0 = ThreadCpuSeconds();
    extracted = s.extractor.ComputeLayer(values);
    extract_s = ThreadCpuSeconds() - t0;
  };
  if (s.simplify_pending) {
    overlap([&] { SimplifyLayer(s); }, extract);  // layer k-1's step beside EXTRACT(k)
  } else {
    extract();
  }
  s.simplify_pending = false;
  if (!extracted.ok()) return extracted;
  const PhaseClock insert(s.simplifier);
  InsertLayer(s, schedule);
  // The staged layer is in the store now: the extractor's figure gives it up first, so that
  // the layer is not counted twice.
  const int64_t slice = s.extractor.slices_done() - 1;
  s.extraction.Hold(s.extractor.HeldBytes(values.dtype), "extracting slice", slice);
  s.CheckHolding("adding slice", slice);
  s.time.extract_s += extract_s + insert.Seconds();
  s.trace.push_back(static_cast<int64_t>(s.store.num_triangles()));
  if (Lockstep(schedule)) {  // DELAY(k); ACTIVATE(k); SIMPLIFY(E0): at the next step
    s.simplify_pending = true;
    s.pending_front = s.extractor.slices_done() - 1;
  }
  return absl::OkStatus();
}

void FinishSlab(Slab& s, Schedule schedule) {
  if (s.simplify_pending) SimplifyLayer(s);
  s.simplify_pending = false;
  if (s.extractor.ComputeClosingLayer()) {  // a closed label volume: the background above
    InsertLayer(s, schedule);
    if (Lockstep(schedule)) {
      s.pending_front = s.extractor.slices_done();
      SimplifyLayer(s);
    }
  }
  s.extractor.Finish();
  if (schedule == Schedule::kNone) return;
  const PhaseClock clock(s.simplifier);
  if (schedule == Schedule::kClassical) {
    // INSERT every edge of the full-resolution surface, then one SIMPLIFY.
    std::vector<TriId> all;
    all.reserve(s.store.num_triangles());
    for (TriId t = 0; t < s.store.triangle_capacity(); ++t) {
      if (s.store.triangle_alive(t)) all.push_back(t);
    }
    s.simplifier.Delay(all);
  }
  s.simplifier.Activate(std::numeric_limits<double>::infinity());  // ACTIVATE(∞)
  s.simplifier.Simplify();
  s.time.simplify_s += clock.Seconds();
  s.CheckHolding("finishing after slice", s.extractor.slices_done() - 1);
}

int64_t FinishWhole(Slab& whole, const SessionOptions& options,
                    const std::vector<VertexId>* seam_vertices, Executor* executor) {
  const bool simplify = options.schedule != Schedule::kNone;
  if (simplify && seam_vertices != nullptr) {
    // SIMPLIFY(E0) from the seam: every other edge was settled inside its slab and keeps its
    // cost; contractions here re-queue their neighbours as usual.
    const PhaseClock clock(whole.simplifier);
    whole.simplifier.PushEdgesAround(*seam_vertices);
    whole.simplifier.Simplify(options.target_triangles);  // the parts may stand near N
    whole.time.simplify_s += clock.Seconds();
  }
  if (simplify && options.target_triangles > 0) {
    const PhaseClock clock(whole.simplifier);
    ReachTarget(whole, options.target_triangles);
    whole.time.simplify_s += clock.Seconds();
  }
  int64_t sag_corrected = 0;
  const PhaseClock clock(whole.simplifier);
  if (whole.sealer) {
    // The rest, sag included.
    whole.sealer->Seal(std::numeric_limits<double>::infinity(), executor);
    sag_corrected = whole.sealer->sag_corrected();
  } else if (simplify) {
    if (options.sag_correction > 0.0) {
      sag_corrected = whole.simplifier.CorrectSag(options.sag_correction, executor);
    }
    whole.simplifier.TidyDegenerate();  // last: the sag correction may leave some
  }
  whole.time.simplify_s += clock.Seconds();
  whole.CheckHolding("finishing after slice", whole.extractor.slices_done() - 1);
  return sag_corrected;
}

}  // namespace tandem
