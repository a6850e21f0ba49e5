// TandemSession::Impl (session_impl.h): the session's slabs stepped slice by slice, Finish, and
// what the observers read. The queued steps and the sealed shares are in slab_pipeline.cc.
#include "session_impl.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "absl/strings/str_cat.h"
#include "label_extractor.h"
#include "simplifier_access.h"
#include "tandem/status_macros.h"

namespace tandem {
namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// The engine frame's unit (TandemSession): the power of two at or below the smallest
// spacing, so that scaling by it is exact.
double EngineScale(const VolumeInfo& g) {
  const double smallest = std::min({g.spacing[0], g.spacing[1], g.spacing[2]});
  return std::ldexp(1.0, std::ilogb(smallest));
}

}  // namespace

TandemSession::Finishing TandemSession::Impl::FinishProgress() const {
  const Impl& s = *this;
  std::lock_guard<std::mutex> lock(s.finish_mu);
  Finishing f;
  if (s.finish_step == nullptr) return f;
  const auto now = Clock::now();
  f.running = true;
  f.step = s.finish_step;
  f.step_seconds = Seconds(s.step_start, now);
  f.seconds = Seconds(s.finish_start, now);
  int64_t done = 0, total = 0;
  for (const Simplifier* t : s.tracked) {
    done += SimplifierProbe::progress_done(*t);
    total += SimplifierProbe::progress_total(*t);
  }
  if (total > 0)
    f.share = std::clamp(static_cast<double>(done) / static_cast<double>(total), 0.0, 1.0);
  return f;
}

void TandemSession::Impl::BeginFinishStep(const char* step, std::vector<Simplifier*> simplifiers) {
  std::lock_guard<std::mutex> lock(finish_mu);
  for (Simplifier* t : tracked) SimplifierProbe::TrackProgress(*t, false);
  for (Simplifier* t : simplifiers) SimplifierProbe::TrackProgress(*t, true);
  tracked = std::move(simplifiers);
  finish_step = step;
  step_start = Clock::now();
  if (step == nullptr) tracked.clear();
}

// ---- Impl ----

TandemSession::Impl::Impl(const VolumeInfo& g, const SessionOptions& o, int count, Executor* ex,
                          std::shared_ptr<MemoryBudget> budget)
    : grid(g), options(o), scale(EngineScale(g)), executor(ex), meter(std::move(budget)) {
  // With several slabs the threads go to the slabs, not to the batches inside one.
  slabs = MakeSlabs(grid, options, scale, count,
                    options.pipeline && count == 1 ? executor : nullptr, &meter);
  seams.resize(static_cast<size_t>(count - 1));
  if (options.target_triangles > 0 && options.schedule != Schedule::kNone) {
    target = std::make_unique<TargetControl>(options.target_triangles, slabs.size(),
                                             slabs[0]->simplifier.error());
    for (auto& s : slabs) {
      s->target = target.get();
      s->waker = [this] { WakeParked(); };
    }
  }
  if (options.pipeline && count == 1) {
    overlap = [ex](const std::function<void()>& first, const std::function<void()>& second) {
      TaskGroup both(ex);
      both.Run(second);
      first();
      both.Wait();
    };
  } else {
    overlap = [](const std::function<void()>& first, const std::function<void()>& second) {
      first();
      second();
    };
  }
  // The ring's slots are allocated on first use, like the extractors' planes: a session that
  // gets no voxel commits no slice memory.
  queued = options.pipeline && count > 1;
  if (queued) {
    queues.resize(static_cast<size_t>(count));
    steps = std::make_unique<TaskGroup>(executor);
    for (const auto& s : slabs) gauges.push_back(Measure(*s));  // the planes as planned
    // The caller waits for its queued steps, which may stand behind other sessions' on a
    // shared executor: a stop ends that wait at once (AddSlice, TakeSealedThrough).
    meter.budget().AddWaker(this, [this] { steps->Notify(); });
  }
  if (slabs[0]->sealer != nullptr) cuts.resize(slabs.size());
  buffers.Set(BufferBytes());  // the slices as planned
}

