// Quadrics (SPEC §3, §4): all quadric math of the project lives here, in double precision.
//
// A Quadric stores the symmetric 4x4 matrix H of x̄ᵀ H x̄ with x̄ = (x, 1) as
//   f(x) = xᵀ A x + 2 bᵀ x + c   (A 3x3 symmetric, 6 entries; b 3; c 1)
// plus the weight W (sum of triangle areas) that turns the sum into an average.
#ifndef TANDEM_QUADRIC_H_
#define TANDEM_QUADRIC_H_

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "tandem/types.h"

namespace tandem {

struct Quadric {
  double a00 = 0, a01 = 0, a02 = 0, a11 = 0, a12 = 0, a22 = 0;
  double b0 = 0, b1 = 0, b2 = 0;
  double c = 0;
  double w = 0;  // W: total area behind the quadric (0 for the isotropy quadric G)

  // The two below are on every edge evaluation and contraction: defined here, inline.
  Quadric& operator+=(const Quadric& o) {
    a00 += o.a00; a01 += o.a01; a02 += o.a02; a11 += o.a11; a12 += o.a12; a22 += o.a22;
    b0 += o.b0; b1 += o.b1; b2 += o.b2;
    c += o.c;
    w += o.w;
    return *this;
  }
  Quadric& operator*=(double s);  // scales the matrix, not w
  double Evaluate(Vec3 x) const {  // x̄ᵀ H x̄ (not divided by w)
    const double ax = a00 * x.x + a01 * x.y + a02 * x.z;
    const double ay = a01 * x.x + a11 * x.y + a12 * x.z;
    const double az = a02 * x.x + a12 * x.y + a22 * x.z;
    return x.x * ax + x.y * ay + x.z * az + 2.0 * (b0 * x.x + b1 * x.y + b2 * x.z) + c;
  }
};

// Area-weighted plane quadric of triangle (p, q, r): H_t = w_t p_t p_tᵀ with p_t = (n, -n·p)
// the unit-normal plane, w = W_t = area. A zero-area triangle gives the zero quadric.
Quadric PlaneQuadric(Vec3 p, Vec3 q, Vec3 r);

// Isotropy quadric of a triangle (SPEC §4): G_t = w_t [[I, -t̂], [-t̂ᵀ, t̂·t̂ + avg(t)]], so
// x̄ᵀ G_t x̄ = w_t (|x - t̂|² + avg(t)), avg(t) = (|p|² + |q|² + |r|²)/12 from the centroid.
// Its w field stays 0 (G is not averaged by W_c).
Quadric IsotropyQuadric(Vec3 p, Vec3 q, Vec3 r);

// Root mean square plane distance ε0 = sqrt(x̄ᵀ H x̄ / W); 0 when W = 0 (no planes).
inline double ShapeError(const Quadric& h, Vec3 x) {
  if (h.w <= 0.0) return 0.0;
  return std::sqrt(std::max(0.0, h.Evaluate(x) / h.w));
}

// Minimises f over x = ref + δ with δ zero on the axes whose bit (1 = x, 2 = y, 4 = z) is in
// `fixed_axes`. Singular or ill-conditioned directions (eigenvalues below 1e-3 of the
// largest) are not moved along, so the result is the closest point to `ref` among the
// minimisers of the well-determined part: for a single plane, ref projected onto it; for a
// crease, ref's projection onto the crease line; for a flat-zero quadric, ref itself. This
// is the stable fallback of SPEC §3 (cf. Lindstrom & Turk 1998).
Vec3 MinimizeQuadric(const Quadric& q, Vec3 ref, uint8_t fixed_axes = 0);
// The same with Eigen's closed-form eigen-decomposition: the definition MinimizeQuadric's
// cheaper rank cases (Newton on the characteristic polynomial, cross-product eigenvectors)
// are tested against, and their fallback where those are ill-conditioned.
Vec3 MinimizeQuadricReference(const Quadric& q, Vec3 ref, uint8_t fixed_axes = 0);

}  // namespace tandem

#endif  // TANDEM_QUADRIC_H_
