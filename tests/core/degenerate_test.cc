// TidyDegenerate (core/src/degenerate.h) on hand-made meshes: each kind of zero-area triangle
// it mends, and the topology it keeps.
#include <array>
#include <vector>

#include <gtest/gtest.h>

#include "degenerate.h"
#include "mesh_store.h"
#include "tandem/geometry.h"
#include "tandem/eval/topology.h"

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
  const eval::TopologyReport before = eval::AnalyzeTopology(s.Snapshot());
  const DegenerateCounts n = Tidy(&s);
  EXPECT_EQ(n.flipped, 1);
  EXPECT_EQ(n.left, 0);
  EXPECT_EQ(CountDegenerate(s), 0);
  const IndexedMesh after = s.Snapshot();
  const eval::TopologyReport t = eval::AnalyzeTopology(after);
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
    const eval::TopologyReport t = eval::AnalyzeTopology(m);
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

// Two sheets touching at a point of the head MR (48x62x42, iso 16): its surface around two
// vertices at one point, as simplification left it (in float), where two zero-area triangles
// share the pair; at E0 1.5 (A) and at the default E0, 0.8 (B).
const std::vector<Vec3> kPinchAPositions = {
    {89.43456268310547f, 165.1192169189453f, 157.4331512451172f},
    {88.67042541503906f, 154.9468231201172f, 156.1416778564453f},
    {83.93706512451172f, 167.28884887695312f, 145.27377319335938f},
    {84.0f, 168.0f, 148.0f},
    {82.29985809326172f, 165.48178100585938f, 149.83494567871094f},
    {87.27256774902344f, 163.3944549560547f, 151.70274353027344f},
    {91.58621215820312f, 162.1622772216797f, 153.33595275878906f},
    {81.20917510986328f, 157.2567901611328f, 150.995361328125f},
    {80.0f, 164.0f, 155.0f},
    {78.39134979248047f, 168.62461853027344f, 156.15162658691406f},
    {84.0f, 168.0f, 148.0f},
    {84.32506561279297f, 174.85166931152344f, 144.46926879882812f},
    {95.29791259765625f, 171.0336151123047f, 152.5615234375f},
    {96.84818267822266f, 176.86082458496094f, 146.58953857421875f},
    {77.48336029052734f, 179.69313049316406f, 150.3502197265625f},
    {83.9054183959961f, 169.72488403320312f, 147.96774291992188f},
    {84.31327819824219f, 164.64768981933594f, 147.0665283203125f},
    {89.37095642089844f, 186.0274200439453f, 150.3267822265625f},
    {93.90615844726562f, 179.72348022460938f, 151.8742218017578f},
    {82.36444854736328f, 173.7377471923828f, 154.0659942626953f},
    {84.925048828125f, 172.19992065429688f, 148.57464599609375f},
    {86.20455932617188f, 148.43240356445312f, 156.96949768066406f},
    {84.44908142089844f, 156.7579803466797f, 149.5115966796875f},
    {87.79855346679688f, 151.90182495117188f, 155.123291015625f},
    {83.99920654296875f, 184.0716552734375f, 135.5477294921875f},
    {83.80818176269531f, 180.027099609375f, 139.8489227294922f},
    {84.57099151611328f, 184.97567749023438f, 138.03173828125f},
    {85.02989959716797f, 180.91473388671875f, 140.1439971923828f},
    {91.66974639892578f, 185.82449340820312f, 142.0950164794922f},
    {79.14539337158203f, 180.17137145996094f, 144.00144958496094f},
};
const std::vector<std::array<uint32_t, 3>> kPinchATriangles = {
    {2, 3, 4}, {5, 0, 6}, {2, 10, 3}, {11, 12, 13}, {11, 14, 15}, {16, 10, 11}, {17, 11, 18},
    {15, 19, 4}, {4, 19, 9}, {16, 3, 10}, {20, 15, 5}, {2, 11, 15}, {4, 3, 15}, {2, 15, 10},
    {5, 1, 0}, {2, 4, 16}, {7, 4, 8}, {20, 10, 15}, {22, 16, 4}, {22, 5, 16}, {11, 13, 18},
    {16, 15, 3}, {15, 14, 19}, {11, 10, 20}, {4, 9, 8}, {5, 12, 20}, {24, 25, 11}, {26, 24, 11},
    {26, 11, 27}, {16, 11, 2}, {22, 23, 1}, {22, 4, 7}, {11, 29, 14}, {6, 12, 5}, {25, 29, 11},
    {27, 11, 28}, {16, 5, 15}, {11, 20, 12}, {28, 11, 17}, {21, 23, 22}, {21, 22, 7},
    {22, 1, 5},
};
const std::vector<Vec3> kPinchBPositions = {
    {91.84213256835938f, 231.96636962890625f, 58.88127517700195f},
    {95.43829345703125f, 232.2139892578125f, 55.91256332397461f},
    {106.37625885009766f, 236.34449768066406f, 68.90508270263672f},
    {88.35347747802734f, 231.257568359375f, 56.32027053833008f},
    {85.08258056640625f, 237.7693328857422f, 60.78778839111328f},
    {93.07828521728516f, 236.10589599609375f, 74.36659240722656f},
    {102.17317962646484f, 236.1925048828125f, 68.03730773925781f},
    {110.07662963867188f, 237.91940307617188f, 56.42593765258789f},
    {93.18414306640625f, 233.63565063476562f, 66.81399536132812f},
    {80.2080307006836f, 234.78099060058594f, 53.28351974487305f},
    {70.25352478027344f, 233.8509521484375f, 58.08085632324219f},
    {77.59420776367188f, 235.45375061035156f, 58.9609375f},
    {76.52882385253906f, 236.53916931152344f, 72.79288482666016f},
    {72.75108337402344f, 234.139404296875f, 70.36833190917969f},
    {80.45637512207031f, 233.76034545898438f, 63.035316467285156f},
    {86.9476547241211f, 234.34255981445312f, 65.78034973144531f},
    {94.52053833007812f, 238.02032470703125f, 54.65166473388672f},
    {75.92854309082031f, 231.07669067382812f, 66.05934143066406f},
    {81.80288696289062f, 233.31924438476562f, 71.65918731689453f},
    {95.02347564697266f, 235.64186096191406f, 72.4824447631836f},
    {108.29695129394531f, 234.6636962890625f, 74.82887268066406f},
    {88.0f, 236.0f, 76.0f},
    {88.0f, 236.0f, 78.0f},
    {88.0f, 236.0f, 76.0f},
    {99.9781265258789f, 236.0400390625f, 76.01332092285156f},
    {90.0f, 236.0f, 80.0f},
    {96.0f, 236.0f, 80.0f},
    {101.91659545898438f, 236.0862579345703f, 79.11843872070312f},
    {104.0f, 236.0f, 80.0f},
    {97.1850357055664f, 236.07203674316406f, 79.53314208984375f},
    {92.0f, 236.0f, 80.0f},
};
const std::vector<std::array<uint32_t, 3>> kPinchBTriangles = {
    {4, 5, 6}, {6, 8, 2}, {12, 10, 13}, {14, 3, 15}, {16, 6, 7}, {15, 0, 8}, {1, 2, 8},
    {4, 12, 5}, {3, 0, 15}, {12, 11, 10}, {9, 11, 4}, {11, 12, 4}, {0, 1, 8}, {16, 4, 6},
    {9, 4, 16}, {2, 7, 6}, {13, 17, 12}, {17, 14, 18}, {17, 18, 12}, {14, 15, 18}, {15, 8, 5},
    {8, 19, 5}, {6, 19, 8}, {21, 12, 18}, {21, 18, 15}, {21, 15, 22}, {23, 22, 15}, {23, 15, 5},
    {6, 24, 19}, {24, 2, 20}, {21, 5, 12}, {23, 5, 21}, {6, 5, 24}, {21, 22, 25}, {23, 25, 26},
    {23, 26, 22}, {5, 19, 26}, {5, 26, 25}, {19, 24, 27}, {19, 27, 26}, {24, 20, 27},
    {23, 21, 25}, {5, 25, 29}, {5, 29, 24}, {24, 29, 28}, {28, 2, 24}, {22, 26, 30},
    {22, 30, 25}, {26, 29, 30}, {26, 27, 29}, {25, 30, 29}, {29, 27, 28},
};

