// Tests of the quality measures (metrics.h) and the Metro-style distances (distance.h).
// Meshes are built here (icosphere, cube-sphere, planar grids) so these tests do not depend
// on the extraction code.
#include "tandem/eval/metrics.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <utility>

#include "tandem/eval/distance.h"
#include "tandem/mesh.h"

namespace tandem {
namespace {

constexpr double kPi = std::numbers::pi;

void AddTriangle(IndexedMesh& m, Vec3 a, Vec3 b, Vec3 c) {
  const uint32_t base = static_cast<uint32_t>(m.positions.size());
  m.positions.insert(m.positions.end(), {a, b, c});
  m.indices.insert(m.indices.end(), {base, base + 1, base + 2});
}

// Icosahedron subdivided `level` times (each triangle into 4 by edge midpoints pushed onto
// the sphere): 20·4^level triangles, CCW seen from outside, welded. The subdivision keeps
// the icosahedral symmetry group.
IndexedMesh Icosphere(int level, double radius = 1.0, Vec3 center = {}) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  IndexedMesh m;
  m.positions = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                 {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  for (Vec3& p : m.positions) p = (1.0 / Norm(p)) * p;
  m.indices = {0, 11, 5,  0, 5,  1, 0, 1, 7, 0, 7,  10, 0, 10, 11, 1, 5, 9, 5, 11,
               4, 11, 10, 2, 10, 7, 6, 7, 1, 8, 3,  9,  4, 3,  4,  2, 3, 2, 6, 3,
               6, 8,  3,  8, 9,  4, 9, 5, 2, 4, 11, 6,  2, 10, 8,  6, 7, 9, 8, 1};
  for (int l = 0; l < level; ++l) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> midpoint;
    auto mid = [&](uint32_t a, uint32_t b) {
      const auto key = std::minmax(a, b);
      auto [it, inserted] = midpoint.try_emplace(key, 0);
      if (inserted) {
        const Vec3 p = m.positions[a] + m.positions[b];
        it->second = static_cast<uint32_t>(m.positions.size());
        m.positions.push_back((1.0 / Norm(p)) * p);
      }
      return it->second;
    };
    std::vector<uint32_t> next;
    for (size_t f = 0; f < m.num_triangles(); ++f) {
      const uint32_t a = m.indices[3 * f], b = m.indices[3 * f + 1], c = m.indices[3 * f + 2];
      const uint32_t ab = mid(a, b), bc = mid(b, c), ca = mid(c, a);
      next.insert(next.end(), {a, ab, ca, b, bc, ab, c, ca, bc, ab, bc, ca});
    }
    m.indices = std::move(next);
  }
  for (Vec3& p : m.positions) p = center + radius * p;
  return m;
}

// The unit sphere as the projection of the cube [-1,1]³ whose faces are gridded with
// n[axis] cells along each axis; every cell is split into 4 triangles around its centre.
// With n = {k, k, k} the mesh has the cube's rotation group; with n[2] < n[0] the
// triangles of the four side faces are stretched along z.
IndexedMesh CubeSphere(std::array<int, 3> n) {
  IndexedMesh m;
  auto on_sphere = [](Vec3 p) { return (1.0 / Norm(p)) * p; };
  for (int axis = 0; axis < 3; ++axis) {
    const int u_axis = (axis + 1) % 3, v_axis = (axis + 2) % 3;
    for (double side : {-1.0, 1.0}) {
      auto point = [&](double u, double v) {
        Vec3 p;
        p[axis] = side;
        p[u_axis] = u;
        p[v_axis] = v;
        return on_sphere(p);
      };
      const int nu = n[u_axis], nv = n[v_axis];
      for (int i = 0; i < nu; ++i) {
        for (int j = 0; j < nv; ++j) {
          const double u0 = -1 + 2.0 * i / nu, u1 = -1 + 2.0 * (i + 1) / nu;
          const double v0 = -1 + 2.0 * j / nv, v1 = -1 + 2.0 * (j + 1) / nv;
          const Vec3 c = point(0.5 * (u0 + u1), 0.5 * (v0 + v1));
          const Vec3 q[4] = {point(u0, v0), point(u1, v0), point(u1, v1), point(u0, v1)};
          for (int k = 0; k < 4; ++k) AddTriangle(m, c, q[k], q[(k + 1) % 4]);
        }
      }
    }
  }
  return m;
}

// A planar grid of nx × ny cells of size (sx, sy) in z = 0, each split along its (1,1)
// diagonal into two right triangles.
IndexedMesh PlaneGrid(int nx, int ny, double sx, double sy) {
  IndexedMesh m;
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i) m.positions.push_back({i * sx, j * sy, 0});
  auto id = [&](int i, int j) { return static_cast<uint32_t>(j * (nx + 1) + i); };
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  return m;
}

