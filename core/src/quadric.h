// Quadrics (paper §2, "Surface simplification" and "Isotropy parameter"): the plane and
// isotropy quadrics, the shape error ε0, the cost ε_α and the placement, in double precision.
//
// A Quadric stores the symmetric 4x4 matrix H of x̄ᵀ H x̄ with x̄ = (x, 1) as
//   f(x) = xᵀ A x + 2 bᵀ x + c   (A 3x3 symmetric, 6 entries; b 3; c 1)
// plus the weight W (sum of triangle areas) that turns the sum into an average.
#ifndef TANDEM_QUADRIC_H_
#define TANDEM_QUADRIC_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

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

// Isotropy quadric of a triangle (paper §2, "Isotropy parameter"): G_t = w_t [[I, -t̂], [-t̂ᵀ, t̂·t̂ + avg(t)]], so
// x̄ᵀ G_t x̄ = w_t (|x - t̂|² + avg(t)), avg(t) = (|p|² + |q|² + |r|²)/12 from the centroid.
// Its w field stays 0 (G is not averaged by W_c).
Quadric IsotropyQuadric(Vec3 p, Vec3 q, Vec3 r);

// Root mean square plane distance ε0 = sqrt(x̄ᵀ H x̄ / W); 0 when W = 0 (no planes).
inline double ShapeError(const Quadric& h, Vec3 x) {
  if (h.w <= 0.0) return 0.0;
  return std::sqrt(std::max(0.0, h.Evaluate(x) / h.w));
}

// ε0 as Error(K) measures it: ShapeError, but 0 where x̄ᵀHx̄ is within rounding of 0.
// x̄ᵀHx̄ = Σ_t w_t (n_t·x + d_t)² is computed from H's entries as a difference of products
// whose magnitudes add up to at most S(x) = (Σ_i √a_ii |x_i| + √c)² (Cauchy-Schwarz over the
// triangles: Σ_t w_t (Σ_i |n_i x_i| + |d_t|)² <= S), so rounding leaves it uncertain by about
// γ S(x): a few units of rounding per triangle's quadric, one per addition of the vertex's
// sum, a dozen in Evaluate. γ = 2⁻⁴⁰ (8192 units) bounds that for thousands of triangles.
// Where the RMS distance is not told apart from 0 it is 0: a vertex that was never moved lies
// on all its planes. That noise, √(γ S/W) <= 2|x|√γ ≈ |x|·2e-6 (2e-3 voxel at the far corner of
// 512³), is far below any E0 that matters, but at extreme anisotropy it is not: with spacing (1e9, 1e6, 1e6) the
// engine frame's unit is 2¹⁹ and |x| reaches 3e4, one unit of rounding in c made an
// untouched vertex read ε0 = 1e-5 > E0 = 6e-6 (E0 = 3.2 in world units; fuzz_session).
// Elsewhere the value is ShapeError's, so a contraction that passed ShapeError <= E0 still
// reads <= E0 here.
inline double MeasuredShapeError(const Quadric& h, Vec3 x) {
  if (h.w <= 0.0) return 0.0;
  constexpr double kRounding = 0x1p-40;
  const double root = std::sqrt(std::max(0.0, h.a00)) * std::abs(x.x) +
                      std::sqrt(std::max(0.0, h.a11)) * std::abs(x.y) +
                      std::sqrt(std::max(0.0, h.a22)) * std::abs(x.z) +
                      std::sqrt(std::max(0.0, h.c));
  const double f = h.Evaluate(x);
  if (f <= kRounding * root * root) return 0.0;
  return std::sqrt(f / h.w);
}

// The paper's isotropic cost ε_α (paper §2, "Isotropy parameter") as one quadric:
// (1 − α) H/W + α G/W_G, with H the plane quadric of the contraction (W = h.w its area), G
// the isotropy quadric of the triangles around a or b (`area` = their total area) and
// W_G = 3·area·√W / E0, which makes G/W_G a squared length like H/W. Its minimiser is the
// placement of c and IsotropicCost at it is ε_α(c). Zero when W = 0 (no planes). The w field
// is 0. On every evaluation with α > 0: inline, and g is scaled in place (no copy).
inline Quadric IsotropicCostQuadric(const Quadric& h, Quadric&& g, double area, double alpha,
                                    double e0) {
  Quadric combined;
  if (h.w > 0.0) {
    combined = h;
    combined *= (1.0 - alpha) / h.w;
  }
  if (area > 0.0 && h.w > 0.0) {
    const double big_w = 3.0 * area * std::sqrt(h.w) / e0;
    g *= alpha / big_w;
    combined += g;
  }
  combined.w = 0.0;
  return combined;
}
// ε_α at x: sqrt(x̄ᵀ C x̄) for C = IsotropicCostQuadric(...).
inline double IsotropicCost(const Quadric& combined, Vec3 x) {
  return std::sqrt(std::max(0.0, combined.Evaluate(x)));
}

