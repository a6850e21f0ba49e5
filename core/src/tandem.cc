#include "tandem/tandem.h"

#include <algorithm>
#include <cassert>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <future>
#include <limits>
#include <new>
#include <stdexcept>

#include "absl/strings/str_cat.h"
#include "prefetch.h"

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

absl::Status StatusOfException(std::exception_ptr e) {
  try {
    std::rethrow_exception(e);
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError("out of memory while processing this volume");
  } catch (const std::length_error& ex) {
    return absl::ResourceExhaustedError(
        absl::StrCat("a buffer of this session would exceed its maximum size (", ex.what(), ")"));
  } catch (const std::exception& ex) {
    return absl::InternalError(absl::StrCat("internal error in the session: ", ex.what()));
  } catch (...) {
    return absl::InternalError("internal error in the session (unknown exception)");
  }
}

namespace {

// The engine frame's unit (TandemSession): the power of two at or below the smallest
// spacing, so that scaling by it is exact.
double EngineScale(const VolumeInfo& g) {
  const double smallest = std::min({g.spacing[0], g.spacing[1], g.spacing[2]});
  return std::ldexp(1.0, std::ilogb(smallest));
}

// Whether all n values are finite; copies them to dst as well unless it is null. One pass
// of integer tests on the exponent bits, which the compiler vectorises.
bool CopyFinite(const float* src, size_t n, float* dst) {
  const uint32_t* in = reinterpret_cast<const uint32_t*>(src);  // float's bits (may alias)
  uint32_t bad = 0;
  if (dst == nullptr) {
    for (size_t i = 0; i < n; ++i) bad |= (in[i] & 0x7f800000u) == 0x7f800000u;
  } else {
    uint32_t* out = reinterpret_cast<uint32_t*>(dst);
    for (size_t i = 0; i < n; ++i) {
      out[i] = in[i];
      bad |= (in[i] & 0x7f800000u) == 0x7f800000u;
    }
  }
  return bad == 0;
}

// The number of parts a session over `grid` uses (SessionOptions::parts).
int PartsFor(const VolumeInfo& grid, int requested, bool seal) {
  if (seal) return 1;  // the seams would stay at full resolution, unsealed
  constexpr int64_t kMinColumns = 16;  // cube columns per part, at least
  const int64_t wanted = requested > 0 ? requested : (grid.nx >= 256 ? 4 : 1);
  return static_cast<int>(std::max<int64_t>(1, std::min(wanted, (grid.nx - 1) / kMinColumns)));
}

}  // namespace

TandemSession::TandemSession(const VolumeInfo& grid, const SessionOptions& options, int parts)
    : grid_(grid), options_(options), scale_(EngineScale(grid)) {
  const std::array<double, 3> spacing{grid.spacing[0] / scale_, grid.spacing[1] / scale_,
                                      grid.spacing[2] / scale_};
  // Part p owns cube columns [c_p, c_{p+1}) and grid columns c_p .. c_{p+1}.
  for (int p = 0; p < parts; ++p) {
    const int64_t c0 = p * (grid.nx - 1) / parts, c1 = (p + 1) * (grid.nx - 1) / parts;
    ExtractorConfig ec{c1 - c0 + 1, grid.ny, grid.nz, spacing, {0, 0, 0}, options.iso};
    ec.x_offset = c0;
    ec.row_stride = grid.nx;
    if (p > 0) ec.seam_faces |= kBoxXMin;
    if (p + 1 < parts) ec.seam_faces |= kBoxXMax;
    // With several parts the threads go to the parts, not to the batches inside one.
    const SimplifierOptions so{options.error / scale_, options.alpha, RuleFor(options.schedule),
                               spacing[2], options.pipeline && parts == 1,
                               options.distance_guard};
    parts_.push_back(std::make_unique<Part>(ec, so));
    if (options.seal) {
      Part& part = *parts_.back();
      const bool simplify = options.schedule != Schedule::kNone;
      part.sealer = std::make_unique<Sealer>(&part.store, simplify ? &part.simplifier : nullptr,
                                             options.seal_margin,
                                             simplify ? options.sag_correction : 0.0);
    }
    parts_.back()->x0 = c0;
    parts_.back()->index = static_cast<size_t>(p);
  }
  seams_.resize(static_cast<size_t>(parts - 1));
  // convert_ and the ring's slots are allocated on first use (AddSliceBytes, AddSliceImpl),
  // like the extractors' planes: a session that gets no voxel commits no slice memory.
  if (options.pipeline && parts > 1) StartWorkers();
}

