#include "server/extract_job.h"

#include <algorithm>
#include <bit>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "codec/draco_codec.h"
#include "common/wire.h"
#include "tandem/distance.h"
#include "tandem/task_group.h"
#include "tandem/report.h"
#include "tandem/run_session.h"

namespace tandem::server {
namespace {

// The wire carries little-endian voxels and core reads host order: a big-endian port
// would need a byte swap in ConsumeSlice.
static_assert(std::endian::native == std::endian::little, "voxel bytes are little-endian");

using Clock = std::chrono::steady_clock;
double SecondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// What a snapshot of a mesh of `triangles` triangles and its Draco encoding take at their
// peak, on top of the session: the IndexedMesh (24 bytes a vertex and 12 a triangle, about
// 24 a triangle), Draco's encoder (its own mesh, corner table and attribute buffers: 67 to
// 99 bytes a triangle measured at 0.1 to 0.6 M triangles, quantization 16, level 7) and
// its output (under 4). Rounded up to 160.
size_t EncodeBytes(int64_t triangles) { return static_cast<size_t>(triangles) * 160; }
size_t SnapshotBytes(int64_t triangles) { return static_cast<size_t>(triangles) * 32; }
// The distances of compute_distances: the reference's snapshot (about 24 bytes a triangle)
// and the BVH over it (boxes, centroids and a permutation: about 80), rounded up.
size_t DistanceBytes(int64_t reference_triangles) {
  return static_cast<size_t>(reference_triangles) * 128;
}

// Sealed chunks: at least this many triangles each, unless kChunkSeconds went by (so that a
// viewer sees a sparse surface grow) or the stream ended. Fewer, larger chunks compress
// better and repeat fewer border vertices.
constexpr int64_t kChunkTriangles = 32768;
constexpr double kChunkSeconds = 1.0;

// One quantization grid for every chunk of a session: the volume's box in world
// coordinates, padded by a quarter of its largest extent on each side (simplified vertices
// may sit a little outside the box). A volume of unknown depth takes --max-slices as its
// depth, with more bits so that the step stays as fine as the slices' own extent gives.
codec::DracoOptions ChunkGrid(const VolumeInfo& g, codec::DracoOptions o, int64_t max_slices) {
  const int64_t nz = g.nz > 0 ? g.nz : max_slices;
  Vec3 lo{0, 0, 0}, hi{0, 0, 0};
  bool first = true;
  for (int corner = 0; corner < 8; ++corner) {
    const double u[3] = {(corner & 1) ? static_cast<double>(g.nx - 1) * g.spacing[0] : 0.0,
                         (corner & 2) ? static_cast<double>(g.ny - 1) * g.spacing[1] : 0.0,
                         (corner & 4) ? static_cast<double>(nz - 1) * g.spacing[2] : 0.0};
    Vec3 p{g.origin[0], g.origin[1], g.origin[2]};
    for (int axis = 0; axis < 3; ++axis) {
      for (int c = 0; c < 3; ++c) p[c] += u[axis] * g.directions[axis][c];
    }
    for (int c = 0; c < 3; ++c) {
      lo[c] = first ? p[c] : std::min(lo[c], p[c]);
      hi[c] = first ? p[c] : std::max(hi[c], p[c]);
    }
    first = false;
  }
  const double extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  if (g.nz == 0) {
    const double slice_extent = std::max(static_cast<double>(g.nx - 1) * g.spacing[0],
                                         static_cast<double>(g.ny - 1) * g.spacing[1]);
    if (slice_extent > 0 && extent > slice_extent) {
      o.quantization_bits = std::min(
          30, o.quantization_bits + static_cast<int>(std::ceil(std::log2(extent / slice_extent))));
    }
  }
  for (int c = 0; c < 3; ++c) o.grid_origin[c] = static_cast<float>(lo[c] - 0.25 * extent);
  o.grid_range = static_cast<float>(1.5 * extent);
  return o;
}

// A chunk's triangles in `count` runs of nearly equal length, each a chunk of the same slices
// (a span that holds every run's vertices) with the vertices its triangles use, in the
// chunk's order and under their ids: welded by id, they are the chunk. The retired ids go with
// the last (no later chunk has them). `fixed` (a flag a vertex of c, the corners the grid may
// not move) comes back as each part's flags, with the vertices of more than one part fixed
// too: the parts are encoded side by side, and each may move only what no other part has.
std::vector<SealedChunk> SplitChunk(SealedChunk c, size_t count,
                                    std::vector<std::vector<uint8_t>>* fixed) {
  const size_t n = c.num_triangles();
  constexpr uint32_t kUnused = ~uint32_t{0};
  std::vector<uint32_t> local(c.positions.size(), kUnused);
  std::vector<uint8_t> whole = std::move(fixed->at(0));
  for (size_t p = 0; p < count; ++p) {  // local: the last part that used the vertex
    for (size_t k = 3 * (n * p / count); k < 3 * (n * (p + 1) / count); ++k) {
      uint32_t& last = local[c.indices[k]];
      if (last != kUnused && last != p) whole[c.indices[k]] = 1;
      last = static_cast<uint32_t>(p);
    }
  }
  fixed->assign(count, {});
  std::vector<SealedChunk> out(count);
  for (size_t p = 0; p < count; ++p) {
    const size_t begin = n * p / count, end = n * (p + 1) / count;
    SealedChunk& o = out[p];
    o.index = c.index;
    o.first_slice = c.first_slice;
    o.last_slice = c.last_slice;
    std::fill(local.begin(), local.end(), kUnused);
    for (size_t k = 3 * begin; k < 3 * end; ++k) local[c.indices[k]] = 0;
    for (size_t v = 0; v < local.size(); ++v) {
      if (local[v] == kUnused) continue;
      local[v] = static_cast<uint32_t>(o.positions.size());
      o.positions.push_back(c.positions[v]);
      o.ids.push_back(c.ids[v]);
      (*fixed)[p].push_back(whole[v]);
    }
    o.indices.reserve(3 * (end - begin));
    for (size_t k = 3 * begin; k < 3 * end; ++k) o.indices.push_back(local[c.indices[k]]);
  }
  out.back().retired = std::move(c.retired);
  return out;
}

// While a session finishes (its caller's thread inside Finish), posts the last Progress
// again every kFinishingEvery seconds (the CLI's period, so a short finish shows in both) with
// the finishing fields: the client's status line after the last slice. The session's other
// observers wait for Finish; FinishProgress alone is read.
class FinishingTicker {
 public:
  FinishingTicker(const TandemSession& session, v1::Progress last, JobSink* sink)
      : thread_([this, &session, last = std::move(last), sink] {
          std::unique_lock<std::mutex> lock(mu_);
          const auto every = std::chrono::duration<double>(kFinishingEvery);
          while (!cv_.wait_for(lock, every, [this] { return stop_; })) {
            v1::Progress p = last;
            wire::FinishingToProto(session.FinishProgress(), &p);
            if (!p.finishing().empty()) sink->PostProgress(std::move(p));
          }
        }) {}
  ~FinishingTicker() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  FinishingTicker(const FinishingTicker&) = delete;
  FinishingTicker& operator=(const FinishingTicker&) = delete;

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread thread_;  // last: started once the rest is
};

// Bytes a job holds for a while beside its sessions (a chunk being encoded), told to their
// budget meanwhile: their queued steps run on beside it.
class HeldBeside {
 public:
  HeldBeside(MemoryBudget& budget, size_t bytes)
      : budget_(budget), bytes_(static_cast<int64_t>(bytes)) {
    budget_.AddOutside(bytes_);
  }
  ~HeldBeside() { budget_.AddOutside(-bytes_); }
  HeldBeside(const HeldBeside&) = delete;
  HeldBeside& operator=(const HeldBeside&) = delete;

