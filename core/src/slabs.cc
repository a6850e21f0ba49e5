#include "slabs.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <queue>
#include <stdexcept>
#include <tuple>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/str_cat.h"
#include "contraction_checks.h"
#include "degenerate.h"
#include "quadric.h"
#include "schedule.h"
#include "simplifier_access.h"

namespace tandem {
namespace {

ReleaseRule RuleFor(Schedule s) {
  switch (s) {
    case Schedule::kTandem: return ReleaseRule::kLayer;
    case Schedule::kTandemLag: return ReleaseRule::kReach;
    default: return ReleaseRule::kImmediate;
  }
}

// A vertex of the welded mesh seen from either slab of a seam: a seam vertex by its left
// copy (unsettled) or its shared id (settled), any other by its slab and id.
class WeldedIds {
 public:
  WeldedIds(const Slab& left, const Slab& right, const std::vector<SeamVertex>& pairs)
      : left_(left), right_(right) {
    left_of_.reserve(pairs.size());
    for (const auto& [a, b] : pairs) left_of_.emplace(b, a);
  }
  // (kind, id), or kind -1 for a right seam vertex not paired yet (refuse).
  std::pair<int, uint64_t> Of(int side, VertexId v) const {
    const Slab& slab = side == 0 ? left_ : right_;
    const uint8_t mask = slab.store.box_mask(v);
    if (!(mask & kSeam)) return {side, v};
    if (mask & kFrozen) return {3, Value(slab.sealer->id(v))};
    if (side == 0) return {2, v};
    const auto it = left_of_.find(v);
    if (it == left_of_.end()) return {-1, 0};
    return {2, it->second};
  }
  // The welded link of a vertex: its neighbours in slab `side` as copy v there, and for a
  // seam vertex in the other slab too as copy w (kInvalid: a vertex of one slab), each
  // once, sorted. False if one is unknown.
  bool Link(int side, VertexId v, VertexId w, std::vector<std::pair<int, uint64_t>>* out) const {
    out->clear();
    for (const auto& [s, a] : {std::pair{side, v}, std::pair{1 - side, w}}) {
      if (a == kInvalid) continue;
      const MeshStore& store = s == 0 ? left_.store : right_.store;
      for (TriId t : store.vertex_triangles(a)) {
        for (VertexId x : store.triangle(t)) {
          if (x == a) continue;
          out->push_back(Of(s, x));
          if (out->back().first < 0) return false;
        }
      }
    }
    std::sort(out->begin(), out->end());
    out->erase(std::unique(out->begin(), out->end()), out->end());
    return true;
  }

