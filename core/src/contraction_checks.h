// The tests an edge contraction ab -> c must pass besides its cost (paper §2, "Surface
// simplification": the link condition LAMBDA(ab); flips, degenerate triangles and the distance
// guard are ours). Free functions of the mesh as it is, plus scratch memory the caller keeps
// between calls, so that a test can call them on a hand-made mesh.
#ifndef TANDEM_CONTRACTION_CHECKS_H_
#define TANDEM_CONTRACTION_CHECKS_H_

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

#include "mesh_store.h"
#include "tandem/geometry.h"
#include "tandem/stats.h"
#include "tandem/types.h"

namespace tandem {

// Occurrences of x in fan arrays of N entries (unused ones kInvalid), summed over one or two
// arrays. A fixed length and no loop exit: no branch to mispredict. Written with vector
// extensions (GCC, Clang: four lanes at a time, on any target): at 16 entries GCC unrolled the
// plain loop into scalar compares. Two arrays share one sum across the lanes (its extraction
// was a third of a count).
namespace fan_count {
using V4 = uint32_t __attribute__((vector_size(16)));
template <size_t N>
void Accumulate(const VertexId (&v)[N], V4 xs, V4* acc) {
  static_assert(N % 4 == 0);
  for (size_t i = 0; i < N; i += 4) {
    V4 chunk;
    std::memcpy(&chunk, v + i, sizeof(chunk));
    *acc -= reinterpret_cast<V4>(chunk == xs);  // a match is all ones: -1
  }
}
inline int Lanes(V4 acc) {
  acc += __builtin_shufflevector(acc, acc, 2, 3, 0, 1);
  acc += __builtin_shufflevector(acc, acc, 1, 0, 3, 2);
  return static_cast<int>(acc[0]);
}
}  // namespace fan_count
template <size_t N>
int CountOf(const VertexId (&v)[N], VertexId x) {
  const fan_count::V4 xs = {x, x, x, x};
  fan_count::V4 acc = {0, 0, 0, 0};
  fan_count::Accumulate(v, xs, &acc);
  return fan_count::Lanes(acc);
}
template <size_t N>
int CountOf(const VertexId (&v)[N], const VertexId (&w)[N], VertexId x) {
  const fan_count::V4 xs = {x, x, x, x};
  fan_count::V4 acc = {0, 0, 0, 0};
  fan_count::Accumulate(v, xs, &acc);
  fan_count::Accumulate(w, xs, &acc);
  return fan_count::Lanes(acc);
}

// LAMBDA(ab): Lk(a) ∩ Lk(b) = Lk(ab) on the complex completed by a dummy vertex joined to every
// boundary edge; false also when a and b are not adjacent or ab lies in three triangles. Two
// implementations of one test, checked against each other and against the definition in
// contraction_checks_test.cc: small fans (at most kFanMax triangles at a and at b, nearly
// every call) gather the neighbours into stack arrays; larger ones tally them in a table
// sized to the two fans (LinkScratch), not to the mesh, since a mark per vertex id would cost
// every vertex memory for the few fans past kFanMax (docs/decisions.md 14).
inline constexpr size_t kFanMax = 16;
struct LinkScratch {
  struct Mark {  // per neighbour x of a or b: tallies of edges (a|b, x)
    VertexId x = kInvalid;
    uint8_t count_a = 0, count_b = 0;
  };
  std::vector<Mark> table;  // open addressing, at most half full
  // Label mode: the labels around a and b, one label's triangles at each, their neighbours.
  std::vector<LabelId> labels_a, labels_b;
  std::vector<std::array<VertexId, 3>> fan_a, fan_b;
  std::vector<std::pair<VertexId, int>> tally_a, tally_b;
  size_t MemoryBytes() const {
    return table.capacity() * sizeof(Mark) +
           (labels_a.capacity() + labels_b.capacity()) * sizeof(LabelId) +
           (fan_a.capacity() + fan_b.capacity()) * sizeof(fan_a[0]) +
           (tally_a.capacity() + tally_b.capacity()) * sizeof(tally_a[0]);
  }
};
bool LinkConditionFans(const MeshStore& store, VertexId a, VertexId b);  // fans <= kFanMax
bool LinkConditionMarks(const MeshStore& store, VertexId a, VertexId b, LinkScratch* scratch);
// The interface complex of a label session (MeshStore::labeled): for every label whose
// surface (its triangles, either side) holds both a and b, ab is an edge of that surface and
// LAMBDA(ab) holds in it; a label whose surface holds one of them asks nothing. So every
// label keeps its topology while the triangles stay shared (docs/decisions.md, "Label
// volumes"). False also when ab lies in more than kMaxEdgeTriangles triangles.
inline constexpr int kMaxEdgeTriangles = 8;
bool LabelLinkCondition(const MeshStore& store, VertexId a, VertexId b, LinkScratch* scratch);
inline bool LinkCondition(const MeshStore& store, VertexId a, VertexId b, LinkScratch* scratch) {
  if (store.labeled()) [[unlikely]] {
    return LabelLinkCondition(store, a, b, scratch);
  }
  if (store.vertex_triangles(a).size() <= kFanMax && store.vertex_triangles(b).size() <= kFanMax) {
    return LinkConditionFans(store, a, b);
  }
  return LinkConditionMarks(store, a, b, scratch);
}

// The edges the extractor's offset makes of a grid point on the iso-value (EdgeOffset,
// tandem/geometry.h): its surface points lie δ to 1.5 δ off it, so at most 3δ apart along an
// axis, where without the offset they were one point. A triangle with an edge that short
// stands for one collapsed at the grid point, whose orientation and plane are the offset's,
// not the surface's.
struct OffsetEdges {
  double reach = 0, reach_per_slice = 0;  // ExtractorConfig's
  double spacing = 0;                     // the smallest, engine units; 0: no edge is one
  double anisotropy = 1;                  // the largest spacing over the smallest
  // Whether d (an edge's vector, engine units) in a triangle whose corners lie at most
  // `height` (slices) up is one: at most 3δ along each axis, δ the offset at that slice (the
  // largest its ends can have).
  bool Holds(Vec3 d, double height) const {
    const double limit = 2 * kEdgeOffsetSpread *
                         EdgeOffset(reach + std::ceil(height) * reach_per_slice, anisotropy) *
                         spacing * (1 + 1e-9);  // the ends' positions as computed
    return std::fabs(d.x) <= limit && std::fabs(d.y) <= limit && std::fabs(d.z) <= limit;
  }
};

// Geometry of contracting ab to a vertex at `pos`: no surviving triangle may flip or collapse
// (tandem/geometry.h's MoveCorners), and with bound > 0 (the distance guard, K·E0) pos may lie
// at most `bound` from each one's present plane. Triangles already collapsed constrain nothing,
// and those with an offset edge (`offsets`) may turn over or leave their plane, but not
// collapse. On refusal, counts its reason in *refusals
// (distance before degenerate before flip) and returns false. `survivors` is scratch.
struct Survivor {  // a triangle that survives the contraction, and its corner that moves
  TriId t;
  VertexId v;
};
bool GeometryOk(const MeshStore& store, VertexId a, VertexId b, Vec3 pos, double bound,
                const OffsetEdges& offsets, std::vector<Survivor>* survivors,
                RefusalCounts* refusals);

// The bodies LinkConditionFans and GeometryOk pick by the CPU at load, each width callable on
// any CPU so that tests check the ones this CPU does not pick: fans 4 (SSE2) or 8 (AVX2)
// lanes; survivors 2 (SSE2) or 4 (AVX2) lanes, or 1: every survivor through the exact test,
// which the lanes only filter.
bool LinkConditionFansWithLanes(int lanes, const MeshStore& store, VertexId a, VertexId b);
bool GeometryOkWithLanes(int lanes, const MeshStore& store, VertexId a, VertexId b, Vec3 pos,
                         double bound, const OffsetEdges& offsets,
                         std::vector<Survivor>* survivors, RefusalCounts* refusals);

}  // namespace tandem

#endif  // TANDEM_CONTRACTION_CHECKS_H_