 private:
  MemoryBudget& budget_;
  const int64_t bytes_;
};

const char* KindName(const v1::ExtractRequest& r) {
  switch (r.kind_case()) {
    case v1::ExtractRequest::kConfig: return "a SessionConfig";
    case v1::ExtractRequest::kChunk: return "a SliceChunk";
    case v1::ExtractRequest::kEnd: return "an End";
    case v1::ExtractRequest::kChunksReceived: return "a ChunksReceived";
    default: return "an empty ExtractRequest";
  }
}

}  // namespace

// What a child job posts, tagged with its surface and passed on through the parent's
// sink (none while the parent is detached: nothing is handled then, so nothing is lost).
class ExtractJob::SurfaceSink final : public JobSink {
 public:
  SurfaceSink(ExtractJob* parent, int surface) : parent_(parent), surface_(surface) {}
  void PostProgress(v1::Progress progress) override {
    parent_->surface_progress_[surface_] = std::move(progress);
    if (parent_->sink_) parent_->sink_->PostProgress(parent_->SumProgress());
  }
  void PostPreview(v1::Preview preview) override {
    preview.set_surface(surface_);
    if (parent_->sink_) parent_->sink_->PostPreview(std::move(preview));
  }
  bool PreviewPending() const override {
    return parent_->sink_ != nullptr && parent_->sink_->PreviewPending();
  }
  void PostFinal(std::vector<v1::ExtractResponse> messages) override {
    for (v1::ExtractResponse& m : messages) {
      if (m.has_final_mesh()) m.mutable_final_mesh()->set_surface(surface_);
      if (m.has_final_metrics()) m.mutable_final_metrics()->set_surface(surface_);
      parent_->surface_final_.push_back(std::move(m));
    }
  }
  void PostChunk(v1::SealedChunk chunk) override {
    chunk.set_surface(surface_);
    chunk.set_index(parent_->chunks_sent_++);
    if (parent_->sink_) parent_->sink_->PostChunk(std::move(chunk));
  }