// A planar patch of equilateral triangles (side 1): rows of a triangular lattice.
IndexedMesh EquilateralPlane(int nx, int ny) {
  IndexedMesh m;
  const double h = std::sqrt(3.0) / 2.0;
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i) m.positions.push_back({i + 0.5 * (j % 2), j * h, 0});
  auto id = [&](int i, int j) { return static_cast<uint32_t>(j * (nx + 1) + i); };
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      if (j % 2 == 0) {
        m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j), id(i, j + 1)});
        if (i + 1 < nx) {
          m.indices.insert(m.indices.end(), {id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)});
        }
      } else {
        m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      }
    }
  }
  return m;
}

IndexedMesh Translated(IndexedMesh m, Vec3 d) {
  for (Vec3& p : m.positions) p = p + d;
  return m;
}

// A rotation (about a generic axis) applied to a point, to test invariance.
Vec3 Rotate(Vec3 p) {
  const double a = 0.7, b = -1.1;
  const Vec3 q{std::cos(a) * p.x - std::sin(a) * p.y, std::sin(a) * p.x + std::cos(a) * p.y, p.z};
  return {q.x, std::cos(b) * q.y - std::sin(b) * q.z, std::sin(b) * q.y + std::cos(b) * q.z};
}

// ---------------------------------------------------------------------------------------
// Aspect ratio and anisotropy

TEST(AspectRatioTest, EquilateralIsOneInAnyPoseAndScale) {
  const double h = std::sqrt(3.0) / 2.0;
  EXPECT_NEAR(eval::TriangleAspectRatio({0, 0, 0}, {1, 0, 0}, {0.5, h, 0}), 1.0, 1e-12);
  for (double scale : {1e-6, 1.0, 1e6}) {
    const Vec3 shift = scale * Vec3{3, -2, 7};  // a fixed shift would cancel at 1e-6
    const Vec3 a = Rotate(scale * Vec3{0, 0, 0}) + shift;
    const Vec3 b = Rotate(scale * Vec3{1, 0, 0}) + shift;
    const Vec3 c = Rotate(scale * Vec3{0.5, h, 0}) + shift;
    EXPECT_NEAR(eval::TriangleAspectRatio(a, b, c), 1.0, 1e-12) << "scale " << scale;
    EXPECT_NEAR(eval::TriangleAspectRatio(c, b, a), 1.0, 1e-12) << "reversed, scale " << scale;
  }
}

TEST(AspectRatioTest, RightIsoscelesByHand) {
  // Centred corners (−1/3,−1/3), (2/3,−1/3), (−1/3,2/3): (aaᵀ+bbᵀ+ccᵀ)/3 =
  // [[2/9, −1/9], [−1/9, 2/9]], eigenvalues 1/3 and 1/9, so ρ = sqrt(1/3).
  EXPECT_NEAR(eval::TriangleAspectRatio({0, 0, 0}, {1, 0, 0}, {0, 1, 0}), std::sqrt(1.0 / 3.0),
              1e-14);
  EXPECT_NEAR(eval::TriangleAspectRatio(Rotate({0, 0, 0}), Rotate({0, 5, 0}), Rotate({0, 0, 5})),
              std::sqrt(1.0 / 3.0), 1e-14);
}

