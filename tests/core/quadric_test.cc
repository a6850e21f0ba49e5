#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "quadric.h"
#include "tandem/geometry.h"
#include "tandem/types.h"

namespace tandem {
namespace {

TEST(Quadric, PlaneHandValues) {
  // Triangle of area 2 in the plane z = 1: H = 2 * (0,0,1,-1)(0,0,1,-1)ᵀ.
  Quadric h = PlaneQuadric({0, 0, 1}, {2, 0, 1}, {0, 2, 1});
  EXPECT_DOUBLE_EQ(h.w, 2.0);
  EXPECT_DOUBLE_EQ(h.a22, 2.0);
  EXPECT_DOUBLE_EQ(h.a00, 0.0);
  EXPECT_DOUBLE_EQ(h.b2, -2.0);
  EXPECT_DOUBLE_EQ(h.c, 2.0);
  EXPECT_DOUBLE_EQ(h.Evaluate({5, -3, 4}), 2.0 * 9.0);  // area * distance²
  EXPECT_DOUBLE_EQ(ShapeError(h, {5, -3, 4}), 3.0);    // RMS distance to the plane
  // Orientation does not matter; a zero-area triangle adds nothing.
  Quadric flipped = PlaneQuadric({0, 0, 1}, {0, 2, 1}, {2, 0, 1});
  EXPECT_DOUBLE_EQ(flipped.Evaluate({1, 1, 0}), h.Evaluate({1, 1, 0}));
  Quadric zero = PlaneQuadric({0, 0, 0}, {1, 1, 1}, {2, 2, 2});
  EXPECT_EQ(zero.w, 0.0);
  EXPECT_EQ(ShapeError(zero, {1, 2, 3}), 0.0);
}

// Fans of small triangles around a corner p at x = 3e4, as in the engine frame at spacing
// (1e9, 1e6, 1e6): p lies on every plane, yet x̄ᵀHx̄ comes out a unit of rounding off 0 in
// about half of them (ShapeError up to 1e-4, where E0 = 3.2 is 6e-6). MeasuredShapeError says
// 0, and off the planes it is ShapeError's value.
TEST(Quadric, MeasuredShapeErrorIsZeroOnThePlanesAndShapeErrorElsewhere) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int noisy = 0;
  for (int trial = 0; trial < 200; ++trial) {
    const Vec3 p{3e4 + 1907.0 * u(rng), 30 + 20 * u(rng), 6 + 4 * u(rng)};
    Quadric h;
    Vec3 prev{p.x + 20.0 * u(rng), p.y + 1.9 * u(rng), p.z + 1.9 * u(rng)};
    for (int k = 0; k < 6; ++k) {
      const Vec3 next{p.x + 20.0 * u(rng), p.y + 1.9 * u(rng), p.z + 1.9 * u(rng)};
      h += PlaneQuadric(p, prev, next);
      prev = next;
    }
    noisy += ShapeError(h, p) > 0.0;
    EXPECT_EQ(MeasuredShapeError(h, p), 0.0) << trial << ": ShapeError " << ShapeError(h, p);
    const Vec3 off = p + Vec3{0.0, 0.5, 0.5};
    EXPECT_EQ(MeasuredShapeError(h, off), ShapeError(h, off));
  }
  EXPECT_GT(noisy, 40);  // the rounding the measure must not count
  const Quadric plane = PlaneQuadric({0, 0, 1}, {2, 0, 1}, {0, 2, 1});
  EXPECT_DOUBLE_EQ(MeasuredShapeError(plane, {5, -3, 4}), 3.0);
  EXPECT_EQ(MeasuredShapeError(plane, {7, 5, 1}), 0.0);
  EXPECT_EQ(MeasuredShapeError(Quadric{}, {1, 2, 3}), 0.0);
}

TEST(Quadric, CornerOfThreePlanesIsTheMinimiser) {
  // Planes x = 1, y = 2, z = 3 (areas 0.5, 2, 4.5): the unique minimiser is their corner.
  Quadric h = PlaneQuadric({1, 0, 0}, {1, 1, 0}, {1, 0, 1});
  h += PlaneQuadric({0, 2, 0}, {0, 2, 2}, {2, 2, 0});
  h += PlaneQuadric({0, 0, 3}, {3, 0, 3}, {0, 3, 3});
  EXPECT_DOUBLE_EQ(h.w, 0.5 + 2.0 + 4.5);
  const Vec3 c = MinimizeQuadric(h, {10, 10, 10});
  EXPECT_NEAR(c.x, 1, 1e-12);
  EXPECT_NEAR(c.y, 2, 1e-12);
  EXPECT_NEAR(c.z, 3, 1e-12);
  EXPECT_NEAR(ShapeError(h, c), 0.0, 1e-9);
  // Average of squared distances at the origin: (0.5*1 + 2*4 + 4.5*9) / 7.
  EXPECT_NEAR(ShapeError(h, {0, 0, 0}), std::sqrt((0.5 + 8 + 40.5) / 7.0), 1e-12);
}

TEST(Quadric, SingularSystemsFallBackToTheNearestMinimiserOfTheReference) {
  // One plane z = 0: rank 1. The reference point is projected onto the plane.
  Quadric plane = PlaneQuadric({0, 0, 0}, {1, 0, 0}, {0, 1, 0});
  Vec3 c = MinimizeQuadric(plane, {0.3, 0.7, 5.0});
  EXPECT_NEAR(c.x, 0.3, 1e-12);
  EXPECT_NEAR(c.y, 0.7, 1e-12);
  EXPECT_NEAR(c.z, 0.0, 1e-12);
  // Two planes x = 0 and y = 0 (a crease along z): projection onto the crease line.
  Quadric crease = plane;
  crease = PlaneQuadric({0, 0, 0}, {0, 1, 0}, {0, 0, 1});
  crease += PlaneQuadric({0, 0, 0}, {0, 0, 1}, {1, 0, 0});
  c = MinimizeQuadric(crease, {2, 3, 4});
  EXPECT_NEAR(c.x, 0, 1e-12);
  EXPECT_NEAR(c.y, 0, 1e-12);
  EXPECT_NEAR(c.z, 4, 1e-12);
  // Empty quadric: the reference itself.
  c = MinimizeQuadric(Quadric{}, {1, 2, 3});
  EXPECT_EQ(c, (Vec3{1, 2, 3}));
  // Fixed axes (box faces): z held at the reference's value while x is optimised.
  Quadric px = PlaneQuadric({1, 0, 0}, {1, 1, 0}, {1, 0, 1});  // plane x = 1
  px += PlaneQuadric({0, 0, 2}, {1, 0, 2}, {0, 1, 2});          // plane z = 2
  c = MinimizeQuadric(px, {0, 0, 7}, /*fixed_axes=*/4);
  EXPECT_NEAR(c.x, 1, 1e-12);
  EXPECT_EQ(c.z, 7);
}

// w (x·n + d)² as a quadric: a plane of normal n (unit), offset d, weight w.
Quadric WeightedPlane(Vec3 n, double d, double w) {
  Quadric h;
  h.a00 = w * n.x * n.x; h.a01 = w * n.x * n.y; h.a02 = w * n.x * n.z;
  h.a11 = w * n.y * n.y; h.a12 = w * n.y * n.z; h.a22 = w * n.z * n.z;
  h.b0 = w * d * n.x; h.b1 = w * d * n.y; h.b2 = w * d * n.z;
  h.c = w * d * d;
  h.w = w;
  return h;
}

TEST(Quadric, CheapRankCasesAgreeWithTheEigenDecomposition) {
  // MinimizeQuadric avoids the trigonometric eigen-solver with Newton on the characteristic
  // polynomial and cross-product eigenvectors. Quadrics are built with known eigenvalues
  // (planes along an orthonormal frame with chosen weights), well away from the truncation
  // threshold (kIllConditioned), in every rank regime: the result must equal the reference.
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto unit = [&] {
    for (;;) {
      const Vec3 v{u(rng), u(rng), u(rng)};
      const double n = Norm(v);
      if (n > 0.1 && n <= 1.0) return v * (1.0 / n);
    }
  };
  int counted[5] = {0, 0, 0, 0, 0};
  for (int trial = 0; trial < 5000; ++trial) {
    // 0: rank 1, 1: rank 2, 2: rank 3, 3: axis frame + fixed axes, 4: a curved patch (full
    // rank, two eigenvalues 1e-7..1e-3 of the largest: the determinant test's fast path)
    const int rank = trial % 5;
    Vec3 e1, e2, e3;
    uint8_t fixed = 0;
    if (rank != 3) {
      e1 = unit();
      e2 = Cross(e1, unit());
      e2 = e2 * (1.0 / Norm(e2));
      e3 = Cross(e1, e2);
    } else {
      const Vec3 axes[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
      const int r = static_cast<int>(rng() % 3);
      e1 = axes[r];
      e2 = axes[(r + 1) % 3];
      e3 = axes[(r + 2) % 3];
      fixed = static_cast<uint8_t>(rng() % 8);
    }
    const double scale = std::pow(10.0, 4.0 * u(rng));  // areas from 1e-4 to 1e4
    double w1 = scale, w2, w3;
    auto small = [&] { return scale * 1e-11 * (1.0 + u(rng)); };  // far below 1e-8
    auto large = [&] { return scale * (0.02 + 0.9 * std::abs(u(rng))); };  // far above
    switch (rank) {
      case 0: w2 = small(); w3 = small(); break;
      case 1: w2 = large(); w3 = small(); break;
      case 2: w2 = large(); w3 = large(); break;
      case 4:
        w2 = scale * std::pow(10.0, -5.0 + 2.0 * u(rng));
        w3 = scale * std::pow(10.0, -5.0 + 2.0 * u(rng));
        break;
      default: w2 = (rng() & 1) ? large() : small(); w3 = (rng() & 1) ? large() : small();
    }
    Quadric h = WeightedPlane(e1, 30.0 * u(rng), w1);
    h += WeightedPlane(e2, 30.0 * u(rng), w2);
    h += WeightedPlane(e3, 30.0 * u(rng), w3);
    const Vec3 ref{40.0 * u(rng), 40.0 * u(rng), 40.0 * u(rng)};
    const Vec3 want = MinimizeQuadricReference(h, ref, fixed);
    const Vec3 got = MinimizeQuadric(h, ref, fixed);
    const double tol = 1e-8 * (1.0 + Norm(want - ref));
    ASSERT_LT(Norm(got - want), tol) << "trial " << trial << " regime " << rank << " fixed "
                                     << int(fixed) << " w " << w1 << " " << w2 << " " << w3;
    for (int i = 0; i < 3; ++i) {
      if ((fixed >> i) & 1) {
        EXPECT_EQ(got[i], ref[i]);
      }
    }
    ++counted[rank];
  }
  for (const int n : counted) EXPECT_EQ(n, 1000);
}

TEST(Quadric, PackedQuadricIsTheSameArithmetic) {
  // An edge's evaluation works on the packed form: ε0 and the full-rank placement must be
  // bit for bit the Quadric's (so a mesh does not depend on which form computed it).
  std::mt19937_64 rng(65);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int solved = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    Quadric h;
    const Vec3 centre{300 * u(rng), 300 * u(rng), 300 * u(rng)};
    for (int k = 0; k < 2 + trial % 6; ++k) {
      const Vec3 p = centre + Vec3{u(rng), u(rng), u(rng)};
      h += PlaneQuadric(p, p + Vec3{u(rng), u(rng), 0.1 * u(rng)},
                        p + Vec3{u(rng), 0.1 * u(rng), u(rng)});
    }
    const PackedQuadric packed = Pack(h);
    const Vec3 ref = centre + Vec3{u(rng), u(rng), u(rng)};
    EXPECT_EQ(packed.Evaluate(ref), h.Evaluate(ref));
    EXPECT_EQ(ShapeError(packed, ref), ShapeError(h, ref));
    Vec3 x;
    if (quadric_internal::MinimizeFullRank(packed, ref, &x)) {
      ++solved;
      EXPECT_EQ(x, MinimizeQuadricSolve(h, ref, 0));
    }
    EXPECT_EQ(MinimizeQuadric(h, ref), MinimizeQuadricSolve(h, ref, 0));
    const Quadric back = packed.Unpack();
    EXPECT_EQ(back.Evaluate(ref), h.Evaluate(ref));
    EXPECT_EQ(back.w, h.w);
  }
  EXPECT_GT(solved, 500);  // the full-rank path was exercised
}

TEST(Quadric, CurvedPatchesAreSolvedNotTruncated) {
  // The planes tangent to a sphere (radius 50) over a small cap (normals within 0.02 rad of
  // +z), as a vertex's quadric on a smooth surface is: the tangential eigenvalues are about
  // 1e-4 of the normal one. That is ill-conditioning only in name: the system still has 12
  // good digits, and the least-squares point is on the cap's axis. Truncating there (the
  // old 1e-3 threshold) left c at the reference's tangential offset, 0.36 off.
  const double radius = 50.0, theta = 0.02;
  Quadric h;
  double sum_nz = 0, sum_nz2 = 0;
  for (int i = -4; i <= 4; ++i) {
    for (int j = -4; j <= 4; ++j) {
      const Vec3 t{theta * i / 4.0, theta * j / 4.0, 1.0};
      const Vec3 n = t * (1.0 / Norm(t));
      h += WeightedPlane(n, -radius, 1.0);
      sum_nz += n.z;
      sum_nz2 += n.z * n.z;
    }
  }
  // The symmetric set of normals makes Σ n nᵀ diagonal: x = y = 0, z = R Σ n_z / Σ n_z².
  const Vec3 want{0, 0, radius * sum_nz / sum_nz2};
  const double ratio = h.a00 / h.a22;  // tangential / normal eigenvalue
  ASSERT_GT(ratio, 10 * kIllConditioned);
  ASSERT_LT(ratio, 1e-3);
  const Vec3 ref{0.3, -0.2, radius};
  for (const Vec3 c : {MinimizeQuadric(h, ref), MinimizeQuadricReference(h, ref)}) {
    EXPECT_LT(Norm(c - want), 1e-6) << c.x << " " << c.y << " " << c.z;
    EXPECT_LT(ShapeError(h, c), ShapeError(h, {ref.x, ref.y, want.z}));
  }
}

TEST(Quadric, RoundedCoplanarQuadricsProjectOntoTheirPlane) {
  // Coplanar triangles in a general orientation sum to a quadric that is rank 1 up to
  // rounding (a flat face of a CT part, of the Pillow Box). Its minimiser nearest to ref is
  // ref's projection. Deriving the small eigenvalues from the invariants (λ2 λ3 = c1 - λ1 s)
  // read rounding noise as full rank in about 1 trial in 1000 and put c up to hundreds of
  // units away.
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int wrong = 0;
  double worst = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    Vec3 n{u(rng), u(rng), u(rng)};
    n = n * (1.0 / Norm(n));
    const Vec3 p0{100 * u(rng), 100 * u(rng), 100 * u(rng)};
    Quadric h;
    for (int k = 0; k < 6; ++k) {
      Vec3 t1 = Cross(n, Vec3{u(rng), u(rng), u(rng)});
      t1 = t1 * (1.0 / Norm(t1));
      const Vec3 t2 = Cross(n, t1);
      const Vec3 p = p0 + t1 * (3 * u(rng)) + t2 * (3 * u(rng));
      h += PlaneQuadric(p, p + t1 * (1 + u(rng)), p + t2 * (1 + u(rng)));
    }
    const Vec3 ref = p0 + Vec3{u(rng), u(rng), u(rng)};
    const Vec3 want = ref - n * Dot(ref - p0, n);
    const double err = Norm(MinimizeQuadric(h, ref) - want);
    worst = std::max(worst, err);
    wrong += err > 1e-9;
  }
  EXPECT_EQ(wrong, 0) << "worst placement error " << worst;
}

