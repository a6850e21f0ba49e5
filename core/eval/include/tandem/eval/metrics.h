// Mesh quality measures of Section 4 of Attali, Cohen-Steiner, Edelsbrunner, "Extraction and
// Simplification of Iso-surfaces in Tandem" (SGP 2005). Pure functions of an IndexedMesh; the
// per-triangle area, normal and degeneracy rule come from tandem/geometry.h, which the engine
// uses too.
//
// Units: lengths and areas are in the mesh's units (physical units for tandem's output);
// aspect ratio, anisotropy and directional bias are dimensionless, in [0, 1].
// Contract: every index in mesh.indices is < mesh.num_vertices() and indices.size() is a
// multiple of 3 (checked with assert only; these are measures, not input validation).
#ifndef TANDEM_METRICS_H_
#define TANDEM_METRICS_H_

#include "tandem/geometry.h"
#include "tandem/mesh.h"
#include "tandem/types.h"

namespace tandem::eval {

// The paper's aspect ratio ρ = sqrt(λ2/λ1), where λ1 ≥ λ2 are the two non-zero eigenvalues of
// M_abc = (aaᵀ + bbᵀ + ccᵀ)/3 with a, b, c taken relative to the centroid. 1 exactly for an
// equilateral triangle (up to round-off), → 0 as the triangle flattens; 0 for a degenerate
// triangle (IsDegenerateTriangle). Example: the right isosceles triangle gives sqrt(1/3).
double TriangleAspectRatio(Vec3 a, Vec3 b, Vec3 c);

// Total area Σ w_t. 0 for an empty mesh.
double SurfaceArea(const IndexedMesh& mesh);

// Anisotropy(K) = 1 − mean over triangles of ρ(t), in [0, 1]; 0 iff all triangles are
// equilateral. Choice: degenerate (zero-area) triangles are SKIPPED, not counted as ρ = 0.
// Marching cubes on integer volumes emits about one such triangle in ten; counting
// them would measure the extraction's zero-area slivers rather than the shape of the
// triangles that make up the surface. Returns NaN when the mesh has no non-degenerate
// triangle (the mean is undefined).
double Anisotropy(const IndexedMesh& mesh);

// Directional bias (paper §4): M_n = (1/area) Σ w_t n_t n_tᵀ, M_s = (2/area) Σ w_t
// M_abc / trace(M_abc), M = M_n + M_s, Bias = 1 − 27 det(M) / trace(M)³, in [0, 1].
// M is the identity for an all-equilateral mesh, so Bias = 0 there; Bias = 0 also for any
// triangulation whose symmetry group acts irreducibly on R³ (icosahedral, cubic). w_t is the
// area, so degenerate triangles contribute nothing. Returns NaN when the total area is 0.
double DirectionalBias(const IndexedMesh& mesh);

// Anisotropy and DirectionalBias as running sums, for a mesh that is never whole in one
// place (sealed chunks): Add each piece, each triangle once; the results equal the functions
// above on the union (up to the order of the sums).
class ShapeSums {
 public:
  void Add(const IndexedMesh& mesh);
  double anisotropy() const;
  double directional_bias() const;

 private:
  double sum_rho_ = 0.0;
  size_t counted_ = 0;
  double m_n_[3][3] = {}, m_s_[3][3] = {};  // Σ w n nᵀ and Σ w M_abc / trace (DirectionalBias)
  double area_ = 0.0;
};

}  // namespace tandem::eval

#endif  // TANDEM_METRICS_H_