TandemSession::~TandemSession() { StopWorkers(); }

void TandemSession::StartWorkers() {
  workers_ = true;
  const size_t cores = std::max(1u, std::thread::hardware_concurrency());
  workers_planned_ = std::min(cores, parts_.size());  // read by the workers: set first
  try {
    for (size_t i = 0; i < workers_planned_; ++i) {
      threads_.emplace_back([this, i] { Work(i); });
    }
  } catch (const std::system_error&) {
    if (threads_.empty()) StopWorkers();  // no thread to be had: the parts run in turn
  }
}

void TandemSession::StopWorkers() {
  if (!workers_) return;
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;  // slices still queued are dropped: only an abandoned session has any
  }
  cv_.notify_all();
  for (std::thread& t : threads_) t.join();
  threads_.clear();
  workers_ = false;
}

TandemSession::Part* TandemSession::NextPart(size_t worker) const {
  Part* next = nullptr;
  bool next_home = false;
  for (const auto& p : parts_) {
    if (p->busy || p->queue.empty()) continue;
    const bool home = p->index % workers_planned_ == worker;  // others steal a missing one's
    // Home parts first, then the part furthest behind.
    if (next == nullptr || (home && !next_home) ||
        (home == next_home && p->steps < next->steps)) {
      next = p.get();
      next_home = home;
    }
  }
  return next;
}

void TandemSession::Work(size_t worker) {
  for (;;) {
    Part* p = nullptr;
    int slot;
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [&] { return stop_ || (p = NextPart(worker)) != nullptr; });
      if (stop_) return;
      slot = p->queue.front();
      p->queue.pop_front();
      p->busy = true;
    }
    // ring_[slot] is not written while a part still needs it (pending > 0).
    absl::Status st;
    bool failed;
    {
      std::lock_guard<std::mutex> lock(mu_);
      failed = !p->error.ok();
    }
    try {
      // A part that failed is left as it is (mid-step): its queued slices are dropped.
      if (!failed) st = PartStep(*p, ring_[static_cast<size_t>(slot)].values.data() + p->x0);
    } catch (...) {  // this part is done for; Sync and AddSlice report it
      st = StatusOfException(std::current_exception());
    }
    {
      std::lock_guard<std::mutex> lock(mu_);
      p->busy = false;
      ++p->steps;
      --ring_[static_cast<size_t>(slot)].pending;
      if (!st.ok() && p->error.ok()) p->error = std::move(st);
    }
    cv_.notify_all();
  }
}

absl::Status TandemSession::Sync() const {
  if (workers_) {
    std::unique_lock<std::mutex> lock(mu_);
    cv_.wait(lock, [&] {
      for (const auto& p : parts_) {
        if (p->busy || !p->queue.empty()) return false;
      }
      return true;
    });
    for (const auto& p : parts_) {
      if (!p->error.ok()) return p->error;
    }
  }
  absl::Status st = PairSeams();
  FoldTraces();
  return st;
}