// The largest s in [0, t] with ShapeError(q, x + s·d) <= limit, for a q with planes (w > 0)
// and an x that meets the limit: along the line, x̄ᵀHx̄ = f0 + 2sg + s²k, solved in closed
// form, then checked as ShapeError computes it (x̄ᵀHx̄ is a difference of terms of order
// |x|², so at 512³ the check can disagree in the 8th digit: s shrinks by a tenth until it
// agrees, or becomes 0 after 40 tries).
double StepWithinError(const Quadric& q, Vec3 x, Vec3 d, double t, double limit);

// What "ill-conditioned" means for MinimizeQuadric: an eigen-direction of A whose eigenvalue
// is below kIllConditioned times the largest. Solving along it would lose more than half of
// double precision's 16 digits (condition number above 1e8); VTK's quadric decimation draws
// its line at 1e-10 (relative determinant). A larger threshold also drops the directions that
// carry a smooth patch's curvature (docs/decisions.md: why 1e-8).
inline constexpr double kIllConditioned = 1e-8;

// A quadric as an edge's evaluation holds it: the same fields in pairs of doubles (one SSE2
// register each on x86-64), so the sum of two ends, the placement and ε0 take half the
// arithmetic instructions of Quadric's fields one by one. Every value is computed in the same
// order as from a Quadric, so results are bit for bit Quadric's (the sign of a zero aside).
using V2d = double __attribute__((vector_size(16)));

struct PackedQuadric {
  V2d a0, a1, a2;  // (a00, a01), (a02, a11), (a12, a22)
  V2d b01;         // (b0, b1)
  V2d b2c;         // (b2, c)
  double w;

  // A's columns (or rows): (a00, a01, a02), (a01, a11, a12), (a02, a12, a22) as a pair of
  // their first two entries and the third.
  V2d col1() const { return __builtin_shufflevector(a0, a1, 1, 3); }  // (a01, a11)
  V2d col2() const { return __builtin_shufflevector(a1, a2, 0, 2); }  // (a02, a12)
  // A x (x's first two entries in a pair): the pair (ax, ay), and az.
  V2d ProductXY(V2d x, double z) const {
    return a0 * V2d{x[0], x[0]} + col1() * V2d{x[1], x[1]} + col2() * V2d{z, z};
  }
  double ProductZ(V2d x, double z) const { return a1[0] * x[0] + a2[0] * x[1] + a2[1] * z; }
  double Evaluate(Vec3 p) const {  // Quadric::Evaluate
    const V2d x{p.x, p.y};
    const V2d axy = ProductXY(x, p.z);
    const V2d sq = x * axy;
    const V2d lin = x * b01;
    return sq[0] + sq[1] + p.z * ProductZ(x, p.z) + 2.0 * (lin[0] + lin[1] + b2c[0] * p.z) +
           b2c[1];
  }
  Quadric Unpack() const {
    Quadric q;
    q.a00 = a0[0], q.a01 = a0[1], q.a02 = a1[0], q.a11 = a1[1], q.a12 = a2[0], q.a22 = a2[1];
    q.b0 = b01[0], q.b1 = b01[1], q.b2 = b2c[0], q.c = b2c[1], q.w = w;
    return q;
  }
};

inline PackedQuadric Pack(const Quadric& q) {
  return {V2d{q.a00, q.a01}, V2d{q.a02, q.a11}, V2d{q.a12, q.a22}, V2d{q.b0, q.b1},
          V2d{q.b2, q.c},    q.w};
}

// ShapeError of a packed quadric.
inline double ShapeError(const PackedQuadric& h, Vec3 x) {
  if (h.w <= 0.0) return 0.0;
  return std::sqrt(std::max(0.0, h.Evaluate(x) / h.w));
}