 private:
  const Slab& left_;
  const Slab& right_;
  absl::flat_hash_map<VertexId, VertexId> left_of_;  // right copy -> left copy
};

// The welded seam vertex's quadric: both sides' planes, as the merge adds them.
Quadric WeldedQuadric(const Slab& left, VertexId a, const Slab& right, VertexId b) {
  Quadric h = SimplifierSeamAccess::quadric(left.simplifier, a);
  h += SimplifierSeamAccess::quadric(right.simplifier, b);
  return h;
}

// Zero-area triangles at the settling seam vertices of `own` (the other slab: `other`;
// partner: own copy -> other copy): where the welded link condition refused to contract two
// seam copies at one grid point, they would freeze so (the quantised tangles sealed kept 4-16
// a mesh, 0-7 with this; the plain session's final pass parts them). A seam vertex moves
// apart as TidyDegenerate moves a corner (degenerate.h), within the seam's plane, both copies
// to one point, where no triangle of either slab turns over or collapses and the welded
// quadric's ε0 stays within E0 (or where it is). Only seam vertices move here; the others
// are mended as their chunks seal. The caller freezes every one of them next.
void MendSettlingSeamSide(Slab& own, Slab& other,
                          const absl::flat_hash_map<VertexId, VertexId>& partner,
                          bool own_is_left) {
  std::vector<TriId> tris;
  for (const auto& [v, w] : partner) {
    for (TriId t : own.store.vertex_triangles(v)) tris.push_back(t);
  }
  std::sort(tris.begin(), tris.end());
  tris.erase(std::unique(tris.begin(), tris.end()), tris.end());
  // The seam's plane fixes x as a face of the box would: MoveApart keeps to such faces.
  for (const auto& [v, w] : partner) {
    own.store.set_box_mask(v, static_cast<uint8_t>(own.store.box_mask(v) | kBoxXMin));
  }
  const double error = own.simplifier.error();
  auto welded = [&](VertexId v, VertexId w) {
    return own_is_left ? WeldedQuadric(own, v, other, w) : WeldedQuadric(other, w, own, v);
  };
  TidyDegenerateAmong(
      &own.store, tris, SimplifierSeamAccess::TidySize(own.simplifier),
      [&](VertexId v, Vec3 p) {
        const auto it = partner.find(v);
        if (it == partner.end() || p.x != own.store.position(v).x) return false;
        const Quadric h = welded(v, it->second);
        const double now = ShapeError(h, own.store.position(v));
        const bool may = ShapeError(h, p) <= std::max(error, now) &&
                         MoveKeepsFacing(other.store, it->second, p, VertexFacing(own.store, v));
        if (may) {  // both copies move next: their quadrics in full first
          SimplifierSeamAccess::KeepQuadric(own.simplifier, v);
          SimplifierSeamAccess::KeepQuadric(other.simplifier, it->second);
        }
        return may;
      },
      [&](VertexId v) {
        const VertexId w = partner.at(v);
        other.store.set_position(w, own.store.position(v));
        // A step off a face of the box (MoveApart on an edge of it) leaves it in both.
        const auto faces = static_cast<uint8_t>(kBoxFaces & ~kBoxXMin);
        other.store.set_box_mask(w, static_cast<uint8_t>((other.store.box_mask(w) & ~faces) |
                                                         (own.store.box_mask(v) & faces)));
      },
      /*flips=*/false);
  for (const auto& [v, w] : partner) {
    own.store.set_box_mask(v, static_cast<uint8_t>(own.store.box_mask(v) & ~kBoxXMin));
  }
}

}  // namespace

void MendSettlingSeam(Slab& left, Slab& right, const std::vector<SeamVertex>& pairs, double limit) {
  absl::flat_hash_map<VertexId, VertexId> to_right, to_left;
  for (const auto& [a, b] : pairs) {
    if (!left.store.vertex_alive(a) || left.store.height(a) > limit) continue;
    to_right.emplace(a, b);
    to_left.emplace(b, a);
  }
  if (to_right.empty()) return;
  MendSettlingSeamSide(left, right, to_right, /*own_is_left=*/true);
  MendSettlingSeamSide(right, left, to_left, /*own_is_left=*/false);
}

int64_t CoarsenSettlingSeam(Slab& left, Slab& right, const std::vector<SeamVertex>& pairs,
                            double limit) {
  // The settling seam vertices (left copy -> right copy).
  absl::flat_hash_map<VertexId, VertexId> partner;
  for (const auto& [a, b] : pairs) {
    if (left.store.height(a) <= limit) partner.emplace(a, b);
  }
  if (partner.empty()) return 0;
  Slab* const slab[2] = {&left, &right};
  const double error = left.simplifier.error();
  const double bound = SimplifierSeamAccess::distance_bound(left.simplifier);
  // kSeamEdge: seam vertices a < b (left ids) to one point of the plane, in both slabs.
  // 0 or 1: b, a vertex of that slab only, onto seam vertex a (left id), which stays put.
  constexpr int kSeamEdge = -1;
  struct Entry {
    double cost;
    int kind;
    VertexId a, b;
    uint32_t sa, sb;  // their stamps when evaluated
    Vec3 pos;
  };
  auto later = [](const Entry& x, const Entry& y) {  // cheapest first, ties by ids
    return std::tie(x.cost, x.kind, x.a, x.b) > std::tie(y.cost, y.kind, y.a, y.b);
  };
  std::priority_queue<Entry, std::vector<Entry>, decltype(later)> heap(later);
  absl::flat_hash_map<VertexId, uint32_t> stamp[2];  // by slab and id (a seam vertex: left)
  auto stamp_of = [&](int kind, VertexId b) -> uint32_t& {
    return stamp[kind == kSeamEdge ? 0 : kind][b];
  };
  auto seam_quadric = [&](VertexId a) { return WeldedQuadric(left, a, right, partner.at(a)); };
  auto evaluate = [&](int kind, VertexId a, VertexId b) {
    if (kind == kSeamEdge && a > b) std::swap(a, b);
    Quadric h = seam_quadric(a);
    Vec3 pos = left.store.position(a);
    if (kind == kSeamEdge) {
      // A vertex on the grid's box (the welded mesh's boundary) keeps to its faces, as in
      // Simplifier::Evaluate: two on different faces are left as they are.
      const uint8_t fa = left.store.box_mask(a) & kBoxFaces;
      const uint8_t fb = left.store.box_mask(b) & kBoxFaces;
      if ((fa & fb) != fa && (fa & fb) != fb) return;
      h += seam_quadric(b);
      Vec3 ref = BoxedMidpoint(pos, fa, left.store.position(b), fb);
      ref.x = pos.x;  // the seam's plane
      pos = MinimizeQuadric(h, ref, static_cast<uint8_t>(FixedAxes(fa | fb) | 1));
    } else {
      // Onto a seam vertex, which stays put (on the box or not).
      const MeshStore& store = slab[kind]->store;
      if (store.box_mask(b) & (kBoxFaces | kSeam | kFrozen)) return;
      h += SimplifierSeamAccess::quadric(slab[kind]->simplifier, b);
    }
    const double eps0 = ShapeError(h, pos);
    if (eps0 > error) return;
    heap.push(Entry{eps0, kind, a, b, stamp[0][a], stamp_of(kind, b), pos});
  };
  // Every contraction of seam vertex a (left id) with a neighbour; `all_seam`: also seam
  // neighbours with a smaller id (the first pass takes each seam edge from one end).
  auto evaluate_around = [&](VertexId a, bool all_seam) {
    for (int side = 0; side < 2; ++side) {
      const MeshStore& store = slab[side]->store;
      const VertexId as = side == 0 ? a : partner.at(a);
      for (TriId t : store.vertex_triangles(as)) {
        for (VertexId x : store.triangle(t)) {
          if (x == as) continue;
          if (!(store.box_mask(x) & kSeam)) {
            evaluate(side, a, x);
          } else if (side == 0 && partner.contains(x) && (all_seam || a < x)) {
            evaluate(kSeamEdge, a, x);
          }
        }
      }
    }
  };
  for (const auto& [a, b] : partner) evaluate_around(a, false);

  const WeldedIds welded(left, right, pairs);
  std::vector<std::pair<int, uint64_t>> link_a, link_b, common;
  // The corners opposite edge ab in `store`'s triangles on it (at most 2, else false).
  auto opposites = [](const MeshStore& store, VertexId a, VertexId b, VertexId out[2], int* n) {
    *n = 0;
    for (TriId t : store.vertex_triangles(a)) {
      const auto& tri = store.triangle(t);
      if (tri[0] != b && tri[1] != b && tri[2] != b) continue;
      if (*n == 2) return false;
      for (VertexId x : tri) {
        if (x != a && x != b) out[*n] = x;
      }
      ++*n;
    }
    return true;
  };
  // A label session's complex is coarsened here only inside one interface: every triangle at
  // both ends, in both slabs, separates the same two labels, so that the welded link
  // condition below is each label's own (where labels meet, seam vertices settle as they are).
  auto one_pair = [&](const Entry& e, VertexId ra) {
    if (!left.store.labeled()) return true;
    const LabelPair* pair = nullptr;
    auto same = [&pair](const MeshStore& store, VertexId v) {
      for (TriId t : store.vertex_triangles(v)) {
        if (pair == nullptr) pair = &store.pair_of(t);
        if (!(store.pair_of(t) == *pair)) return false;
      }
      return true;
    };
    if (!same(left.store, e.a) || !same(right.store, ra)) return false;
    if (e.kind == kSeamEdge) return same(left.store, e.b) && same(right.store, partner.at(e.b));
    return same(slab[e.kind]->store, e.b);
  };
  int64_t contracted = 0;
  while (!heap.empty()) {
    const Entry e = heap.top();
    heap.pop();
    if (stamp[0][e.a] != e.sa || stamp_of(e.kind, e.b) != e.sb) continue;
    const VertexId ra = partner.at(e.a);
    if (!one_pair(e, ra)) continue;
    // The link condition on the welded mesh: the welded links of the two ends share exactly
    // the corners opposite the edge, one in each of its two triangles (a seam edge: one
    // in each slab), and those two are not joined (only seam vertices could be, across).
    VertexId opp[2][2];
    int n[2] = {0, 0};
    std::pair<int, uint64_t> want[2];
    if (e.kind == kSeamEdge) {
      const VertexId rb = partner.at(e.b);
      if (!opposites(left.store, e.a, e.b, opp[0], &n[0]) ||
          !opposites(right.store, ra, rb, opp[1], &n[1]) || n[0] != 1 || n[1] != 1 ||
          !welded.Link(0, e.a, ra, &link_a) || !welded.Link(0, e.b, rb, &link_b)) {
        continue;
      }
      want[0] = welded.Of(0, opp[0][0]);
      want[1] = welded.Of(1, opp[1][0]);
    } else {
      const int side = e.kind;
      const MeshStore& store = slab[side]->store;
      const VertexId as = side == 0 ? e.a : ra;
      if (!opposites(store, as, e.b, opp[side], &n[side]) || n[side] != 2 ||
          !welded.Link(0, e.a, ra, &link_a) || !welded.Link(side, e.b, kInvalid, &link_b)) {
        continue;
      }
      want[0] = welded.Of(side, opp[side][0]);
      want[1] = welded.Of(side, opp[side][1]);
    }
    if (want[0] == want[1] || (want[0].first >= 2 && want[1].first >= 2)) continue;
    common.clear();
    std::set_intersection(link_a.begin(), link_a.end(), link_b.begin(), link_b.end(),
                          std::back_inserter(common));
    std::sort(want, want + 2);
    if (common.size() != 2 || common[0] != want[0] || common[1] != want[1]) continue;
    // Each slab stays a manifold with its seam as boundary, and nothing folds on either side:
    // SIMPLIFY's checks and contraction, in each slab.
    if (e.kind == kSeamEdge) {
      const VertexId rb = partner.at(e.b);
      if (!SimplifierSeamAccess::MayContract(left.simplifier, e.a, e.b, e.pos, bound) ||
          !SimplifierSeamAccess::MayContract(right.simplifier, ra, rb, e.pos, bound)) {
        continue;
      }
      SimplifierSeamAccess::ContractAt(left.simplifier, e.a, e.b, e.pos, e.cost, /*onto_a=*/false);
      SimplifierSeamAccess::ContractAt(right.simplifier, ra, rb, e.pos, e.cost, /*onto_a=*/false);
      partner.erase(e.b);
    } else {
      Slab& s = *slab[e.kind];
      const VertexId as = e.kind == 0 ? e.a : ra;
      if (!SimplifierSeamAccess::MayContract(s.simplifier, as, e.b, e.pos, bound)) continue;
      SimplifierSeamAccess::ContractAt(s.simplifier, as, e.b, e.pos, e.cost, /*onto_a=*/true);
    }
    ++stamp[0][e.a];
    ++stamp_of(e.kind, e.b);
    ++contracted;
    evaluate_around(e.a, true);
  }
  if (contracted > 0) {
    left.sealer->DropDead();  // before the next EXTRACT hands the dead ids out again
    right.sealer->DropDead();
  }
  return contracted;
}

int SlabCount(const VolumeInfo& grid, const SessionOptions& options) {
  const int requested = options.parts;
  constexpr int64_t kMinColumns = 16;  // cube columns per slab, at least
  // The automatic split asks for slabs of at least 40 columns: two from 81 wide. Narrower ones
  // cost more at their seams than the second core saves (docs/decisions.md, "Two slabs from
  // 81 wide").
  constexpr int64_t kMinAutoColumns = 40;
  const bool automatic = requested <= 0;
  const int64_t wanted = automatic ? (grid.nx >= 256 ? 4 : 2) : requested;
  const int64_t columns = automatic ? kMinAutoColumns : kMinColumns;
  return static_cast<int>(std::max<int64_t>(1, std::min(wanted, (grid.nx - 1) / columns)));
}

// Q keeps edges up to this multiple of E0 toward a target count, so that a rise of E0
// needs fewer evaluations (RaiseError); more only piles up expensive entries between rises
// (docs/decisions.md 23).
constexpr double kTargetKeep = 1.5;

// The late lag (SimplifierOptions::late_lag): a contraction above 0.4 E0 over a patch at least
// 5 slices wide waits for the front 1.5 radii longer (docs/decisions.md 67: why these).
constexpr double kLateLag = 1.5, kLateShare = 0.4, kLateRadius = 5;

Slab::Slab(const ExtractorConfig& ec, const SimplifierOptions& so, Meter* m)
    : meter(m), extractor(ec, &store), simplifier(&store, so) {
  // Slabs live behind unique_ptrs: `this` stays where it is.
  simplifier.set_checkpoint([this] { CheckHolding("simplifying slice", pending_front); });
}

size_t Slab::HoldingBytes() const {
  size_t bytes = store.MemoryBytes() + simplifier.MemoryBytes() +
                 (sealer ? sealer->MemoryBytes() : 0) +
                 (new_tris.capacity() + new_verts.capacity()) * sizeof(uint32_t) +
                 new_edges.capacity() + trace.capacity() * sizeof(int64_t);
  for (const auto& log : seam_log) bytes += log.capacity() * sizeof(VertexId);
  return bytes;
}

std::vector<std::unique_ptr<Slab>> MakeSlabs(const VolumeInfo& grid, const SessionOptions& options,
                                             double scale, int count, Executor* batches,
                                             Meter* meter) {
  const std::array<double, 3> spacing{grid.spacing[0] / scale, grid.spacing[1] / scale,
                                      grid.spacing[2] / scale};
  // The world frame's coordinates (ToWorld: origin plus the axes' steps, each axis of unit
  // length) in smallest spacings, which set the edge offset: the same in every slab.
  const double smallest = std::min({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  const double origin =
      std::max({std::fabs(grid.origin[0]), std::fabs(grid.origin[1]), std::fabs(grid.origin[2])});
  const double reach = (origin + static_cast<double>(grid.nx - 1) * grid.spacing[0] +
                        static_cast<double>(grid.ny - 1) * grid.spacing[1]) /
                       smallest;
  std::vector<std::unique_ptr<Slab>> slabs;
  for (int p = 0; p < count; ++p) {
    const int64_t c0 = p * (grid.nx - 1) / count, c1 = (p + 1) * (grid.nx - 1) / count;
    ExtractorConfig ec{c1 - c0 + 1, grid.ny, grid.nz, spacing, {0, 0, 0}, options.iso};
    ec.labels = options.labels;
    ec.reach = reach;
    ec.reach_per_slice = grid.spacing[2] / smallest;
    const OffsetEdges offset_edges{
        ec.reach, ec.reach_per_slice, smallest / scale,
        std::max({grid.spacing[0], grid.spacing[1], grid.spacing[2]}) / smallest};
    ec.x_offset = c0;
    ec.row_stride = grid.nx;
    if (p > 0) ec.seam_faces |= kBoxXMin;
    if (p + 1 < count) ec.seam_faces |= kBoxXMax;
    // Tiles of a chunked release: 256 x 256 of them cover the grid's plane, at least a voxel
    // each, a power of two voxels across.
    int64_t tile = 1;
    while (tile * 256 < std::max(grid.nx, grid.ny)) tile *= 2;
    // Not toward a target count, whose E0 rises with what the lock-step leaves, nor sealed,
    // where a held edge would hold its vertices back from sealing, nor when the paper's
    // lock-step is asked for (lockstep_error 1).
    const bool late = options.schedule == Schedule::kTandemLag &&
                      options.target_triangles == 0 && !options.seal &&
                      options.lockstep_error < 1;
    const SimplifierOptions so{.error = StartError(grid, options, scale),
                               .alpha = options.alpha,
                               .release = RuleFor(options.schedule),
                               .slice_spacing = spacing[2],
                               .parallel = batches,
                               .distance_guard = options.distance_guard,
                               .late_lag = late ? kLateLag : 0.0,
                               .late_share = kLateShare,
                               .late_radius = kLateRadius,
                               .keep = options.target_triangles > 0 ? kTargetKeep : 1.0,
                               .rises = options.target_triangles > 0,
                               .tile_x = spacing[0] * static_cast<double>(tile),
                               .tile_y = spacing[1] * static_cast<double>(tile),
                               .check_quadrics = options.check_quadrics,
                               .offset_edges = offset_edges};
    auto slab = std::make_unique<Slab>(ec, so, meter);
    if (options.labels.enabled) slab->store.EnableLabels();
    const bool simplify = options.schedule != Schedule::kNone;
    // A staged vertex becomes a store record with its smallest incidence slot, its quadric
    // (simplifying), and an entry of the commit's id lists; a triangle its record and lists.
    slab->extractor.set_account(
        &slab->extraction,
        MeshStore::VertexBytes() + (simplify ? Simplifier::VertexBytes() : 0) +
            2 * sizeof(VertexId),
        MeshStore::TriangleBytes() + sizeof(TriId) + 1);
    if (options.seal) {
      slab->sealer = std::make_unique<Sealer>(
          &slab->store, simplify ? &slab->simplifier : nullptr, options.seal_margin,
          simplify ? options.sag_correction : 0.0, static_cast<uint32_t>(p),
          SealerIdStride(count));
    }
    slab->x0 = c0;
    slab->index = static_cast<size_t>(p);
    slab->extraction.Set(slab->extractor.HeldBytes(grid.dtype));  // the planes as planned
    slab->holding.Set(slab->HoldingBytes());
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
    for (size_t i = 0; i < left.size(); ++i) (*seams)[s].push_back({left[i], right[i]});
    left.clear();
    right.clear();
  }
  return absl::OkStatus();
}

void SettleSeams(const std::vector<std::unique_ptr<Slab>>& slabs, Seams* seams, double front,
                 int64_t settle_slices, int64_t hold_vertices, bool coarsen, int64_t* seam_ids) {
  const auto count = static_cast<int64_t>(slabs.size());
  const int64_t stride = SealerIdStride(static_cast<int>(count));
  const double by_slices = front - static_cast<double>(settle_slices);
  const double floor = front - static_cast<double>(std::min(settle_slices, kSeamSettleFloor));
  for (size_t s = 0; s < seams->size(); ++s) {
    Slab& left = *slabs[s];
    Slab& right = *slabs[s + 1];
    auto& pairs = (*seams)[s];
    // Pairs are listed as the slabs made them, slice by slice: past hold_vertices, those up
    // to the height of the newest one beyond them settle.
    double limit = by_slices;
    const auto held = static_cast<int64_t>(pairs.size());
    if (held > hold_vertices) {
      const VertexId newest_settling = pairs[static_cast<size_t>(held - hold_vertices - 1)].left;
      limit = std::max(limit, std::min(floor, left.store.height(newest_settling)));
    }
    if (coarsen) {
      CoarsenSettlingSeam(left, right, pairs, limit);
      MendSettlingSeam(left, right, pairs, limit);
    }
    size_t keep = 0;
    for (const auto& [a, b] : pairs) {
      if (!left.store.vertex_alive(a)) continue;  // contracted away just now
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
      if (const Vec3 p = left.store.position(a); !(right.store.position(b) == p)) {
        SimplifierSeamAccess::KeepQuadric(right.simplifier, b);
        right.store.set_position(b, p);
      }
      // Error(K) at the welded vertex: both sides' planes.
      const double shape_error =
          coarsen ? MeasuredShapeError(WeldedQuadric(left, a, right, b), left.store.position(a))
                  : 0.0;
      const GlobalId global{static_cast<uint32_t>(id)};
      left.sealer->FreezeShared(a, global, shape_error);
      right.sealer->FreezeShared(b, global, shape_error);
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

void AppendWeldedPatches(const std::vector<std::unique_ptr<Slab>>& slabs,
                         std::vector<uint32_t>* patch, std::vector<LabelPair>* pairs) {
  absl::flat_hash_map<std::pair<LabelId, LabelId>, uint32_t> index;
  for (uint32_t p = 0; p < pairs->size(); ++p) {
    index.try_emplace(std::pair{(*pairs)[p].inside, (*pairs)[p].outside}, p);
  }
  std::vector<uint32_t> to;  // a slab's patches -> the output's
  for (const auto& slab : slabs) {
    const std::vector<LabelPair>& own = slab->store.pairs();
    to.resize(own.size());
    for (size_t p = 0; p < own.size(); ++p) {
      const auto [it, added] = index.try_emplace(std::pair{own[p].inside, own[p].outside},
                                                 static_cast<uint32_t>(pairs->size()));
      if (added) pairs->push_back(own[p]);
      to[p] = it->second;
    }
    for (uint32_t p : slab->store.SnapshotPatches()) patch->push_back(to[p]);
  }
}

std::vector<VertexId> MergeSlabs(std::vector<std::unique_ptr<Slab>>* slabs, Seams* seams,
                                 bool simplify, MergedCounts* merged) {
  Slab& dst = *(*slabs)[0];
  std::vector<VertexId> seam_vertices;  // in dst
  PartVertexMap map, prev;              // a slab's ids -> dst's (prev: the slab before)
  std::vector<PartVertex> welded;       // src's seam copies welded to dst's vertices
  std::vector<uint32_t> patch_of;       // src's patches -> dst's (kInvalid: not met yet)
  for (size_t p = 1; p < slabs->size(); ++p) {
    Slab& src = *(*slabs)[p];
    map.Reset(src.store.vertex_capacity());
    welded.clear();
    for (const auto& [left, right] : (*seams)[p - 1]) {
      const PartVertex copy{right};
      welded.push_back(copy);
      const VertexId v = p == 1 ? left : prev[PartVertex{left}];
      assert(dst.store.vertex_alive(v) && src.store.vertex_alive(right));
      map[copy] = v;
      dst.store.set_box_mask(v, (dst.store.box_mask(v) | src.store.box_mask(right)) &
                                    static_cast<uint8_t>(~kSeam));
      if (simplify)
        SimplifierSeamAccess::AdoptVertex(dst.simplifier, src.simplifier, copy, v, /*shared=*/true);
      seam_vertices.push_back(v);
    }
    for (VertexId v = 0; v < src.store.vertex_capacity(); ++v) {
      const PartVertex part{v};
      if (!src.store.vertex_alive(v) || map[part] != kInvalid) continue;
      map[part] = dst.store.AddVertex(src.store.position(v), src.store.height(v),
                                      src.store.layer(v), src.store.box_mask(v));
      if (simplify)
        SimplifierSeamAccess::AdoptVertex(dst.simplifier, src.simplifier, part, map[part],
                                          /*shared=*/false);
    }
    // A label session's patches: src's pair table is its own, each pair found in dst's (added
    // if new) as its first live triangle comes.
    patch_of.assign(src.store.labeled() ? src.store.pairs().size() : 0, kInvalid);
    for (TriId t = 0; t < src.store.triangle_capacity(); ++t) {
      if (!src.store.triangle_alive(t)) continue;
      const auto& tri = src.store.triangle(t);
      const TriId added = dst.store.AddTriangle(map[PartVertex{tri[0]}], map[PartVertex{tri[1]}],
                                                map[PartVertex{tri[2]}]);
      if (patch_of.empty()) continue;
      uint32_t& p = patch_of[src.store.patch(t)];
      if (p == kInvalid) p = dst.store.PatchOf(src.store.pair_of(t));
      dst.store.set_patch(added, p);
    }
    if (simplify) {
      SimplifierSeamAccess::AdoptCounters(dst.simplifier, src.simplifier);
      SimplifierSeamAccess::AdoptQueues(dst.simplifier, src.simplifier, map);
    }
    if (dst.sealer) dst.sealer->Absorb(*src.sealer, map, welded);
    merged->crossed_cubes += src.extractor.crossed_cubes();
    merged->triangles_extracted += src.triangles_extracted;
    merged->time.extract_s += src.time.extract_s;
    merged->time.simplify_s += src.time.simplify_s;
    prev.swap(map);
    // Both copies are held at this moment: the budget sees the merge's peak.
    dst.CheckHolding("merging the parts after slice", dst.extractor.slices_done() - 1);
    (*slabs)[p].reset();  // copied: give its memory back before the next slab grows dst
  }
  slabs->resize(1);
  seams->clear();
  return seam_vertices;
}

}  // namespace tandem