// Parted toward their neighbours, each mended triangle must face as the triangles across its
// edges do: with the moved vertex's own triangles as the reference, which mix the two sheets'
// sides there, both of A's stayed zero-area. Where that direction turns a mended triangle
// the wrong way, the same step across the triangle's long edge parts it (B).
TEST(TidyDegenerate, PartsTwoSheetsTouchingAtAPoint) {
  for (const auto& [positions, triangles] :
       {std::pair{&kPinchAPositions, &kPinchATriangles},
        std::pair{&kPinchBPositions, &kPinchBTriangles}}) {
    MeshStore s;
    for (const Vec3& p : *positions) s.AddVertex(p, 0, 0, 0);
    for (const auto& t : *triangles) s.AddTriangle(t[0], t[1], t[2]);
    ASSERT_EQ(CountDegenerate(s), 2);
    const eval::TopologyReport before = eval::AnalyzeTopology(s.Snapshot());
    const DegenerateCounts n = Tidy(&s);
    const bool b = positions == &kPinchBPositions;
    EXPECT_GE(n.moved, 1) << b;
    EXPECT_EQ(n.left, 0) << b;
    EXPECT_EQ(CountDegenerate(s), 0) << b;
    const eval::TopologyReport after = eval::AnalyzeTopology(s.Snapshot());
    EXPECT_EQ(after.euler, before.euler) << b;
    EXPECT_EQ(after.boundary_edges, before.boundary_edges) << b;
    EXPECT_EQ(after.misoriented_edges, 0u) << b;
    for (size_t i = 0; i < positions->size(); ++i) {  // a small step: 5 % toward the neighbours
      EXPECT_LT(Norm(s.position(VertexId(i)) - (*positions)[i]), 0.5) << b << " " << i;
    }
  }
}