 private:
  ExtractJob* parent_;
  int surface_;
};

ExtractJob::ExtractJob(const ServerLimits& limits, JobSink* sink, Executor* compute,
                       std::shared_ptr<MemoryBudget> budget)
    : limits_(limits),
      compute_(compute != nullptr ? compute : &Executor::Shared()),
      budget_(budget ? std::move(budget)
                     : std::make_shared<MemoryBudget>(limits.session_memory_bytes)),
      sink_(sink) {}

ExtractJob::~ExtractJob() {
  // The sessions stop and let go first (their own ends), then this job's own bytes.
  surfaces_.clear();
  session_.reset();
  reference_.reset();
  budget_->AddOutside(-static_cast<int64_t>(own_reported_));
}

absl::Status ExtractJob::StartSurfaces(const v1::SessionConfig& config) {
  const size_t n = config_.isos.size();
  ServerLimits child_limits = limits_;
  child_limits.session_memory_bytes = limits_.session_memory_bytes / static_cast<int64_t>(n);
  surface_progress_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    surface_sinks_.push_back(std::make_unique<SurfaceSink>(this, static_cast<int>(i)));
    surfaces_.push_back(std::make_unique<ExtractJob>(child_limits, surface_sinks_.back().get(),
                                                     compute_, budget_));
  }
  for (size_t i = 0; i < n; ++i) {
    v1::ExtractRequest request;
    v1::SessionConfig& c = *request.mutable_config();
    c = config;
    c.set_iso(config_.isos[i]);
    c.clear_extra_isos();
    if (absl::Status st = surfaces_[i]->Handle(request); !st.ok()) {
      return absl::Status(st.code(), absl::StrCat("surface ", i, " (iso ", config_.isos[i], "): ",
                                                  std::string(st.message())));
    }
  }
  start_ = Clock::now();
  state_ = State::kStreaming;
  return absl::OkStatus();
}

absl::Status ExtractJob::HandleSurfaces(v1::ExtractRequest& request) {
  if (state_ == State::kDone) {
    return absl::InvalidArgumentError(absl::StrCat("got ", KindName(request), " after End"));
  }
  for (size_t i = 0; i < surfaces_.size(); ++i) {
    absl::Status st;
    if (i + 1 < surfaces_.size()) {
      v1::ExtractRequest copy = request;
      st = surfaces_[i]->Handle(copy);
    } else {
      st = surfaces_[i]->Handle(request);  // the last one may take the data
    }
    // A problem of the request is found by the first child; one of a surface (its memory,
    // say) names it.
    if (!st.ok()) {
      if (i == 0) return st;
      return absl::Status(st.code(), absl::StrCat("surface ", i, " (iso ", config_.isos[i], "): ",
                                                  std::string(st.message())));
    }
  }
  if (surfaces_.back()->done()) {
    state_ = State::kDone;
    if (sink_) sink_->PostFinal(std::move(surface_final_));
    surface_final_.clear();
  }
  return absl::OkStatus();
}

v1::Progress ExtractJob::SumProgress() const {
  v1::Progress sum;
  for (size_t i = 0; i < surface_progress_.size(); ++i) {
    const v1::Progress& p = surface_progress_[i];
    if (i == 0 || p.slices_consumed() < sum.slices_consumed()) {
      sum.set_slices_consumed(p.slices_consumed());
    }
    sum.set_triangles(sum.triangles() + p.triangles());
    sum.set_peak_triangles(sum.peak_triangles() + p.peak_triangles());
    sum.set_sealed_triangles(sum.sealed_triangles() + p.sealed_triangles());
    if (!p.finishing().empty()) {  // the surface finishing now (they finish in turn)
      wire::FinishingToProto(wire::FinishingFromProto(p), &sum);
    }
  }
  if (config_.options.seal) sum.set_sealed_chunks(chunks_sent_);
  sum.set_slices_expected(config_.grid.nz);
  return sum;
}

int64_t ExtractJob::triangles() const {
  if (!surfaces_.empty()) {
    int64_t sum = 0;
    for (const auto& s : surfaces_) sum += s->triangles();
    return sum;
  }
  return session_ ? session_->Peek().triangles : final_triangles_;
}

absl::Status ExtractJob::Handle(v1::ExtractRequest& request) {
  absl::Status st = HandleMessage(request);
  ReportOwnBytes();
  return st;
}

