#include "tandem/quadric.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

namespace tandem {

Quadric& Quadric::operator+=(const Quadric& o) {
  a00 += o.a00; a01 += o.a01; a02 += o.a02; a11 += o.a11; a12 += o.a12; a22 += o.a22;
  b0 += o.b0; b1 += o.b1; b2 += o.b2;
  c += o.c;
  w += o.w;
  return *this;
}

Quadric& Quadric::operator*=(double s) {
  a00 *= s; a01 *= s; a02 *= s; a11 *= s; a12 *= s; a22 *= s;
  b0 *= s; b1 *= s; b2 *= s;
  c *= s;
  return *this;
}

double Quadric::Evaluate(Vec3 x) const {
  const double ax = a00 * x.x + a01 * x.y + a02 * x.z;
  const double ay = a01 * x.x + a11 * x.y + a12 * x.z;
  const double az = a02 * x.x + a12 * x.y + a22 * x.z;
  return x.x * ax + x.y * ay + x.z * az + 2.0 * (b0 * x.x + b1 * x.y + b2 * x.z) + c;
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

double ShapeError(const Quadric& h, Vec3 x) {
  if (h.w <= 0.0) return 0.0;
  return std::sqrt(std::max(0.0, h.Evaluate(x) / h.w));
}

Vec3 MinimizeQuadric(const Quadric& q, Vec3 ref, uint8_t fixed_axes) {
  if (fixed_axes == 0) {
    // Fast path: λmin >= det / λmax² >= det / trace², and the truncation threshold is
    // 1e-3 λmax <= 1e-3 trace; so det >= 1e-3 trace³ proves no eigenvalue would be
    // dropped, and the direct solve equals the eigen-solution below (up to rounding).
    const double c00 = q.a11 * q.a22 - q.a12 * q.a12;
    const double c01 = q.a02 * q.a12 - q.a01 * q.a22;
    const double c02 = q.a01 * q.a12 - q.a02 * q.a11;
    const double det = q.a00 * c00 + q.a01 * c01 + q.a02 * c02;
    const double tr = q.a00 + q.a11 + q.a22;
    if (tr > 0.0 && det >= 1e-3 * tr * tr * tr) {
      const double c11 = q.a00 * q.a22 - q.a02 * q.a02;
      const double c12 = q.a01 * q.a02 - q.a00 * q.a12;
      const double c22 = q.a00 * q.a11 - q.a01 * q.a01;
      const double inv = 1.0 / det;
      // x = -A⁻¹ b with A⁻¹ = adj(A) / det (A symmetric, so adj is too).
      return {-(c00 * q.b0 + c01 * q.b1 + c02 * q.b2) * inv,
              -(c01 * q.b0 + c11 * q.b1 + c12 * q.b2) * inv,
              -(c02 * q.b0 + c12 * q.b1 + c22 * q.b2) * inv};
    }
  }
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

}  // namespace tandem
