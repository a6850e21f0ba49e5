// Triangle geometry shared by the engine (quadrics, contraction checks, sag correction) and
// the measures (metrics.h, distance.h): the area vector, when a triangle counts as having no
// area, and whether moving corners keeps a triangle's orientation. Small and
// inline: the contraction loop calls them for every surviving triangle of every contraction.
#ifndef TANDEM_GEOMETRY_H_
#define TANDEM_GEOMETRY_H_

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "tandem/types.h"

namespace tandem {

// (b − a) × (c − a): its length is twice the triangle's area, its direction the unit normal
// of a counter-clockwise triangle. The cross product every triangle measure starts from.
inline Vec3 TwiceAreaVector(Vec3 a, Vec3 b, Vec3 c) { return Cross(b - a, c - a); }
// The same halved: length = area.
inline Vec3 TriangleAreaVector(Vec3 a, Vec3 b, Vec3 c) { return 0.5 * TwiceAreaVector(a, b, c); }
inline double TriangleArea(Vec3 a, Vec3 b, Vec3 c) { return Norm(TriangleAreaVector(a, b, c)); }

// Σ of the squared edge lengths |b − a|² + |c − b|² + |a − c|²: the scale a triangle's area is
// compared with (an equilateral triangle has area / Σe² = √3/12 ≈ 0.14).
inline double SumSquaredEdges(Vec3 a, Vec3 b, Vec3 c) {
  return Dot(b - a, b - a) + Dot(c - b, c - b) + Dot(a - c, a - c);
}

// When a triangle counts as having no area: area ≤ r·Σe², written without a square root as
// |TwiceAreaVector|² ≤ (2r)²·(Σe²)². Scale-invariant; `!(x > y)`, so NaN counts too. Two
// ratios, for two uses: one ratio for both changes outputs (docs/decisions.md).
// The measures' degenerate triangle: zero area up to round-off (r = 1e-12, aspect ratio below
// ~1e-11); it carries no weight and is skipped where a measure counts triangles.
inline constexpr double kDegenerateSquared = 4e-24;  // (2 · 1e-12)²
// The outputs' zero area: positions leave as float32, where corners 1e-9 apart in the
// engine's doubles fall on one point; twice the area at most 2e-6 of the squared edges, on
// the positions as written (r = 1e-6). The final mending, Draco's grid and the benchmark's
// mesh_check count with it.
inline constexpr double kWrittenSquared = 4e-12;  // (2 · 1e-6)²
// The engine's collapsed triangle: too thin to make, no contraction or sag move may turn a
// triangle into one; that of the outputs, so that the live mesh (previews) has none either.
inline constexpr double kCollapsedSquared = kWrittenSquared;
inline bool AreaAtMost(double squared_ratio, Vec3 twice_area_vector, double sum_squared_edges) {
  return !(Dot(twice_area_vector, twice_area_vector) >
           squared_ratio * sum_squared_edges * sum_squared_edges);
}
inline bool IsDegenerateTriangle(Vec3 a, Vec3 b, Vec3 c) {
  return AreaAtMost(kDegenerateSquared, TwiceAreaVector(a, b, c), SumSquaredEdges(a, b, c));
}
inline bool IsWrittenDegenerate(Vec3 a, Vec3 b, Vec3 c) {
  return AreaAtMost(kWrittenSquared, TwiceAreaVector(a, b, c), SumSquaredEdges(a, b, c));
}

// Where marching cubes puts a grid edge's surface point: at interpolation parameter t
// clamped so that it lies δ smallest spacings or more from both ends, never on a grid point,
// and the sheets meeting at a grid point whose value equals the iso-value stay apart
// (distinct positions, no zero-area triangle). δ = EdgeOffset(reach, anisotropy), reach
// bounding |written coordinate| / smallest spacing near the edge, anisotropy the largest
// spacing over the smallest: the least power of two above kEdgeOffsetFloor, above
// kEdgeOffsetUlps float32 steps at that reach and above kEdgeOffsetPerAnisotropy x
// anisotropy, at most kEdgeOffsetCap. Surface points on three edges of a cube, each δ off the
// corners, span twice an area of at least 0.4 δ / anisotropy of their squared edges, three
// times the 2e-6 of kWrittenSquared or more, and eight float32 steps keep that and their
// distinct positions through the rounding on output. The cap binds past a reach of 2^16
// voxels, where float32 cannot hold a voxel's points apart anyway, or an anisotropy of 4096.
inline constexpr double kEdgeOffsetFloor = 0x1p-10;
inline constexpr double kEdgeOffsetUlps = 8;
inline constexpr double kEdgeOffsetPerAnisotropy = 0x1p-16;  // 0.4 x 2^-16 = 3 x 2e-6
inline constexpr double kEdgeOffsetCap = 0x1p-4;
// Each grid edge takes its own share of δ to kEdgeOffsetSpread δ, from a hash of the edge
// (its lower grid point, whole-grid indices, and axis): the points around one grid point then
// form no regular figure, whose planes would meet at the other sheets' points, and a
// contraction would put a vertex exactly where one of those is.
inline constexpr double kEdgeOffsetSpread = 1.5;
inline double EdgeOffsetShare(int64_t i, int64_t j, int64_t k, int axis) {
  uint64_t h = static_cast<uint64_t>(i) * 0x9E3779B97F4A7C15u ^
               static_cast<uint64_t>(j) * 0xC2B2AE3D27D4EB4Fu ^
               static_cast<uint64_t>(k) * 0x165667B19E3779F9u ^ static_cast<uint64_t>(axis);
  h = (h ^ (h >> 30)) * 0xBF58476D1CE4E5B9u;  // splitmix64's finaliser
  h = (h ^ (h >> 27)) * 0x94D049BB133111EBu;
  h ^= h >> 31;
  return 1.0 + (kEdgeOffsetSpread - 1.0) * std::ldexp(static_cast<double>(h >> 11), -53);
}
inline double EdgeOffset(double reach, double anisotropy) {
  // A float32 step at magnitude x is at most x · 2^-23.
  const double want = std::max(kEdgeOffsetUlps * std::ldexp(std::fabs(reach), -23),
                               kEdgeOffsetPerAnisotropy * anisotropy);
  if (!(want > kEdgeOffsetFloor)) return kEdgeOffsetFloor;
  if (!(want < kEdgeOffsetCap)) return kEdgeOffsetCap;
  return std::ldexp(1.0, std::ilogb(want) + 1);  // a power of two above want
}

// What moving some of a triangle's corners does to it: with `twice_area_before` its
// TwiceAreaVector before the move (non-zero: a degenerate triangle has no orientation to keep)
// and q0, q1, q2 its corners after, whether it collapses (kCollapsedSquared) or turns over
// (its normal no longer has a positive component along the old one).
struct CornerMove {
  bool collapses;
  bool flips;
};
inline CornerMove MoveCorners(Vec3 twice_area_before, Vec3 q0, Vec3 q1, Vec3 q2) {
  const Vec3 after = TwiceAreaVector(q0, q1, q2);
  return {AreaAtMost(kCollapsedSquared, after, SumSquaredEdges(q0, q1, q2)),
          !(Dot(twice_area_before, after) > 0.0)};
}
inline bool MovedCornerKeepsOrientation(Vec3 twice_area_before, Vec3 q0, Vec3 q1, Vec3 q2) {
  const CornerMove m = MoveCorners(twice_area_before, q0, q1, q2);
  return !(m.collapses | m.flips);
}

}  // namespace tandem

#endif  // TANDEM_GEOMETRY_H_
