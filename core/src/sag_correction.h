// Sag correction (not in the paper; SessionOptions::sag_correction), run on the final mesh
// (Simplifier::CorrectSag) or on each vertex as the sealer freezes it (Sealer::Seal): both go
// through CorrectSagAt below, the one implementation of the rule.
//
// A coarse triangle is a chord of the curved surface it replaces: on average its interior lies
// off the surface, on the concave side, by s = Σ eᵀKe / 24 over its three edges e (K the
// curvature tensor: linear interpolation of a quadratic errs by ½ Σ λiλj eᵀKe, and λiλj
// averages 1/12 over a triangle). The quadric minimiser puts each vertex off the surface on
// the convex side, which cancels only part of s; what is left is a bias toward the concave
// side. Each vertex moves along its normal by `fraction` times the area-weighted mean s of its
// triangles (docs/decisions.md: why 0.3 by default). eᵀKe is taken from the mesh itself,
// (n_j − n_i)·(x_j − x_i) with area-weighted vertex normals: nothing more is stored while
// simplifying.
#ifndef TANDEM_SAG_CORRECTION_H_
#define TANDEM_SAG_CORRECTION_H_

#include <cstdint>
#include <span>
#include <vector>

#include "id_index.h"
#include "mesh_store.h"
#include "quadric.h"
#include "tandem/executor.h"
#include "tandem/types.h"

namespace tandem {

// The area-weighted unit normal of v from its current triangles (summed over its fan in
// increasing triangle id, whichever vertex asks; 0 without area). `fan` is scratch.
Vec3 VertexNormal(const MeshStore& store, VertexId v, std::vector<TriId>* fan);
// VertexNormal of each of `verts`, into normal[v]; with an executor, large lists in ranges
// side by side (the CPU time they take on other threads is added to *helper_seconds).
void VertexNormals(const MeshStore& store, std::span<const VertexId> verts,
                   std::span<Vec3> normal, Executor* executor = nullptr,
                   double* helper_seconds = nullptr);

// Vertex normals by vertex id: normal[v], or, kept compactly (the sealer keeps those of its
// frozen vertices only), normal[*slot.Find(v)], 0 where v has none.
struct VertexNormalTable {
  VertexNormalTable(std::span<const Vec3> by_id) : normal(by_id) {}  // NOLINT: implicit
  VertexNormalTable(const std::vector<Vec3>& by_id) : normal(by_id) {}  // NOLINT: implicit
  VertexNormalTable(std::span<const Vec3> compact, const IdMap<uint32_t>* slots)
      : normal(compact), slot(slots) {}
  Vec3 operator[](VertexId v) const {
    if (slot == nullptr) return normal[v];
    const uint32_t* s = slot->Find(v);
    return s == nullptr ? Vec3{} : normal[*s];
  }
  std::span<const Vec3> normal;
  const IdMap<uint32_t>* slot = nullptr;  // null: normal is indexed by vertex id
};

// Scratch of CorrectSagAt, kept by the caller between calls.
struct SagScratch {
  IdIndex slot;  // a vertex id's index in verts, or kInvalid
  std::vector<TriId> fan, checks;
  size_t MemoryBytes() const { return slot.MemoryBytes(); }
};

// Moves each vertex of `verts` not on the grid's box (frozen ones may move: they are frozen
// now) along normal[v] by `fraction` times the mean sag of its triangles, as far as its ε0
// (quadric[i] for verts[i]) stays <= max(error, ε0 now), unless it sits at a crease. No
// triangle may flip or collapse (tandem/geometry.h): the corners of any that would are put
// back until none does. normal[v] must hold the unit normal of every vertex of their
// triangles (VertexNormals). Appends the moved vertices to *moved_ids; returns their number.
// With an executor the steps of a large list are taken in ranges side by side, with the same
// result (the CPU time they take on other threads is added to *helper_seconds).
int64_t CorrectSagAt(MeshStore* store, std::span<const VertexId> verts,
                     VertexNormalTable normal, std::span<const Quadric> quadric, double fraction,
                     double error, SagScratch* scratch, std::vector<VertexId>* moved_ids,
                     Executor* executor = nullptr, double* helper_seconds = nullptr);

}  // namespace tandem

#endif  // TANDEM_SAG_CORRECTION_H_
