// Triangle geometry shared by the engine (quadrics, contraction checks, sag correction) and
// the measures (metrics.h, distance.h): the area vector, when a triangle counts as having no
// area, and whether moving corners keeps a triangle's orientation. Small and
// inline: the contraction loop calls them for every surviving triangle of every contraction.
#ifndef TANDEM_GEOMETRY_H_
#define TANDEM_GEOMETRY_H_

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
// The engine's collapsed triangle: too thin to make (r = 5e-11); no contraction or sag move
// may turn a triangle into one.
inline constexpr double kCollapsedSquared = 1e-20;  // (2 · 5e-11)²
inline bool AreaAtMost(double squared_ratio, Vec3 twice_area_vector, double sum_squared_edges) {
  return !(Dot(twice_area_vector, twice_area_vector) >
           squared_ratio * sum_squared_edges * sum_squared_edges);
}
inline bool IsDegenerateTriangle(Vec3 a, Vec3 b, Vec3 c) {
  return AreaAtMost(kDegenerateSquared, TwiceAreaVector(a, b, c), SumSquaredEdges(a, b, c));
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
