#include "quadric.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>

#include "tandem/geometry.h"

namespace tandem {

Quadric& Quadric::operator*=(double s) {
  a00 *= s; a01 *= s; a02 *= s; a11 *= s; a12 *= s; a22 *= s;
  b0 *= s; b1 *= s; b2 *= s;
  c *= s;
  return *this;
}

Quadric PlaneQuadric(Vec3 p, Vec3 q, Vec3 r) {
  const Vec3 n2 = TwiceAreaVector(p, q, r);  // length = 2 * area
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
  const double area = 0.5 * Norm(TwiceAreaVector(p, q, r));
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

using quadric_internal::SolveLdlt;
using quadric_internal::Sym3;

Sym3 FreeMatrix(const Quadric& q, uint8_t fixed_axes) {
  Sym3 m{q.a00, q.a01, q.a02, q.a11, q.a12, q.a22};
  if (fixed_axes & 1) m.a00 = m.a01 = m.a02 = 0.0;
  if (fixed_axes & 2) m.a01 = m.a11 = m.a12 = 0.0;
  if (fixed_axes & 4) m.a02 = m.a12 = m.a22 = 0.0;
  return m;
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

// The step along the two eigen-directions orthogonal to the unit eigenvector v1 whose
// eigenvalues exceed tau: m restricted to the plane orthogonal to v1 (a 2x2 problem in a basis
// p, q of that plane). Every eigenvalue found this way is within a few ε λ1 of the truth
// (Weyl), where the invariants (λ2 λ3 = c1 - λ1 (λ2 + λ3)) cancel to an absolute error of
// about ε λ1², so λ3 = that / λ2 was noise whenever λ2 was small: a (near-)planar quadric
// could pass for full rank and be "solved" hundreds of units away (1 in 1000 rounded
// coplanar quadrics did, before 2026-11).
Vec3 MinorStep(const Sym3& m, Vec3 v1, Vec3 gv, double tau) {
  const double ax = std::abs(v1.x), ay = std::abs(v1.y), az = std::abs(v1.z);
  const Vec3 least = (ax <= ay && ax <= az) ? Vec3{1, 0, 0}
                     : (ay <= az)           ? Vec3{0, 1, 0}
                                            : Vec3{0, 0, 1};
  Vec3 pv = Cross(v1, least);
  pv = pv * (1.0 / Norm(pv));
  const Vec3 qv = Cross(v1, pv);
  auto apply = [&m](Vec3 x) {
    return Vec3{m.a00 * x.x + m.a01 * x.y + m.a02 * x.z, m.a01 * x.x + m.a11 * x.y + m.a12 * x.z,
                m.a02 * x.x + m.a12 * x.y + m.a22 * x.z};
  };
  const Vec3 mp = apply(pv), mq = apply(qv);
  const double b00 = Dot(pv, mp), b01 = Dot(pv, mq), b11 = Dot(qv, mq);
  const double mean = 0.5 * (b00 + b11), half = 0.5 * (b00 - b11);
  const double r = std::sqrt(half * half + b01 * b01);
  const double l2 = mean + r, l3 = mean - r;
  // Unit eigenvector of the 2x2 for l2: the longer of (b01, l2 - b00) and (l2 - b11, b01);
  // when both vanish (b01 = 0 and equal diagonal: any direction), take p.
  double e0 = b01, e1 = l2 - b00;
  if (std::abs(l2 - b11) + std::abs(b01) > std::abs(e0) + std::abs(e1)) {
    e0 = l2 - b11;
    e1 = b01;
  }
  const double en = std::sqrt(e0 * e0 + e1 * e1);
  const Vec3 v2 = en > 0.0 ? (pv * e0 + qv * e1) * (1.0 / en) : pv;
  const Vec3 v3 = Cross(v1, v2);
  Vec3 step{0, 0, 0};
  if (l2 > tau) step = step + v2 * (Dot(v2, gv) / l2);
  if (l3 > tau) step = step + v3 * (Dot(v3, gv) / l3);
  return step;
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
  es.compute(a);  // iterative (QR): eigenvalues within a few ε λmax; computeDirect's
                  // closed form was off by ~3e-9 λmax, too close to kIllConditioned
  const Eigen::Vector3d& lambda = es.eigenvalues();  // ascending
  const double lmax = std::max({std::abs(lambda(0)), std::abs(lambda(1)), std::abs(lambda(2))});
  if (!(lmax > 0.0)) return ref;
  const double tau = kIllConditioned * lmax;
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

Vec3 MinimizeQuadricSolve(const Quadric& q, Vec3 ref, uint8_t fixed_axes) {
  // Same result as MinimizeQuadricReference (up to rounding) without its costly trigonometric
  // eigen-solver (docs/decisions.md 20): smooth surfaces give near-rank-1 quadrics.
  const Sym3 m = FreeMatrix(q, fixed_axes);
  double g[3] = {-(q.a00 * ref.x + q.a01 * ref.y + q.a02 * ref.z + q.b0),
                 -(q.a01 * ref.x + q.a11 * ref.y + q.a12 * ref.z + q.b1),
                 -(q.a02 * ref.x + q.a12 * ref.y + q.a22 * ref.z + q.b2)};
  if (fixed_axes != 0) {  // most edges are off the box
    for (int i = 0; i < 3; ++i) {
      if ((fixed_axes >> i) & 1) g[i] = 0.0;
    }
  }
  // Characteristic polynomial p(x) = x³ - c2 x² + c1 x - c0 (invariants of m).
  const double c2 = m.a00 + m.a11 + m.a22;
  const double c1 =
      m.a00 * m.a11 - m.a01 * m.a01 + m.a00 * m.a22 - m.a02 * m.a02 + m.a11 * m.a22 - m.a12 * m.a12;
  const double c0 = m.a00 * (m.a11 * m.a22 - m.a12 * m.a12) +
                    m.a01 * (m.a02 * m.a12 - m.a01 * m.a22) +
                    m.a02 * (m.a01 * m.a12 - m.a02 * m.a11);
  if (!(c2 > 0.0)) return MinimizeQuadricReference(q, ref, fixed_axes);  // not PSD / zero
  double delta[3] = {0.0, 0.0, 0.0};
  // Fast path: certify that no eigenvalue is below τ λ1 (τ = kIllConditioned) and solve
  // directly. λ3 = det / (λ1 λ2), and λ1 λ2 <= c1 (the other two products in c1 are >= 0),
  // λ1 <= c2; so det >= τ c1 c2 proves λ3 >= τ λ1. det and c1 are rounded to an absolute
  // error of a few dozen ε c2³ and ε c2² (every entry is at most c2), so the test keeps a
  // margin of 64 ε c2³: a (near-)planar quadric, whose det is rounding noise, never passes.
  // This catches every curved patch (λ2 λ3 of 1e-10..1e-6 λ1²); the truncating path below is
  // left to planes and creases (docs/decisions.md 20).
  constexpr double kRounding = quadric_internal::kInvariantRounding;
  if (c0 >= kIllConditioned * c1 * c2 + kRounding * c2 * c2 * c2) {
    if (!SolveLdlt(m, g, delta)) return MinimizeQuadricReference(q, ref, fixed_axes);
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
    // The other eigenpairs: MinorStep (not from the invariants, see there).
    Vec3 v1;
    if (!EigenVector(m, l1, c2, &v1)) return MinimizeQuadricReference(q, ref, fixed_axes);
    const double tau = kIllConditioned * l1;
    const Vec3 gv{g[0], g[1], g[2]};
    Vec3 step = v1 * (Dot(v1, gv) / l1);
    // λ2 + λ3 = trace - λ1 is exact to a few ε λ1: when it is below τ, the quadric is rank 1
    // (flat faces: the common case on CT parts and the Pillow Box) and v1 is the whole step.
    if (c2 - l1 > tau) step = step + MinorStep(m, v1, gv, tau);
    delta[0] = step.x;
    delta[1] = step.y;
    delta[2] = step.z;
  }
  if (fixed_axes != 0) {
    for (int i = 0; i < 3; ++i) {
      if ((fixed_axes >> i) & 1) delta[i] = 0.0;  // exact, whatever the rounding above
    }
  }
  return {ref.x + delta[0], ref.y + delta[1], ref.z + delta[2]};
}

double StepWithinError(const Quadric& q, Vec3 x, Vec3 d, double t, double limit) {
  const double f0 = q.Evaluate(x);
  const double bound = std::max(q.w * limit * limit, f0);
  if (q.Evaluate(x + d * t) > bound) {
    const Vec3 ad{q.a00 * d.x + q.a01 * d.y + q.a02 * d.z, q.a01 * d.x + q.a11 * d.y + q.a12 * d.z,
                  q.a02 * d.x + q.a12 * d.y + q.a22 * d.z};
    const double g = Dot(ad, x) + q.b0 * d.x + q.b1 * d.y + q.b2 * d.z;  // ½ d/ds at s = 0
    const double k = Dot(ad, d);
    // The positive root of k s² + 2 g s = bound - f0, in the form that stays exact as k -> 0.
    const double den = g + std::sqrt(std::max(0.0, g * g + k * (bound - f0)));
    t = den > 0.0 ? std::min(t, (bound - f0) / den * (1.0 - 1e-9)) : 0.0;
  }
  for (int tries = 0; t > 0.0 && ShapeError(q, x + d * t) > limit; ++tries) {
    t = tries < 40 ? 0.9 * t : 0.0;
  }
  return t;
}

}  // namespace tandem
