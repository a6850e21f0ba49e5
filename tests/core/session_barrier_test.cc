// A session's geometry and failure barrier (tandem.h): extreme grids are refused with a
// message, results do not depend on where the grid sits or on its unit, and an exception
// anywhere inside a session (a failed allocation, on any of its threads) becomes that
// session's status instead of ending the process.
//
// The failure injection replaces the global operator new of this test program: once armed
// with n, the n-th allocation after arming throws std::bad_alloc (once), whatever thread
// makes it.
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tandem/eval/synthetic.h"
#include "tandem/tandem.h"
#include "tandem/eval/topology.h"
#include "tandem/volume.h"

// The replaced operator new allocates with malloc, so its delete frees with free; GCC 12
// cannot see the pair through inlining and warns about every sized delete.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif

namespace {
std::atomic<int64_t> g_fail_in{-1};  // allocations left before the injected failure; < 0: off
}  // namespace

void* operator new(std::size_t n) {
  if (g_fail_in.load(std::memory_order_relaxed) >= 0 &&
      g_fail_in.fetch_sub(1, std::memory_order_relaxed) == 0) {
    throw std::bad_alloc();
  }
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

namespace tandem {
namespace {

// Every slice of a synthetic shape, as floats, so that feeding a session allocates nothing
// outside it.
std::vector<std::vector<float>> Slices(eval::Shape shape, int64_t n, int64_t nz) {
  auto src = eval::MakeSyntheticSource(shape, n, n, nz);
  std::vector<std::vector<float>> out;
  std::vector<uint8_t> bytes;
  while (src->ReadSlice(&bytes).ok()) {
    out.emplace_back(static_cast<size_t>(n * n));
    ConvertToFloat(src->info().dtype, bytes.data(), out.back().size(), out.back().data());
  }
  return out;
}

struct Outcome {
  absl::Status status;
  IndexedMesh mesh;
  double error_max = 0;
};

Outcome RunGrid(const VolumeInfo& grid, const SessionOptions& o,
            const std::vector<std::vector<float>>& slices) {
  Outcome r;
  auto s = TandemSession::Create(grid, o);
  if (!s.ok()) {
    r.status = s.status();
    return r;
  }
  for (const auto& slice : slices) {
    r.status = (*s)->AddSlice(slice.data());
    if (!r.status.ok()) return r;
  }
  r.status = (*s)->Finish();
  if (r.status.ok()) {
    r.mesh = (*s)->Snapshot();
    r.error_max = (*s)->MaxShapeError();
  }
  return r;
}

VolumeInfo Grid(int64_t n, int64_t nz, std::array<double, 3> spacing,
                std::array<double, 3> origin = {0, 0, 0}) {
  VolumeInfo g;
  g.nx = g.ny = n;
  g.nz = nz;
  g.dtype = DType::kFloat32;
  g.spacing = spacing;
  g.origin = origin;
  return g;
}

TEST(Geometry, ExtremeGridsAreRefusedWithTheField) {
  struct Case {
    std::array<double, 3> spacing, origin;
    const char* text;
  };
  for (const Case& c : {Case{{1e160, 1e160, 1}, {0, 0, 0}, "invalid spacing 1e+160 on axis 0"},
                        Case{{1e-300, 1e-300, 1e-300}, {0, 0, 0}, "invalid spacing 1e-300"},
                        Case{{1, 1, 2e4}, {0, 0, 0}, "times longer on one axis"},
                        Case{{1, 1, 1}, {0, 1e30, 0}, "invalid origin 1e+30 on axis 1"},
                        Case{{0.5, 0.5, 0.5}, {0, 0, -6e5}, "invalid origin -600000 on axis 2"}}) {
    const VolumeInfo g = Grid(16, 16, c.spacing, c.origin);
    const absl::Status st = ValidateVolumeInfo(g);
    EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << c.text;
    EXPECT_NE(st.message().find(c.text), std::string_view::npos) << st.message();
    SessionOptions o;
    o.error = 0.1;
    EXPECT_EQ(TandemSession::Create(g, o).status().code(), absl::StatusCode::kInvalidArgument);
  }
  // E0 relative to the spacing.
  SessionOptions o;
  const VolumeInfo g = Grid(16, 16, {0.5, 0.5, 2});
  o.error = 1e-7;
  EXPECT_NE(o.ValidateFor(g).message().find("smallest voxel spacing (0.5)"), std::string::npos)
      << o.ValidateFor(g);
  o.error = 3e6;
  EXPECT_NE(o.ValidateFor(g).message().find("largest voxel spacing (2)"), std::string::npos);
  o.error = 0.3;
  EXPECT_TRUE(o.ValidateFor(g).ok());
  o.schedule = Schedule::kNone;  // E0 unused
  o.error = 0;
  EXPECT_TRUE(o.ValidateFor(g).ok());
}

// `r` is `base` times `unit`, bit for bit: the same triangles, every coordinate and the
// error bound reached multiplied.
void ExpectScaledBy(const Outcome& r, const Outcome& base, double unit) {
  SCOPED_TRACE(unit);
  ASSERT_TRUE(r.status.ok()) << r.status;
  EXPECT_EQ(r.mesh.indices, base.mesh.indices);
  ASSERT_EQ(r.mesh.positions.size(), base.mesh.positions.size());
  for (size_t i = 0; i < base.mesh.positions.size(); ++i) {
    ASSERT_EQ(r.mesh.positions[i].x, base.mesh.positions[i].x * unit) << i;
    ASSERT_EQ(r.mesh.positions[i].y, base.mesh.positions[i].y * unit) << i;
    ASSERT_EQ(r.mesh.positions[i].z, base.mesh.positions[i].z * unit) << i;
  }
  EXPECT_EQ(r.error_max, base.error_max * unit);
}

// The engine works relative to the grid: moving the grid moves the mesh and nothing else,
// and changing the unit by a power of two scales it exactly (the quadrics, costs and
// queues see the same numbers). Only the surface points' offset from the grid points grows
// where float32 holds fewer digits of the coordinates (EdgeOffset): far off, the mesh keeps
// its topology and error bound.
TEST(Geometry, MeshDoesNotDependOnOriginOrUnit) {
  const auto slices = Slices(eval::Shape::kPillowBox, 48, 48);
  SessionOptions o;
  o.error = 0.2;
  const Outcome base = RunGrid(Grid(48, 48, {1, 1, 1}), o, slices);
  ASSERT_TRUE(base.status.ok()) << base.status;
  ASSERT_GT(base.mesh.num_triangles(), 100u);
  const eval::TopologyReport topology = eval::AnalyzeTopology(base.mesh);

  const std::array<double, 3> far{1e5, -7e5, 3.25e5};
  const Outcome far_off = RunGrid(Grid(48, 48, {1, 1, 1}, far), o, slices);
  ASSERT_TRUE(far_off.status.ok()) << far_off.status;
  const eval::TopologyReport far_topology = eval::AnalyzeTopology(far_off.mesh);
  EXPECT_TRUE(far_topology.IsClosedManifold());
  EXPECT_EQ(far_topology.euler, topology.euler);
  EXPECT_EQ(far_topology.components, topology.components);
  EXPECT_LE(far_off.error_max, o.error);

  // Within 1,000 voxels of 0 the offset is its floor.
  const std::array<double, 3> origin{-900.5, 640.25, 333};
  const Outcome moved = RunGrid(Grid(48, 48, {1, 1, 1}, origin), o, slices);
  ASSERT_TRUE(moved.status.ok()) << moved.status;
  EXPECT_EQ(moved.mesh.indices, base.mesh.indices);
  ASSERT_EQ(moved.mesh.positions.size(), base.mesh.positions.size());
  for (size_t i = 0; i < base.mesh.positions.size(); ++i) {
    const Vec3 want = base.mesh.positions[i] + Vec3{origin[0], origin[1], origin[2]};
    ASSERT_EQ(moved.mesh.positions[i].x, want.x) << i;
    ASSERT_EQ(moved.mesh.positions[i].y, want.y) << i;
    ASSERT_EQ(moved.mesh.positions[i].z, want.z) << i;
  }
  EXPECT_EQ(moved.error_max, base.error_max);

  for (double unit : {0x1p-36, 0x1p30}) {
    SessionOptions scaled = o;
    scaled.error = o.error * unit;
    ExpectScaledBy(RunGrid(Grid(48, 48, {unit, unit, unit}), scaled, slices), base, unit);
  }
}

// What a change of unit keeps, exactly: by a power of two (spacing, origin and E0 all
// multiplied by it) the mesh is the same mesh multiplied, bit for bit, for any spacing and
// origin; by another factor (millimetres to metres or inches) the frame's numbers round
// differently, which can reorder contractions of equal cost: the mesh keeps its guarantees
// (closed manifold, topology, Error(K) <= E0) and about its size, not its triangles.
TEST(Geometry, AUnitChangeIsExactByAPowerOfTwoAndKeepsTheGuaranteesOtherwise) {
  const auto slices = Slices(eval::Shape::kPillowBox, 48, 48);
  const std::array<double, 3> spacing{0.7, 0.7, 1.3};
  const std::array<double, 3> origin{-12.5, 30.25, 7};
  SessionOptions o;
  o.error = 0.05;
  const Outcome base = RunGrid(Grid(48, 48, spacing, origin), o, slices);
  ASSERT_TRUE(base.status.ok()) << base.status;
  const eval::TopologyReport topology = eval::AnalyzeTopology(base.mesh);
  ASSERT_TRUE(topology.IsClosedManifold());
  const double triangles = static_cast<double>(base.mesh.num_triangles());
  ASSERT_GT(triangles, 100);
  auto scaled = [&](const std::array<double, 3>& v, double unit) {
    return std::array<double, 3>{v[0] * unit, v[1] * unit, v[2] * unit};
  };
  for (double unit : {0x1p-10, 0x1p7}) {
    SessionOptions so = o;
    so.error = o.error * unit;
    ExpectScaledBy(RunGrid(Grid(48, 48, scaled(spacing, unit), scaled(origin, unit)), so, slices),
                   base, unit);
  }
  for (double unit : {1e-3, 1 / 25.4, 1000.0}) {
    SCOPED_TRACE(unit);
    SessionOptions so = o;
    so.error = o.error * unit;
    const Outcome r =
        RunGrid(Grid(48, 48, scaled(spacing, unit), scaled(origin, unit)), so, slices);
    ASSERT_TRUE(r.status.ok()) << r.status;
    const eval::TopologyReport t = eval::AnalyzeTopology(r.mesh);
    EXPECT_TRUE(t.IsClosedManifold());
    EXPECT_EQ(t.euler, topology.euler);
    EXPECT_EQ(t.components, topology.components);
    EXPECT_LE(r.error_max, so.error);
    const double change = std::abs(static_cast<double>(r.mesh.num_triangles()) / triangles - 1);
    EXPECT_LT(change, 0.05) << r.mesh.num_triangles() << " vs " << triangles;
    std::printf("unit %g: %zu triangles (%zu at unit 1), change %.2f %%, indices %s\n", unit,
                r.mesh.num_triangles(), base.mesh.num_triangles(), 100 * change,
                r.mesh.indices == base.mesh.indices ? "equal" : "differ");
  }
}

// A grid far finer across than between its slices puts the reach of most edges thousands
// of slices ahead (rad is counted in slice units): they wait outside the release buckets,
// which stay small, and the result keeps every guarantee.
TEST(Geometry, HighlyAnisotropicGridKeepsTheGuarantees) {
  const auto slices = Slices(eval::Shape::kSphere, 32, 32);
  SessionOptions o;
  o.error = 5;
  const VolumeInfo g = Grid(32, 32, {500, 500, 0.05});
  auto s = TandemSession::Create(g, o);
  ASSERT_TRUE(s.ok()) << s.status();
  size_t peak = 0;
  for (const auto& slice : slices) {
    ASSERT_TRUE((*s)->AddSlice(slice.data()).ok());
    peak = std::max(peak, (*s)->MemoryBytes());
  }
  ASSERT_TRUE((*s)->Finish().ok());
  EXPECT_LT(peak, size_t{16} << 20);
  EXPECT_LE((*s)->MaxShapeError(), o.error);
  const eval::TopologyReport t = eval::AnalyzeTopology((*s)->Snapshot());
  EXPECT_TRUE(t.IsClosedManifold());
  EXPECT_EQ(t.euler, 2);
}

// Every allocation of a session, one at a time, fails: the call that ran into it returns
// RESOURCE_EXHAUSTED, every later call the same, and the process carries on (a split
// session's worker threads included).
TEST(Barrier, AFailedAllocationAnywhereEndsOnlyTheSession) {
  struct Case {
    int64_t n;
    int parts;
    bool pipeline;
  };
  for (const Case& c : {Case{24, 1, false}, Case{24, 1, true}, Case{72, 4, true}}) {
    const auto slices = Slices(eval::Shape::kLink, c.n, 20);
    SessionOptions o;
    o.error = 0.2;
    o.parts = c.parts;
    o.pipeline = c.pipeline;
    const VolumeInfo g = Grid(c.n, 20, {1, 1, 1});
    const Outcome clean = RunGrid(g, o, slices);
    ASSERT_TRUE(clean.status.ok()) << clean.status;
    int failed = 0;
    bool reached_end = false;
    for (int64_t k = 0; k < 4000 && !reached_end; k += (k < 200 ? 1 : 37)) {
      auto s = TandemSession::Create(g, o);
      ASSERT_TRUE(s.ok());
      std::vector<absl::Status> status;
      status.reserve(slices.size() + 2);
      g_fail_in.store(k);
      for (const auto& slice : slices) status.push_back((*s)->AddSlice(slice.data()));
      status.push_back((*s)->Finish());
      status.push_back((*s)->AddSlice(slices[0].data()));  // after a failure: the same status
      const bool injected = g_fail_in.exchange(-1) < 0;
      size_t first = 0;
      while (first < status.size() && status[first].ok()) ++first;
      if (!injected) {
        reached_end = true;
        EXPECT_EQ(first, status.size() - 1) << "k=" << k;  // only the AddSlice after Finish
        continue;
      }
      if (first == status.size()) continue;  // the failure hit an allocation that was caught
      ++failed;
      EXPECT_EQ(status[first].code(), absl::StatusCode::kResourceExhausted)
          << "k=" << k << " parts=" << c.parts << ": " << status[first];
      for (size_t i = first + 1; i < status.size(); ++i) {
        EXPECT_EQ(status[i], status[first]) << "k=" << k << " call " << i;
      }
    }
    EXPECT_TRUE(reached_end) << "parts=" << c.parts;
    EXPECT_GT(failed, 10) << "parts=" << c.parts;
  }
}

}  // namespace
}  // namespace tandem