TEST(Quadric, StepWithinErrorStopsAtTheLimit) {
  // Plane z = 0 (area 2): ε0 at height z is |z|. From z = 0.1 upward, ε0 <= 0.3 allows 0.2.
  const Quadric h = PlaneQuadric({0, 0, 0}, {2, 0, 0}, {0, 2, 0});
  EXPECT_NEAR(StepWithinError(h, {1, 1, 0.1}, {0, 0, 1}, 1.0, 0.3), 0.2, 1e-9);
  EXPECT_LE(ShapeError(h, {1, 1, 0.1 + StepWithinError(h, {1, 1, 0.1}, {0, 0, 1}, 1.0, 0.3)}), 0.3);
  EXPECT_EQ(StepWithinError(h, {1, 1, 0.1}, {0, 0, 1}, 0.15, 0.3), 0.15);  // within: all of t
  EXPECT_NEAR(StepWithinError(h, {1, 1, 0.1}, {0, 0, -1}, 1.0, 0.3), 0.4, 1e-9);
  EXPECT_EQ(StepWithinError(h, {1, 1, 0.1}, {1, 0, 0}, 5.0, 0.1), 5.0);  // along the plane
}

TEST(Quadric, IsotropyQuadricIsAreaTimesSquaredDistancePlusSpread) {
  const Vec3 p{0, 0, 0}, q{3, 0, 0}, r{0, 3, 0};
  Quadric g = IsotropyQuadric(p, q, r);
  const double area = 4.5;
  const Vec3 t{1, 1, 0};
  // avg(t) = (|p-t|² + |q-t|² + |r-t|²) / 12 = (2 + 5 + 5) / 12 = 1.
  const Vec3 x{2, -1, 3};
  const Vec3 d = x - t;
  EXPECT_NEAR(g.Evaluate(x), area * (Dot(d, d) + 1.0), 1e-12);
  EXPECT_EQ(g.w, 0.0);
  const Vec3 c = MinimizeQuadric(g, {9, 9, 9});
  EXPECT_NEAR(Norm(c - t), 0.0, 1e-12);  // the centroid
}