TEST(AspectRatioTest, IsoscelesFamilyByHand) {
  // (−1,0), (1,0), (0,h): centred tensor diag(2/3, 2h²/9), so ρ = h/√3 for h ≤ √3 and
  // √3/h beyond (the long axis switches to the apex direction).
  for (double h : {0.01, 0.5, 1.0, 1.7, 2.5, 10.0}) {
    const double expected = h <= std::sqrt(3.0) ? h / std::sqrt(3.0) : std::sqrt(3.0) / h;
    EXPECT_NEAR(eval::TriangleAspectRatio({-1, 0, 0}, {1, 0, 0}, {0, h, 0}), expected, 1e-13)
        << "h = " << h;
  }
}

TEST(AspectRatioTest, ThinAndDegenerateTriangles) {
  EXPECT_LT(eval::TriangleAspectRatio({0, 0, 0}, {1, 0, 0}, {0.5, 0.05, 0}), 0.2);
  EXPECT_GT(eval::TriangleAspectRatio({0, 0, 0}, {1, 0, 0}, {0.5, 0.05, 0}), 0.0);
  // A needle (one very short edge) is thin as well.
  EXPECT_LT(eval::TriangleAspectRatio({0, 0, 0}, {10, 0, 0}, {10, 0.1, 0}), 0.2);
  EXPECT_EQ(eval::TriangleAspectRatio({0, 0, 0}, {1, 1, 1}, {2, 2, 2}), 0.0);  // collinear
  EXPECT_EQ(eval::TriangleAspectRatio({1, 2, 3}, {1, 2, 3}, {1, 2, 3}), 0.0);  // a point
  EXPECT_EQ(eval::TriangleAspectRatio({0, 0, 0}, {0, 0, 0}, {1, 0, 0}), 0.0);  // two coincide
  EXPECT_TRUE(IsDegenerateTriangle({0, 0, 0}, {1, 1, 1}, {2, 2, 2}));
  EXPECT_FALSE(IsDegenerateTriangle({0, 0, 0}, {1, 0, 0}, {0.5, 1e-3, 0}));
}

TEST(AnisotropyTest, ZeroForEquilateralMeshes) {
  EXPECT_NEAR(eval::Anisotropy(Icosphere(0)), 0.0, 1e-12);  // the icosahedron
  const IndexedMesh plane = EquilateralPlane(12, 9);
  ASSERT_GT(plane.num_triangles(), 150u);
  EXPECT_NEAR(eval::Anisotropy(plane), 0.0, 1e-12);
  // A subdivided icosphere's triangles are only nearly equilateral (ρ down to 0.80 at
  // level 3). Reference value from an independent Jacobi eigen-solver of the 3×3 M_abc.
  EXPECT_NEAR(eval::Anisotropy(Icosphere(3)), 0.1284565, 1e-6);
}

TEST(AnisotropyTest, MeanOverTrianglesSkippingDegenerateOnes) {
  IndexedMesh m;
  const double h = std::sqrt(3.0) / 2.0;
  AddTriangle(m, {0, 0, 0}, {1, 0, 0}, {0.5, h, 0});  // ρ = 1
  AddTriangle(m, {0, 0, 1}, {1, 0, 1}, {0, 1, 1});    // ρ = sqrt(1/3)
  const double expected = 1.0 - (1.0 + std::sqrt(1.0 / 3.0)) / 2.0;
  EXPECT_NEAR(eval::Anisotropy(m), expected, 1e-14);
  AddTriangle(m, {0, 0, 2}, {1, 0, 2}, {2, 0, 2});  // zero area: skipped, by contract
  AddTriangle(m, {5, 5, 5}, {5, 5, 5}, {5, 5, 5});
  EXPECT_NEAR(eval::Anisotropy(m), expected, 1e-14);
}

TEST(AnisotropyTest, EmptyOrAllDegenerateIsNaN) {
  EXPECT_TRUE(std::isnan(eval::Anisotropy(IndexedMesh{})));
  IndexedMesh m;
  AddTriangle(m, {0, 0, 0}, {1, 0, 0}, {2, 0, 0});
  EXPECT_TRUE(std::isnan(eval::Anisotropy(m)));
  EXPECT_TRUE(std::isnan(eval::DirectionalBias(m)));
  EXPECT_EQ(eval::SurfaceArea(m), 0.0);
}