absl::Status ExtractJob::HandleMessage(v1::ExtractRequest& request) {
  if (!surfaces_.empty()) return HandleSurfaces(request);
  switch (state_) {
    case State::kWaitConfig:
      if (!request.has_config()) {
        return absl::InvalidArgumentError(absl::StrCat(
            "the first message must be a SessionConfig, got ", KindName(request)));
      }
      return HandleConfig(request.config());
    case State::kStreaming:
      if (request.has_chunk()) return HandleChunk(*request.mutable_chunk());
      if (request.has_end()) return HandleEnd(request.end());
      return absl::InvalidArgumentError(absl::StrCat(
          "expected a SliceChunk or End after the config, got ", KindName(request)));
    case State::kDone:
      return absl::InvalidArgumentError(absl::StrCat("got ", KindName(request), " after End"));
  }
  return absl::InternalError("unreachable");
}

absl::Status ExtractJob::HandleEndOfInput() const {
  if (done()) return absl::OkStatus();
  if (state_ == State::kWaitConfig) {
    return absl::InvalidArgumentError("the stream ended before a SessionConfig");
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "the stream ended without an End marker after ", slices(),
      " complete slices; send End after the last slice"));
}

absl::Status ExtractJob::HandleConfig(const v1::SessionConfig& config) {
  absl::StatusOr<JobConfig> cfg = ValidateConfig(config, limits_);
  if (!cfg.ok()) return cfg.status();
  config_ = *std::move(cfg);
  if (config_.isos.size() > 1) return StartSurfaces(config);
  auto session = TandemSession::Create(config_.grid, config_.options, compute_, budget_);
  if (!session.ok()) return session.status();
  session_ = *std::move(session);
  if (config_.options.seal) chunk_draco_ = ChunkGrid(config_.grid, config_.draco, limits_.max_slices);
  if (config_.compute_distances) {
    SessionOptions full = config_.options;
    full.schedule = Schedule::kNone;
    full.seal = false;  // the whole surface stays, to measure against
    auto reference = TandemSession::Create(config_.grid, full, compute_, budget_);
    if (!reference.ok()) return reference.status();
    reference_ = *std::move(reference);
  }
  // A slice sent in pieces is assembled in a buffer of its own: count it now.
  if (absl::Status st = CheckMemory(config_.grid.slice_bytes(), "for this grid"); !st.ok()) {
    return st;
  }
  start_ = Clock::now();
  state_ = State::kStreaming;
  // At once, before any slice: tells the client the session is taken (it sends no slice
  // before it hears from the server, so a refused stream can be sent again untouched).
  sink_->PostProgress(MakeProgress());
  return absl::OkStatus();
}

absl::Status ExtractJob::HandleChunk(v1::SliceChunk& chunk) {
  if (absl::Status st = ValidateChunk(chunk, config_, cursor_, limits_); !st.ok()) return st;
  const size_t slice_bytes = config_.grid.slice_bytes();
  const std::string& data = chunk.data();
  if (cursor_.bytes_so_far == 0 && data.size() == slice_bytes) {
    // A whole slice in one message: no copy.
    return ConsumeSlice(reinterpret_cast<const uint8_t*>(data.data()));
  }
  if (slice_.size() != slice_bytes) {
    slice_.resize(slice_bytes);
    ReportOwnBytes();
  }
  std::memcpy(slice_.data() + cursor_.bytes_so_far, data.data(), data.size());
  cursor_.bytes_so_far += data.size();
  if (cursor_.bytes_so_far < slice_bytes) return absl::OkStatus();
  return ConsumeSlice(slice_.data());
}

absl::Status ExtractJob::ConsumeSlice(const uint8_t* bytes) {
  // The sessions refuse non-finite values (and name the voxel); the slice is prefixed here.
  for (TandemSession* s : {session_.get(), reference_.get()}) {
    if (s == nullptr) continue;
    if (absl::Status st = s->AddSliceBytes(config_.grid.dtype, bytes); !st.ok()) {
      if (budget_->stopped()) return SessionFailure(st);  // (names the slice it was at)
      return absl::Status(st.code(), absl::StrCat("slice ", cursor_.slice, ": ",
                                                  std::string(st.message())));
    }
  }
  ++cursor_.slice;
  cursor_.bytes_so_far = 0;
  if (absl::Status st = CheckMemory(0, absl::StrCat("after slice ", cursor_.slice - 1)); !st.ok()) {
    return st;
  }
  if (absl::Status st = MaybeChunk(false); !st.ok()) return st;
  sink_->PostProgress(MakeProgress());
  MaybePreview();
  return absl::OkStatus();
}