TandemSession::Impl::~Impl() {
  // Steps queued never start, and one running returns at its next check.
  meter.Stop();
  if (!queued) return;
  meter.budget().RemoveWaker(this);
  {
    std::lock_guard<std::mutex> lock(mu);
    for (SlabQueue& q : queues) q.slices.clear();  // only an abandoned session has any
  }
  // Waits for the step running now, if any; the group stays set meanwhile (a step that ends
  // queues the next through it).
  try {
    steps->Wait();
  } catch (...) {  // a failure of an abandoned session: nobody to tell
  }
  steps.reset();
}

absl::Status TandemSession::Impl::Sync() {
  if (queued) {
    steps->Wait();
    std::lock_guard<std::mutex> lock(mu);
    TANDEM_RETURN_IF_ERROR(QueuedFailure());
  }
  absl::Status st = PairSeams(slabs, &seams);
  FoldTraces();
  return st;
}

void TandemSession::Impl::MaybeSettleSeams() {
  // At fixed slices, every slab stepped up to the same one: the result does not depend on
  // threads or on when the caller looks.
  if (!options.seal || slabs.size() < 2 || slices_added == 0 || slices_added % kSettleEvery != 0) {
    return;
  }
  if (!Sync().ok()) return;  // the failure is reported by the caller
  SettleSeams(slabs, &seams, static_cast<double>(slabs[0]->extractor.slices_done() - 1),
              options.seam_settle_slices, options.seam_hold_vertices,
              options.schedule != Schedule::kNone, &seam_ids);
}

void TandemSession::Impl::Record() {
  int64_t n = 0;
  for (const auto& slab : slabs) n += static_cast<int64_t>(slab->store.num_triangles());
  stats.trace.push_back(n);
  stats.peak_triangles = std::max(stats.peak_triangles, n);
}

void TandemSession::Impl::FoldTraces() {
  const size_t n = slabs[0]->trace.size();
  for (; folded < n; ++folded) {
    int64_t sum = 0;
    for (const auto& slab : slabs) sum += slab->trace[folded];
    stats.trace.push_back(sum);
    stats.peak_triangles = std::max(stats.peak_triangles, sum);
  }
}

void TandemSession::Impl::ToWorld(std::vector<Vec3>* positions,
                                  std::vector<uint32_t>* indices) const {
  const bool identity = scale == 1.0 && grid.origin == std::array<double, 3>{0, 0, 0};
  const Vec3 origin{grid.origin[0], grid.origin[1], grid.origin[2]};
  if (!grid.axis_aligned()) {
    // world = origin + scale * (x d0 + y d1 + z d2); a mirrored frame reverses the winding so
    // that normals keep pointing out of the surface.
    const auto& d = grid.directions;
    const Vec3 d0{d[0][0], d[0][1], d[0][2]}, d1{d[1][0], d[1][1], d[1][2]},
        d2{d[2][0], d[2][1], d[2][2]};
    for (Vec3& p : *positions) p = origin + (d0 * p.x + d1 * p.y + d2 * p.z) * scale;
    if (Dot(Cross(d0, d1), d2) < 0) {
      for (size_t t = 0; t + 2 < indices->size(); t += 3) {
        std::swap((*indices)[t + 1], (*indices)[t + 2]);
      }
    }
  } else if (!identity) {
    for (Vec3& p : *positions) p = p * scale + origin;
  }
}

void TandemSession::Impl::ForEachSlab(const std::function<void(Slab&)>& f, bool balanced) {
  if (options.pipeline && slabs.size() > 1 && balanced) {
    // The caller and threads - 1 tasks take the slabs in turn: with one worker a core, no
    // slab starts late to run alone while a core idles (tests/bench/DENSE.md).
    const size_t workers =
        std::min(slabs.size(), static_cast<size_t>(std::max(1, executor->threads())));
    std::atomic<size_t> next{0};
    auto work = [&] {
      for (size_t p = next++; p < slabs.size(); p = next++) f(*slabs[p]);
    };
    TaskGroup all(executor);
    for (size_t w = 1; w < workers; ++w) all.Run(work);
    work();
    all.Wait();
    return;
  }
  if (options.pipeline && slabs.size() > 1) {
    TaskGroup all(executor);
    for (size_t p = 0; p + 1 < slabs.size(); ++p) all.Run([&f, s = slabs[p].get()] { f(*s); });
    f(*slabs.back());
    all.Wait();
    return;
  }
  for (auto& slab : slabs) f(*slab);
}