// ---------------------------------------------------------------------------------------
// Area and directional bias

TEST(SurfaceAreaTest, KnownAreas) {
  EXPECT_NEAR(eval::SurfaceArea(PlaneGrid(7, 5, 0.5, 2.0)), 3.5 * 10.0, 1e-12);
  IndexedMesh tri;
  AddTriangle(tri, Rotate({0, 0, 0}), Rotate({2, 0, 0}), Rotate({1, std::sqrt(3.0), 0}));
  EXPECT_NEAR(eval::SurfaceArea(tri), std::sqrt(3.0), 1e-14);
  // Inscribed polyhedra approach 4π from below.
  const double a5 = eval::SurfaceArea(Icosphere(5));
  EXPECT_LT(a5, 4 * kPi);
  EXPECT_NEAR(a5, 4 * kPi, 4 * kPi * 2e-3);
  EXPECT_EQ(eval::SurfaceArea(IndexedMesh{}), 0.0);
  const Vec3 v = TriangleAreaVector({0, 0, 0}, {1, 0, 0}, {0, 1, 0});  // CCW seen from +z
  EXPECT_EQ(v, (Vec3{0, 0, 0.5}));
}

TEST(DirectionalBiasTest, ZeroForEquilateralPlane) {
  // M_n = e_z e_zᵀ and M_s = I − e_z e_zᵀ, so M = I.
  EXPECT_NEAR(eval::DirectionalBias(EquilateralPlane(10, 10)), 0.0, 1e-12);
}

TEST(DirectionalBiasTest, ZeroForSymmetricSpheres) {
  // The icosahedral and cubic rotation groups act irreducibly on R³, so a triangulation with
  // either symmetry has M ∝ I whatever its triangles look like.
  for (int level : {0, 1, 4}) {
    EXPECT_NEAR(eval::DirectionalBias(Icosphere(level)), 0.0, 1e-12) << "level " << level;
  }
  EXPECT_NEAR(eval::DirectionalBias(CubeSphere({12, 12, 12})), 0.0, 1e-12);
  // Independent of pose: a rotated icosphere.
  IndexedMesh r = Icosphere(3);
  for (Vec3& p : r.positions) p = Rotate(p);
  EXPECT_NEAR(eval::DirectionalBias(r), 0.0, 1e-12);
}

TEST(DirectionalBiasTest, RightTriangleGridByHand) {
  // Unit squares split along (1,1): every triangle has M_abc/trace = [[1/2, 1/4], [1/4, 1/2]]
  // (long axis along the shared hypotenuse direction), so M = [[1, 1/2, 0], [1/2, 1, 0],
  // [0, 0, 1]]: trace 3, det 3/4, Bias = 1 − 27·(3/4)/27 = 1/4.
  EXPECT_NEAR(eval::DirectionalBias(PlaneGrid(6, 4, 1.0, 1.0)), 0.25, 1e-12);
}

TEST(DirectionalBiasTest, PositiveForStretchedTriangles) {
  // Cells 6 times longer along x than along y.
  const double plane = eval::DirectionalBias(PlaneGrid(4, 24, 6.0, 1.0));
  EXPECT_GT(plane, 0.5);
  // The same sphere, with side-face triangles stretched 4:1 along z (the sweep direction of
  // a tandem run without time-lag produces this kind of bias).
  // Bias grows with the stretch: ≈0 (1:1, cubic symmetry), 0.05 (2:1), 0.13 (4:1).
  const double stretched4 = eval::DirectionalBias(CubeSphere({16, 16, 4}));
  const double stretched2 = eval::DirectionalBias(CubeSphere({16, 16, 8}));
  EXPECT_GT(stretched4, 0.1);
  EXPECT_LE(stretched4, 1.0);
  EXPECT_GT(stretched4, 2 * stretched2);
  EXPECT_GT(stretched2, 0.03);
  EXPECT_LT(eval::DirectionalBias(CubeSphere({16, 16, 16})), 1e-12);
}