absl::Status ExtractJob::MaybeChunk(bool now, bool last) {
  if (!config_.options.seal) return absl::OkStatus();
  // Whether a chunk is due, between slices: what the slabs' finished steps sealed (Peek and
  // TakeSealedThrough: no wait for the steps in flight, which overlap the next slices; a wait
  // for them after every slice stepped the slabs in lock-step). `now`: all of it, the steps
  // waited for.
  const auto t0 = Clock::now();
  const TandemSession::Gauge gauge = now ? TandemSession::Gauge{} : session_->Peek();
  if (!now && (gauge.sealed_pending == 0 ||
               (gauge.sealed_pending < kChunkTriangles &&
                std::chrono::duration<double>(t0 - last_chunk_.value_or(start_)).count() <
                    kChunkSeconds))) {
    return absl::OkStatus();
  }
  const int64_t pending = now ? session_->sealed_pending() : gauge.sealed_pending;
  if (pending == 0) return absl::OkStatus();
  // Unlike a preview, a chunk cannot be skipped: over the budget, the stream fails.
  if (absl::Status st = CheckMemory(EncodeBytes(pending), "to encode a sealed chunk"); !st.ok()) {
    return st;
  }
  const HeldBeside encoding(*budget_, EncodeBytes(pending));
  SealedChunk c;
  if (!(now ? session_->TakeSealed(&c) : session_->TakeSealedThrough(gauge.sealed_through, &c))) {
    return absl::OkStatus();
  }
  // The stream's last chunk holds the time lag's band and the seams, sealed at once, and its
  // encoding ran on one core while the finished session left the others idle (0.5 s of a
  // dense 2048² stream's 4.3 s wait after its last slice). A large one goes out as one chunk
  // a compute thread (each of at least kChunkTriangles), encoded side by side.
  const size_t count =
      last ? std::clamp<size_t>(c.num_triangles() / static_cast<size_t>(kChunkTriangles), 1,
                                static_cast<size_t>(std::max(1, compute_->threads())))
           : 1;
  // On the session's grid, a corner an earlier chunk sent may not move, and goes out where
  // it was sent.
  std::vector<std::vector<uint8_t>> fixed(1, std::vector<uint8_t>(c.ids.size(), 0));
  for (size_t i = 0; i < c.ids.size(); ++i) {
    fixed[0][i] = sent_ids_.contains(c.ids[i]);
    if (auto it = sent_moved_.find(c.ids[i]); it != sent_moved_.end()) c.positions[i] = it->second;
  }
  for (uint32_t id : c.ids) sent_ids_.insert(id);
  std::vector<SealedChunk> parts;
  if (count > 1) {
    parts = SplitChunk(std::move(c), count, &fixed);
  } else {
    parts.push_back(std::move(c));
  }
  std::vector<IndexedMesh> meshes(parts.size());
  for (size_t i = 0; i < parts.size(); ++i) {
    meshes[i].positions = std::move(parts[i].positions);
    meshes[i].indices = std::move(parts[i].indices);
  }
  std::vector<absl::StatusOr<std::string>> bytes(parts.size());
  std::vector<codec::MovedCorners> moved(parts.size());
  {
    // Each part keeps off the last chunk's grid points and the earlier parts' (encoded side
    // by side, they cannot see each other's steps).
    std::vector<std::vector<Vec3>> avoid(parts.size(), last_sent_);
    for (size_t i = 1; i < parts.size(); ++i) {
      avoid[i] = avoid[i - 1];
      avoid[i].insert(avoid[i].end(), meshes[i - 1].positions.begin(),
                      meshes[i - 1].positions.end());
    }
    TaskGroup group(compute_);
    for (size_t i = 1; i < parts.size(); ++i) {
      group.Run([&, i] {
        bytes[i] = codec::EncodeDraco(meshes[i], chunk_draco_, parts[i].ids, fixed[i], &moved[i],
                                      avoid[i]);
      });
    }
    bytes[0] =
        codec::EncodeDraco(meshes[0], chunk_draco_, parts[0].ids, fixed[0], &moved[0], avoid[0]);
    for (const IndexedMesh& mesh : meshes) shape_.Add(mesh);  // the chunk's triangles in order
    group.Wait();
  }
  encode_s_ += SecondsSince(t0);
  last_sent_.clear();
  for (size_t i = 0; i < parts.size(); ++i) {
    const size_t at_part = last_sent_.size();
    last_sent_.insert(last_sent_.end(), meshes[i].positions.begin(), meshes[i].positions.end());
    for (const auto& [v, at] : moved[i]) {
      sent_moved_[parts[i].ids[v]] = at;
      last_sent_[at_part + v] = at;
    }
  }
  for (uint32_t id : parts.back().retired) {  // no later chunk has them
    sent_ids_.erase(id);
    sent_moved_.erase(id);
  }
  for (size_t i = 0; i < parts.size(); ++i) {
    if (!bytes[i].ok()) {
      return absl::InternalError(absl::StrCat("encoding sealed chunk ", chunks_sent_ + i, ": ",
                                              std::string(bytes[i].status().message())));
    }
  }
  for (size_t i = 0; i < parts.size(); ++i) {
    SealedChunk& part = parts[i];
    v1::SealedChunk out;
    out.set_index(chunks_sent_);  // 0, 1, ... as posted (the session's, but for a split)
    out.set_first_slice(part.first_slice);
    out.set_last_slice(part.last_slice);
    out.set_draco(*std::move(bytes[i]));
    out.set_triangles(static_cast<int64_t>(meshes[i].num_triangles()));
    out.set_vertices(static_cast<int64_t>(meshes[i].num_vertices()));
    sealed_posted_ += out.triangles();
    if (config_.compute_distances) {
      part.positions = std::move(meshes[i].positions);
      part.indices = std::move(meshes[i].indices);
      kept_.push_back(std::move(part));
    }
    ++chunks_sent_;
    chunk_bytes_ += static_cast<int64_t>(out.draco().size());
    sink_->PostChunk(std::move(out));
  }
  last_chunk_ = t0;
  return absl::OkStatus();
}

