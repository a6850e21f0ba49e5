#include "tandem/quadric.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

namespace tandem {

Quadric& Quadric::operator*=(double s) {
  a00 *= s; a01 *= s; a02 *= s; a11 *= s; a12 *= s; a22 *= s;
  b0 *= s; b1 *= s; b2 *= s;
  c *= s;
  return *this;
}

Quadric PlaneQuadric(Vec3 p, Vec3 q, Vec3 r) {
  const Vec3 n2 = Cross(q - p, r - p);  // length = 2 * area
  const double len = Norm(n2);
  Quadric h;
  if (len == 0.0) return h;
  const double area = 0.5 * len;
  const Vec3 n = n2 * (1.0 / len);
  const double d = -Dot(n, p);
  h.a00 = area * n.x * n.x; h.a01 = area * n.x * n.y; h.a02 = area * n.x * n.z;
  h.a11 = area * n.y * n.y; h.a12 = area * n.y * n.z; h.a22 = area * n.z * n.z;
  h.b0 = area * n.x * d; h.b1 = area * n.y * d; h.b2 = area * n.z * d;
  h.c = area * d * d;
  h.w = area;
  return h;
}

Quadric IsotropyQuadric(Vec3 p, Vec3 q, Vec3 r) {
  const double area = 0.5 * Norm(Cross(q - p, r - p));
  Quadric g;
  if (area == 0.0) return g;
  const Vec3 t = (p + q + r) * (1.0 / 3.0);
  const Vec3 dp = p - t, dq = q - t, dr = r - t;
  const double avg = (Dot(dp, dp) + Dot(dq, dq) + Dot(dr, dr)) / 12.0;
  g.a00 = g.a11 = g.a22 = area;
  g.b0 = -area * t.x; g.b1 = -area * t.y; g.b2 = -area * t.z;
  g.c = area * (Dot(t, t) + avg);
  return g;
}

namespace {

// The symmetric 3x3 matrix of a quadric with the rows and columns of fixed axes zeroed.
struct Sym3 {
  double a00, a01, a02, a11, a12, a22;
};

Sym3 FreeMatrix(const Quadric& q, uint8_t fixed_axes) {
  Sym3 m{q.a00, q.a01, q.a02, q.a11, q.a12, q.a22};
  if (fixed_axes & 1) m.a00 = m.a01 = m.a02 = 0.0;
  if (fixed_axes & 2) m.a01 = m.a11 = m.a12 = 0.0;
  if (fixed_axes & 4) m.a02 = m.a12 = m.a22 = 0.0;
  return m;
}

// x = M⁻¹ g through the adjugate; false when det is not positive (callers only use it for
// matrices whose eigenvalues they know to be >= 1e-3 of the largest).
bool SolveAdjugate(const Sym3& m, const double g[3], double x[3]) {
  const double c00 = m.a11 * m.a22 - m.a12 * m.a12;
  const double c01 = m.a02 * m.a12 - m.a01 * m.a22;
  const double c02 = m.a01 * m.a12 - m.a02 * m.a11;
  const double det = m.a00 * c00 + m.a01 * c01 + m.a02 * c02;
  if (!(det > 0.0)) return false;
  const double c11 = m.a00 * m.a22 - m.a02 * m.a02;
  const double c12 = m.a01 * m.a02 - m.a00 * m.a12;
  const double c22 = m.a00 * m.a11 - m.a01 * m.a01;
  const double inv = 1.0 / det;
  x[0] = (c00 * g[0] + c01 * g[1] + c02 * g[2]) * inv;
  x[1] = (c01 * g[0] + c11 * g[1] + c12 * g[2]) * inv;
  x[2] = (c02 * g[0] + c12 * g[1] + c22 * g[2]) * inv;
  return true;
}

// Unit eigenvector of m for the simple eigenvalue lambda: the longest cross product of two
// rows of m - lambda I (they span the plane orthogonal to it). False when all are tiny
// (lambda not simple, or not an eigenvalue to working precision).
bool EigenVector(const Sym3& m, double lambda, double scale, Vec3* v) {
  const Vec3 r0{m.a00 - lambda, m.a01, m.a02};
  const Vec3 r1{m.a01, m.a11 - lambda, m.a12};
  const Vec3 r2{m.a02, m.a12, m.a22 - lambda};
  const Vec3 c[3] = {Cross(r0, r1), Cross(r0, r2), Cross(r1, r2)};
  int best = 0;
  double best2 = Dot(c[0], c[0]);
  for (int i = 1; i < 3; ++i) {
    const double n2 = Dot(c[i], c[i]);
    if (n2 > best2) {
      best = i;
      best2 = n2;
    }
  }
  if (!(best2 > 1e-20 * scale * scale * scale * scale)) return false;
  *v = c[best] * (1.0 / std::sqrt(best2));
  return true;
}

}  // namespace

Vec3 MinimizeQuadricReference(const Quadric& q, Vec3 ref, uint8_t fixed_axes) {
  Eigen::Matrix3d a;
  a << q.a00, q.a01, q.a02, q.a01, q.a11, q.a12, q.a02, q.a12, q.a22;
  const Eigen::Vector3d r(ref.x, ref.y, ref.z);
  // Gradient at ref is 2 (A ref + b); the step δ solves A δ = -(A ref + b) on free axes.
  Eigen::Vector3d g = -(a * r + Eigen::Vector3d(q.b0, q.b1, q.b2));
  for (int i = 0; i < 3; ++i) {
    if ((fixed_axes >> i) & 1) {
      a.row(i).setZero();
      a.col(i).setZero();
      g(i) = 0.0;
    }
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
  es.computeDirect(a);
  const Eigen::Vector3d& lambda = es.eigenvalues();  // ascending
  const double lmax = std::max({std::abs(lambda(0)), std::abs(lambda(1)), std::abs(lambda(2))});
  if (!(lmax > 0.0)) return ref;
  const double tau = 1e-3 * lmax;
  Eigen::Vector3d delta = Eigen::Vector3d::Zero();
  for (int k = 0; k < 3; ++k) {
    if (lambda(k) > tau) {
      const Eigen::Vector3d v = es.eigenvectors().col(k);
      delta += (v.dot(g) / lambda(k)) * v;
    }
  }
  for (int i = 0; i < 3; ++i) {
    if ((fixed_axes >> i) & 1) delta(i) = 0.0;  // exact, whatever the rounding above
  }
  return {ref.x + delta(0), ref.y + delta(1), ref.z + delta(2)};
}

Vec3 MinimizeQuadric(const Quadric& q, Vec3 ref, uint8_t fixed_axes) {
  // Same result as MinimizeQuadricReference (up to rounding) without its trigonometric
  // eigen-solver, which cost ~1000 instructions a call and a third of all simplification
  // work: smooth surfaces give near-rank-1 quadrics, so almost every call truncates.
  const Sym3 m = FreeMatrix(q, fixed_axes);
  double g[3] = {-(q.a00 * ref.x + q.a01 * ref.y + q.a02 * ref.z + q.b0),
                 -(q.a01 * ref.x + q.a11 * ref.y + q.a12 * ref.z + q.b1),
                 -(q.a02 * ref.x + q.a12 * ref.y + q.a22 * ref.z + q.b2)};
  for (int i = 0; i < 3; ++i) {
    if ((fixed_axes >> i) & 1) g[i] = 0.0;
  }
  // Characteristic polynomial p(x) = x³ - c2 x² + c1 x - c0 (invariants of m).
  const double c2 = m.a00 + m.a11 + m.a22;
  const double c1 = m.a00 * m.a11 - m.a01 * m.a01 + m.a00 * m.a22 - m.a02 * m.a02 +
                    m.a11 * m.a22 - m.a12 * m.a12;
  const double c0 = m.a00 * (m.a11 * m.a22 - m.a12 * m.a12) +
                    m.a01 * (m.a02 * m.a12 - m.a01 * m.a22) +
                    m.a02 * (m.a01 * m.a12 - m.a02 * m.a11);
  if (!(c2 > 0.0)) return MinimizeQuadricReference(q, ref, fixed_axes);  // not PSD / zero
  double delta[3] = {0.0, 0.0, 0.0};
  // Fast path: λmin >= det / λmax² >= det / trace², and the truncation threshold is
  // 1e-3 λmax <= 1e-3 trace; so det >= 1e-3 trace³ proves no eigenvalue is dropped.
  if (c0 >= 1e-3 * c2 * c2 * c2) {
    if (!SolveAdjugate(m, g, delta)) return MinimizeQuadricReference(q, ref, fixed_axes);
  } else {
    // λmax by Newton from above: c2 - c1/c2 >= λ1 for a positive semi-definite matrix
    // (c1 = λ1(λ2+λ3) + λ2λ3 <= (λ2+λ3) c2), and p is convex above c2/3 <= λ1, so the
    // iterates fall monotonically to λ1 (from the trace, the start used before, it took
    // about two more steps). Convergence is quadratic: once a step is below 1e-8 of the
    // trace, the error left is at rounding level, so stop there. A (near-)double largest
    // root converges slowly: hand those to the reference solver.
    double l1 = c2 - c1 / c2;
    bool converged = false;
    for (int it = 0; it < 16; ++it) {
      const double p = ((l1 - c2) * l1 + c1) * l1 - c0;
      const double dp = (3.0 * l1 - 2.0 * c2) * l1 + c1;
      if (!(dp > 0.0)) break;
      const double step = p / dp;
      l1 -= step;
      if (std::abs(step) <= 1e-8 * c2) {
        converged = true;
        break;
      }
    }
    if (!converged || !(l1 > 0.0)) return MinimizeQuadricReference(q, ref, fixed_axes);
    // The other two: λ2 + λ3 = c2 - λ1, λ2 λ3 = c1 - λ1 (λ2 + λ3).
    const double s = c2 - l1, prod = c1 - l1 * s;
    const double root = std::sqrt(std::max(0.0, s * s - 4.0 * prod));
    const double l2 = 0.5 * (s + root);
    const double l3 = l2 > 0.0 ? prod / l2 : 0.5 * (s - root);
    const double tau = 1e-3 * l1;
    if (l3 > tau) {
      if (!SolveAdjugate(m, g, delta)) return MinimizeQuadricReference(q, ref, fixed_axes);
    } else if (l2 > tau) {
      // Rank 2: drop the eigen-direction v3 of λ3. B = m + (λ1 - λ3) v3 v3ᵀ has the same
      // eigenpairs except (λ1, v3), so B⁻¹ of g without its v3 part is the truncated step.
      Vec3 v3;
      if (!EigenVector(m, l3, c2, &v3)) return MinimizeQuadricReference(q, ref, fixed_axes);
      const double k = l1 - l3;
      const Sym3 b{m.a00 + k * v3.x * v3.x, m.a01 + k * v3.x * v3.y, m.a02 + k * v3.x * v3.z,
                   m.a11 + k * v3.y * v3.y, m.a12 + k * v3.y * v3.z, m.a22 + k * v3.z * v3.z};
      const double gv = g[0] * v3.x + g[1] * v3.y + g[2] * v3.z;
      const double gp[3] = {g[0] - gv * v3.x, g[1] - gv * v3.y, g[2] - gv * v3.z};
      if (!SolveAdjugate(b, gp, delta)) return MinimizeQuadricReference(q, ref, fixed_axes);
    } else {
      // Rank 1: move along the top eigen-direction only.
      Vec3 v1;
      if (!EigenVector(m, l1, c2, &v1)) return MinimizeQuadricReference(q, ref, fixed_axes);
      const double t = (g[0] * v1.x + g[1] * v1.y + g[2] * v1.z) / l1;
      delta[0] = t * v1.x;
      delta[1] = t * v1.y;
      delta[2] = t * v1.z;
    }
  }
  for (int i = 0; i < 3; ++i) {
    if ((fixed_axes >> i) & 1) delta[i] = 0.0;  // exact, whatever the rounding above
  }
  return {ref.x + delta[0], ref.y + delta[1], ref.z + delta[2]};
}

}  // namespace tandem