// ---------------------------------------------------------------------------------------
// Closest points and the BVH

TEST(ClosestPointTest, HandComputedRegions) {
  const Vec3 a{0, 0, 0}, b{1, 0, 0}, c{0, 1, 0};
  struct Case {
    Vec3 p, expected;
    const char* region;
  };
  const Case cases[] = {
      {{0.25, 0.25, 2}, {0.25, 0.25, 0}, "face (above)"},
      {{0.2, 0.3, -1}, {0.2, 0.3, 0}, "face (below)"},
      {{-1, -1, 0}, a, "vertex a"},
      {{2, -1, 0.5}, b, "vertex b"},
      {{-1, 3, 0}, c, "vertex c"},
      {{0.5, -1, 1}, {0.5, 0, 0}, "edge ab"},
      {{1, 1, 0}, {0.5, 0.5, 0}, "edge bc"},
      {{-2, 0.25, -3}, {0, 0.25, 0}, "edge ca"},
      {{0.1, 0.1, 0}, {0.1, 0.1, 0}, "on the triangle"},
  };
  for (const Case& t : cases) {
    const Vec3 q = eval::ClosestPointOnTriangle(t.p, a, b, c);
    EXPECT_NEAR(q.x, t.expected.x, 1e-15) << t.region;
    EXPECT_NEAR(q.y, t.expected.y, 1e-15) << t.region;
    EXPECT_NEAR(q.z, t.expected.z, 1e-15) << t.region;
  }
  // Distances: vertex region √2, edge region √2, bc region √(1/2).
  EXPECT_NEAR(Norm(Vec3{-1, -1, 0} - eval::ClosestPointOnTriangle({-1, -1, 0}, a, b, c)),
              std::sqrt(2.0), 1e-15);
  EXPECT_NEAR(Norm(Vec3{1, 1, 0} - eval::ClosestPointOnTriangle({1, 1, 0}, a, b, c)),
              std::sqrt(0.5), 1e-15);
}

TEST(ClosestPointTest, DegenerateTriangles) {
  // Collinear corners: the closest point of the segment [0, 2] on the x axis.
  const Vec3 q = eval::ClosestPointOnTriangle({1.5, 1, 0}, {0, 0, 0}, {1, 0, 0}, {2, 0, 0});
  EXPECT_NEAR(Norm(q - Vec3{1.5, 0, 0}), 0.0, 1e-15);
  const Vec3 r = eval::ClosestPointOnTriangle({3, 1, 0}, {0, 0, 0}, {2, 0, 0}, {1, 0, 0});
  EXPECT_NEAR(Norm(r - Vec3{2, 0, 0}), 0.0, 1e-15);
  const Vec3 s = eval::ClosestPointOnTriangle({1, 1, 1}, {4, 5, 6}, {4, 5, 6}, {4, 5, 6});
  EXPECT_EQ(s, (Vec3{4, 5, 6}));
}

TEST(TriangleBvhTest, MatchesBruteForce) {
  // A bumpy sphere so that many triangles compete for each query.
  IndexedMesh m = Icosphere(3);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> jitter(-0.05, 0.05), box(-1.6, 1.6);
  for (Vec3& p : m.positions) p = p + Vec3{jitter(rng), jitter(rng), jitter(rng)};
  const eval::TriangleBvh bvh(m);
  ASSERT_EQ(bvh.num_triangles(), m.num_triangles());
  std::uniform_int_distribution<uint32_t> any_triangle(
      0, static_cast<uint32_t>(m.num_triangles() - 1));
  for (int i = 0; i < 500; ++i) {
    const Vec3 p{box(rng), box(rng), box(rng)};
    double brute = std::numeric_limits<double>::infinity();
    for (size_t t = 0; t < m.num_triangles(); ++t) {
      const Vec3 q = eval::ClosestPointOnTriangle(p, m.positions[m.indices[3 * t]],
                                                  m.positions[m.indices[3 * t + 1]],
                                                  m.positions[m.indices[3 * t + 2]]);
      brute = std::min(brute, Norm(p - q));
    }
    const eval::TriangleBvh::Hit hit = bvh.Closest(p);
    EXPECT_NEAR(hit.distance, brute, 1e-14) << "query " << i;
    EXPECT_NEAR(Norm(hit.point - p), hit.distance, 1e-14);
    ASSERT_LT(hit.triangle, m.num_triangles());
    // A hint, even a far-away triangle, never changes the answer.
    EXPECT_NEAR(bvh.Closest(p, any_triangle(rng)).distance, brute, 1e-14) << "query " << i;
  }
}