ExtractJob::Phases ExtractJob::PhaseSeconds() const {
  if (!surfaces_.empty()) {
    Phases sum;
    for (const auto& child : surfaces_) {
      const Phases p = child->PhaseSeconds();
      sum.extract_s += p.extract_s;
      sum.simplify_s += p.simplify_s;
      sum.encode_s += p.encode_s;
    }
    return sum;
  }
  const PhaseTimes& t = session_ ? session_->stats().time : session_time_;
  return {t.extract_s, t.simplify_s, encode_s_};
}

void ExtractJob::MaybePreview() {
  const int64_t every = config_.preview_every_slices;
  if (every <= 0 || cursor_.slice % every != 0) return;
  const auto now = Clock::now();
  // The server's floor bounds the cost whatever the client asks; a preview the client has
  // not taken yet means it reads slower than they come: encoding another would be wasted.
  const int64_t interval_ms =
      std::max(config_.preview_min_interval_ms, limits_.min_preview_interval_ms);
  if (last_preview_ && now - *last_preview_ < std::chrono::milliseconds(interval_ms)) return;
  if (sink_->PreviewPending()) return;
  // Previews are extra work on the session's thread: past their share of the wall time,
  // the next one waits (the first one always goes).
  const double share = limits_.max_preview_share;
  if (share > 0 && last_preview_ &&
      preview_s_ > share * std::chrono::duration<double>(now - start_).count()) {
    return;
  }
  // Sealed, a preview resends the whole band: their bytes stay under a share of the chunks'
  // (a quarter: a stream then sends under 2x its final mesh plus the last band, the chunks
  // being about 1.5x it).
  const double band_share = limits_.max_band_bytes_share;
  if (config_.options.seal && band_share > 0 && last_preview_ &&
      static_cast<double>(preview_bytes_) > band_share * static_cast<double>(chunk_bytes_)) {
    return;
  }
  // A preview is best effort: one that would take the session over its budget is skipped.
  if (!CheckMemory(EncodeBytes(session_->num_triangles()), "").ok()) return;
  // Sealed: everything sealed so far goes out first, so that chunks and band cover the mesh.
  if (!MaybeChunk(true).ok()) return;  // the stream fails at the next check anyway
  last_preview_ = now;
  const auto t0 = Clock::now();  // (MaybeChunk counted its own encoding)
  const IndexedMesh mesh = session_->Snapshot();
  absl::StatusOr<std::string> bytes = codec::EncodeDraco(mesh, config_.draco);
  encode_s_ += SecondsSince(t0);
  preview_s_ += SecondsSince(now);
  if (!bytes.ok()) return;  // a preview is best effort; the final mesh reports errors
  v1::Preview preview;
  preview.set_slice(cursor_.slice - 1);
  preview.set_draco(*std::move(bytes));
  preview.set_triangles(static_cast<int64_t>(mesh.num_triangles()));
  preview.set_vertices(static_cast<int64_t>(mesh.num_vertices()));
  preview.set_band_only(config_.options.seal);
  preview_bytes_ += static_cast<int64_t>(preview.draco().size());
  sink_->PostPreview(std::move(preview));
}

void ExtractJob::Detach() {
  cursor_.bytes_so_far = 0;  // the slice comes again, whole
  sink_ = nullptr;
  for (auto& s : surfaces_) s->cursor_.bytes_so_far = 0;
}