// The paper's ε_α: α = 0 is the shape error ε0; α = 1 is the isotropy term alone, scaled by
// W_G = 3·area·√W / E0; in between, the weighted sum. No planes (W = 0): zero.
TEST(Quadric, IsotropicCostCombinesShapeAndIsotropy) {
  const Vec3 p{0, 0, 0}, q{2, 0, 0}, r{0, 1, 0.5};
  const Quadric h = PlaneQuadric(p, q, r);
  Quadric h2 = h;
  h2 += PlaneQuadric(p, {0, 0, 1}, q);
  const Quadric g = IsotropyQuadric(p, q, r);
  const double area = g.a00, e0 = 0.3;
  const Vec3 x{0.4, 0.7, -0.2};
  EXPECT_NEAR(IsotropicCost(IsotropicCostQuadric(h2, Quadric(g), area, 0.0, e0), x), ShapeError(h2, x), 1e-12);
  const double big_w = 3.0 * area * std::sqrt(h2.w) / e0;
  EXPECT_NEAR(IsotropicCostQuadric(h2, Quadric(g), area, 1.0, e0).Evaluate(x), g.Evaluate(x) / big_w, 1e-12);
  const double alpha = 0.3;
  const Quadric mixed = IsotropicCostQuadric(h2, Quadric(g), area, alpha, e0);
  EXPECT_NEAR(mixed.Evaluate(x),
              (1 - alpha) * h2.Evaluate(x) / h2.w + alpha * g.Evaluate(x) / big_w, 1e-12);
  EXPECT_EQ(mixed.w, 0.0);
  EXPECT_EQ(IsotropicCostQuadric(Quadric{}, Quadric(g), area, alpha, e0).Evaluate(x), 0.0);
}

}  // namespace
}  // namespace tandem