absl::Status TandemSession::Impl::AddSlice(const float* values, DType dtype, const uint8_t* bytes) {
  if (finished) return absl::FailedPreconditionError("session already finished");
  const auto start = Clock::now();
  const absl::Status st =
      queued ? QueueSlice(values, dtype, bytes) : StepSlice(values, dtype, bytes);
  stats.time.total_s += Seconds(start, Clock::now());
  return st;
}

absl::Status TandemSession::Impl::CheckSliceIndex() const {
  // Each slab checks its own columns (and the extractor the end of the volume); with
  // several, a bad slice must be refused before any of them moves.
  if (slabs.size() > 1 && grid.nz > 0 && slices_added >= grid.nz) {
    return absl::InvalidArgumentError(absl::StrCat(
        "slice ", slices_added, " is past the end of the volume (nz = ", grid.nz, ")"));
  }
  return absl::OkStatus();
}

absl::Status TandemSession::Impl::CheckLabels(const uint8_t* bytes, DType dtype) const {
  if (!options.labels.enabled || slabs.size() < 2 || bytes == nullptr) return absl::OkStatus();
  return CheckLabelSlice(SliceValues{bytes, dtype}, grid.nx, grid.ny, grid.nx, slices_added);
}

absl::Status TandemSession::Impl::NonFiniteError(const float* values) const {
  const int64_t i = FirstNonFinite(reinterpret_cast<const uint8_t*>(values),
                                   static_cast<size_t>(grid.nx * grid.ny));
  return NonFiniteVoxelError(i % grid.nx, i / grid.nx, values[i]);
}

absl::Status TandemSession::Impl::StepSlice(const float* values, DType dtype,
                                            const uint8_t* bytes) {
  TANDEM_RETURN_IF_ERROR(CheckSliceIndex());
  // A slice must be refused before any slab moves: with several, its values are checked
  // first; one slab's extractor checks them as it scans.
  if (values != nullptr && slabs.size() > 1 &&
      FirstNonFinite(reinterpret_cast<const uint8_t*>(values),
                     static_cast<size_t>(grid.nx * grid.ny)) >= 0) {
    return NonFiniteError(values);
  }
  TANDEM_RETURN_IF_ERROR(CheckLabels(bytes, dtype));
  MaybeSettleSeams();
  // Float32 bytes come here as values (aligned by AddSliceBytes); integers as they are.
  const SliceValues slice =
      values != nullptr ? SliceValues::Floats(values) : SliceValues{bytes, dtype};
  std::vector<absl::Status> status(slabs.size());
  ForEachSlab(
      [&](Slab& s) { status[s.index] = StepSlab(s, slice.From(s.x0), options.schedule, overlap); });
  for (const absl::Status& st : status) {
    if (!st.ok()) {
      FoldTraces();  // the SIMPLIFY step before the failed EXTRACT happened
      return st;
    }
  }
  TANDEM_RETURN_IF_ERROR(Sync());
  for (auto& s : slabs) CutSealed(*s);
  ++slices_added;
  return absl::OkStatus();
}