void ExtractJob::Attach(JobSink* sink) {
  sink_ = sink;
  sink_->PostProgress(surfaces_.empty() ? MakeProgress() : SumProgress());
}

v1::Progress ExtractJob::MakeProgress() const {
  v1::Progress p;
  p.set_slices_consumed(cursor_.slice);
  p.set_slices_expected(config_.grid.nz);
  // Sent after every slice: Peek, so that the stream does not wait for the session's
  // queued steps each time (they overlap the next slices).
  const TandemSession::Gauge gauge = session_->Peek();
  p.set_triangles(gauge.triangles);
  p.set_peak_triangles(gauge.peak_triangles);
  if (config_.options.seal) {
    p.set_sealed_triangles(sealed_posted_);
    p.set_sealed_chunks(chunks_sent_);
  }
  return p;
}

absl::Status ExtractJob::HandleEnd(const v1::End& end) {
  if (absl::Status st = ValidateEnd(end, config_, cursor_); !st.ok()) return st;
  for (TandemSession* s : {session_.get(), reference_.get()}) {
    if (s == nullptr) continue;
    std::optional<FinishingTicker> ticker;
    if (s == session_.get() && sink_ != nullptr) ticker.emplace(*s, MakeProgress(), sink_);
    if (absl::Status st = s->Finish(); !st.ok()) return SessionFailure(st);
  }
  if (absl::Status st = CheckMemory(0, "after the last slice"); !st.ok()) return st;
  if (config_.options.seal) return FinishSealed();
  // Every step below is counted before it allocates; the session is freed as soon as its
  // mesh and report are out, so the encoder never runs beside it.
  const int64_t triangles = session_->num_triangles();
  if (absl::Status st = CheckMemory(SnapshotBytes(triangles), "to copy out the final mesh");
      !st.ok()) {
    return st;
  }
  const IndexedMesh mesh = session_->Snapshot();
  // The triangles' shape sums (a tenth of a second a million triangles) are taken beside the
  // encoding below, on a core the finished session left idle.
  MetricsReport report = MakeReport(*session_, static_cast<int64_t>(mesh.num_triangles()),
                                    static_cast<int64_t>(mesh.num_vertices()), ShapeSums{});
  sink_->PostProgress(MakeProgress());
  session_time_ = session_->stats().time;
  session_.reset();
  final_triangles_ = triangles;
  if (absl::Status st = MeasureDistancesTo(mesh, &report); !st.ok()) return st;
  if (absl::Status st = CheckMemory(EncodeBytes(triangles), "to encode the final mesh");
      !st.ok()) {
    return st;
  }

  const auto t0 = Clock::now();
  absl::StatusOr<std::string> bytes;
  {
    ShapeSums shape;
    TaskGroup group(compute_);
    group.Run([&] { shape.Add(mesh); });
    bytes = codec::EncodeDraco(mesh, config_.draco);
    group.Wait();
    report.anisotropy = shape.anisotropy();
    report.directional_bias = shape.directional_bias();
  }
  encode_s_ += SecondsSince(t0);
  if (!bytes.ok()) {
    return absl::InternalError(absl::StrCat("encoding the final mesh: ",
                                            std::string(bytes.status().message())));
  }
  const std::string& all = *bytes;
  const size_t chunk = wire::kFinalMeshChunkBytes;
  const size_t count = std::max<size_t>(1, (all.size() + chunk - 1) / chunk);
  std::vector<v1::ExtractResponse> out;
  out.reserve(count + 1);
  for (size_t i = 0; i < count; ++i) {
    v1::FinalMesh* m = out.emplace_back().mutable_final_mesh();
    m->set_chunk_index(static_cast<uint32_t>(i));
    m->set_chunk_count(static_cast<uint32_t>(count));
    m->set_draco(all.substr(i * chunk, chunk));  // i * chunk <= size: no throw
    m->set_total_bytes(all.size());
    m->set_triangles(static_cast<int64_t>(mesh.num_triangles()));
    m->set_vertices(static_cast<int64_t>(mesh.num_vertices()));
  }
  final_triangles_ = static_cast<int64_t>(mesh.num_triangles());
  PostMetrics(report, std::move(out));
  return absl::OkStatus();
}

absl::Status ExtractJob::FinishSealed() {
  if (absl::Status st = MaybeChunk(true, true); !st.ok()) return st;  // the rest, sealed by Finish
  const SessionStats& stats = session_->stats();
  final_triangles_ = stats.sealed_triangles;
  MetricsReport report =
      MakeReport(*session_, stats.sealed_triangles, stats.sealed_vertices, shape_);
  sink_->PostProgress(MakeProgress());
  session_time_ = stats.time;
  session_.reset();
  if (reference_) {
    const IndexedMesh mesh = WeldChunks(kept_);
    kept_ = {};
    if (absl::Status st = MeasureDistancesTo(mesh, &report); !st.ok()) return st;
  }
  PostMetrics(report, {});
  return absl::OkStatus();
}

