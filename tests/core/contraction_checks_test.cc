#include <algorithm>
#include <cmath>
#include <array>
#include <iterator>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "contraction_checks.h"
#include "engine_testutil.h"
#include "mesh_store.h"
#include "simplifier.h"
#include "tandem/geometry.h"
#include "tandem/eval/synthetic.h"
#include "tandem/volume.h"

namespace tandem {
namespace {

// LAMBDA(ab) from its definition (paper §2, "Surface simplification"): Lk(a) ∩ Lk(b) = Lk(ab) in the complex completed
// by a dummy vertex ω joined to every boundary edge (an edge in one triangle). Links hold
// vertices and edges; ω is kInvalid.
bool LinkConditionByDefinition(const MeshStore& store, const EdgeTriangles& edge_triangles,
                               VertexId a, VertexId b) {
  const VertexId omega = kInvalid;
  auto boundary_edge = [&](VertexId x, VertexId y) {
    auto it = edge_triangles.find(std::minmax(x, y));
    return it != edge_triangles.end() && it->second == 1;
  };
  using Simplex = std::pair<VertexId, VertexId>;  // a vertex is (x, x), an edge (min, max)
  auto link = [&](VertexId v) {
    std::set<Simplex> lk;
    for (TriId t : store.vertex_triangles(v)) {
      const auto& tri = store.triangle(t);
      VertexId o[2];
      int n = 0;
      for (VertexId x : tri) {
        if (x != v) o[n++] = x;
      }
      lk.insert({o[0], o[0]});
      lk.insert({o[1], o[1]});
      lk.insert(std::minmax(o[0], o[1]));
      for (VertexId x : o) {
        if (boundary_edge(v, x)) {
          lk.insert({omega, omega});
          lk.insert(std::minmax(omega, x));
        }
      }
    }
    return lk;
  };
  const std::set<Simplex> la = link(a), lb = link(b);
  std::set<Simplex> common;
  std::set_intersection(la.begin(), la.end(), lb.begin(), lb.end(),
                        std::inserter(common, common.begin()));
  std::set<Simplex> lab;
  for (TriId t : store.vertex_triangles(a)) {
    const auto& tri = store.triangle(t);
    if (tri[0] != b && tri[1] != b && tri[2] != b) continue;
    for (VertexId x : tri) {
      if (x != a && x != b) lab.insert({x, x});
    }
  }
  if (boundary_edge(a, b)) lab.insert({omega, omega});
  return common == lab;
}

// Small complexes where the answer hinges on one clause of the test: a common neighbour
// reached through a boundary edge (the three triangles around c with boundary a-b-x), a
// tetrahedron (closed: every contraction pinches), the same without a face (a fan whose
// boundary is a triangle), a single triangle and two triangles on an edge.
TEST(LinkCondition, OnSmallComplexes) {
  using Tri = std::array<int, 3>;
  const std::vector<std::vector<Tri>> complexes = {
      {{0, 1, 2}, {1, 3, 2}, {0, 2, 3}},
      {{0, 1, 2}, {0, 3, 1}, {0, 2, 3}, {1, 3, 2}},
      {{0, 1, 3}, {1, 2, 3}, {2, 0, 3}},
      {{0, 1, 2}},
      {{0, 1, 2}, {1, 0, 3}},
  };
  int64_t allowed = 0, refused = 0;
  for (size_t i = 0; i < complexes.size(); ++i) {
    MeshStore store;
    std::vector<VertexId> v;
    for (int k = 0; k < 4; ++k) {
      v.push_back(store.AddVertex({static_cast<double>(k & 1), static_cast<double>(k >> 1), k * 0.1},
                                  0, 0, 0));
    }
    for (const Tri& t : complexes[i]) store.AddTriangle(v[t[0]], v[t[1]], v[t[2]]);
    LinkScratch scratch;
    const EdgeTriangles edge_triangles = CountEdgeTriangles(store);
    for (const auto& [edge, count] : edge_triangles) {
      for (auto [a, b] : {edge, std::pair{edge.second, edge.first}}) {
        const bool expected = LinkConditionByDefinition(store, edge_triangles, a, b);
        (expected ? allowed : refused) += 1;
        EXPECT_EQ(LinkConditionFans(store, a, b), expected) << i << ": " << a << "-" << b;
        EXPECT_EQ(LinkConditionMarks(store, a, b, &scratch), expected) << i << ": " << a << "-" << b;
      }
    }
  }
  EXPECT_GT(allowed, 0);
  EXPECT_GT(refused, 0);
}

// The link condition's two implementations (small fans in stack arrays, larger ones with
// per-vertex marks) agree with the definition on every edge, both ways round: on a closed
// and a box-cut surface as extracted (valence about 6, every contraction allowed but a few)
// and after simplifying them hard (high valences past kFanMax, tetrahedral corners, thin
// handles: many refusals). Wrong answers here change topology or stall the simplifier.
TEST(LinkCondition, MatchesItsDefinition) {
  int64_t large = 0;  // calls on fans too big for the stack arrays
  for (const std::string name : {"sphere", "gyroid", "link", "box-cut gyroid"}) {
    for (double e0 : {0.0, 0.4, 3.0}) {
      auto src = name == "box-cut gyroid"
                     ? BoxCutGyroid(22, 20, 18)
                     : eval::MakeSyntheticSource(*eval::ParseShape(name), 22, 20, 18);
      MeshStore store;
      SimplifierOptions so;
      so.error = e0 > 0 ? e0 : 1e-9;
      so.release = ReleaseRule::kImmediate;
      Simplifier simplifier(&store, so);
      const std::vector<TriId> all = ExtractLayers(src.get(), &store, &simplifier, false);
      if (e0 > 0) {
        simplifier.Delay(all);
        simplifier.Activate(std::numeric_limits<double>::infinity());
        simplifier.Simplify();
      }
      const std::string what = name + " E0 " + std::to_string(e0);
      LinkScratch scratch;
      const EdgeTriangles edge_triangles = CountEdgeTriangles(store);
      int64_t allowed = 0, refused = 0, fans = 0;
      for (TriId t = 0; t < store.triangle_capacity(); ++t) {
        if (!store.triangle_alive(t)) continue;
        const auto& tri = store.triangle(t);
        for (int i = 0; i < 3; ++i) {
          for (auto [a, b] : {std::pair{tri[i], tri[(i + 1) % 3]}, std::pair{tri[(i + 1) % 3], tri[i]}}) {
            const bool expected = LinkConditionByDefinition(store, edge_triangles, a, b);
            (expected ? allowed : refused) += 1;
            ASSERT_EQ(LinkConditionMarks(store, a, b, &scratch), expected) << what << " " << a << "-" << b;
            ASSERT_EQ(LinkCondition(store, a, b, &scratch), expected) << what << " " << a << "-" << b;
            if (store.vertex_triangles(a).size() <= kFanMax &&
                store.vertex_triangles(b).size() <= kFanMax) {
              ++fans;
              ASSERT_EQ(LinkConditionFans(store, a, b), expected) << what << " " << a << "-" << b;
              // Both widths, whichever this CPU picks.
              ASSERT_EQ(LinkConditionFansWithLanes(4, store, a, b), expected) << what << " " << a;
              ASSERT_EQ(LinkConditionFansWithLanes(8, store, a, b), expected) << what << " " << a;
            } else {
              ++large;
            }
          }
        }
      }
      // At E0 3 the sphere may come down to the smallest closed mesh, where every contraction
      // is refused (which one it reaches is up to rounding: its edges tie).
      if (e0 < 1) {
        EXPECT_GT(allowed, 0) << what;
      }
      EXPECT_GT(fans, 0) << what;
      if (e0 > 1) {
        EXPECT_GT(refused, 0) << what;
      }
    }
  }
  EXPECT_GT(large, 0);
}

// A fan past kFanMax is tallied in a table the size of the two fans, not a mark per vertex
// id: on a 2048² closed gyroid's cap that array was 10.6 MiB of each part's 262 (12 bytes a
// vertex id) for the few dozen vertices with such a fan. Two fans of 20 in a store of 200,000
// vertex ids: the answers as the definition's, and the scratch within 4 KiB (2.4 MB before).
TEST(LinkCondition, LargeFansTakeScratchForTheFansOnly) {
  MeshStore store;
  for (int i = 0; i < 200000; ++i) store.AddVertex({0, 0, -1.0 - i}, 0, 0, 0);  // ids only
  constexpr int kRim = 20;
  const VertexId a = store.AddVertex({0, 0, 0}, 0, 0, 0);
  const VertexId b = store.AddVertex({10, 0, 0}, 0, 0, 0);
  auto rim = [&](Vec3 c) {
    std::vector<VertexId> r;
    for (int k = 0; k < kRim; ++k) {
      const double t = 2 * std::numbers::pi * k / kRim;
      r.push_back(store.AddVertex({c.x + std::cos(t), c.y + std::sin(t), c.z}, 0, 0, 0));
    }
    return r;
  };
  const std::vector<VertexId> ra = rim({0, 0, 0}), rb = rim({10, 0, 0});
  for (int k = 0; k < kRim; ++k) {
    store.AddTriangle(a, ra[k], ra[(k + 1) % kRim]);
    store.AddTriangle(b, rb[k], rb[(k + 1) % kRim]);
  }
  // Two disjoint fans: a and b are not adjacent, and a rim edge of each is allowed.
  LinkScratch scratch;
  EXPECT_FALSE(LinkConditionMarks(store, a, b, &scratch));
  EXPECT_TRUE(LinkConditionMarks(store, a, ra[0], &scratch));
  EXPECT_TRUE(LinkConditionMarks(store, b, rb[3], &scratch));
  EXPECT_TRUE(LinkCondition(store, ra[0], a, &scratch));
  EXPECT_LE(scratch.MemoryBytes(), size_t{4096});
}

// ---------------------------------------------------------------- geometry (tandem/geometry.h)

TEST(Geometry, AreaVectorAndTheTwoNoAreaRules) {
  const Vec3 n = TwiceAreaVector({0, 0, 0}, {2, 0, 0}, {0, 1, 0});  // CCW seen from +z
  EXPECT_EQ(n, (Vec3{0, 0, 2}));
  EXPECT_EQ(TriangleAreaVector({0, 0, 0}, {2, 0, 0}, {0, 1, 0}), (Vec3{0, 0, 1}));
  EXPECT_DOUBLE_EQ(SumSquaredEdges({0, 0, 0}, {2, 0, 0}, {0, 1, 0}), 4.0 + 5.0 + 1.0);
  EXPECT_TRUE(IsDegenerateTriangle({0, 0, 0}, {1, 1, 1}, {2, 2, 2}));
  EXPECT_TRUE(IsDegenerateTriangle({0, 0, 0}, {0, 0, 0}, {1, 0, 0}));
  EXPECT_FALSE(IsDegenerateTriangle({0, 0, 0}, {1, 0, 0}, {0.5, 1e-3, 0}));
  // area / Σe² ≈ 1e-11: a triangle for the measures, too thin for the engine to make.
  const Vec3 a{0, 0, 0}, b{1, 0, 0}, c{0.5, 3e-11, 0};
  EXPECT_FALSE(IsDegenerateTriangle(a, b, c));
  EXPECT_TRUE(MoveCorners(Vec3{0, 0, 1}, a, b, c).collapses);
  EXPECT_FALSE(MovedCornerKeepsOrientation(Vec3{0, 0, 1}, a, b, c));
}

TEST(Geometry, MovedCornersFlipOrCollapse) {
  const Vec3 p0{0, 0, 0}, p1{1, 0, 0}, p2{0, 1, 0};
  const Vec3 before = TwiceAreaVector(p0, p1, p2);
  EXPECT_TRUE(MovedCornerKeepsOrientation(before, {0.2, 0.1, 0.5}, p1, p2));  // tilted
  const CornerMove flip = MoveCorners(before, {2, 2, 0}, p1, p2);             // across p1p2
  EXPECT_TRUE(flip.flips);
  EXPECT_FALSE(flip.collapses);
  const CornerMove onto = MoveCorners(before, {0.5, 0.5, 0}, p1, p2);  // onto p1p2
  EXPECT_TRUE(onto.collapses);
  EXPECT_FALSE(MovedCornerKeepsOrientation(before, {0.5, 0.5, 0}, p1, p2));
}

// ---------------------------------------------------------------- GeometryOk

// A flat hexagonal fan around vertex 0 in the plane z = 0, counter-clockwise seen from +z;
// the contraction 0-1 moves vertex 0 and removes triangles 0-6-1 and 0-1-2.
struct Fan {
  MeshStore store;
  std::vector<VertexId> v;
  Fan() {
    v.push_back(store.AddVertex({0, 0, 0}, 0, 0, 0));
    for (int k = 0; k < 6; ++k) {
      const double t = k * std::numbers::pi / 3.0;
      v.push_back(store.AddVertex({std::cos(t), std::sin(t), 0}, 0, 0, 0));
    }
    for (int k = 1; k <= 6; ++k) store.AddTriangle(v[0], v[k], v[k % 6 + 1]);
  }
  bool Ok(Vec3 pos, double bound, RefusalCounts* refusals) {
    std::vector<Survivor> survivors;
    return GeometryOk(store, v[0], v[1], pos, bound, OffsetEdges{}, &survivors, refusals);
  }
};

// The lanes only filter which survivors the exact test sees: with 2 lanes (SSE2), 4 (AVX2) or
// every survivor through the exact test, each contraction of meshes as the simplifier has
// them (whole and simplified, on the box or not), to positions near and far, guarded or not,
// is refused or not alike, and a refusal counted for the same reason.
TEST(GeometryOk, EveryLaneWidthAnswersAsTheExactTest) {
  std::mt19937 rng(65);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  int64_t calls = 0, refused = 0;
  RefusalCounts all;
  for (const std::string name : {"sphere", "gyroid", "box-cut gyroid"}) {
    for (double e0 : {0.0, 0.4}) {
      auto src = name == "box-cut gyroid"
                     ? BoxCutGyroid(18, 16, 14)
                     : eval::MakeSyntheticSource(*eval::ParseShape(name), 18, 16, 14);
      MeshStore store;
      SimplifierOptions so;
      so.error = e0 > 0 ? e0 : 1e-9;
      so.release = ReleaseRule::kImmediate;
      Simplifier simplifier(&store, so);
      const std::vector<TriId> whole = ExtractLayers(src.get(), &store, &simplifier, false);
      if (e0 > 0) {
        simplifier.Delay(whole);
        simplifier.Activate(std::numeric_limits<double>::infinity());
        simplifier.Simplify();
      }
      std::vector<Survivor> survivors;
      for (TriId t = 0; t < store.triangle_capacity(); ++t) {
        if (!store.triangle_alive(t)) continue;
        const auto& tri = store.triangle(t);
        for (int i = 0; i < 3; ++i) {
          const VertexId a = tri[i], b = tri[(i + 1) % 3];
          const Vec3 pa = store.position(a), pb = store.position(b);
          const double length = std::sqrt(Dot(pb - pa, pb - pa));
          std::vector<Vec3> positions;
          for (double reach : {0.0, 0.3, 1.0, 3.0}) {
            const Vec3 jitter{unit(rng), unit(rng), unit(rng)};
            positions.push_back((pa + pb) * 0.5 + jitter * (reach * length));
          }
          // Onto a neighbour of a off ab: the triangle they share collapses.
          for (TriId s : store.vertex_triangles(a)) {
            const auto& other = store.triangle(s);
            if (std::find(other.begin(), other.end(), b) != other.end()) continue;
            positions.push_back(store.position(other[0] == a ? other[1] : other[0]));
            break;
          }
          for (const Vec3 pos : positions) {
            for (double bound : {0.0, 0.05 * length, 0.5 * length}) {
              RefusalCounts r[3];
              bool ok[3];
              const int widths[3] = {1, 2, 4};
              for (int w = 0; w < 3; ++w) {
                ok[w] = GeometryOkWithLanes(widths[w], store, a, b, pos, bound, OffsetEdges{},
                                            &survivors, &r[w]);
              }
              const std::string what = name + " E0 " + std::to_string(e0) + " " +
                                       std::to_string(a) + "-" + std::to_string(b);
              for (int w = 1; w < 3; ++w) {
                ASSERT_EQ(ok[w], ok[0]) << what << " lanes " << widths[w];
                ASSERT_EQ(r[w].distance, r[0].distance) << what;
                ASSERT_EQ(r[w].degenerate, r[0].degenerate) << what;
                ASSERT_EQ(r[w].flip, r[0].flip) << what;
              }
              ++calls;
              refused += !ok[0];
              all.distance += r[0].distance;
              all.degenerate += r[0].degenerate;
              all.flip += r[0].flip;
            }
          }
        }
      }
    }
  }
  // Every outcome and every reason occurred, so the widths were compared on each.
  EXPECT_GT(refused, 0);
  EXPECT_LT(refused, calls);
  EXPECT_GT(all.distance, 0);
  EXPECT_GT(all.degenerate, 0);
  EXPECT_GT(all.flip, 0);
}

TEST(GeometryOk, AcceptsAMoveInsideTheFan) {
  Fan fan;
  RefusalCounts r;
  EXPECT_TRUE(fan.Ok({0.5, 0, 0}, 0.0, &r));
  EXPECT_TRUE(fan.Ok({0.5, 0, 0.3}, 0.0, &r));  // off the plane, no guard: tilted, not flipped
  EXPECT_EQ(r.flip + r.degenerate + r.distance, 0);
}

TEST(GeometryOk, RefusesAFlipACollapseAndAFarMoveAndCountsWhy) {
  Fan fan;
  RefusalCounts r;
  EXPECT_FALSE(fan.Ok({-2, 0, 0}, 0.0, &r));  // past vertex 4: triangle 0-3-4 turns over
  EXPECT_EQ(r.flip, 1);
  EXPECT_FALSE(fan.Ok({0, std::sqrt(3.0) / 2, 0}, 0.0, &r));  // onto edge 2-3: 0-2-3 collapses
  EXPECT_EQ(r.degenerate, 1);
  EXPECT_FALSE(fan.Ok({0.5, 0, 0.3}, 0.1, &r));  // 0.3 off the planes, guard 0.1
  EXPECT_EQ(r.distance, 1);
  EXPECT_TRUE(fan.Ok({0.5, 0, 0.05}, 0.1, &r));
  EXPECT_EQ(r.flip, 1);
  EXPECT_EQ(r.degenerate, 1);
  EXPECT_EQ(r.distance, 1);
}

// A triangle that is already degenerate (an exact iso hit) constrains nothing.
TEST(GeometryOk, IgnoresTrianglesAlreadyDegenerate) {
  MeshStore store;
  const VertexId a = store.AddVertex({0, 0, 0}, 0, 0, 0), b = store.AddVertex({1, 0, 0}, 0, 0, 0),
                 c = store.AddVertex({0, 1, 0}, 0, 0, 0), d = store.AddVertex({0, 2, 0}, 0, 0, 0);
  store.AddTriangle(a, b, c);
  store.AddTriangle(a, c, d);  // collinear: a, c, d on x = 0
  std::vector<Survivor> survivors;
  RefusalCounts r;
  EXPECT_TRUE(GeometryOk(store, b, a, {0.1, 0.0, 0}, 0.0, OffsetEdges{}, &survivors, &r));
  EXPECT_EQ(r.flip + r.degenerate + r.distance, 0);
}

// A triangle with an edge of the extractor's offset (two surface points δ off one grid point
// on the iso-value, where without the offset they were one point) may turn over and leave its
// plane, as the collapsed triangle it stands for may, but may not collapse; an edge longer
// than 3δ along an axis is an edge of the surface.
TEST(GeometryOk, LetsATriangleOnAnOffsetEdgeTurnButNotCollapse) {
  const double delta = EdgeOffset(0, 1);
  for (const double length : {delta, 1.5 * delta, 4 * delta}) {
    MeshStore store;
    const VertexId u = store.AddVertex({length, 0, 0}, 0, 0, 0),
                   v = store.AddVertex({0, length, 0}, 0, 0, 0),
                   a = store.AddVertex({1, 1, 0}, 0, 0, 0), b = store.AddVertex({2, 1, 0}, 0, 0, 0),
                   w = store.AddVertex({2, 2, 0}, 0, 0, 0);
    store.AddTriangle(u, a, v);  // on the offset edge uv, moves with a
    store.AddTriangle(a, b, w);  // on ab: goes
    std::vector<Survivor> survivors;
    const OffsetEdges offsets{0, 0, 1, 1};
    const bool offset_edge = length <= 3 * delta;
    RefusalCounts r;
    // Across uv: u-a-v turns over.
    EXPECT_EQ(GeometryOk(store, a, b, {-1, -1, 0}, 0.0, offsets, &survivors, &r), offset_edge);
    EXPECT_FALSE(GeometryOk(store, a, b, {-1, -1, 0}, 0.0, OffsetEdges{}, &survivors, &r));
    // 0.5 off u-a-v's plane, the guard 0.1.
    EXPECT_EQ(GeometryOk(store, a, b, {1, 1, 0.5}, 0.1, offsets, &survivors, &r), offset_edge);
    // Onto the line uv: u-a-v collapses.
    EXPECT_FALSE(GeometryOk(store, a, b, {-1, 1 + length, 0}, 0.0, offsets, &survivors, &r));
    EXPECT_EQ(r.degenerate, 1);
  }
}

}  // namespace
}  // namespace tandem
