#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <numbers>
#include <tuple>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "engine_testutil.h"
#include "id_index.h"
#include "mesh_store.h"
#include "quadric.h"
#include "sag_correction.h"
#include "tandem/eval/distance.h"
#include "tandem/eval/synthetic.h"
#include "tandem/io/run_session.h"
#include "tandem/tandem.h"
#include "tandem/eval/topology.h"

namespace tandem {
namespace {

// The sag correction (SessionOptions::sag_correction) on a curved surface: the same mesh
// (count, topology, every guarantee) with its vertices moved, so that it no longer leans to
// the concave side; the RMS distance to the full-resolution surface falls by a tenth (12%
// here; docs/decisions.md has the benchmark's figures), Hausdorff too.
TEST(SagCorrection, BringsACurvedSurfaceCloserWithTheSameMesh) {
  const int n = 128;
  const IndexedMesh reference =
      FullSurface(*eval::MakeSyntheticSource(eval::Shape::kLink, n, n, n));
  auto run = [&](double fraction) {
    SessionOptions o;
    o.error = 0.048;
    o.sag_correction = fraction;
    auto src = eval::MakeSyntheticSource(eval::Shape::kLink, n, n, n);
    auto session = io::RunSession(*src, o);
    EXPECT_TRUE(session.ok()) << session.status();
    EXPECT_LE((*session)->MaxShapeError(), o.error) << fraction;
    return std::pair{(*session)->Snapshot(), (*session)->stats().sag_corrected};
  };
  const auto [off, moved_off] = run(0);
  const auto [on, moved_on] = run(0.3);
  EXPECT_EQ(moved_off, 0);
  EXPECT_GT(moved_on, int64_t(on.num_vertices()) / 2);
  ASSERT_EQ(on.num_triangles(), off.num_triangles());
  ASSERT_EQ(on.num_vertices(), off.num_vertices());
  EXPECT_TRUE(std::equal(on.indices.begin(), on.indices.end(), off.indices.begin()));
  const eval::TopologyReport t = eval::AnalyzeTopology(on);
  EXPECT_TRUE(t.IsClosedManifold());
  EXPECT_EQ(t.euler, 0);
  eval::DistanceOptions d;
  d.samples = 200000;
  const eval::Distances before = eval::MeasureDistances(reference, off, d);
  const eval::Distances after = eval::MeasureDistances(reference, on, d);
  EXPECT_LT(after.l2_max, 0.92 * before.l2_max) << before.l2_max << " -> " << after.l2_max;
  EXPECT_LT(after.linf_max, before.linf_max);
}

// Where the sag estimate does not describe a curvature, nothing moves: on a cube with sharp
// edges (flat faces have no sag; at the edges and corners the vertex normal averages faces
// at right angles, and moving along it would cut the edge) and on the grid's box, where the
// surface's boundary must stay.
TEST(SagCorrection, LeavesCreasesAndTheBoxAlone) {
  const int n = 48;
  const auto cube = [](double x, double y, double z) {
    return 15.3 - std::max({std::abs(x - 23.6), std::abs(y - 24.2), std::abs(z - 23.9)});
  };
  auto cube_run = [&](double fraction) {
    auto src = std::make_unique<FieldSource>(n, n, n, cube);
    SessionOptions o;
    o.error = 0.05;
    o.sag_correction = fraction;
    auto s = io::RunSession(*src, o);
    EXPECT_TRUE(s.ok()) << s.status();
    return std::pair{(*s)->Snapshot(), (*s)->stats().sag_corrected};
  };
  const auto [cube_off, cube_moved_off] = cube_run(0);
  const auto [cube_on, cube_moved] = cube_run(0.3);
  FieldSource full_src(n, n, n, cube);
  const IndexedMesh reference = FullSurface(full_src);
  eval::DistanceOptions d;
  d.samples = 100000;
  const double h_off = eval::MeasureDistances(reference, cube_off, d).linf_max;
  const double h_on = eval::MeasureDistances(reference, cube_on, d).linf_max;
  // At most two stray vertices on the chamfers marching cubes cuts along the edges, which
  // bend (which of them survive the simplification is up to the order ties pop in).
  EXPECT_LE(cube_moved, 2) << cube_moved << " of " << cube_on.num_vertices();
  EXPECT_LE(h_on, h_off * (1 + 1e-6)) << h_off << " -> " << h_on;
  EXPECT_TRUE(eval::AnalyzeTopology(cube_on).IsClosedManifold());

  auto run = [&](double fraction) {
    SessionOptions g;
    g.error = 0.05;
    g.sag_correction = fraction;
    auto src = BoxCutGyroid(40, 40, 40);
    auto s = io::RunSession(*src, g);
    EXPECT_TRUE(s.ok()) << s.status();
    return std::pair{(*s)->Snapshot(), (*s)->stats().sag_corrected};
  };
  const auto [off, moved_off] = run(0);
  const auto [on, moved_on] = run(0.3);
  EXPECT_GT(moved_on, 0);
  ASSERT_EQ(on.num_vertices(), off.num_vertices());
  size_t on_box = 0, moved = 0;
  for (size_t v = 0; v < on.num_vertices(); ++v) {
    const Vec3 p = off.positions[v];
    bool box = false;
    for (int a = 0; a < 3; ++a) box |= p[a] == 0.0 || p[a] == 39.0;
    on_box += box;
    if (box) {
      EXPECT_EQ(on.positions[v], p) << v;
    } else {
      moved += !(on.positions[v] == p);
    }
  }
  EXPECT_GT(on_box, 100u);
  EXPECT_EQ(int64_t(moved), moved_on);
}

// ---------------------------------------------------------------- CorrectSagAt on a hand mesh

// A hexagonal dome: vertex 0 at height h above a unit ring. Its fan is convex, so its sag is
// toward the outside: it moves up along its normal, by no more than `fraction` of the mean
// sag, and stays where it is on a flat fan, on the box, or with fraction 0.
struct Dome {
  MeshStore store;
  std::vector<VertexId> v;
  // spare_ids: vertices with no triangle made first, so that the dome's ids come after them.
  explicit Dome(double h, uint8_t box = 0, int spare_ids = 0) {
    for (int i = 0; i < spare_ids; ++i) store.AddVertex({0, 0, -1}, 0, 0, 0);
    v.push_back(store.AddVertex({0, 0, h}, 0, 0, box));
    for (int k = 0; k < 6; ++k) {
      const double t = k * std::numbers::pi / 3.0;
      v.push_back(store.AddVertex({std::cos(t), std::sin(t), 0}, 0, 0, 0));
    }
    for (int k = 1; k <= 6; ++k) store.AddTriangle(v[0], v[k], v[k % 6 + 1]);
  }
  // Corrects vertex 0 only; returns the number moved.
  int64_t Correct(double fraction, double error, std::vector<VertexId>* moved,
                  SagScratch* kept = nullptr) {
    std::vector<Vec3> normal(store.vertex_capacity());
    VertexNormals(store, v, normal);
    Quadric q;
    for (TriId t : store.vertex_triangles(v[0])) {
      const auto& tri = store.triangle(t);
      q += PlaneQuadric(store.position(tri[0]), store.position(tri[1]), store.position(tri[2]));
    }
    SagScratch scratch;
    const VertexId only[] = {v[0]};
    const Quadric quadrics[] = {q};
    return CorrectSagAt(&store, only, normal, quadrics, fraction, error, kept ? kept : &scratch,
                        moved);
  }
};

TEST(SagCorrection, MovesAConvexFanOutwardWithinTheLimits) {
  Dome dome(0.3);
  std::vector<VertexId> moved;
  EXPECT_EQ(dome.Correct(0.3, 1.0, &moved), 1);
  EXPECT_EQ(moved, std::vector<VertexId>{dome.v[0]});
  const Vec3 p = dome.store.position(dome.v[0]);
  EXPECT_NEAR(p.x, 0.0, 1e-12);
  EXPECT_NEAR(p.y, 0.0, 1e-12);
  EXPECT_GT(p.z, 0.3);
  EXPECT_LT(p.z, 0.6);
  // The ε0 limit: with E0 = 0 (and ε0 = 0 now, every plane through the vertex) it stays.
  Dome tight(0.3);
  moved.clear();
  EXPECT_EQ(tight.Correct(0.3, 0.0, &moved), 0);
  EXPECT_TRUE(moved.empty());
  EXPECT_EQ(tight.store.position(tight.v[0]), (Vec3{0, 0, 0.3}));
}

// A Seal corrects the few thousand vertices it freezes on a store of a million ids: the
// scratch that says which corners move is sized to that list, not to the ids (a 4-byte slot
// per id would cost the whole store's ids). The result is the same wherever the ids are.
TEST(SagCorrection, ScratchIsSizedToTheListNotToTheIds) {
  Dome near(0.3), far(0.3, 0, 200000);
  std::vector<VertexId> moved_near, moved_far;
  SagScratch scratch;
  EXPECT_EQ(near.Correct(0.3, 1.0, &moved_near), 1);
  EXPECT_EQ(far.Correct(0.3, 1.0, &moved_far, &scratch), 1);
  EXPECT_EQ(moved_far, std::vector<VertexId>{far.v[0]});
  EXPECT_EQ(far.store.position(far.v[0]), near.store.position(near.v[0]));
  EXPECT_LE(scratch.MemoryBytes(), 1024u);
}

TEST(IdIndex, FindsTheListedIdsInATableOrBySlot) {
  IdIndex index;
  const std::vector<VertexId> few = {7, 123456, 5, 99999, 7};  // 7 twice: its last index
  index.Assign(few, 1000000);
  EXPECT_EQ(index.Find(7), 4u);
  EXPECT_EQ(index.Find(123456), 1u);
  EXPECT_EQ(index.Find(5), 2u);
  EXPECT_EQ(index.Find(99999), 3u);
  for (VertexId v : {0u, 6u, 8u, 123457u, 999999u}) EXPECT_EQ(index.Find(v), kInvalid) << v;
  EXPECT_LE(index.MemoryBytes(), 256u);  // a table, not a slot per id
  // A list of a quarter of the ids or more: a slot per id, cleared for the next list.
  std::vector<VertexId> many;
  for (VertexId v = 0; v < 1000; v += 2) many.push_back(v);
  index.Assign(many, 1000);
  EXPECT_EQ(index.Find(998), 499u);
  EXPECT_EQ(index.Find(999), kInvalid);
  EXPECT_EQ(index.Find(7), kInvalid);
  index.Assign(few, 1000000);
  EXPECT_EQ(index.Find(0), kInvalid);
  EXPECT_EQ(index.Find(5), 2u);
  index.Clear();
  EXPECT_EQ(index.Find(5), kInvalid);
}

// IdMap against std::map under a random mix of inserts and erases (erasing moves later
// entries of a probe run back into the hole: every key must still be found after).
TEST(IdMap, AgreesWithAnOrderedMapUnderInsertsAndErases) {
  IdMap<uint32_t> map;
  std::map<VertexId, uint32_t> expected;
  uint64_t x = 12345;
  auto next = [&x] {
    x = x * 6364136223846793005u + 1442695040888963407u;
    return static_cast<uint32_t>(x >> 33);
  };
  for (int step = 0; step < 200000; ++step) {
    const VertexId v = next() % 5000;  // few keys: long runs, many collisions
    if (next() % 3 == 0) {
      map.Erase(v);
      expected.erase(v);
    } else {
      map.At(v) = static_cast<uint32_t>(step);
      expected[v] = static_cast<uint32_t>(step);
    }
    if (step % 1000 == 0) {
      ASSERT_EQ(map.size(), expected.size());
      for (VertexId k = 0; k < 5000; ++k) {
        const uint32_t* found = map.Find(k);
        const auto it = expected.find(k);
        ASSERT_EQ(found != nullptr, it != expected.end()) << k << " at step " << step;
        if (found != nullptr) {
          ASSERT_EQ(*found, it->second);
        }
      }
    }
  }
  EXPECT_LE(map.MemoryBytes(), 8192 * 8u);  // at most half full: 4096 to 8192 slots
}

TEST(SagCorrection, LeavesFlatFansBoxVerticesAndFractionZeroAlone) {
  for (auto [h, box, fraction] : {std::tuple{0.0, uint8_t{0}, 0.3}, std::tuple{0.3, uint8_t{kBoxZMax}, 0.3},
                                  std::tuple{0.3, uint8_t{0}, 0.0}}) {
    Dome dome(h, box);
    std::vector<VertexId> moved;
    EXPECT_EQ(dome.Correct(fraction, 1.0, &moved), 0) << h << " " << int(box) << " " << fraction;
    EXPECT_EQ(dome.store.position(dome.v[0]), (Vec3{0, 0, h}));
  }
}

}  // namespace
}  // namespace tandem