// A boundary triangle (a, b, m) with its three corners on an edge of the grid's box (x = 0,
// y = 10, along z: the quantised tangles kept one so): no flip across its boundary edge ab,
// and every step within both faces stays on the line. The middle corner steps off one of its
// faces into the box, loses that face's flag, and every triangle faces as before.
TEST(TidyDegenerate, PartsCollinearCornersOnAnEdgeOfTheBoxOffOneFace) {
  MeshStore s;
  const uint8_t edge = kBoxXMin | kBoxYMax;
  const VertexId a = s.AddVertex({0, 10, 0}, 0, 0, edge), b = s.AddVertex({0, 10, 2}, 0, 0, edge),
                 m = s.AddVertex({0, 10, 1}, 0, 0, edge), c = s.AddVertex({1, 9, 1}, 0, 0, 0);
  s.AddTriangle(a, b, m);  // the sliver, ab on the box's edge
  s.AddTriangle(m, b, c);  // facing (1, 1, 0)
  s.AddTriangle(a, m, c);
  ASSERT_EQ(CountDegenerate(s), 1);
  const DegenerateCounts n = Tidy(&s);
  EXPECT_EQ(n.left, 0);
  EXPECT_EQ(n.moved, 1);
  EXPECT_EQ(CountDegenerate(s), 0);
  const Vec3 p = s.position(m);
  EXPECT_GE(p.x, 0);  // into the box, off exactly one face
  EXPECT_LE(p.y, 10);
  EXPECT_EQ(p.z, 1);
  EXPECT_EQ((p.x == 0) + (p.y == 10), 1);
  EXPECT_EQ(s.box_mask(m), p.x == 0 ? kBoxXMin : kBoxYMax);
  const IndexedMesh after = s.Snapshot();
  EXPECT_TRUE(eval::AnalyzeTopology(after).IsManifold());
  for (size_t t = 0; t < after.num_triangles(); ++t) {
    const Vec3 n2 = TwiceAreaVector(after.positions[after.indices[3 * t]],
                                    after.positions[after.indices[3 * t + 1]],
                                    after.positions[after.indices[3 * t + 2]]);
    EXPECT_GT(Dot(n2, Vec3{1, 1, 0}), 0) << t;
  }
}

