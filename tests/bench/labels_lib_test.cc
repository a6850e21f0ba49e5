// The segmentation benchmark's own measures (labels_lib.h): the gap between touching labels,
// the interface samples, the reference surfaces and the generated label volumes.
#include "labels_lib.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <set>

#include "tandem/eval/topology.h"

namespace labels {
namespace {

using tandem::IndexedMesh;
using tandem::eval::TriangleBvh;
using tandem::Vec3;

// An axis-aligned box as 12 triangles.
IndexedMesh Box(Vec3 lo, Vec3 hi) {
  IndexedMesh m;
  for (int c = 0; c < 8; ++c) {
    m.positions.push_back({c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z});
  }
  const uint32_t quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                                {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.indices.insert(m.indices.end(), {q[0], q[1], q[2], q[0], q[2], q[3]});
  }
  return m;
}

IndexedMesh Shifted(IndexedMesh m, Vec3 by) {
  for (Vec3& p : m.positions) p = p + by;
  return m;
}

TEST(GapTest, CubesSharingAFaceHaveNoGap) {
  const TriangleBvh a(Box({0, 0, 0}, {1, 1, 1}));
  const TriangleBvh b(Box({1, 0, 0}, {2, 1, 1}));
  for (Vec3 p : {Vec3{1, 0.5, 0.5}, Vec3{1, 0.1, 0.9}, Vec3{1.2, 0.5, 0.5}}) {
    EXPECT_NEAR(GapAt(a, b, p), 0.0, 1e-12) << p.x << " " << p.y << " " << p.z;
  }
}

TEST(GapTest, CubesHalfApartHaveAGapOfOneHalf) {
  const TriangleBvh a(Box({0, 0, 0}, {1, 1, 1}));
  const TriangleBvh b(Box({1.5, 0, 0}, {2.5, 1, 1}));
  EXPECT_NEAR(GapAt(a, b, {1.25, 0.5, 0.5}), 0.5, 1e-12);
  EXPECT_NEAR(GapAt(a, b, {1.0, 0.3, 0.7}), 0.5, 1e-12);
  // Symmetric in the two labels.
  EXPECT_NEAR(GapAt(b, a, {1.25, 0.5, 0.5}), 0.5, 1e-12);
}

TEST(GapTest, ASampleBeyondTheReachOfASurfaceIsNotCounted) {
  const TriangleBvh a(Box({0, 0, 0}, {1, 1, 1}));
  const TriangleBvh b(Box({1.5, 0, 0}, {2.5, 1, 1}));
  ASSERT_TRUE(GapWithin(a, b, {1.25, 0.5, 0.5}, 0.3).has_value());
  EXPECT_NEAR(*GapWithin(a, b, {1.25, 0.5, 0.5}, 0.3), 0.5, 1e-12);
  EXPECT_FALSE(GapWithin(a, b, {1.25, 0.5, 0.5}, 0.2).has_value());
  EXPECT_FALSE(GapWithin(a, b, {1.1, 0.5, 0.5}, 0.3).has_value());  // 0.4 from b
}

TEST(GapTest, AGapOnOneSideOnlyCounts) {
  // b covers a's face only partly: from p, a's nearest point is on the face, b's is 0.25 off.
  const TriangleBvh a(Box({0, 0, 0}, {1, 1, 1}));
  const TriangleBvh b(Box({1, 0, 0}, {2, 0.25, 1}));
  EXPECT_NEAR(GapAt(a, b, {1, 0.5, 0.5}), 0.25, 1e-12);
}

// x < split: label a, else b; a third label c in one corner block when asked.
LabelVolume TwoBlocks(int64_t n, int64_t split, uint32_t a, uint32_t b, uint32_t c = 0) {
  LabelVolume v;
  v.nx = v.ny = v.nz = n;
  v.spacing = {1, 1, 2};
  v.ids.resize(size_t(n * n * n));
  for (int64_t k = 0; k < n; ++k)
    for (int64_t j = 0; j < n; ++j)
      for (int64_t i = 0; i < n; ++i)
        v.ids[v.Index(i, j, k)] = (c != 0 && j < 2 && k < 2) ? c : (i < split ? a : b);
  return v;
}

TEST(InterfaceTest, SamplesLieOnTheInterfaceAwayFromOtherLabels) {
  const LabelVolume v = TwoBlocks(10, 5, 70000, 9, 123456);
  const auto pairs = InterfaceSamples(v, 1000, {2, 2, 2});
  // Pairs (9, 70000), (9, 123456), (70000, 123456), in increasing order.
  ASSERT_EQ(pairs.size(), 3u);
  EXPECT_EQ(pairs[0].a, 9u);
  EXPECT_EQ(pairs[0].b, 70000u);
  EXPECT_EQ(pairs[1].b, 123456u);
  EXPECT_EQ(pairs[0].faces, 10 * 10 - 4);  // the x = 4.5 plane, less the corner block's 4
  EXPECT_FALSE(pairs[0].points.empty());
  for (const Vec3& p : pairs[0].points) {
    EXPECT_DOUBLE_EQ(p.x, 4.5);
    // No voxel of label c within 2 voxels: j <= 1 and k <= 1 hold c, so y >= 4 or z >= 4 voxels.
    EXPECT_TRUE(p.y >= 4 || p.z >= 2 * 4) << p.y << " " << p.z;
  }
  EXPECT_EQ(InterfaceSamples(v, 5, {2, 2, 2})[0].points.size(), 5u);
  // A wider margin along y keeps samples farther from the corner block.
  for (const Vec3& p : InterfaceSamples(v, 1000, {2, 4, 2})[0].points) {
    EXPECT_TRUE(p.y >= 6 || p.z >= 2 * 4) << p.y << " " << p.z;
  }
}

TEST(InterfaceTest, MarginFollowsAPhysicalLengthPerAxis) {
  LabelVolume v;
  v.spacing = {4, 4, 40};
  EXPECT_EQ(MarginFor(v, 2, 12), (Margin{3, 3, 2}));
  EXPECT_EQ(MarginFor(v, 2, 0), (Margin{2, 2, 2}));
  EXPECT_EQ(MarginFor(v, 1, 81), (Margin{21, 21, 3}));
}

TEST(InterfaceTest, ReferenceSurfacesOfTouchingLabelsHaveNoGap) {
  const LabelVolume v = TwoBlocks(8, 4, 5, 3000000000u);
  const auto boxes = LabelBoxes(v);
  ASSERT_EQ(boxes.size(), 2u);
  const IndexedMesh ma = ReferenceSurface(v, boxes[0]);
  const IndexedMesh mb = ReferenceSurface(v, boxes[1]);
  ASSERT_GT(ma.num_triangles(), 0u);
  const TriangleBvh a(ma), b(mb);
  const TriangleBvh b_moved(Shifted(mb, {0.5, 0, 0}));
  const auto pairs = InterfaceSamples(v, 64, {2, 2, 2});
  ASSERT_EQ(pairs.size(), 1u);
  ASSERT_FALSE(pairs[0].points.empty());
  for (const Vec3& p : pairs[0].points) {
    EXPECT_NEAR(GapAt(a, b, p), 0.0, 1e-9);
    EXPECT_NEAR(GapAt(a, b_moved, p), 0.5, 1e-9);
  }
}

TEST(ReferenceTest, OneVoxelIsAClosedManifold) {
  LabelVolume v;
  v.nx = v.ny = v.nz = 5;
  v.ids.assign(125, 0);
  v.ids[v.Index(2, 2, 2)] = 77;
  const auto boxes = LabelBoxes(v);
  ASSERT_EQ(boxes.size(), 1u);
  EXPECT_EQ(boxes[0].voxels, 1);
  const IndexedMesh m = ReferenceSurface(v, boxes[0]);
  const tandem::eval::TopologyReport t = tandem::eval::AnalyzeTopology(m);
  EXPECT_EQ(m.num_triangles(), 8u);  // the octahedron of the 6 edge midpoints
  EXPECT_TRUE(t.IsClosedManifold());
  EXPECT_EQ(t.euler, 2);
}

// Every voxel lies in a cell whose seed is nearest to it (ties aside), z distances counted
// 1 / elongation.
void ExpectNearestCells(const LabelVolume& v, const VoronoiCells& cells, double elongation) {
  auto dist = [&](Vec3 a, Vec3 b) {
    Vec3 d = a - b;
    d.z /= elongation;
    return tandem::Norm(d);
  };
  for (int64_t k = 0; k < v.nz; ++k) {
    for (int64_t j = 0; j < v.ny; ++j) {
      for (int64_t i = 0; i < v.nx; ++i) {
        const Vec3 p = v.Position(i, j, k);
        double best = INFINITY;
        for (const Vec3& s : cells.seeds) best = std::min(best, dist(s, p));
        const uint32_t id = v.At(i, j, k);
        bool nearest = false;
        for (size_t s = 0; s < cells.seeds.size(); ++s) {
          nearest |= cells.ids[s] == id && dist(cells.seeds[s], p) <= best + 1e-9;
        }
        ASSERT_TRUE(nearest) << i << " " << j << " " << k;
      }
    }
  }
}

TEST(VoronoiTest, IdsAreUniqueScatteredAndEachVoxelIsInItsNearestCell) {
  VoronoiOptions o;
  o.nx = 40;
  o.ny = 36;
  o.nz = 12;
  o.cells = 60;
  o.wobble = 0;  // plain Voronoi cells, to check against the nearest seed
  o.background_fraction = 0.2;
  VoronoiCells cells;
  const LabelVolume v = MakeVoronoi(o, &cells);
  ASSERT_EQ(cells.ids.size(), 60u);
  std::set<uint32_t> distinct;
  int background_cells = 0;
  for (uint32_t id : cells.ids) {
    if (id == 0) {
      ++background_cells;
    } else {
      EXPECT_TRUE(distinct.insert(id).second) << "id " << id << " twice";
    }
  }
  EXPECT_GT(background_cells, 0);
  EXPECT_LT(background_cells, 30);
  // Scattered over uint32: not 1..N, and spread far beyond 16 bits.
  EXPECT_GT(*distinct.rbegin(), uint32_t{1} << 24);
  EXPECT_GT(*distinct.rbegin() - *distinct.begin(), 1000u * distinct.size());
  ExpectNearestCells(v, cells, 1);
  // The same seed gives the same volume; the labels in it are those of the cells.
  EXPECT_EQ(MakeVoronoi(o).ids, v.ids);
  for (const LabelBox& b : LabelBoxes(v)) EXPECT_TRUE(distinct.count(b.id)) << b.id;
}

TEST(VoronoiTest, ElongatedCellsAreNearestWithZShrunk) {
  VoronoiOptions o;
  o.nx = 30;
  o.ny = 30;
  o.nz = 16;
  o.cells = 40;
  o.wobble = 0;
  o.elongation = 3;
  VoronoiCells cells;
  const LabelVolume v = MakeVoronoi(o, &cells);
  ExpectNearestCells(v, cells, 3);
}

TEST(VoronoiTest, SixteenBitIdsFit) {
  VoronoiOptions o;
  o.nx = o.ny = 24;
  o.nz = 6;
  o.cells = 30;
  o.max_id = UINT16_MAX;
  const LabelVolume v = MakeVoronoi(o);
  for (uint32_t id : v.ids) EXPECT_LE(id, UINT16_MAX);
  EXPECT_GT(LabelBoxes(v).size(), 10u);
}

TEST(VolumeFileTest, RoundTripsAndRefusesIdsTooLarge) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");  // the sessions of other tests left threads
  const std::string dir = ::testing::TempDir() + "/labels_lib_test";
  std::filesystem::create_directories(dir);
  const LabelVolume v = TwoBlocks(6, 3, 4000000000u, 12);
  WriteLabelVolume(dir + "/v32.json", v, "uint32");
  nlohmann::json sidecar;
  const LabelVolume back = ReadLabelVolume(dir + "/v32.json", &sidecar);
  EXPECT_EQ(sidecar["dtype"], "uint32");
  EXPECT_EQ(sidecar["raw_bytes"], 6 * 6 * 6 * 4);
  EXPECT_EQ(back.ids, v.ids);
  EXPECT_EQ(back.spacing, v.spacing);
  EXPECT_EXIT(WriteLabelVolume(dir + "/v16.json", v, "uint16"), ::testing::ExitedWithCode(1),
              "label 4000000000 does not fit uint16");
}

TEST(BandTest, BandsSplitIntoComponentsSmallOnesDropped) {
  LabelVolume ct;
  ct.nx = ct.ny = 12;
  ct.nz = 4;
  ct.ids.assign(12 * 12 * 4, 10);
  auto fill = [&](int64_t i0, int64_t i1, uint32_t value) {
    for (int64_t k = 0; k < 4; ++k)
      for (int64_t j = 0; j < 12; ++j)
        for (int64_t i = i0; i < i1; ++i) ct.ids[ct.Index(i, j, k)] = value;
  };
  fill(0, 3, 100);                   // band 1, one component
  fill(5, 8, 100);                   // band 1, a second one
  fill(8, 10, 250);                  // band 2, touching the second
  ct.ids[ct.Index(11, 0, 0)] = 100;  // band 1, one voxel: below min_voxels
  const LabelVolume v = BandComponents(ct, {60, 200}, 2, 100, UINT32_MAX, 7);
  const auto boxes = LabelBoxes(v);
  ASSERT_EQ(boxes.size(), 3u);
  EXPECT_EQ(v.At(11, 0, 0), 0u);
  EXPECT_EQ(v.At(4, 0, 0), 0u);
  EXPECT_NE(v.At(0, 0, 0), v.At(6, 0, 0));
  EXPECT_NE(v.At(6, 0, 0), v.At(9, 0, 0));
  EXPECT_EQ(v.At(0, 0, 0), v.At(2, 11, 3));
}

}  // namespace
}  // namespace labels