namespace quadric_internal {

// The symmetric 3x3 matrix of a quadric with the rows and columns of fixed axes zeroed.
struct Sym3 {
  double a00, a01, a02, a11, a12, a22;
};

// x = M⁻¹ g by LDLᵀ (Cholesky without square roots): backward stable for a positive
// definite M, so x is good to about κ ε. The adjugate (Cramer's rule) is not: det cancels
// to an absolute error of ε λ1³, a relative one of ε κ² (2e-6 at κ = 1e5). False on a
// pivot that is not positive (callers only use it for matrices they know to be well inside
// positive definite).
inline bool SolveLdlt(const Sym3& m, const double g[3], double x[3]) {
  const double d0 = m.a00;
  if (!(d0 > 0.0)) return false;
  const double l10 = m.a01 / d0, l20 = m.a02 / d0;
  const double d1 = m.a11 - l10 * m.a01;
  if (!(d1 > 0.0)) return false;
  const double l21 = (m.a12 - l20 * m.a01) / d1;
  const double d2 = m.a22 - l20 * m.a02 - l21 * l21 * d1;
  if (!(d2 > 0.0)) return false;
  const double y0 = g[0], y1 = g[1] - l10 * y0, y2 = g[2] - l20 * y0 - l21 * y1;
  x[2] = y2 / d2;
  x[1] = y1 / d1 - l21 * x[2];
  x[0] = y0 / d0 - l10 * x[1] - l20 * x[2];
  return true;
}

// The margin of MinimizeQuadric's fast-path test for the rounding of det and c1.
inline constexpr double kInvariantRounding = 64.0 * std::numeric_limits<double>::epsilon();

// MinimizeQuadric's full-rank case with nothing fixed, the one nearly every edge off a flat
// face takes: false (nothing written) where the full solve has to decide.
inline bool MinimizeFullRank(const PackedQuadric& q, Vec3 ref, Vec3* x) {
  const V2d r{ref.x, ref.y};
  const V2d gxy = -(q.ProductXY(r, ref.z) + q.b01);
  const double a00 = q.a0[0], a01 = q.a0[1], a02 = q.a1[0], a11 = q.a1[1], a12 = q.a2[0],
               a22 = q.a2[1];
  const double g[3] = {gxy[0], gxy[1], -(q.ProductZ(r, ref.z) + q.b2c[0])};
  const double c2 = a00 + a11 + a22;
  const double c1 = a00 * a11 - a01 * a01 + a00 * a22 - a02 * a02 + a11 * a22 - a12 * a12;
  const double c0 = a00 * (a11 * a22 - a12 * a12) + a01 * (a02 * a12 - a01 * a22) +
                    a02 * (a01 * a12 - a02 * a11);
  if (!(c2 > 0.0)) return false;
  if (!(c0 >= kIllConditioned * c1 * c2 + kInvariantRounding * c2 * c2 * c2)) return false;
  double delta[3];
  if (!SolveLdlt(Sym3{a00, a01, a02, a11, a12, a22}, g, delta)) return false;
  *x = {ref.x + delta[0], ref.y + delta[1], ref.z + delta[2]};
  return true;
}

}  // namespace quadric_internal

// Minimises f over x = ref + δ with δ zero on the axes whose bit (1 = x, 2 = y, 4 = z) is in
// `fixed_axes`. Singular or ill-conditioned directions (eigenvalues below kIllConditioned of
// the largest) are not moved along, so the result is the closest point to `ref` among the
// minimisers of the well-determined part: for a single plane, ref projected onto it; for a
// crease, ref's projection onto the crease line; for a flat-zero quadric, ref itself. This
// is the stable fallback for singular systems (cf. Lindstrom & Turk 1998).
Vec3 MinimizeQuadricSolve(const Quadric& q, Vec3 ref, uint8_t fixed_axes);
// The same: the full-rank case inline (on every edge evaluation), the rest out of line.
inline Vec3 MinimizeQuadric(const Quadric& q, Vec3 ref, uint8_t fixed_axes = 0) {
  Vec3 x;
  if (fixed_axes == 0 && quadric_internal::MinimizeFullRank(Pack(q), ref, &x)) return x;
  return MinimizeQuadricSolve(q, ref, fixed_axes);
}
// The same with Eigen's closed-form eigen-decomposition: the definition MinimizeQuadric's
// cheaper rank cases (Newton on the characteristic polynomial, cross-product eigenvectors)
// are tested against, and their fallback where those are ill-conditioned.
Vec3 MinimizeQuadricReference(const Quadric& q, Vec3 ref, uint8_t fixed_axes = 0);

}  // namespace tandem

#endif  // TANDEM_QUADRIC_H_