absl::Status TandemSession::Impl::Finish() {
  if (finished) return absl::FailedPreconditionError("session already finished");
  const auto start = Clock::now();  // queued steps may still be running: their time counts
  TANDEM_RETURN_IF_ERROR(Sync());
  const int64_t done = slabs[0]->extractor.slices_done();
  if (done < 2) {
    return absl::FailedPreconditionError(
        absl::StrCat("the stream ended after ", done, " slice(s); at least 2 are needed"));
  }
  if (grid.nz > 0 && done != grid.nz) {
    return absl::FailedPreconditionError(absl::StrCat(
        "the stream ended after ", done, " slices but the volume declared nz = ", grid.nz));
  }
  if (queued) {     // no slice will be queued any more: the ring's slots are not counted now
    steps->Wait();  // Sync did; nothing is left
    steps.reset();
    queued = false;
  }
  {
    std::lock_guard<std::mutex> lock(finish_mu);
    finish_start = Clock::now();
  }
  struct EndSteps {  // however Finish leaves (an exception too): no step is running
    Impl* impl;
    ~EndSteps() { impl->BeginFinishStep(nullptr, {}); }
  } end_steps{this};
  auto simplifiers = [this] {
    std::vector<Simplifier*> all;
    for (auto& s : slabs) all.push_back(&s->simplifier);
    return all;
  };
  BeginFinishStep(options.schedule == Schedule::kClassical ? "simplifying the whole mesh"
                                                           : "simplifying the last slices",
                  simplifiers());
  ForEachSlab([this](Slab& s) { FinishSlab(s, options.schedule); }, /*balanced=*/true);
  finished = true;
  // A closed label volume's last layer has seam vertices of its own.
  TANDEM_RETURN_IF_ERROR(PairSeams(slabs, &seams));
  const bool merge = slabs.size() > 1;
  if (merge && options.target_triangles > 0 && options.schedule != Schedule::kNone &&
      !slabs[0]->sealer) {
    BeginFinishStep("simplifying toward the target triangle count", {});
    ApproachTarget(slabs, options.target_triangles, [this](const std::function<void(Slab&)>& f) {
      ForEachSlab(f, /*balanced=*/true);
    });
  }
  if (options.schedule != Schedule::kNone && options.target_triangles <= 0 &&
      slabs[0]->simplifier.error() < FinalError(options, scale)) {  // the finishing pass
    BeginFinishStep("simplifying the whole mesh to E0", simplifiers());
    FinishAtError(slabs, FinalError(options, scale), [this](const std::function<void(Slab&)>& f) {
      ForEachSlab(f, /*balanced=*/true);
    });
  }
  FoldTraces();
  std::vector<VertexId> seam_vertices;
  if (merge) {
    BeginFinishStep("merging the parts", {});  // the slabs go away: none is tracked
    seam_vertices = MergeSlabs(&slabs, &seams, options.schedule != Schedule::kNone, &merged);
  }
  BeginFinishStep(merge ? "simplifying the seams, correcting the sag" : "correcting the sag",
                  simplifiers());
  const int64_t sag = FinishWhole(*slabs[0], options, merge ? &seam_vertices : nullptr,
                                  options.pipeline ? executor : nullptr);
  if (sag > 0 || slabs[0]->sealer) stats.sag_corrected = sag;
  Record();
  stats.time.total_s += Seconds(start, Clock::now());
  return absl::OkStatus();
}