absl::Status ExtractJob::MeasureDistancesTo(const IndexedMesh& mesh, MetricsReport* report) {
  if (reference_) {
    if (absl::Status st = CheckMemory(EncodeBytes(static_cast<int64_t>(mesh.num_triangles())) +
                                          DistanceBytes(reference_->num_triangles()),
                                      "to measure the distances");
        !st.ok()) {
      return st;
    }
    DistanceOptions dopt;
    dopt.threads = 1;  // one core per session: other sessions share the machine
    report->distance = MeasureDistances(mesh, reference_->Snapshot(), dopt);
    reference_.reset();
  }
  report->peak_rss_bytes = PeakRssBytes();
  return absl::OkStatus();
}

void ExtractJob::PostMetrics(const MetricsReport& report, std::vector<v1::ExtractResponse> out) {
  v1::FinalMetrics* metrics = out.emplace_back().mutable_final_metrics();
  wire::ReportToProto(report, metrics);
  metrics->set_time_encode_s(encode_s_);
  metrics->set_time_wall_s(SecondsSince(start_));
  metrics->set_sealed_chunks(chunks_sent_);
  metrics->set_peak_session_bytes(static_cast<int64_t>(std::max(peak_memory_, MemoryBytes())));
  // bytes_received, bytes_sent and previews_sent are filled in by the transport, which
  // alone knows what went over the wire.
  slice_ = {};
  state_ = State::kDone;
  sink_->PostFinal(std::move(out));
}

absl::Status ExtractJob::CheckMemory(size_t extra, const std::string& when) {
  const int64_t budget = limits_.session_memory_bytes;
  const size_t bytes = MemoryBytes() + extra;
  if (budget <= 0 || bytes <= static_cast<uint64_t>(budget)) {
    peak_memory_ = std::max(peak_memory_, bytes);  // what is then allocated
    return absl::OkStatus();
  }
  return BudgetError(bytes, budget, when);
}

absl::Status ExtractJob::SessionFailure(absl::Status st) const {
  if (!absl::IsResourceExhausted(st) || !budget_->exceeded()) return st;
  return BudgetError(static_cast<size_t>(budget_->exceeded_bytes()), budget_->limit(),
                     "while " + budget_->exceeded_where());
}

absl::Status ExtractJob::BudgetError(size_t bytes, int64_t budget,
                                     const std::string& when) const {
  constexpr double kMiB = 1 << 20;
  return absl::ResourceExhaustedError(absl::StrFormat(
      "session memory budget exceeded: this stream needs %.1f MiB %s (mesh, simplification "
      "queues, slice buffers%s), over this server's per-session budget of %.1f MiB "
      "(tandem-server --session-memory-mb). Use a larger E0, a target triangle count or a "
      "smaller grid%s%s, or ask the operator to raise --session-memory-mb",
      static_cast<double>(bytes) / kMiB, when,
      reference_ ? ", and the full-resolution reference of compute_distances" : "",
      static_cast<double>(budget) / kMiB, reference_ ? ", drop compute_distances" : "",
      // Without sealing the simplified mesh stays in the session: its memory grows with the
      // slices (none yet: the grid's own buffers, which sealing does not change).
      config_.options.seal || cursor_.slice == 0
          ? ""
          : ", stream with sealed chunks (tandem-client --seal, SessionConfig.sealed_chunks: "
            "the session then holds the front, not the whole mesh)"));
}

size_t ExtractJob::OwnBytes() const {
  return slice_.capacity() + sent_ids_.capacity() * (sizeof(uint32_t) + 1) +
         sent_moved_.capacity() * (sizeof(uint32_t) + sizeof(Vec3) + 1) +
         last_sent_.capacity() * sizeof(Vec3);
}

void ExtractJob::ReportOwnBytes() {
  const size_t own = OwnBytes();
  budget_->AddOutside(static_cast<int64_t>(own) - static_cast<int64_t>(own_reported_));
  own_reported_ = own;
}

size_t ExtractJob::MemoryBytes() const {
  size_t bytes = OwnBytes();
  for (const auto& child : surfaces_) bytes += child->MemoryBytes();
  // Peek: exact between messages except for the slab steps still in flight (a few slices'
  // growth, counted at their end), and exact after Finish.
  if (session_) bytes += session_->Peek().memory_bytes;
  if (reference_) bytes += reference_->Peek().memory_bytes;
  return bytes;
}

}  // namespace tandem::server
