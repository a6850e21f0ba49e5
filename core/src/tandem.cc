#include "tandem/tandem.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <new>

#include "absl/strings/str_cat.h"
#include "tandem/prefetch.h"

namespace tandem {
namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

ReleaseRule RuleFor(Schedule s) {
  switch (s) {
    case Schedule::kTandem: return ReleaseRule::kLayer;
    case Schedule::kTandemLag: return ReleaseRule::kReach;
    default: return ReleaseRule::kImmediate;
  }
}

}  // namespace

std::string_view ScheduleName(Schedule s) {
  switch (s) {
    case Schedule::kNone: return "none";
    case Schedule::kClassical: return "classical";
    case Schedule::kTandem: return "tandem";
    case Schedule::kTandemLag: return "tandem-lag";
  }
  return "?";
}

absl::StatusOr<Schedule> ParseSchedule(std::string_view name) {
  for (Schedule s : {Schedule::kNone, Schedule::kClassical, Schedule::kTandem,
                     Schedule::kTandemLag}) {
    if (name == ScheduleName(s)) return s;
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "unknown schedule '", std::string(name), "'; expected classical, tandem or tandem-lag"));
}

absl::Status SessionOptions::Validate() const {
  if (!std::isfinite(iso)) return absl::InvalidArgumentError("iso-value must be a finite number");
  if (schedule == Schedule::kNone) return absl::OkStatus();
  if (!(error > 0) || !std::isfinite(error)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "error threshold E0 must be a finite number > 0 (physical units), got ", error));
  }
  if (!(alpha >= 0 && alpha <= 1)) {
    return absl::InvalidArgumentError(
        absl::StrCat("isotropy alpha must lie in [0, 1], got ", alpha));
  }
  if (target_triangles < 0) {
    return absl::InvalidArgumentError("target triangle count must be >= 0");
  }
  return absl::OkStatus();
}

TandemSession::TandemSession(const VolumeInfo& grid, const SessionOptions& options)
    : grid_(grid),
      options_(options),
      extractor_(ExtractorConfig{grid.nx, grid.ny, grid.nz, grid.spacing, grid.origin, options.iso},
                 &store_),
      simplifier_(&store_, SimplifierOptions{options.error, options.alpha,
                                             RuleFor(options.schedule), grid.spacing[2],
                                             options.pipeline}) {
  convert_.resize(static_cast<size_t>(grid.nx * grid.ny));
}

absl::StatusOr<std::unique_ptr<TandemSession>> TandemSession::Create(
    const VolumeInfo& grid, const SessionOptions& options) {
  VolumeInfo g = grid;
  if (absl::Status st = ValidateVolumeInfo(g); !st.ok()) return st;
  if (absl::Status st = options.Validate(); !st.ok()) return st;
  try {
    return std::unique_ptr<TandemSession>(new TandemSession(g, options));
  } catch (const std::bad_alloc&) {
    // The extractor's plane caches are O(nx*ny); the only allocation that can be large here.
    return absl::ResourceExhaustedError(absl::StrCat(
        "not enough memory for a ", g.nx, "x", g.ny, " grid (about ",
        (g.nx * g.ny * 40) >> 20, " MiB of plane caches); use smaller slices"));
  }
}

void TandemSession::Record() {
  const int64_t n = static_cast<int64_t>(store_.num_triangles());
  stats_.trace.push_back(n);
  stats_.peak_triangles = std::max(stats_.peak_triangles, n);
}

absl::Status TandemSession::AddSliceBytes(DType dtype, const uint8_t* bytes) {
  ConvertToFloat(dtype, bytes, convert_.size(), convert_.data());
  return AddSlice(convert_.data());
}

void TandemSession::SimplifyStep() {
  const auto t0 = Clock::now();
  simplifier_.Delay(new_tris_);
  simplifier_.Activate(static_cast<double>(pending_front_));
  simplifier_.Simplify();
  stats_.time.simplify_s += Seconds(t0, Clock::now());
  simplify_pending_ = false;
  Record();
}

