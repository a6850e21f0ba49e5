// The tests an edge contraction ab -> c must pass besides its cost (paper §2, "Surface
// simplification": the link condition LAMBDA(ab); flips, degenerate triangles and the distance
// guard are ours). Free functions of the mesh as it is, plus scratch memory the caller keeps
// between calls, so that a test can call them on a hand-made mesh.
#ifndef TANDEM_CONTRACTION_CHECKS_H_
#define TANDEM_CONTRACTION_CHECKS_H_

#include <cstddef>
#include <cstdint>
#include <vector>

#include "mesh_store.h"
#include "tandem/stats.h"
#include "tandem/types.h"

namespace tandem {

// LAMBDA(ab): Lk(a) ∩ Lk(b) = Lk(ab) on the complex completed by a dummy vertex joined to every
// boundary edge; false also when a and b are not adjacent or ab lies in three triangles. Two
// implementations of one test, checked against each other and against the definition in
// contraction_checks_test.cc: small fans (at most kFanMax triangles at a and at b, nearly
// every call) gather the neighbours into stack arrays; larger ones tally them in a table
// sized to the two fans (LinkScratch), not to the mesh: a mark per vertex id cost 12 bytes
// a vertex for the few fans past kFanMax (docs/decisions.md, stop 55).
inline constexpr size_t kFanMax = 16;
struct LinkScratch {
  struct Mark {  // per neighbour x of a or b: tallies of edges (a|b, x)
    VertexId x = kInvalid;
    uint8_t count_a = 0, count_b = 0;
  };
  std::vector<Mark> table;  // open addressing, at most half full
  size_t MemoryBytes() const { return table.capacity() * sizeof(Mark); }
};
bool LinkConditionFans(const MeshStore& store, VertexId a, VertexId b);  // fans <= kFanMax
bool LinkConditionMarks(const MeshStore& store, VertexId a, VertexId b, LinkScratch* scratch);
inline bool LinkCondition(const MeshStore& store, VertexId a, VertexId b, LinkScratch* scratch) {
  if (store.vertex_triangles(a).size() <= kFanMax && store.vertex_triangles(b).size() <= kFanMax) {
    return LinkConditionFans(store, a, b);
  }
  return LinkConditionMarks(store, a, b, scratch);
}

// Geometry of contracting ab to a vertex at `pos`: no surviving triangle may flip or collapse
// (tandem/geometry.h's MoveCorners), and with bound > 0 (the distance guard, K·E0) pos may lie
// at most `bound` from each one's present plane. Triangles already degenerate (exact iso hits)
// constrain nothing. On refusal, counts its reason in *refusals (distance before degenerate
// before flip) and returns false. `survivors` is scratch.
struct Survivor {  // a triangle that survives the contraction, and its corner that moves
  TriId t;
  VertexId v;
};
bool GeometryOk(const MeshStore& store, VertexId a, VertexId b, Vec3 pos, double bound,
                std::vector<Survivor>* survivors, RefusalCounts* refusals);

}  // namespace tandem

#endif  // TANDEM_CONTRACTION_CHECKS_H_