const SessionStats& TandemSession::Impl::Stats() {
  (void)Sync();
  const Slab& first = *slabs[0];
  stats.slices = first.extractor.slices_done();
  stats.crossed_cubes = merged.crossed_cubes;
  stats.triangles_extracted = merged.triangles_extracted;
  stats.time.extract_s = merged.time.extract_s;
  stats.time.simplify_s = merged.time.simplify_s;
  stats.error_reached =
      options.schedule == Schedule::kNone ? 0.0 : first.simplifier.error() * scale;
  stats.refusals = RefusalCounts{};
  stats.contractions = stats.evaluations = stats.q_pushes = stats.w_pushes = 0;
  stats.quadric_mismatches = 0;
  stats.max_reach_over_front = -std::numeric_limits<double>::infinity();
  stats.max_layer_over_front = -std::numeric_limits<double>::infinity();
  if (first.sealer) {
    stats.sealed_triangles = stats.sag_corrected = 0;
    stats.sealed_vertices = seam_ids;
  }
  for (const auto& s : slabs) {
    stats.crossed_cubes += s->extractor.crossed_cubes();
    stats.triangles_extracted += s->triangles_extracted;
    stats.time.extract_s += s->time.extract_s;
    stats.time.simplify_s += s->time.simplify_s;
    stats.refusals += SimplifierProbe::refusals(s->simplifier);
    stats.contractions += SimplifierProbe::contractions(s->simplifier);
    stats.evaluations += SimplifierProbe::evaluations(s->simplifier);
    stats.q_pushes += SimplifierProbe::q_pushes(s->simplifier);
    stats.w_pushes += SimplifierProbe::w_pushes(s->simplifier);
    stats.quadric_mismatches += SimplifierProbe::quadric_mismatches(s->simplifier);
    stats.max_reach_over_front =
        std::max(stats.max_reach_over_front, SimplifierProbe::max_reach_over_front(s->simplifier));
    stats.max_layer_over_front =
        std::max(stats.max_layer_over_front, SimplifierProbe::max_layer_over_front(s->simplifier));
    if (s->sealer) {
      stats.sealed_triangles += s->sealer->sealed_triangles();
      stats.sealed_vertices += s->sealer->sealed_vertices();
      stats.sag_corrected += s->sealer->sag_corrected();
    }
  }
  return stats;
}

size_t TandemSession::Impl::BufferBytes() const {
  // Slice buffers as planned (allocated on the first slice), so that a budget checked before
  // any voxel counts them: the ring's slots hold slices as they arrive (a 16-bit slice in 2
  // bytes a voxel); unqueued, the caller's slice (or its aligned copy).
  size_t bytes = std::max(grid.slice_bytes(), convert.capacity() * sizeof(float));
  if (queued) {
    bytes = 0;
    for (const RingSlot& slot : ring) {
      bytes += std::max(grid.slice_bytes(), slot.storage.capacity() * sizeof(float));
    }
  }
  for (const auto& s : seams) bytes += s.capacity() * sizeof(s[0]);
  return bytes;
}

TandemSession::Impl::SlabGauge TandemSession::Impl::Measure(const Slab& s) const {
  SlabGauge g;
  g.triangles = static_cast<int64_t>(s.store.num_triangles());
  if (s.sealer) g.bytes += s.sealer->MemoryBytes();
  // The queues at their fullest in the last step, not as its end left them: a budget checked
  // between slices would otherwise miss Q's peak (a cap's release, docs/decisions.md 8).
  // Plane caches as planned, like the slices.
  const size_t queues =
      std::max(s.simplifier.MemoryBytes(), SimplifierProbe::StepPeakBytes(s.simplifier));
  g.bytes += s.store.MemoryBytes() + queues + s.extractor.PlaneBytes(grid.dtype) +
             s.extractor.EdgeIdBytes() + s.extractor.StagingBytes();
  return g;
}

size_t TandemSession::Impl::MemoryBytes() {
  (void)Sync();
  size_t bytes = BufferBytes();
  for (const auto& s : slabs) bytes += Measure(*s).bytes;
  std::lock_guard<std::mutex> lock(mu);
  return bytes + cut_bytes;
}

TandemSession::Gauge TandemSession::Impl::Peek() {
  TandemSession::Gauge g;
  auto add = [&g](const SlabGauge& s) {
    g.triangles += s.triangles;
    g.memory_bytes += s.bytes;
  };
  if (queued) {
    std::lock_guard<std::mutex> lock(mu);
    for (const SlabGauge& s : gauges) add(s);
  } else {  // nothing runs behind the caller: the slabs as they are
    (void)Sync();
    for (const auto& s : slabs) add(Measure(*s));
  }
  {
    std::lock_guard<std::mutex> lock(mu);
    g.memory_bytes += cut_bytes;
    g.sealed_through = CutThrough();
    g.sealed_pending = CutTriangles(g.sealed_through);
  }
  g.memory_bytes += BufferBytes();  // after Sync, which pairs the seams
  g.peak_triangles = std::max(stats.peak_triangles, g.triangles);
  return g;
}

}  // namespace tandem