absl::Status TandemSession::AddSlice(const float* values) {
  if (finished_) return absl::FailedPreconditionError("session already finished");
  const auto start = Clock::now();
  absl::Status st;
  double extract_s = 0;
  auto compute = [this, values, &extract_s] {
    const auto t0 = Clock::now();
    absl::Status s = extractor_.ComputeLayer(values);
    extract_s = Seconds(t0, Clock::now());
    return s;
  };
  if (simplify_pending_ && options_.pipeline) {
    // EXTRACT(k) on a worker while SIMPLIFY of layer k-1 runs here. ComputeLayer touches
    // only the extractor's own buffers, and the simplifier never touches the front (the top
    // plane of layer k-1, which layer k reads), so the two do not share mutable data; the
    // store sees the same mutations in the same order as a sequential run.
    std::future<absl::Status> extracted = std::async(std::launch::async, compute);
    SimplifyStep();
    st = extracted.get();
  } else {
    if (simplify_pending_) SimplifyStep();
    st = compute();
  }
  if (!st.ok()) {
    stats_.time.total_s += Seconds(start, Clock::now());
    return st;
  }
  const auto t1 = Clock::now();
  new_tris_.clear();
  new_verts_.clear();
  extractor_.CommitLayer(&new_tris_, &new_verts_);
  stats_.triangles_extracted += static_cast<int64_t>(new_tris_.size());
  if (options_.schedule != Schedule::kNone) simplifier_.AddTriangles(new_tris_, new_verts_);
  stats_.time.extract_s += extract_s + Seconds(t1, Clock::now());
  Record();
  if (tandem_schedule()) {
    simplify_pending_ = true;
    pending_front_ = extractor_.slices_done() - 1;
  }
  stats_.time.total_s += Seconds(start, Clock::now());
  return absl::OkStatus();
}

absl::Status TandemSession::Finish() {
  if (finished_) return absl::FailedPreconditionError("session already finished");
  const int64_t done = extractor_.slices_done();
  if (done < 2) {
    return absl::FailedPreconditionError(
        absl::StrCat("the stream ended after ", done, " slice(s); at least 2 are needed"));
  }
  if (grid_.nz > 0 && done != grid_.nz) {
    return absl::FailedPreconditionError(absl::StrCat(
        "the stream ended after ", done, " slices but the volume declared nz = ", grid_.nz));
  }
  const auto start = Clock::now();
  if (simplify_pending_) SimplifyStep();
  finished_ = true;
  extractor_.Finish();
  if (options_.schedule == Schedule::kNone) return absl::OkStatus();
  const auto t0 = Clock::now();
  if (options_.schedule == Schedule::kClassical) {
    // INSERT every edge of the full-resolution surface, then one SIMPLIFY.
    std::vector<TriId> all;
    all.reserve(store_.num_triangles());
    for (TriId t = 0; t < store_.triangle_capacity(); ++t) {
      if (store_.triangle_alive(t)) all.push_back(t);
    }
    simplifier_.Delay(all);
  }
  simplifier_.Activate(std::numeric_limits<double>::infinity());
  simplifier_.Simplify();
  if (options_.target_triangles > 0 && num_triangles() > options_.target_triangles) {
    simplifier_.RequeueAll();
    simplifier_.Simplify(options_.target_triangles);
  }
  stats_.time.simplify_s += Seconds(t0, Clock::now());
  Record();
  stats_.time.total_s += Seconds(start, Clock::now());
  return absl::OkStatus();
}

const SessionStats& TandemSession::stats() const {
  stats_.slices = extractor_.slices_done();
  stats_.crossed_cubes = extractor_.crossed_cubes();
  stats_.refusals = simplifier_.refusals();
  stats_.contractions = simplifier_.contractions();
  stats_.max_reach_over_front = simplifier_.max_reach_over_front();
  stats_.max_layer_over_front = simplifier_.max_layer_over_front();
  return stats_;
}

double TandemSession::MaxShapeError() const {
  return options_.schedule == Schedule::kNone ? 0.0 : simplifier_.MaxShapeError();
}

size_t TandemSession::MemoryBytes() const {
  return store_.MemoryBytes() + simplifier_.MemoryBytes() +
         convert_.capacity() * sizeof(float) +
         static_cast<size_t>(grid_.nx * grid_.ny) * (2 * sizeof(double) + 5 * sizeof(VertexId));
}

absl::StatusOr<std::unique_ptr<TandemSession>> RunSession(
    SliceSource& source, const SessionOptions& options,
    const std::function<void(int64_t, int64_t)>& progress) {
  const VolumeInfo& info = source.info();
  auto session = TandemSession::Create(info, options);
  if (!session.ok()) return session.status();
  // Reading and conversion run one slice ahead on a second thread.
  SlicePrefetcher prefetch(&source);
  std::vector<float> values;
  for (int64_t k = 0; k < info.nz; ++k) {
    if (absl::Status st = prefetch.Next(&values); !st.ok()) return st;
    if (absl::Status st = (*session)->AddSlice(values.data()); !st.ok()) {
      return absl::Status(st.code(), absl::StrCat("slice ", k, ": ", std::string(st.message())));
    }
    if (progress) progress(k + 1, info.nz);
  }
  if (absl::Status st = (*session)->Finish(); !st.ok()) return st;
  return session;
}

}  // namespace tandem