absl::Status TandemSession::PairSeams() const {
  for (size_t s = 0; s < seams_.size(); ++s) {
    auto& left = parts_[s]->seam_log[1];
    auto& right = parts_[s + 1]->seam_log[0];
    // Both parts see the same values on the shared plane, so they cross the same edges.
    if (left.size() != right.size()) {
      return absl::InternalError(absl::StrCat("the parts disagree on seam ", s, " (",
                                              left.size(), " vs ", right.size(), " vertices)"));
    }
    for (size_t i = 0; i < left.size(); ++i) seams_[s].emplace_back(left[i], right[i]);
    left.clear();
    right.clear();
  }
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<TandemSession>> TandemSession::Create(
    const VolumeInfo& grid, const SessionOptions& options) {
  VolumeInfo g = grid;
  if (absl::Status st = ValidateVolumeInfo(g); !st.ok()) return st;
  if (absl::Status st = options.ValidateFor(g); !st.ok()) return st;
  try {
    return std::unique_ptr<TandemSession>(new TandemSession(g, options, PartsFor(g, options.parts, options.seal)));
  } catch (const std::bad_alloc&) {
    // The extractor's plane caches are O(nx*ny); the only allocation that can be large here.
    return absl::ResourceExhaustedError(absl::StrCat(
        "not enough memory for a ", g.nx, "x", g.ny, " grid (about ",
        (g.nx * g.ny * 40) >> 20, " MiB of plane caches); use smaller slices"));
  }
}

void TandemSession::Record() {
  const int64_t n = num_triangles();
  stats_.trace.push_back(n);
  stats_.peak_triangles = std::max(stats_.peak_triangles, n);
}

void TandemSession::FoldTraces() const {
  const size_t n = parts_[0]->trace.size();
  for (; folded_ < n; ++folded_) {
    int64_t sum = 0;
    for (const auto& p : parts_) sum += p->trace[folded_];
    stats_.trace.push_back(sum);
    stats_.peak_triangles = std::max(stats_.peak_triangles, sum);
  }
}

int64_t TandemSession::num_triangles() const {
  (void)Sync();  // a failure is reported by AddSlice or Finish
  int64_t n = 0;
  for (const auto& p : parts_) n += static_cast<int64_t>(p->store.num_triangles());
  return n;
}

IndexedMesh TandemSession::Snapshot() const {
  (void)Sync();
  IndexedMesh out;
  if (parts_.size() == 1) {
    out = parts_[0]->store.Snapshot();
  } else {
    AppendPartSnapshots(&out);
  }
  ToWorld(&out.positions, &out.indices);
  return out;
}

void TandemSession::ToWorld(std::vector<Vec3>* positions, std::vector<uint32_t>* indices) const {
  const bool identity = scale_ == 1.0 && grid_.origin == std::array<double, 3>{0, 0, 0};
  const Vec3 origin{grid_.origin[0], grid_.origin[1], grid_.origin[2]};
  if (!grid_.axis_aligned()) {
    // world = origin + scale * (x d0 + y d1 + z d2); a mirrored frame reverses the winding so
    // that normals keep pointing out of the surface.
    const auto& d = grid_.directions;
    const Vec3 d0{d[0][0], d[0][1], d[0][2]}, d1{d[1][0], d[1][1], d[1][2]},
        d2{d[2][0], d[2][1], d[2][2]};
    for (Vec3& p : *positions) p = origin + (d0 * p.x + d1 * p.y + d2 * p.z) * scale_;
    if (Dot(Cross(d0, d1), d2) < 0) {
      for (size_t t = 0; t + 2 < indices->size(); t += 3) {
        std::swap((*indices)[t + 1], (*indices)[t + 2]);
      }
    }
  } else if (!identity) {
    for (Vec3& p : *positions) p = p * scale_ + origin;
  }
}

int64_t TandemSession::sealed_pending() const {
  (void)Sync();
  const Sealer* sealer = parts_[0]->sealer.get();
  return sealer != nullptr ? sealer->pending_triangles() : 0;
}

bool TandemSession::TakeSealed(SealedChunk* out) {
  (void)Sync();
  Sealer* sealer = parts_[0]->sealer.get();
  if (sealer == nullptr || !sealer->TakeChunk(out)) return false;
  ToWorld(&out->positions, &out->indices);
  return true;
}

void TandemSession::AppendPartSnapshots(IndexedMesh* out) const {
  // Part by part; a seam vertex takes the index its copy got in the part before.
  std::vector<uint32_t> map, prev;
  for (size_t p = 0; p < parts_.size(); ++p) {
    map.assign(parts_[p]->store.vertex_capacity(), kInvalid);
    if (p > 0) {
      for (const auto& [left, right] : seams_[p - 1]) map[right] = prev[left];
    }
    parts_[p]->store.AppendSnapshot(out, &map);
    prev.swap(map);
  }
}

template <typename F>
absl::Status TandemSession::Guarded(F&& f) {
  if (!failed_.ok()) return failed_;
  try {
    absl::Status st = f();
    if (!st.ok() && workers_) {
      // A worker's failure (Work) leaves its part mid-step: the session is done for.
      std::lock_guard<std::mutex> lock(mu_);
      for (const auto& p : parts_) {
        if (!p->error.ok()) failed_ = st;
      }
    }
    return st;
  } catch (...) {
    failed_ = StatusOfException(std::current_exception());
    return failed_;
  }
}

absl::Status TandemSession::AddSliceBytes(DType dtype, const uint8_t* bytes) {
  return Guarded([&] {
    if (dtype == DType::kFloat32 && reinterpret_cast<uintptr_t>(bytes) % alignof(float) == 0) {
      // host-order floats as they are
      return AddSliceImpl(reinterpret_cast<const float*>(bytes), DType::kFloat32, nullptr);
    }
    if (workers_) return AddSliceImpl(nullptr, dtype, bytes);  // converted into the ring
    convert_.resize(static_cast<size_t>(grid_.nx * grid_.ny));
    ConvertToFloat(dtype, bytes, convert_.size(), convert_.data());
    return AddSliceImpl(convert_.data(), dtype, nullptr);
  });
}

absl::Status TandemSession::AddSlice(const float* values) {
  return Guarded([&] { return AddSliceImpl(values, DType::kFloat32, nullptr); });
}

void TandemSession::ForEachPart(const std::function<void(Part&)>& f) {
  if (options_.pipeline && parts_.size() > 1) {
    std::vector<std::future<void>> running;
    try {
      for (size_t p = 0; p + 1 < parts_.size(); ++p) {
        running.push_back(std::async(std::launch::async, f, std::ref(*parts_[p])));
      }
    } catch (const std::system_error&) {
      // No thread to be had: the parts not started run here, in order (same result).
      for (size_t p = running.size(); p + 1 < parts_.size(); ++p) f(*parts_[p]);
    }
    f(*parts_.back());
    for (auto& r : running) r.get();
    return;
  }
  for (auto& p : parts_) f(*p);
}

void TandemSession::SimplifyStep(Part& p) {
  const auto t0 = Clock::now();
  p.simplifier.Delay(p.new_tris);
  p.simplifier.Activate(static_cast<double>(p.pending_front));
  p.simplifier.Simplify();
  if (p.sealer) p.sealer->Seal(static_cast<double>(p.pending_front));
  p.time.simplify_s += Seconds(t0, Clock::now());
  p.trace.push_back(static_cast<int64_t>(p.store.num_triangles()));
}

absl::Status TandemSession::PartStep(Part& p, const float* values) {
  absl::Status st;
  double extract_s = 0;
  auto compute = [&p, values, &extract_s] {
    const auto t0 = Clock::now();
    absl::Status s = p.extractor.ComputeLayer(values);
    extract_s = Seconds(t0, Clock::now());
    return s;
  };
  if (p.simplify_pending && options_.pipeline && parts_.size() == 1) {
    // EXTRACT(k) on a worker while SIMPLIFY of layer k-1 runs here. ComputeLayer touches
    // only the extractor's own buffers, and the simplifier never touches the front (the top
    // plane of layer k-1, which layer k reads), so the two do not share mutable data; the
    // store sees the same mutations in the same order as a sequential run.
    std::future<absl::Status> extracted = std::async(std::launch::async, compute);
    SimplifyStep(p);
    st = extracted.get();
  } else {
    if (p.simplify_pending) SimplifyStep(p);
    st = compute();
  }
  p.simplify_pending = false;
  if (!st.ok()) return st;
  const auto t1 = Clock::now();
  p.new_tris.clear();
  p.new_verts.clear();
  p.extractor.CommitLayer(&p.new_tris, &p.new_verts, &p.seam_log);
  p.triangles_extracted += static_cast<int64_t>(p.new_tris.size());
  if (options_.schedule != Schedule::kNone) p.simplifier.AddTriangles(p.new_tris, p.new_verts);
  if (p.sealer) {
    p.sealer->AddVertices(p.new_verts);
    // Full resolution: nothing will change below the front plane.
    if (options_.schedule == Schedule::kNone) {
      p.sealer->Seal(static_cast<double>(p.extractor.slices_done() - 1));
    }
  }
  p.time.extract_s += extract_s + Seconds(t1, Clock::now());
  p.trace.push_back(static_cast<int64_t>(p.store.num_triangles()));
  if (tandem_schedule()) {
    p.simplify_pending = true;
    p.pending_front = p.extractor.slices_done() - 1;
  }
  return absl::OkStatus();
}

absl::Status TandemSession::AddSliceImpl(const float* values, DType dtype,
                                         const uint8_t* bytes) {
  if (finished_) return absl::FailedPreconditionError("session already finished");
  const auto start = Clock::now();
  auto fail = [&](absl::Status st) {
    stats_.time.total_s += Seconds(start, Clock::now());
    return st;
  };
  const int64_t k = slices_added_;
  if (parts_.size() > 1) {
    // Each part checks its own columns (and the extractor the end of the volume); with
    // several, a bad slice must be refused before any of them moves (non-finite values:
    // below, while the slice is copied for the workers).
    if (grid_.nz > 0 && k >= grid_.nz) {
      return fail(absl::InvalidArgumentError(
          absl::StrCat("slice ", k, " is past the end of the volume (nz = ", grid_.nz, ")")));
    }
  }
  const size_t n = static_cast<size_t>(grid_.nx * grid_.ny);
  auto non_finite = [&](const float* v) {
    size_t idx = 0;
    while (std::isfinite(v[idx])) ++idx;
    const int64_t i = static_cast<int64_t>(idx);
    return fail(LayerExtractor::NonFiniteError(k, i % grid_.nx, i / grid_.nx, v[idx]));
  };
  if (workers_) {
    RingSlot& slot = ring_[static_cast<size_t>(ring_next_)];
    {
      std::unique_lock<std::mutex> lock(mu_);
      for (const auto& p : parts_) {
        if (!p->error.ok()) return fail(p->error);
      }
      cv_.wait(lock, [&] { return slot.pending == 0; });
    }
    // The slot is free (pending == 0) until it is queued: a refused slice leaves it so.
    slot.values.resize(n);
    float* dst = slot.values.data();
    if (values != nullptr) {
      if (!CopyFinite(values, n, dst)) return non_finite(values);
    } else {
      ConvertToFloat(dtype, bytes, n, dst);  // integer types are always finite
      if (dtype == DType::kFloat32 && !CopyFinite(dst, n, nullptr)) return non_finite(dst);
    }
    {
      std::lock_guard<std::mutex> lock(mu_);
      slot.pending = static_cast<int>(parts_.size());
      for (auto& p : parts_) p->queue.push_back(ring_next_);
    }
    cv_.notify_all();
    ring_next_ = (ring_next_ + 1) % kRingSlots;
    ++slices_added_;
    stats_.time.total_s += Seconds(start, Clock::now());
    return absl::OkStatus();
  }
  if (parts_.size() > 1 && !CopyFinite(values, n, nullptr)) return non_finite(values);
  std::vector<absl::Status> status(parts_.size());
  ForEachPart([&](Part& p) { status[p.index] = PartStep(p, values + p.x0); });
  for (const absl::Status& st : status) {
    if (!st.ok()) {
      FoldTraces();  // the SIMPLIFY step before the failed EXTRACT happened
      return fail(st);
    }
  }
  if (absl::Status st = Sync(); !st.ok()) return fail(st);
  ++slices_added_;
  stats_.time.total_s += Seconds(start, Clock::now());
  return absl::OkStatus();
}

void TandemSession::FinishPart(Part& p) {
  if (p.simplify_pending) SimplifyStep(p);
  p.simplify_pending = false;
  p.extractor.Finish();
  if (options_.schedule == Schedule::kNone) return;
  const auto t0 = Clock::now();
  if (options_.schedule == Schedule::kClassical) {
    // INSERT every edge of the full-resolution surface, then one SIMPLIFY.
    std::vector<TriId> all;
    all.reserve(p.store.num_triangles());
    for (TriId t = 0; t < p.store.triangle_capacity(); ++t) {
      if (p.store.triangle_alive(t)) all.push_back(t);
    }
    p.simplifier.Delay(all);
  }
  p.simplifier.Activate(std::numeric_limits<double>::infinity());
  p.simplifier.Simplify();
  p.time.simplify_s += Seconds(t0, Clock::now());
}

void TandemSession::MergeParts() {
  Part& dst = *parts_[0];
  const bool simplify = options_.schedule != Schedule::kNone;
  std::vector<VertexId> seam_vertices;  // in dst
  std::vector<VertexId> map, prev;      // a part's ids -> dst's (prev: the part before)
  for (size_t p = 1; p < parts_.size(); ++p) {
    Part& src = *parts_[p];
    map.assign(src.store.vertex_capacity(), kInvalid);
    for (const auto& [left, right] : seams_[p - 1]) {
      const VertexId v = p == 1 ? left : prev[left];
      assert(dst.store.vertex_alive(v) && src.store.vertex_alive(right));
      map[right] = v;
      dst.store.set_box_mask(v, (dst.store.box_mask(v) | src.store.box_mask(right)) &
                                    static_cast<uint8_t>(~kSeam));
      if (simplify) dst.simplifier.AdoptVertex(src.simplifier, right, v, /*shared=*/true);
      seam_vertices.push_back(v);
    }
    for (VertexId v = 0; v < src.store.vertex_capacity(); ++v) {
      if (!src.store.vertex_alive(v) || map[v] != kInvalid) continue;
      map[v] = dst.store.AddVertex(src.store.position(v), src.store.height(v), src.store.layer(v),
                                   src.store.box_mask(v));
      if (simplify) dst.simplifier.AdoptVertex(src.simplifier, v, map[v], /*shared=*/false);
    }
    for (TriId t = 0; t < src.store.triangle_capacity(); ++t) {
      if (!src.store.triangle_alive(t)) continue;
      const auto& tri = src.store.triangle(t);
      dst.store.AddTriangle(map[tri[0]], map[tri[1]], map[tri[2]]);
    }
    if (simplify) dst.simplifier.AdoptCounters(src.simplifier);
    merged_crossed_cubes_ += src.extractor.crossed_cubes();
    merged_triangles_extracted_ += src.triangles_extracted;
    merged_time_.extract_s += src.time.extract_s;
    merged_time_.simplify_s += src.time.simplify_s;
    prev.swap(map);
    parts_[p].reset();  // copied: give its memory back before the next part grows dst
  }
  parts_.resize(1);
  seams_.clear();
  if (!simplify) return;
  // SIMPLIFY(E0) from the seam: every other edge was settled inside its part and keeps its
  // cost; contractions here re-queue their neighbours as usual.
  const auto t0 = Clock::now();
  dst.simplifier.PushEdgesAround(seam_vertices);
  dst.simplifier.Simplify();
  dst.time.simplify_s += Seconds(t0, Clock::now());
}

absl::Status TandemSession::Finish() {
  return Guarded([&] { return FinishImpl(); });
}

absl::Status TandemSession::FinishImpl() {
  if (finished_) return absl::FailedPreconditionError("session already finished");
  const auto start = Clock::now();  // the parts' workers may still be busy: their time counts
  if (absl::Status st = Sync(); !st.ok()) return st;
  const int64_t done = parts_[0]->extractor.slices_done();
  if (done < 2) {
    return absl::FailedPreconditionError(
        absl::StrCat("the stream ended after ", done, " slice(s); at least 2 are needed"));
  }
  if (grid_.nz > 0 && done != grid_.nz) {
    return absl::FailedPreconditionError(absl::StrCat(
        "the stream ended after ", done, " slices but the volume declared nz = ", grid_.nz));
  }
  StopWorkers();
  ForEachPart([this](Part& p) { FinishPart(p); });
  finished_ = true;
  FoldTraces();
  if (parts_.size() > 1) MergeParts();
  Part& whole = *parts_[0];
  if (options_.schedule != Schedule::kNone && options_.target_triangles > 0 &&
      num_triangles() > options_.target_triangles) {
    const auto t0 = Clock::now();
    whole.simplifier.RequeueAll();
    whole.simplifier.Simplify(options_.target_triangles);
    whole.time.simplify_s += Seconds(t0, Clock::now());
  }
  if (whole.sealer) {
    const auto t0 = Clock::now();
    whole.sealer->Seal(std::numeric_limits<double>::infinity());  // the rest, sag included
    stats_.sag_corrected = whole.sealer->sag_corrected();
    whole.time.simplify_s += Seconds(t0, Clock::now());
  } else if (options_.schedule != Schedule::kNone && options_.sag_correction > 0.0) {
    const auto t0 = Clock::now();
    stats_.sag_corrected = whole.simplifier.CorrectSag(options_.sag_correction);
    whole.time.simplify_s += Seconds(t0, Clock::now());
  }
  Record();
  stats_.time.total_s += Seconds(start, Clock::now());
  return absl::OkStatus();
}

const SessionStats& TandemSession::stats() const {
  (void)Sync();
  const Part& first = *parts_[0];
  stats_.slices = first.extractor.slices_done();
  stats_.crossed_cubes = merged_crossed_cubes_;
  stats_.triangles_extracted = merged_triangles_extracted_;
  stats_.time.extract_s = merged_time_.extract_s;
  stats_.time.simplify_s = merged_time_.simplify_s;
  stats_.refusals = RefusalCounts{};
  stats_.contractions = 0;
  stats_.max_reach_over_front = -std::numeric_limits<double>::infinity();
  stats_.max_layer_over_front = -std::numeric_limits<double>::infinity();
  for (const auto& p : parts_) {
    stats_.crossed_cubes += p->extractor.crossed_cubes();
    stats_.triangles_extracted += p->triangles_extracted;
    stats_.time.extract_s += p->time.extract_s;
    stats_.time.simplify_s += p->time.simplify_s;
    stats_.refusals += p->simplifier.refusals();
    stats_.contractions += p->simplifier.contractions();
    stats_.max_reach_over_front =
        std::max(stats_.max_reach_over_front, p->simplifier.max_reach_over_front());
    stats_.max_layer_over_front =
        std::max(stats_.max_layer_over_front, p->simplifier.max_layer_over_front());
    if (p->sealer) {
      stats_.sealed_triangles = p->sealer->sealed_triangles();
      stats_.sealed_vertices = p->sealer->sealed_vertices();
      stats_.sag_corrected = p->sealer->sag_corrected();
    }
  }
  return stats_;
}

double TandemSession::MaxShapeError() const {
  if (options_.schedule == Schedule::kNone) return 0.0;
  (void)Sync();
  double worst = 0.0;
  for (const auto& p : parts_) {
    worst = std::max(worst, p->simplifier.MaxShapeError());
    if (p->sealer) worst = std::max(worst, p->sealer->max_shape_error());
  }
  return worst * scale_;
}

size_t TandemSession::MemoryBytes() const {
  (void)Sync();
  // Slice buffers and plane caches as planned (allocated on the first slice), so that a
  // budget checked before any voxel counts them.
  const size_t slice = static_cast<size_t>(grid_.nx * grid_.ny) * sizeof(float);
  size_t bytes = workers_ ? kRingSlots * slice : slice;
  for (const auto& p : parts_) {
    const ExtractorConfig& ec = p->extractor.config();
    if (p->sealer) bytes += p->sealer->MemoryBytes();
    bytes += p->store.MemoryBytes() + p->simplifier.MemoryBytes() +
             static_cast<size_t>(ec.nx * ec.ny) * (2 * sizeof(double) + 5 * sizeof(VertexId));
  }
  for (const auto& s : seams_) bytes += s.capacity() * sizeof(s[0]);
  return bytes;
}

absl::StatusOr<std::unique_ptr<TandemSession>> RunSession(
    SliceSource& source, const SessionOptions& options,
    const std::function<void(int64_t, int64_t)>& progress,
    const std::function<absl::Status(SealedChunk)>& on_chunk) {
  std::function<absl::Status(size_t, SealedChunk)> each;
  if (on_chunk) each = [&](size_t, SealedChunk c) { return on_chunk(std::move(c)); };
  auto sessions = RunSessions(source, {options}, progress, each);
  if (!sessions.ok()) return sessions.status();
  return std::move(sessions->front());
}

absl::StatusOr<std::vector<std::unique_ptr<TandemSession>>> RunSessions(
    SliceSource& source, const std::vector<SessionOptions>& options,
    const std::function<void(int64_t, int64_t)>& progress,
    const std::function<absl::Status(size_t, SealedChunk)>& on_chunk) {
  const VolumeInfo& info = source.info();
  if (options.empty()) return absl::InvalidArgumentError("RunSessions: no session options");
  std::vector<std::unique_ptr<TandemSession>> sessions;
  for (const SessionOptions& o : options) {
    if (o.seal && on_chunk == nullptr) {
      return absl::InvalidArgumentError("RunSession: sealing needs somewhere to put the chunks");
    }
    auto session = TandemSession::Create(info, o);
    if (!session.ok()) return session.status();
    sessions.push_back(*std::move(session));
  }
  auto take = [&]() -> absl::Status {
    for (size_t i = 0; i < sessions.size(); ++i) {
      if (!options[i].seal) continue;
      SealedChunk c;
      while (sessions[i]->TakeSealed(&c)) {
        if (absl::Status st = on_chunk(i, std::move(c)); !st.ok()) return st;
      }
    }
    return absl::OkStatus();
  };
  // Each session copies the slice into its own ring and, when pipelined, returns while its
  // workers go on: the sessions run side by side from one read of the slice.
  auto add = [&](int64_t k, const uint8_t* bytes) {
    for (auto& session : sessions) {
      absl::Status st = session->AddSliceBytes(info.dtype, bytes);
      if (!st.ok()) {
        return absl::Status(st.code(), absl::StrCat("slice ", k, ": ", std::string(st.message())));
      }
    }
    if (absl::Status st = take(); !st.ok()) return st;
    if (progress) progress(k + 1, info.nz);
    return absl::OkStatus();
  };
  // A mapped file hands its slices over in place: the session's copy into its ring is the
  // only one (a read() would copy every byte out of the page cache first).
  const uint8_t* view = nullptr;
  if (absl::Status st = source.ViewSlice(&view); !st.ok()) return st;
  if (view != nullptr) {
    for (int64_t k = 0; k < info.nz; ++k) {
      if (k > 0) {
        if (absl::Status st = source.ViewSlice(&view); !st.ok()) return st;
      }
      if (absl::Status st = add(k, view); !st.ok()) return st;
    }
  } else {
    // Reading runs ahead on another thread; conversion happens on the way into the session.
    // nz = 0 (a followed acquisition): until the source says OutOfRange.
    SlicePrefetcher prefetch(&source);
    std::vector<uint8_t> bytes;
    for (int64_t k = 0; info.nz == 0 || k < info.nz; ++k) {
      absl::Status st = prefetch.Next(&bytes);
      if (info.nz == 0 && absl::IsOutOfRange(st)) break;
      if (!st.ok()) return st;
      if (absl::Status st = add(k, bytes.data()); !st.ok()) return st;
    }
  }
  // The final SIMPLIFY of each surface, side by side as well (async | deferred: here, in
  // turn, when no thread can be had).
  std::vector<std::future<absl::Status>> finishing;
  for (size_t i = 1; i < sessions.size(); ++i) {
    finishing.push_back(std::async(std::launch::async | std::launch::deferred,
                                   [s = sessions[i].get()] { return s->Finish(); }));
  }
  absl::Status finished = sessions[0]->Finish();
  for (auto& f : finishing) {
    absl::Status st = f.get();
    if (finished.ok()) finished = st;
  }
  if (!finished.ok()) return finished;
  if (absl::Status st = take(); !st.ok()) return st;
  return sessions;
}

}  // namespace tandem