TEST(TriangleBvhTest, EmptyAndTinyMeshes) {
  const eval::TriangleBvh empty{IndexedMesh{}};
  EXPECT_TRUE(empty.empty());
  EXPECT_TRUE(std::isinf(empty.Distance({0, 0, 0})));
  EXPECT_EQ(empty.Closest({0, 0, 0}).triangle, kInvalid);
  IndexedMesh one;
  AddTriangle(one, {0, 0, 0}, {1, 0, 0}, {0, 1, 0});
  EXPECT_NEAR(eval::TriangleBvh(one).Distance({0.25, 0.25, -3}), 3.0, 1e-15);
}

// ---------------------------------------------------------------------------------------
// Distances between meshes

TEST(DistanceTest, IdenticalMeshesAreAtZero) {
  const IndexedMesh m = Icosphere(3);
  const eval::Distances d = eval::MeasureDistances(m, m);
  EXPECT_LT(d.linf_max, 1e-12);
  EXPECT_LT(d.l2_max, 1e-12);
  EXPECT_LT(d.l1_max, 1e-12);
  EXPECT_EQ(d.forward.samples, 100'000u);  // auto: max(100000, 2 × 1280)
}

TEST(DistanceTest, ParallelPlanesAreExactlyOffset) {
  // Every sample of one square lies straight above the other: all distances equal h.
  const IndexedMesh lower = PlaneGrid(3, 3, 1.0, 1.0);
  const IndexedMesh upper = Translated(lower, {0, 0, 0.125});
  const eval::Distances d = eval::MeasureDistances(lower, upper, {.samples = 20'000});
  for (const eval::DirectedDistance& dd : {d.forward, d.backward}) {
    EXPECT_NEAR(dd.l1, 0.125, 1e-15);
    EXPECT_NEAR(dd.l2, 0.125, 1e-15);
    EXPECT_NEAR(dd.linf, 0.125, 1e-15);
    EXPECT_EQ(dd.samples, 20'000u);
  }
}

TEST(DistanceTest, HalfSquareAgainstSquare) {
  // A = [0,1]², B = [0,1/2]×[0,1]. A→B: d(x, y) = max(0, x − 1/2), so L1 = ∫ = 1/8,
  // L2 = sqrt(∫ (x−1/2)² over [1/2, 1]) = sqrt(1/24), L∞ = 1/2 (at the vertices x = 1).
  // B→A: 0.
  const IndexedMesh a = PlaneGrid(8, 8, 1.0 / 8, 1.0 / 8);
  const IndexedMesh b = PlaneGrid(4, 8, 1.0 / 8, 1.0 / 8);
  const eval::Distances d = eval::MeasureDistances(a, b, {.samples = 200'000});
  EXPECT_NEAR(d.forward.l1, 1.0 / 8, 1e-3);
  EXPECT_NEAR(d.forward.l2, std::sqrt(1.0 / 24), 1e-3);
  EXPECT_NEAR(d.forward.linf, 0.5, 1e-15);
  EXPECT_LT(d.backward.linf, 1e-15);
  EXPECT_EQ(d.linf_max, d.forward.linf);
  EXPECT_EQ(d.l1_max, d.forward.l1);
}

TEST(DistanceTest, ShiftedSphereHausdorffIsTheShift) {
  // For unit spheres centred δ apart, d(p) = |‖p − δe‖ − 1| ≈ δ|p·e|: Hausdorff δ (at the
  // poles p = ±e), mean δ/2 and RMS δ/√3 over the sphere. The polyhedral error of a level-5
  // icosphere (~2e-4) is well within the 3% tolerance.
  const double delta = 0.05;
  const IndexedMesh a = Icosphere(5);
  const IndexedMesh b = Translated(a, {delta, 0, 0});
  const eval::Distances d = eval::MeasureDistances(a, b);
  EXPECT_NEAR(d.linf_max, delta, 0.03 * delta);
  EXPECT_NEAR(d.forward.linf, d.backward.linf, 0.01 * delta);
  EXPECT_NEAR(d.forward.l1, delta / 2, 0.03 * delta / 2);
  EXPECT_NEAR(d.forward.l2, delta / std::sqrt(3.0), 0.03 * delta / std::sqrt(3.0));
  EXPECT_NEAR(d.forward.l1, d.backward.l1, 0.01 * delta);
  EXPECT_NEAR(d.forward.l2, d.backward.l2, 0.01 * delta);
  EXPECT_EQ(d.forward.samples, 100'000u);
}

TEST(DistanceTest, DeterministicForAnyThreadCount) {
  const IndexedMesh a = Icosphere(4);
  const IndexedMesh b = Translated(Icosphere(2, 1.02), {0.01, 0.02, 0});
  const eval::Distances one =
      eval::MeasureDistances(a, b, {.samples = 50'000, .seed = 3, .threads = 1});
  for (int threads : {2, 3, 0}) {
    const eval::Distances many =
        eval::MeasureDistances(a, b, {.samples = 50'000, .seed = 3, .threads = threads});
    EXPECT_EQ(one.forward.l1, many.forward.l1) << threads << " threads";
    EXPECT_EQ(one.forward.l2, many.forward.l2) << threads << " threads";
    EXPECT_EQ(one.forward.linf, many.forward.linf) << threads << " threads";
    EXPECT_EQ(one.backward.l1, many.backward.l1) << threads << " threads";
    EXPECT_EQ(one.backward.linf, many.backward.linf) << threads << " threads";
  }
  // Another seed gives other samples, hence a slightly different (but close) mean.
  const eval::Distances other =
      eval::MeasureDistances(a, b, {.samples = 50'000, .seed = 4, .threads = 2});
  EXPECT_NE(one.forward.l1, other.forward.l1);
  EXPECT_NEAR(one.forward.l1, other.forward.l1, 0.01 * one.forward.l1);
}

TEST(DistanceTest, ReusableReferenceHierarchy) {
  const IndexedMesh reference = Icosphere(4);
  const eval::TriangleBvh bvh(reference);
  const IndexedMesh shifted = Translated(reference, {0, 0, 0.02});
  const eval::DirectedDistance dd =
      eval::MeasureDirectedDistance(shifted, bvh, {.samples = 30'000});
  const eval::Distances full = eval::MeasureDistances(shifted, reference, {.samples = 30'000});
  EXPECT_EQ(dd.l1, full.forward.l1);
  EXPECT_EQ(dd.linf, full.forward.linf);
}

TEST(DistanceTest, EmptyMeshesGiveNaN) {
  const IndexedMesh m = Icosphere(1);
  const eval::Distances d = eval::MeasureDistances(m, IndexedMesh{});
  EXPECT_TRUE(std::isnan(d.forward.l1));
  EXPECT_TRUE(std::isnan(d.forward.linf));
  EXPECT_TRUE(std::isnan(d.backward.l2));
  EXPECT_TRUE(std::isnan(d.linf_max));
  EXPECT_EQ(d.forward.samples, 0u);
  // A mesh without area (points only) is measured by its vertices.
  IndexedMesh points;
  points.positions = {{0.5, 0.5, 1}, {0.5, 0.5, 2}};
  const eval::DirectedDistance p =
      eval::MeasureDirectedDistance(points, eval::TriangleBvh(PlaneGrid(2, 2, 1, 1)));
  EXPECT_EQ(p.samples, 0u);
  EXPECT_NEAR(p.linf, 2.0, 1e-15);
  EXPECT_NEAR(p.l1, 1.5, 1e-15);
}

}  // namespace
}  // namespace tandem