// A triangle alone in its component, flat on the grid's box at a point or along a line (a
// voxel at the iso-value on the box's first slice: two of them in the head MR at any E0): it
// parts within its face, facing into the box. On an edge of the box (two faces) it parts
// within one of them, facing into the box there, the moved corners stepping off the other
// into the box and losing its flag (the quantised tangles: one on x = 0, y = max, where it
// used to stay). At a corner of the box it stays.
TEST(TidyDegenerate, PartsALoneTriangleOnTheBoxWithinItsFace) {
  struct Case {
    std::array<Vec3, 3> corners;
    uint8_t box;
    std::vector<Vec3> inward;  // of each face it is on; none: left as it is
  };
  const std::vector<Case> cases = {
      {{Vec3{60, 180, 0}, Vec3{60, 180, 0}, Vec3{60, 180, 0}}, kBoxZMin, {{0, 0, 1}}},
      {{Vec3{56, 168, 0}, Vec3{56, 168, 0}, Vec3{56, 172, 0}}, kBoxZMin, {{0, 0, 1}}},
      {{Vec3{56, 172, 0}, Vec3{56, 168, 0}, Vec3{56, 168, 0}}, kBoxZMin, {{0, 0, 1}}},
      {{Vec3{9, 3, 4}, Vec3{9, 3, 4}, Vec3{9, 3, 4}}, kBoxXMax, {{-1, 0, 0}}},
      {{Vec3{0, 3, 0}, Vec3{0, 3, 0}, Vec3{0, 3, 0}}, kBoxXMin | kBoxZMin, {{1, 0, 0}, {0, 0, 1}}},
      {{Vec3{0, 39, 4}, Vec3{0, 39, 6}, Vec3{0, 39, 5}}, kBoxXMin | kBoxYMax, {{1, 0, 0}, {0, -1, 0}}},
      {{Vec3{0, 39, 6}, Vec3{0, 39, 4}, Vec3{0, 39, 5}}, kBoxXMin | kBoxYMax, {{1, 0, 0}, {0, -1, 0}}},
      {{Vec3{0, 39, 0}, Vec3{0, 39, 0}, Vec3{0, 39, 0}}, kBoxXMin | kBoxYMax | kBoxZMin, {}},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    MeshStore s;
    std::array<VertexId, 3> v;
    for (int k = 0; k < 3; ++k) v[k] = s.AddVertex(c.corners[k], 0, 0, c.box);
    s.AddTriangle(v[0], v[1], v[2]);
    ASSERT_EQ(CountDegenerate(s), 1) << i;
    const DegenerateCounts n = Tidy(&s);
    const Vec3 area = TwiceAreaVector(s.position(v[0]), s.position(v[1]), s.position(v[2]));
    if (c.inward.empty()) {
      EXPECT_EQ(n.left, 1) << i;
      for (int k = 0; k < 3; ++k) EXPECT_EQ(s.position(v[k]), c.corners[k]) << i;
      continue;
    }
    EXPECT_EQ(n.left, 0) << i;
    EXPECT_EQ(CountDegenerate(s), 0) << i;
    int within = 0;  // faces it still lies in, facing into the box
    for (const Vec3& f : c.inward) {
      bool on = Dot(area, f) > 0;
      for (int k = 0; k < 3; ++k) {
        const Vec3 p = s.position(v[k]);
        const double off = Dot(p, f) - Dot(c.corners[k], f);
        EXPECT_GE(off, 0) << i;  // never out of the box
        on = on && off == 0;
        // A corner that left a face has lost its flag; the others keep theirs.
        const uint8_t bit = f.x > 0 ? kBoxXMin : f.y < 0 ? kBoxYMax : f.z > 0 ? kBoxZMin : kBoxXMax;
        EXPECT_EQ((s.box_mask(v[k]) & bit) != 0, off == 0) << i << " " << k;
      }
      within += on;
    }
    EXPECT_EQ(within, 1) << i;
    for (int k = 0; k < 3; ++k) {
      EXPECT_LE(Norm(s.position(v[k]) - c.corners[k]), 0.1 + 1e-12) << i;  // Tidy's size
    }
  }
}

}  // namespace
}  // namespace tandem
