#include "slabs.h"

#include <algorithm>
#include <cassert>
#include <limits>
#include <stdexcept>

#include "absl/strings/str_cat.h"

namespace tandem {
namespace {

ReleaseRule RuleFor(Schedule s) {
  switch (s) {
    case Schedule::kTandem: return ReleaseRule::kLayer;
    case Schedule::kTandemLag: return ReleaseRule::kReach;
    default: return ReleaseRule::kImmediate;
  }
}

}  // namespace

int SlabCount(const VolumeInfo& grid, const SessionOptions& options) {
  const int requested = options.parts;
  constexpr int64_t kMinColumns = 16;  // cube columns per slab, at least
  const int64_t wanted = requested > 0 ? requested : (grid.nx >= 256 ? 4 : 1);
  return static_cast<int>(std::max<int64_t>(1, std::min(wanted, (grid.nx - 1) / kMinColumns)));
}

// Q keeps edges up to this multiple of E0 toward a target count, so that a rise of E0
// needs fewer evaluations (RaiseError). Measured on the engine CT, N = 25,000 and 100,000:
// 1.5 took 0.85-0.95 s, 1 (none kept) 1.06-1.36 s, 2-8 the same time as 1.5 but up to
// 1.5x the memory (the expensive entries pile up between rises).
constexpr double kTargetKeep = 1.5;

double StartError(const VolumeInfo& grid, const SessionOptions& options) {
  if (options.target_triangles <= 0) return options.error;
  const double spacing = std::min({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  return std::min(options.error, spacing / 1000);
}

std::vector<std::unique_ptr<Slab>> MakeSlabs(const VolumeInfo& grid, const SessionOptions& options,
                                             double scale, int count, Executor* batches) {
  const std::array<double, 3> spacing{grid.spacing[0] / scale, grid.spacing[1] / scale,
                                      grid.spacing[2] / scale};
  std::vector<std::unique_ptr<Slab>> slabs;
  for (int p = 0; p < count; ++p) {
    const int64_t c0 = p * (grid.nx - 1) / count, c1 = (p + 1) * (grid.nx - 1) / count;
    ExtractorConfig ec{c1 - c0 + 1, grid.ny, grid.nz, spacing, {0, 0, 0}, options.iso};
    ec.x_offset = c0;
    ec.row_stride = grid.nx;
    if (p > 0) ec.seam_faces |= kBoxXMin;
    if (p + 1 < count) ec.seam_faces |= kBoxXMax;
    const SimplifierOptions so{.error = StartError(grid, options) / scale,
                               .alpha = options.alpha,
                               .release = RuleFor(options.schedule),
                               .slice_spacing = spacing[2],
                               .parallel = batches,
                               .distance_guard = options.distance_guard,
                               .keep = options.target_triangles > 0 ? kTargetKeep : 1.0};
    auto slab = std::make_unique<Slab>(ec, so);
    if (options.seal) {
      const bool simplify = options.schedule != Schedule::kNone;
      slab->sealer = std::make_unique<Sealer>(
          &slab->store, simplify ? &slab->simplifier : nullptr, options.seal_margin,
          simplify ? options.sag_correction : 0.0, static_cast<uint32_t>(p),
          SealerIdStride(count));
    }
    slab->x0 = c0;
    slab->index = static_cast<size_t>(p);
    slabs.push_back(std::move(slab));
  }
  return slabs;
}

absl::Status PairSeams(const std::vector<std::unique_ptr<Slab>>& slabs, Seams* seams) {
  seams->resize(slabs.size() - 1);
  for (size_t s = 0; s + 1 < slabs.size(); ++s) {
    auto& left = slabs[s]->seam_log[1];
    auto& right = slabs[s + 1]->seam_log[0];
    // Both slabs see the same values on the shared plane, so they cross the same edges.
    if (left.size() != right.size()) {
      return absl::InternalError(absl::StrCat("the slabs disagree on seam ", s, " (",
                                              left.size(), " vs ", right.size(), " vertices)"));
    }
    for (size_t i = 0; i < left.size(); ++i) (*seams)[s].emplace_back(left[i], right[i]);
    left.clear();
    right.clear();
  }
  return absl::OkStatus();
}

void SettleSeams(const std::vector<std::unique_ptr<Slab>>& slabs, Seams* seams,
                 double front, int64_t* seam_ids) {
  const auto count = static_cast<int64_t>(slabs.size());
  const int64_t stride = SealerIdStride(static_cast<int>(count));
  const double limit = front - static_cast<double>(kSeamSettleSlices);
  for (size_t s = 0; s < seams->size(); ++s) {
    Slab& left = *slabs[s];
    Slab& right = *slabs[s + 1];
    auto& pairs = (*seams)[s];
    size_t keep = 0;
    for (const auto& [a, b] : pairs) {
      if (left.store.height(a) > limit) {
        pairs[keep++] = {a, b};
        continue;
      }
      const int64_t id = *seam_ids * stride + count;
      if (id > int64_t{std::numeric_limits<uint32_t>::max()} - 1) {
        throw std::overflow_error("a sealed session ran out of 32-bit vertex ids");
      }
      ++*seam_ids;
      // Both slabs computed the point from the same grid edge; one position, bit for bit.
      right.store.set_position(b, left.store.position(a));
      left.sealer->FreezeShared(a, static_cast<uint32_t>(id));
      right.sealer->FreezeShared(b, static_cast<uint32_t>(id));
    }
    pairs.resize(keep);
  }
}

void AppendWeldedSnapshot(const std::vector<std::unique_ptr<Slab>>& slabs, const Seams& seams,
                          IndexedMesh* out) {
  // Slab by slab; a seam vertex takes the index its copy got in the slab before.
  std::vector<uint32_t> map, prev;
  for (size_t p = 0; p < slabs.size(); ++p) {
    map.assign(slabs[p]->store.vertex_capacity(), kInvalid);
    if (p > 0) {
      for (const auto& [left, right] : seams[p - 1]) map[right] = prev[left];
    }
    slabs[p]->store.AppendSnapshot(out, &map);
    prev.swap(map);
  }
}

std::vector<VertexId> MergeSlabs(std::vector<std::unique_ptr<Slab>>* slabs, Seams* seams,
                                 bool simplify, MergedCounts* merged) {
  Slab& dst = *(*slabs)[0];
  std::vector<VertexId> seam_vertices;  // in dst
  std::vector<VertexId> map, prev;      // a slab's ids -> dst's (prev: the slab before)
  std::vector<VertexId> welded;         // src's seam copies welded to dst's vertices
  for (size_t p = 1; p < slabs->size(); ++p) {
    Slab& src = *(*slabs)[p];
    map.assign(src.store.vertex_capacity(), kInvalid);
    welded.clear();
    for (const auto& [left, right] : (*seams)[p - 1]) {
      welded.push_back(right);
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
    if (dst.sealer) dst.sealer->Absorb(*src.sealer, map, welded);
    merged->crossed_cubes += src.extractor.crossed_cubes();
    merged->triangles_extracted += src.triangles_extracted;
    merged->time.extract_s += src.time.extract_s;
    merged->time.simplify_s += src.time.simplify_s;
    prev.swap(map);
    (*slabs)[p].reset();  // copied: give its memory back before the next slab grows dst
  }
  slabs->resize(1);
  seams->clear();
  return seam_vertices;
}

}  // namespace tandem
