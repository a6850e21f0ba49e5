// Mesh quality measures (paper §4). See tandem/metrics.h for the contracts.
#include "tandem/eval/metrics.h"

#include <cstring>

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <limits>

namespace tandem::eval {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// The corners of a triangle relative to its centroid: the a, b, c of the paper's M_abc.
struct CenteredTriangle {
  std::array<Vec3, 3> p;
  double trace;  // trace(M_abc) = (|a|² + |b|² + |c|²) / 3
};

CenteredTriangle Center(Vec3 a, Vec3 b, Vec3 c) {
  const Vec3 g = (1.0 / 3.0) * (a + b + c);
  CenteredTriangle t{{a - g, b - g, c - g}, 0.0};
  t.trace = (Dot(t.p[0], t.p[0]) + Dot(t.p[1], t.p[1]) + Dot(t.p[2], t.p[2])) / 3.0;
  return t;
}

// Symmetric 3×3 matrix accumulator, row-major full storage (clarity over 6-entry packing).
struct Sym3 {
  double m[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  void AddOuter(Vec3 v, double w) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) m[i][j] += w * v[i] * v[j];
  }
  double Trace() const { return m[0][0] + m[1][1] + m[2][2]; }
  double Det() const {
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
           m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  }
};

// Calls f(a, b, c) for every triangle of the mesh.
template <typename F>
void ForEachTriangle(const IndexedMesh& mesh, F&& f) {
  assert(mesh.indices.size() % 3 == 0);
  const size_t n = mesh.num_triangles();
  for (size_t t = 0; t < n; ++t) {
    const uint32_t i0 = mesh.indices[3 * t], i1 = mesh.indices[3 * t + 1],
                   i2 = mesh.indices[3 * t + 2];
    assert(i0 < mesh.positions.size() && i1 < mesh.positions.size() && i2 < mesh.positions.size());
    f(mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
  }
}

}  // namespace

double TriangleAspectRatio(Vec3 a, Vec3 b, Vec3 c) {
  if (IsDegenerateTriangle(a, b, c)) return 0.0;
  const CenteredTriangle t = Center(a, b, c);
  const Vec3 area_vector = TriangleAreaVector(a, b, c);
  const double area = Norm(area_vector);

  // In-plane orthonormal frame (e1, e2): e1 along the corner farthest from the centroid
  // (never zero for a non-degenerate triangle), e2 = n × e1.
  int far = 0;
  for (int k = 1; k < 3; ++k)
    if (Dot(t.p[k], t.p[k]) > Dot(t.p[far], t.p[far])) far = k;
  const Vec3 e1 = (1.0 / Norm(t.p[far])) * t.p[far];
  const Vec3 e2 = Cross((1.0 / area) * area_vector, e1);

  // The 2×2 tensor [[p, q], [q, r]] of the projected corners.
  double p = 0, q = 0, r = 0;
  for (const Vec3& v : t.p) {
    const double x = Dot(v, e1), y = Dot(v, e2);
    p += x * x;
    q += x * y;
    r += y * y;
  }
  p /= 3.0;
  q /= 3.0;
  r /= 3.0;
  // λ1 = mean + half gap, with the half gap as a sum of squares (not sqrt(T²/4 − det), which
  // cancels and would leave ρ = 1 − 1e-8 for an equilateral triangle).
  const double lambda1 = 0.5 * t.trace + std::hypot(0.5 * (p - r), q);
  // λ1·λ2 = det = 4·area²/27 (Cauchy–Binet on the centred corners), exact even for slivers
  // where mean − half gap would cancel. So ρ = sqrt(λ2/λ1) = sqrt(det)/λ1.
  const double rho = 2.0 * area / (std::sqrt(27.0) * lambda1);
  return std::min(rho, 1.0);
}

double SurfaceArea(const IndexedMesh& mesh) {
  double area = 0.0;
  ForEachTriangle(mesh, [&](Vec3 a, Vec3 b, Vec3 c) { area += TriangleArea(a, b, c); });
  return area;
}

double Anisotropy(const IndexedMesh& mesh) {
  ShapeSums sums;
  sums.Add(mesh);
  return sums.anisotropy();
}

double DirectionalBias(const IndexedMesh& mesh) {
  ShapeSums sums;
  sums.Add(mesh);
  return sums.directional_bias();
}

void ShapeSums::Add(const IndexedMesh& mesh) {
  // Both bias sums carry the same 1/area(K) factor and Bias is invariant under scaling of M,
  // so the division by area(K) only matters for readability of the intermediate M.
  Sym3 m_n, m_s;
  std::memcpy(m_n.m, m_n_, sizeof(m_n_));
  std::memcpy(m_s.m, m_s_, sizeof(m_s_));
  ForEachTriangle(mesh, [&](Vec3 a, Vec3 b, Vec3 c) {
    if (IsDegenerateTriangle(a, b, c)) return;
    sum_rho_ += TriangleAspectRatio(a, b, c);
    ++counted_;
    const Vec3 area_vector = TriangleAreaVector(a, b, c);
    const double w = Norm(area_vector);
    // w n nᵀ = (w n)(w n)ᵀ / w.
    m_n.AddOuter(area_vector, 1.0 / w);
    // w M_abc / trace(M_abc) = Σ_k (w / (3 trace)) p_k p_kᵀ.
    const CenteredTriangle t = Center(a, b, c);
    const double s = w / (3.0 * t.trace);
    for (const Vec3& v : t.p) m_s.AddOuter(v, s);
    area_ += w;
  });
  std::memcpy(m_n_, m_n.m, sizeof(m_n_));
  std::memcpy(m_s_, m_s.m, sizeof(m_s_));
}

double ShapeSums::anisotropy() const {
  if (counted_ == 0) return kNaN;
  return 1.0 - sum_rho_ / static_cast<double>(counted_);
}

double ShapeSums::directional_bias() const {
  if (!(area_ > 0.0)) return kNaN;
  Sym3 m;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m.m[i][j] = (m_n_[i][j] + 2.0 * m_s_[i][j]) / area_;
  const double trace = m.Trace();
  const double bias = 1.0 - 27.0 * m.Det() / (trace * trace * trace);
  // AM–GM makes bias ≥ 0 for a positive semi-definite M; clamp the round-off.
  return std::clamp(bias, 0.0, 1.0);
}

}  // namespace tandem::eval
