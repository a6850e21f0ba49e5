// TidyDegenerate (core/src/degenerate.h) on hand-made meshes: each kind of zero-area triangle
// it mends, and the topology it keeps.
#include <array>
#include <vector>

#include <gtest/gtest.h>

#include "degenerate.h"
#include "mesh_store.h"
#include "tandem/geometry.h"
#include "tandem/topology.h"

namespace tandem {
namespace {

int64_t CountDegenerate(const MeshStore& s) {
  int64_t n = 0;
  for (TriId t = 0; t < s.triangle_capacity(); ++t) {
    if (!s.triangle_alive(t)) continue;
    const auto& w = s.triangle(t);
    n += IsDegenerateTriangle(s.position(w[0]), s.position(w[1]), s.position(w[2]));
  }
  return n;
}

DegenerateCounts Tidy(MeshStore* s) {
  return TidyDegenerate(
      s, 0.1, [](VertexId, Vec3) { return true; }, [](VertexId) {});
}

// A sliver (a, b, m) with m on the edge ab, so it has zero area; across ab lies (b, a, c).
// The flip to m c tiles (b, a, c) exactly: no corner moves, the area and the boundary stay.
TEST(TidyDegenerate, FlipsACollinearSliver) {
  MeshStore s;
  const VertexId a = s.AddVertex({0, 0, 0}, 0, 0, 0), b = s.AddVertex({2, 0, 0}, 0, 0, 0),
                 m = s.AddVertex({1, 0, 0}, 0, 0, 0), c = s.AddVertex({1, 1, 0}, 0, 0, 0),
                 d = s.AddVertex({1, -1, 0}, 0, 0, 0);
  s.AddTriangle(b, a, c);  // up
  s.AddTriangle(a, b, m);  // the sliver
  s.AddTriangle(a, m, d);  // below, on each side of m
  s.AddTriangle(m, b, d);
  ASSERT_EQ(CountDegenerate(s), 1);
  const TopologyReport before = AnalyzeTopology(s.Snapshot());
  const DegenerateCounts n = Tidy(&s);
  EXPECT_EQ(n.flipped, 1);
  EXPECT_EQ(n.left, 0);
  EXPECT_EQ(CountDegenerate(s), 0);
  const IndexedMesh after = s.Snapshot();
  const TopologyReport t = AnalyzeTopology(after);
  EXPECT_TRUE(t.IsManifold());
  EXPECT_EQ(t.euler, before.euler);
  EXPECT_EQ(t.boundary_edges, before.boundary_edges);
  EXPECT_EQ(after.num_triangles(), 4u);
  for (const Vec3& p : after.positions) EXPECT_EQ(p.z, 0.0);  // nothing moved
}

// A closed component of four triangles at one point (a lone voxel at the iso-value) becomes
// a small tetrahedron facing out, whichever way its triangles' ids were assigned.
TEST(TidyDegenerate, InflatesATetrahedronCollapsedToAPoint) {
  for (bool mirrored : {false, true}) {
    MeshStore s;
    std::array<VertexId, 4> v;
    for (auto& x : v) x = s.AddVertex({5, 5, 5}, 0, 0, 0);
    if (mirrored) std::swap(v[0], v[1]);
    // Outward from (0,0,0), (1,0,0), (0,1,0), (0,0,1) when the corners get those places.
    s.AddTriangle(v[0], v[2], v[1]);
    s.AddTriangle(v[0], v[1], v[3]);
    s.AddTriangle(v[0], v[3], v[2]);
    s.AddTriangle(v[1], v[2], v[3]);
    ASSERT_EQ(CountDegenerate(s), 4);
    const DegenerateCounts n = Tidy(&s);
    EXPECT_EQ(n.moved, 4);
    EXPECT_EQ(CountDegenerate(s), 0);
    const IndexedMesh m = s.Snapshot();
    const TopologyReport t = AnalyzeTopology(m);
    EXPECT_TRUE(t.IsClosedManifold());
    EXPECT_EQ(t.euler, 2);
    double volume = 0;  // six times the signed volume: positive when the faces look out
    for (size_t f = 0; f < m.num_triangles(); ++f) {
      const Vec3 p0 = m.positions[m.indices[3 * f]] - Vec3{5, 5, 5},
                 p1 = m.positions[m.indices[3 * f + 1]] - Vec3{5, 5, 5},
                 p2 = m.positions[m.indices[3 * f + 2]] - Vec3{5, 5, 5};
      volume += Dot(p0, Cross(p1, p2));
    }
    EXPECT_GT(volume, 0) << mirrored;
    for (const Vec3& p : m.positions) EXPECT_LE(Norm(p - Vec3{5, 5, 5}), 0.1 + 1e-12);
  }
}

// Two corners at one point where a fan is otherwise sound: the one that can part toward its
// own neighbours does, no triangle turns over, and a refusal (may_move) is respected.
TEST(TidyDegenerate, PartsCornersAtOnePointWithinWhatMayMove) {
  for (bool allowed : {true, false}) {
    MeshStore s;
    // A flat fan around w = (0,0,0) in z = 0; u sits on w, splitting the fan's edge to e.
    const VertexId w = s.AddVertex({0, 0, 0}, 0, 0, 0), u = s.AddVertex({0, 0, 0}, 0, 0, 0),
                   e = s.AddVertex({1, 0, 0}, 0, 0, 0), f = s.AddVertex({0, 1, 0}, 0, 0, 0),
                   g = s.AddVertex({-1, 0, 0}, 0, 0, 0), h = s.AddVertex({1, -1, 0}, 0, 0, 0);
    s.AddTriangle(w, e, f);  // w's side
    s.AddTriangle(w, f, g);
    s.AddTriangle(u, w, g);  // the sliver: u and w at one point
    s.AddTriangle(u, g, h);  // u's side, below
    s.AddTriangle(u, h, e);
    s.AddTriangle(u, e, w);  // the other sliver on uw
    ASSERT_EQ(CountDegenerate(s), 2);
    const DegenerateCounts n = TidyDegenerate(
        &s, 0.1, [&](VertexId, Vec3) { return allowed; }, [](VertexId) {});
    if (!allowed) {
      EXPECT_EQ(n.moved, 0);
      EXPECT_EQ(CountDegenerate(s), 2);
      continue;
    }
    EXPECT_GE(n.moved, 1);
    EXPECT_EQ(CountDegenerate(s), 0);
    const IndexedMesh m = s.Snapshot();
    for (size_t t = 0; t < m.num_triangles(); ++t) {  // every triangle faces +z still
      const Vec3 n2 = TwiceAreaVector(m.positions[m.indices[3 * t]], m.positions[m.indices[3 * t + 1]],
                                      m.positions[m.indices[3 * t + 2]]);
      EXPECT_GT(n2.z, 0) << t;
    }
  }
}

}  // namespace
}  // namespace tandem
