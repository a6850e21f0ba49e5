// What an ExtractJob sends while the slices arrive: sealed chunks on one Draco grid, and
// previews.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "extract_job_internal.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/server/extract_job.h"
#include "tandem/status_macros.h"
#include "tandem/task_group.h"

namespace tandem::server {
namespace {

// Sealed chunks: at least this many triangles each, unless kChunkSeconds went by (so that a
// viewer sees a sparse surface grow) or the stream ended. Fewer, larger chunks compress
// better and repeat fewer border vertices; smaller ones hold less while they are taken and
// encoded, and a short stream already reaches their size, so a long one peaks no higher.
constexpr int64_t kChunkTriangles = 16384;
constexpr double kChunkSeconds = 1.0;
// A chunk is encoded in parts of at most this many triangles, so that the encoder's buffers
// (EncodeBytes a triangle) stay bounded whatever the server's pace left pending.
constexpr int64_t kEncodeTriangles = kChunkTriangles;

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
    if (!c.patch.empty()) {  // a label session's: each triangle's pair goes with it
      o.patch.assign(c.patch.begin() + static_cast<ptrdiff_t>(begin),
                     c.patch.begin() + static_cast<ptrdiff_t>(end));
      o.pairs = c.pairs;
    }
  }
  out.back().retired = std::move(c.retired);
  return out;
}

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

}  // namespace

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
  // The stream's last chunk holds the time lag's band and the seams, sealed at once, and its
  // encoding ran on one core while the finished session left the others idle
  // (docs/decisions.md 46): its parts are encoded side by side, one a compute thread.
  const int64_t side_by_side = last ? std::max(1, compute_->threads()) : 1;
  // The chunk itself, and the parts being encoded at once.
  const size_t encode_bytes =
      SnapshotBytes(pending) + EncodeBytes(std::min(pending, side_by_side * kEncodeTriangles));
  // Unlike a preview, a chunk cannot be skipped: over the budget, the stream fails.
  TANDEM_RETURN_IF_ERROR(CheckMemory(encode_bytes, "to encode a sealed chunk"));
  const HeldBeside encoding(*budget_, encode_bytes);
  SealedChunk c;
  if (!(now ? session_->TakeSealed(&c) : session_->TakeSealedThrough(gauge.sealed_through, &c))) {
    return absl::OkStatus();
  }
  const size_t count = static_cast<size_t>(std::max<int64_t>(
      1, (static_cast<int64_t>(c.num_triangles()) + kEncodeTriangles - 1) / kEncodeTriangles));
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
    // Each part keeps off the last chunk's grid points and the earlier parts' as they were
    // taken (a part encoded side by side cannot see the others' steps): a prefix of `seen`.
    std::vector<Vec3> seen = last_sent_;
    std::vector<size_t> avoid(parts.size());
    for (size_t i = 0; i < parts.size(); ++i) {
      avoid[i] = seen.size();
      seen.insert(seen.end(), meshes[i].positions.begin(), meshes[i].positions.end());
    }
    auto encode = [&](size_t i) {
      bytes[i] = codec::EncodeDraco(meshes[i], chunk_draco_, parts[i].ids, fixed[i], &moved[i],
                                    std::span<const Vec3>(seen.data(), avoid[i]));
    };
    const size_t width = static_cast<size_t>(side_by_side);
    for (size_t first = 0; first < parts.size(); first += width) {
      TaskGroup group(compute_);
      const size_t end = std::min(parts.size(), first + width);
      for (size_t i = first + 1; i < end; ++i) group.Run([&encode, i] { encode(i); });
      encode(first);
      group.Wait();
    }
    for (const IndexedMesh& mesh : meshes) shape_.Add(mesh);  // the chunk's triangles in order
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
  if (config_.options.labels.enabled) {
    for (size_t i = 0; i < parts.size(); ++i) {
      TANDEM_RETURN_IF_ERROR(PostLabelChunks(std::move(parts[i]), std::move(meshes[i]), moved[i],
                                             *std::move(bytes[i])));
    }
    last_chunk_ = t0;
    return absl::OkStatus();
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
  // (A label session's preview has each interface triangle twice, once for each label.)
  const bool labels = config_.options.labels.enabled;
  if (!CheckMemory(EncodeBytes((labels ? 2 : 1) * session_->num_triangles()), "").ok()) return;
  // Sealed: everything sealed so far goes out first, so that chunks and band cover the mesh.
  if (!MaybeChunk(true).ok()) return;  // the stream fails at the next check anyway
  last_preview_ = now;
  const auto t0 = Clock::now();  // (MaybeChunk counted its own encoding)
  std::vector<uint32_t> group;
  std::vector<LabelId> label_ids;
  const IndexedMesh mesh =
      labels ? LabelPreviewMesh(*session_, config_.options.labels.background, &group, &label_ids)
             : session_->Snapshot();
  absl::StatusOr<std::string> bytes = codec::EncodeDraco(mesh, config_.draco, group);
  encode_s_ += SecondsSince(t0);
  preview_s_ += SecondsSince(now);
  if (!bytes.ok()) return;  // a preview is best effort; the final mesh reports errors
  v1::Preview preview;
  preview.set_slice(cursor_.slice - 1);
  preview.set_draco(*std::move(bytes));
  preview.set_triangles(static_cast<int64_t>(mesh.num_triangles()));
  preview.set_vertices(static_cast<int64_t>(mesh.num_vertices()));
  preview.set_band_only(config_.options.seal);
  for (LabelId id : label_ids) preview.add_labels(id);
  preview_bytes_ += static_cast<int64_t>(preview.draco().size());
  sink_->PostPreview(std::move(preview));
}

}  // namespace tandem::server
