// Sealing (sealer.h): chunks that never change, together the mesh; memory that follows the
// front, not the depth.
#include <algorithm>
#include <array>
#include <string>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <future>
#include <mutex>
#include <map>
#include <tuple>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>

#include "absl/strings/escaping.h"

#include "engine_testutil.h"
#include "tandem/task_group.h"
#include "thread_pool.h"
#include "tandem/io/mesh_io.h"
#include "sealer.h"
#include "slabs.h"
#include "tandem/budget.h"
#include "tandem/eval/synthetic.h"
#include "tandem/tandem.h"
#include "tandem/eval/topology.h"
#include "tandem/volume.h"

namespace tandem {
namespace {

struct SealRun {
  IndexedMesh mesh;  // Snapshot, or the welded chunks
  std::vector<SealedChunk> chunks;
  SessionStats stats;
  double error_max = 0;
  size_t peak_memory = 0;        // MemoryBytes, after every slice
  int64_t peak_held = 0;         // triangles held, after every slice
  int parts = 0;
  size_t chunks_before_finish = 0;
};

SealRun RunSealed(SliceSource& src, SessionOptions o,
                  std::shared_ptr<MemoryBudget> budget = nullptr) {
  SealRun r;
  auto s = TandemSession::Create(src.info(), o, nullptr, std::move(budget));
  EXPECT_TRUE(s.ok()) << s.status();
  if (!s.ok()) return r;
  std::vector<uint8_t> bytes;
  auto take = [&] {
    SealedChunk c;
    while ((*s)->TakeSealed(&c)) {
      r.chunks.push_back(std::move(c));
      // One call takes all there is (the server takes one chunk a slice), every slab's.
      EXPECT_EQ((*s)->sealed_pending(), 0);
    }
  };
  while (src.ReadSlice(&bytes).ok()) {
    EXPECT_TRUE((*s)->AddSliceBytes(src.info().dtype, bytes.data()).ok());
    take();
    r.peak_memory = std::max(r.peak_memory, (*s)->MemoryBytes());
    r.peak_held = std::max(r.peak_held, (*s)->num_triangles());
  }
  r.parts = (*s)->num_parts();
  r.chunks_before_finish = r.chunks.size();
  EXPECT_TRUE((*s)->Finish().ok());
  take();
  r.stats = (*s)->stats();
  r.error_max = (*s)->MaxShapeError();
  r.mesh = o.seal ? WeldChunks(r.chunks) : (*s)->Snapshot();
  if (o.seal) {
    EXPECT_EQ((*s)->num_triangles(), 0);  // everything was handed out
  }
  return r;
}

SessionOptions Options(Schedule schedule, double e0, bool seal) {
  SessionOptions o;
  o.schedule = schedule;
  o.error = e0;
  o.seal = seal;
  o.parts = 1;
  // A sealed stream runs the paper's lock-step at E0 (its chunks cannot wait for a finishing
  // pass), and so does the plain session it is compared with.
  o.lockstep_error = 1;
  return o;
}

std::vector<int64_t> Sorted(std::vector<int64_t> v) {
  std::sort(v.begin(), v.end());
  return v;
}

// The welded chunks against the plain session's mesh: a closed manifold of the same topology,
// within the error bound, and within `count_tolerance` of its triangle count, all of them
// handed out. Returns the welded mesh's report.
eval::TopologyReport ExpectSealedLikePlain(const SealRun& plain, const SealRun& sealed, double e0,
                                           double count_tolerance, const std::string& what) {
  const eval::TopologyReport p = eval::AnalyzeTopology(plain.mesh),
                             s = eval::AnalyzeTopology(sealed.mesh);
  EXPECT_TRUE(s.IsClosedManifold()) << what;
  EXPECT_EQ(s.euler, p.euler) << what;
  EXPECT_EQ(Sorted(s.component_euler), Sorted(p.component_euler)) << what;
  // Where a voxel value equals the iso-value exactly, marching cubes puts several vertices
  // at that grid point; a contraction may not have merged them yet when they freeze
  // (the gyroid at E0 = 0.05: one pair, twice). Anything more would be a vertex handed
  // out under two ids.
  EXPECT_LE(eval::CountDuplicatePositions(sealed.mesh),
            eval::CountDuplicatePositions(plain.mesh) + 2)
      << what;
  EXPECT_LE(sealed.error_max, e0 * (1 + 1e-9)) << what;
  EXPECT_NEAR(static_cast<double>(s.triangles), static_cast<double>(p.triangles),
              count_tolerance * static_cast<double>(p.triangles)) << what;
  EXPECT_EQ(sealed.stats.sealed_triangles, static_cast<int64_t>(s.triangles)) << what;
  return s;
}

TEST(Sealing, ChunksWeldIntoAClosedManifoldWithTheSameTopologyAndCount) {
  for (eval::Shape shape :
       {eval::Shape::kSphere, eval::Shape::kLink, eval::Shape::kGyroid, eval::Shape::kPillowBox}) {
    for (double e0 : {0.05, 0.3}) {
      auto a = eval::MakeSyntheticSource(shape, 64, 64, 64);
      auto b = eval::MakeSyntheticSource(shape, 64, 64, 64);
      const SealRun plain = RunSealed(*a, Options(Schedule::kTandemLag, e0, false));
      const SealRun sealed = RunSealed(*b, Options(Schedule::kTandemLag, e0, true));
      const std::string what = std::string(eval::ShapeName(shape)) + " E0=" + std::to_string(e0);
      // Sealing freezes nothing a contraction could still want: the counts stay close.
      ExpectSealedLikePlain(plain, sealed, e0, 0.05, what);
      EXPECT_GT(sealed.chunks.size(), 8u) << what;  // handed out along the way, not at the end
    }
  }
}

TEST(Sealing, AVertexSharedByChunksHasOneIdAndBitIdenticalCoordinates) {
  auto src = eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 64, {0.7, 0.7, 1.3});
  const SealRun r = RunSealed(*src, Options(Schedule::kTandemLag, 0.1, true));
  std::map<uint32_t, Vec3> seen;
  size_t shared = 0;
  int64_t index = 0;
  for (const SealedChunk& c : r.chunks) {
    EXPECT_EQ(c.index, index++);
    ASSERT_EQ(c.ids.size(), c.positions.size());
    EXPECT_TRUE(std::is_sorted(c.ids.begin(), c.ids.end()));
    EXPECT_LE(c.first_slice, c.last_slice);
    for (uint32_t i : c.indices) ASSERT_LT(i, c.ids.size());
    for (size_t i = 0; i < c.ids.size(); ++i) {
      auto [it, fresh] = seen.emplace(c.ids[i], c.positions[i]);
      if (!fresh) {
        ++shared;
        EXPECT_EQ(std::memcmp(&it->second, &c.positions[i], sizeof(Vec3)), 0);
      }
    }
  }
  EXPECT_GT(shared, 100u);  // chunks do meet
  EXPECT_EQ(seen.size(), r.mesh.num_vertices());
  EXPECT_EQ(static_cast<int64_t>(seen.size()), r.stats.sealed_vertices);
}

TEST(Sealing, FullResolutionChunksAreExactlyTheSurface) {
  auto a = eval::MakeSyntheticSource(eval::Shape::kGyroid, 48, 40, 56);
  auto b = eval::MakeSyntheticSource(eval::Shape::kGyroid, 48, 40, 56);
  const SealRun plain = RunSealed(*a, Options(Schedule::kNone, 0, false));
  const SealRun sealed = RunSealed(*b, Options(Schedule::kNone, 0, true));
  // The same triangles, as sets of corner coordinates.
  auto key = [](const IndexedMesh& m) {
    std::vector<std::array<double, 9>> tris;
    for (size_t t = 0; t < m.num_triangles(); ++t) {
      std::array<Vec3, 3> c;
      for (int k = 0; k < 3; ++k) c[k] = m.positions[m.indices[3 * t + k]];
      std::rotate(c.begin(), std::min_element(c.begin(), c.end(), [](Vec3 x, Vec3 y) {
        return std::tie(x.x, x.y, x.z) < std::tie(y.x, y.y, y.z);
      }), c.end());
      tris.push_back({c[0].x, c[0].y, c[0].z, c[1].x, c[1].y, c[1].z, c[2].x, c[2].y, c[2].z});
    }
    std::sort(tris.begin(), tris.end());
    return tris;
  };
  EXPECT_EQ(key(sealed.mesh), key(plain.mesh));
  EXPECT_EQ(sealed.mesh.num_vertices(), plain.mesh.num_vertices());
  // Full resolution holds about two layers: far below the whole surface.
  EXPECT_LT(sealed.peak_held, static_cast<int64_t>(plain.mesh.num_triangles()) / 8);
}

// The same triangles, as sorted triples of float32-rounded corners (what PLY and OBJ keep).
std::vector<std::array<float, 9>> TriangleSet(const IndexedMesh& m) {
  std::vector<std::array<float, 9>> tris;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    std::array<std::array<float, 3>, 3> c;
    for (int k = 0; k < 3; ++k) {
      const Vec3 p = m.positions[m.indices[3 * t + k]];
      c[k] = {static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)};
    }
    std::rotate(c.begin(), std::min_element(c.begin(), c.end()), c.end());  // keeps winding
    tris.push_back({c[0][0], c[0][1], c[0][2], c[1][0], c[1][1], c[1][2], c[2][0], c[2][1], c[2][2]});
  }
  std::sort(tris.begin(), tris.end());
  return tris;
}

TEST(Sealing, ChunkedWriterWritesTheWeldedMeshAsTheChunksCome) {
  const std::string dir = ::testing::TempDir();
  for (const char* ext : {".ply", ".obj", ".4.ply"}) {  // .4: three slabs side by side
    auto src = eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 64, {0.8, 0.8, 1.1});
    SessionOptions o = Options(Schedule::kTandemLag, 0.05, true);
    if (std::string(ext) == ".4.ply") o.parts = 4;
    auto s = TandemSession::Create(src->info(), o);
    ASSERT_TRUE(s.ok());
    const std::string path = dir + "/chunked" + ext;
    auto writer = io::ChunkedMeshWriter::Open(path);
    ASSERT_TRUE(writer.ok()) << writer.status();
    std::vector<SealedChunk> chunks;
    int64_t retired_before_end = 0;
    auto take = [&] {
      SealedChunk c;
      while ((*s)->TakeSealed(&c)) {
        ASSERT_TRUE((*writer)->Add(c).ok());
        chunks.push_back(std::move(c));
      }
    };
    std::vector<uint8_t> bytes;
    while (src->ReadSlice(&bytes).ok()) {
      ASSERT_TRUE((*s)->AddSliceBytes(src->info().dtype, bytes.data()).ok());
      take();
    }
    retired_before_end = (*writer)->vertices();
    ASSERT_TRUE((*s)->Finish().ok());
    take();
    ASSERT_TRUE((*writer)->Finish().ok());
    const IndexedMesh welded = WeldChunks(chunks);
    // Most vertices went out before the stream ended (the writer holds the front).
    EXPECT_GT(retired_before_end, static_cast<int64_t>(welded.num_vertices()) / 2) << ext;
    auto read = io::ReadMesh(path);
    ASSERT_TRUE(read.ok()) << read.status();
    EXPECT_EQ(read->num_vertices(), welded.num_vertices()) << ext;
    EXPECT_EQ(TriangleSet(*read), TriangleSet(welded)) << ext;
    EXPECT_TRUE(eval::AnalyzeTopology(*read).IsClosedManifold()) << ext;
  }
  // A missing chunk: a vertex is never retired.
  auto writer = io::ChunkedMeshWriter::Open(dir + "/missing.ply");
  ASSERT_TRUE(writer.ok());
  SealedChunk c;
  c.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  c.ids = {0, 1, 2};
  c.indices = {0, 1, 2};
  c.retired = {0, 1};
  ASSERT_TRUE((*writer)->Add(c).ok());
  EXPECT_EQ((*writer)->Finish().code(), absl::StatusCode::kInternal);
  EXPECT_FALSE(io::ChunkedMeshWriter::Supports("x.stl"));
  EXPECT_EQ(io::ChunkedMeshWriter::Open(dir + "/x.glb").status().code(),
            absl::StatusCode::kInvalidArgument);
}

// A periodic field in z: the same slices over and over, so a deeper volume only adds
// repetitions of the same surface.
class PeriodicSource final : public SliceSource {
 public:
  PeriodicSource(int64_t n, int64_t nz) : PeriodicSource(n, n, nz) {}
  PeriodicSource(int64_t nx, int64_t ny, int64_t nz) {
    info_.nx = nx;
    info_.ny = ny;
    info_.nz = nz;
    info_.dtype = DType::kFloat32;
  }
  const VolumeInfo& info() const override { return info_; }
  int64_t next_slice() const override { return k_; }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    if (k_ >= info_.nz) return absl::OutOfRangeError("end");
    bytes->resize(static_cast<size_t>(info_.nx * info_.ny) * sizeof(float));
    float* v = reinterpret_cast<float*>(bytes->data());
    const double w = 2 * std::numbers::pi / 24.0;  // period: 24 voxels
    for (int64_t j = 0; j < info_.ny; ++j) {
      for (int64_t i = 0; i < info_.nx; ++i) {
        // A gyroid, closed off at the x/y borders so the surface does not depend on them.
        const double g = std::sin(w * i) * std::cos(w * j) + std::sin(w * j) * std::cos(w * k_) +
                         std::sin(w * k_) * std::cos(w * i);
        const double edge = std::min({i, j, info_.nx - 1 - i, info_.ny - 1 - j}) < 2 ? 1.0 : 0.0;
        v[j * info_.nx + i] = static_cast<float>(edge > 0 ? edge : g);
      }
    }
    ++k_;
    return absl::OkStatus();
  }

 private:
  VolumeInfo info_;
  int64_t k_ = 0;
};

// The chunked writer holds the vertices still open and the triangles waiting for them, not
// the mesh: written from a volume four times deeper (the same slices repeated), it needs no
// more memory than from the shallow one (a table indexed by global id would need 4x).
TEST(Sealing, ChunkedWriterMemoryFollowsTheFrontNotTheDepth) {
  const std::string dir = ::testing::TempDir();
  size_t peak[2] = {0, 0};
  int64_t vertices[2] = {0, 0};
  for (int deep = 0; deep < 2; ++deep) {
    PeriodicSource src(64, deep ? 192 : 48);
    SessionOptions o = Options(Schedule::kTandemLag, 0.2, true);
    o.parts = 2;
    o.seam_settle_slices = 32;  // the seams' hold stops growing within the shallow volume
    auto s = TandemSession::Create(src.info(), o);
    ASSERT_TRUE(s.ok()) << s.status();
    const std::string path = dir + "/depth" + std::to_string(deep) + ".ply";
    auto writer = io::ChunkedMeshWriter::Open(path);
    ASSERT_TRUE(writer.ok()) << writer.status();
    auto take = [&] {
      SealedChunk c;
      while ((*s)->TakeSealed(&c)) {
        ASSERT_TRUE((*writer)->Add(c).ok());
        peak[deep] = std::max(peak[deep], (*writer)->MemoryBytes());
      }
    };
    std::vector<uint8_t> bytes;
    while (src.ReadSlice(&bytes).ok()) {
      ASSERT_TRUE((*s)->AddSliceBytes(src.info().dtype, bytes.data()).ok());
      take();
    }
    ASSERT_TRUE((*s)->Finish().ok());
    take();
    ASSERT_TRUE((*writer)->Finish().ok());
    vertices[deep] = (*writer)->vertices();
    auto read = io::ReadMesh(path);
    ASSERT_TRUE(read.ok()) << read.status();
    EXPECT_EQ(static_cast<int64_t>(read->num_vertices()), vertices[deep]);
    EXPECT_TRUE(eval::AnalyzeTopology(*read).IsManifold());
  }
  EXPECT_GT(vertices[1], 3 * vertices[0]);
  EXPECT_LE(peak[1], peak[0] * 5 / 4) << peak[0] << " bytes at 48 slices, " << peak[1] << " at 192";
}

// A sealed split session's seams settle once they hold SessionOptions::seam_hold_vertices (at
// its default), so what it holds is flat in the depth: from a volume eight times deeper (the
// same slices repeated), its peak accounting, the merge at the end included (the budget's
// peak), stays within 1.2x of the shallow one's. The grid is tall in y, so that its seam
// nears the default hold within the shallow volume; a seam settled only by
// seam_settle_slices (512) would hold about 2x at 512 slices.
TEST(Sealing, SplitSessionMemoryIsFlatInDepth) {
  constexpr int64_t kDepth = 64;
  size_t peak[2] = {0, 0};
  int64_t budget_peak[2] = {0, 0}, triangles[2] = {0, 0};
  for (int deep = 0; deep < 2; ++deep) {
    PeriodicSource src(48, 192, deep ? 8 * kDepth : kDepth);
    SessionOptions o = Options(Schedule::kTandemLag, 0.2, true);
    o.parts = 2;
    auto budget = std::make_shared<MemoryBudget>(0);
    const SealRun r = RunSealed(src, o, budget);
    ASSERT_EQ(r.parts, 2);
    peak[deep] = r.peak_memory;
    budget_peak[deep] = budget->peak();
    triangles[deep] = static_cast<int64_t>(r.mesh.num_triangles());
  }
  EXPECT_GT(triangles[1], 7 * triangles[0]);
  EXPECT_LE(peak[1], peak[0] * 6 / 5) << peak[0] << " bytes at " << kDepth << " slices, "
                                      << peak[1] << " at " << 8 * kDepth;
  EXPECT_LE(budget_peak[1], budget_peak[0] * 6 / 5)
      << budget_peak[0] << " bytes at " << kDepth << " slices, " << budget_peak[1] << " at "
      << 8 * kDepth;
}

// Sealed chunks are mended as the final mesh is without sealing (degenerate.h), each as it is
// sealed: on the quantised tangles, whose values equal to the iso-value leave zero-area
// triangles that the link condition must keep, the welded chunks hold none in 6 tangles (13
// before the chunks were tidied, then 2 on edges of the grid's box, as the unsealed meshes),
// and the mesh keeps its topology and error bound.
TEST(Sealing, ChunksAreTidiedOfZeroAreaTriangles) {
  constexpr int n = 40;
  int64_t degenerate = 0;
  for (int seed = 0; seed < 6; ++seed) {
    FieldSource full_src(n, n, n, [seed](double i, double j, double k) { return QuantisedTangle(seed, i, j, k); });
    FieldSource sealed_src(n, n, n, [seed](double i, double j, double k) { return QuantisedTangle(seed, i, j, k); });
    SessionOptions o = Options(Schedule::kTandemLag, 0.2, true);
    o.iso = 4.0;
    SessionOptions f = Options(Schedule::kNone, 0.2, false);
    f.iso = 4.0;
    const SealRun sealed = RunSealed(sealed_src, o);
    const SealRun full = RunSealed(full_src, f);
    degenerate += CountDegenerate(sealed.mesh);
    const eval::TopologyReport a = eval::AnalyzeTopology(full.mesh),
                               b = eval::AnalyzeTopology(sealed.mesh);
    EXPECT_TRUE(b.IsManifold()) << "seed " << seed;
    EXPECT_EQ(b.euler, a.euler) << "seed " << seed;
    EXPECT_EQ(b.components, a.components) << "seed " << seed;
    EXPECT_LE(sealed.error_max, 0.2) << "seed " << seed;
    EXPECT_LT(sealed.mesh.num_triangles(), full.mesh.num_triangles() / 3) << "seed " << seed;
  }
  EXPECT_EQ(degenerate, 0);
}

// A cut of the shared MR head, kept here so that the test runs without ../shared: 16 x 20 x 18
// voxels of mr_head_48x62x42_uint8 from x 32, y 22, z 16, x fastest, base64 (VTK's example
// data, BSD-3-Clause). Two sheets of its surface touch at a grid point at the iso-value, 16.
const char kPinchVolumeBase64[] =
    "T1FoTRQaExpIIREDAwMDA0BGhHJHERYSOSsWBgQEAwRiVHBhWiwbGBsyJAcGBwYGc5WWYEpSExgSMCIGBggGBnayT1VAaC4S"
    "ECIgCQUKBQiAdGdUS1pWFBEmHwcGCAgJUVVtRlBFaiwTJRgIBwsIBktHXzo5RV5JERgVBQQFBQQ8QEo4V2hQTREZGwUDBQQC"
    "ODY4Q0Y6PEskEx8EAwMCAjoxMTM1P1N1OA8fBAIEAgJHODA2Pj9AWDcQHgYDAgIBVEEwTWBrXEk3Dx0IAwICAWhGNUxNRzxA"
    "QQ8dCgQDAgNvSDNARDoxQ0IQHwoEAwIFd0E0Nz42Qk8yESMKBgUFB4ZDNkJINTZFJRMjCQUHBQV4PDM2QTsxRhoUJAoHCAUG"
    "XTQyLDM8OkMVEikIBQYFBVYwMS4xLzdFDBMvBwQDBAM+V1kzHhcZFDIaDAIDAwECO0NZWDYPEhYtJhMEBQQEA2lKWG5eGxgY"
    "GC4aBgQGBQRjfrCGUE0SGxEqHwYHBgcFc7CAmk5eJhgSMB0IBgUGB1eGfXlBYGMRECYgBwUGBgVCVZVSRWF8ExEbJAYICAcF"
    "PVF4Qz86VFITIBkGCQcHBDtabEFfX1pOER4cBwUGBQM7Y1hDVUpAVxUVHQUEBAQDPl1KQVxCRnQdDx4GBAQEAjlHOTxIS0JV"
    "Hg0bCAUDAwI0ODVOYFxiYS4QGwkFBAYDNjQ+QU1hRUorEh8JBQUEAz84RFlXTDtBHRIdCAUGAwNIPEhaV1k/RyESHQoICAUG"
    "STxAWVZeRkshEyUKBgkFB0g4RltdYUthHxMjCQUGBQRQM0ZYYWFgUhkSKwgEBQUEUjdDT0xQRkcREjUIAwQCA0JWcVYiFBsV"
    "LR0IAwMCAgI+PlZeGhESFyYgCwQEAwMDbFdPbVAVERgWIhAFBQMFBXKDtbZSPhMfFCEYBwYGBwVhgNi1TV0UGw4aHgQDAwQD"
    "TGSSeUdoUBYPICMFAwQHBT1VglVCUWMREx8hBwYGBgVCWm1FSEVbJhYaHgUKBwgGR1xpQl5lfj8SGh0GBgYGBE1ecDtDUlZN"
    "DBYfBwcFBwNOYGo5VGlPVA0UIAgFBAcDU2pMOl5lXmsPEyIKBwQFA0lgPEBYR0tcDRMdBwUCBAM8SDUyNkJTVAsUIAgFAgMD"
    "Mzc0PkphV1cTFiMIAwQEAzI3N0FKVk5WGhYiCwQFBQQzOC8wOThCUB0XKw4FAwQEMjU3NjIzOUQSFiUMAwMEAzE2SE5MRD9M"
    "FBMtCQMDAwM8OlpnVWFnYg8UOAcDAwMDODZCSGAQGBIjFgMDAgMDA0M/QVpMDBYUJBwHBAQDBAN6f0ptVA0VGhofDgQEBQQE"
    "Y2unpGE9DBkTHxgFBAQEBFlkm5VPWg8cEhkgBgUEBANRW4J9RFoxFBUYHQUDBAQDSmiTWT5FRg0ZFycGBgUFBU1ofElWZ30T"
    "FhgqDAYFBwlOX4NCU0thGxMVOAgFBAYES1aSPzQ2RS0PFiAFBAQEA0pjnTovOEc+DREhBAMDBANNeH02MUZfTQ4RIgUDBAQD"
    "UmxZMDRIQTcJFCIJBAQFBGdgQjA0MTVACRMgCwMCAwJEOzo7MjlMXwoTIw4CAwMDNEJKMzE0N1INFCcOBAQDAzdJPTNFQD9K"
    "DBMsEAQDBAM4OTIvNT5IVA8RKg4DAwICODU3PDw5M0MNDjEIAwMBAzg4Q0xHRkZMDRAzBAICAgJDNENeXywUFR0RAwMDAgMD"
    "ck1KX3kWEhQXGQQEAwMEAld4dYmVEBYYGhwMBQUDBARMWrrCpDgMFhEfEgMEBAMDVGqfvFxoEBUSFxcFBQQDA1BYZqxMTUEV"
    "FBAhBQQDAgRMWHF+PlFdDRYTJQcEBQQFSldvZj1QagsXEigIBgcGB0lui1Q4PVEUEg9BCgYEBARSYqBjOztgJxIQIwkEAwQC"
    "TlCZUThEQioNDisJAwMEA01oaDdDM0A0Dg8mCgMCAwNvfjk1OTI6NQwQIAwDAwIDbT4yNEVHNkwKEx4QAwQEAj80MT5VQDE/"
    "CxMmEAMEAwM1Nj1YYkg4PAwTKBQDAwIDO0teUV5qV18PFCsSBAQEBGZnTDw4Nzc+DxAsDAMCAwFES0Q5MTtAOg8QMAcCAgIB"
    "ODkwLzpBUkERFTMEAgMCAlxYW0JMUBYUGRIDBAQEBAVjd1RAT0cRFhoaBAUEAwMDUoR+cpE0GBYaHgoFBQQEBGp4bWh7Uw8S"
    "FB0PBAQDBANha4m+l4wPFBYcFAUEAwQDWVl5sF9vThURFhsEAwMDA1xeZIhQTWMRFQ8gBwUGBANUYm19YktzERQTJgoGBQQH"
    "Rk5kdlpEaxcVDkgMBQMEBkldf3pNPYAfEw8kCwMDAwNgeG1NOGOEKRISKwsEAwMER1tmQ1RnUjEREyQMAwMDBEh1TzlnSUFH"
    "ERQnDgQCAwNvb0Q4iVo8RRESJhAFAgMFgmtLPXR9TkMUFC0SBAQFBURjTldjVV1PEhUvDwMDBAU/SXRaUXBrUxETNA4EBQQD"
    "bF1MTmRVTTcREDMIAwMDBEJdZFU/PEAvFBIzBAMCAgI5Rjc0QkNZMBUdKgMDAwICWjU1OUVOExIcDwMCAgIDA2BIQktFSBIT"
    "FBQEBAQDBQRpYmlrcU8YFhMXBgQDBAQEXUZCP1FdFBMQGQkDAwQCA29kXWSblA8UEh4PBgUEBANbT1Jqe4w2ExQVFQUEAwIC"
    "UVRSSGRoWg4UDh0EAwQDAmpVS2RfXl4REwwlBQYHBQRsaV9KR0hvFxMPRAcGBAMESFtfQVREXxgUECAHBAMCA2FgPmyJX4oe"
    "Ew8oBwQEAwN8bEtcUGOLLBQPJgkEAwIETWZgWVBEWioRESQKAwMDA2ZZTm5zUV84FBEmCQUDBARfQ1ZPSWaRLhMSKgsEAwME"
    "cnNTUT89XCwUETMKBQMDBHdkWUIzPUIkExE1BwMDAwNeQjg8XVpMKRQSNgQCAwMDO0xmWlBPVisVHCwEAgMDAzhFQUVec2og"
    "GScfBQIDAgM2MExDRU8WFRsHBAMCAgMDREdViXtRExUYDQMDBAMDBFtaZGdMUhgVEhoDAwQEAwI/Nzo9RVwSFA4kBgMEAwMF"
    "Zk4/WJWbDhMRHwoEAwQFBVZAU2tZdzATExwPBAQCBAVISFVCQkNeDxMVGQUEAwUEXkE8UTxTghAUEScFBAQEBpR1aUU3TGMQ"
    "FBQ5BwYEBAVSbGkyMzpXEhMPIwUFBAMEY1Y8RlM8UREUDyYGBAQDBFdKNzs4O1cRExMjBgQEAgNgT0VGNkZpEBIOJQUDAwMD"
    "Xk89Qj84SRMTDiYGAwMCA0Q3SmdhVnMPEw0sBgQEAwNEQzQ6NEpqEBIULwYDAgMEP0E+MjpEQBgTGC8CAwMCAkY4Mzc5MUUi"
    "Fh0mAwIDAwI1OllWSTtNHxUjHAMDAwIDNTpWT0xYWhETNRQDAwIDAi4uND1ZPhYYHAMDAgICAgMzMDJRXDgREhoGAwMDAgMC"
    "OjAvMjw3FRMZEAMCAwMCAzEsLjI+VhQUDx8DAwMEAwI8LkNDXpAQFQ0kBgMDAwMEOT1rcmyFKBYQJQoDAwQDBDs6REw8TFAU"
    "EiMPBAMDAgI7Ly4wPIppDxEpHwQCAwICUEc4OVp6XhAUHC4EBAMCAlJCNDlNPUoPFBEmAwQDAgNlTDIvLjhSDBQOJgMDAgME"
    "QjEuMUlAWQkTEiQDAwMCAkAxLDVVdWgLExIoAgMDAgNGMi0yMzNBCBMTIQICAwIDNS83U1lfcwcVFSUDAwICAzEwND5DXlUL"
    "FRskAwMCAgMxLS05SjlFFRYhHwMDAgECMCssLi47SBYXKRoDAwECAjYtLzI5OEgTFTIUAwMCAgIzLi41QElPCxA1DQICAgMC"
    "QDs0OVwWFRMPAgMDAgICAS45QjlGHRIVGAICAgECAgIwQVRcWTsVEh0HAwICAgICLSw5PUdiFRMYEQQDAgICAy0zOTxvjBIV"
    "ESADAwMDAgMvMTxLZ5oXEw4nBQQEAwMDM0BVWDpVOBQPIAoEBAIBAy8tLjBMiFQQETkPBgMDAgMtLTFQUERFDhMZFgICAgMC"
    "LS88VTo3NQ0TGx0CAwIBAzEsLjEyOUQLFRkeAwMDAQIwLjE1PV9EDhMaGgMEAgICLS86U19VSg0VGxwDBAIBAi4wMzAzNz4J"
    "FR8YAwMCAgMvLi87TW5rDBUhFwMDAgICMDAzP0RUVgwXJBUDAgICAjIzMUNHN2EVFSkRAwMCAgI0OEM5PF1qFBQ1DwMCAgIC"
    "OjpUXm1PTBEVMAkDAgECAjYzOTMzOE4MEzgFAQICAQJUVllOSRAaHgcCBAIBAgICTFZSUWUSExkPAgICAgICAkxRU1mNHhMY"
    "HQMCAwICAgM4QlNcckIPEyEIAgICAgIDSXB4dZBxEBYcEQMDAwIDBEI8QXWMmg4XGB0EAwMCBAQvM0xGO3AZFRIlAwQDAwMD"
    "Ly81OliCJhMPPggEAwIDAjdNVV89RkASEh8IAgIDAwNFTkxEMT07EBMoCQQCAwMCMC0uLi46Qg8VJQsDAgICAjEwMjc3Uy8N"
    "FSkPAwICAwI1PFFhWzVFDBYpDgQDAwMDPks/NTEzRAsUJwwDAgIEAjg3OEY2RWMLEywMBAICAgJFQTtfWWZ0DhMtDQMDAgIC"
    "QzgwNDg3WRMTLwgCAgICAjNCTlU9SoIPEzYHAgICAgNbYXGTblNaERguBQIDAwMES0lFVDNDURMiJwUCAgQDAjA7PE46FB8U"
    "AwMDAwMCAgIuLzRKUhQXHwcDAgICAgIBMjg4NksRExwPAgMCAgICAlVhZ0FOJRUWGwMDAwICAgI9REI4RksNEiQFAgICAgIC"
    "RVBSWn9yDRYhDAMDAgMCAkpDPD5Big4UGhoDAgICAwMvLT1WYXoMEx4qBQIDAwMCP0NpUzNjIRQSIgQDAgECA2NbPSs1biYT"
    "ECgEAgMCAgI5MS4vOG0jExEqAwIDAgIBLy03OEqJJg8QKgQDAgICATZUa2NARyURETAFAwMCAwFgXjk/Qk9FDxgqBQMDAgIC"
    "S1tATWtsXw0fKgYDAwICAjVQSExyjksNIC0EAwMCAgNYVjQzOVxSEiMpBAMCAwMDNjIyTT9LXxQaIwMEAwICAWhcb3B+ZFYY"
    "KB4FAwIDAwNmd2GWQUBHFDIVBAMCAgIDL0pIWx0PHwoDAwICAwMCAyk0R1coECMVBQICAwMDAwMnKy9BPg8THwYDAgIDAgIC"
    "KC4tPmUPFCAPAgICAwMCAisyOzdKKg8XGQMDAgIDAgMwPWBlfkcOFSQFAwMCAgMDQ1FIO1VmExQiCgMDAwMCAkQ9O2JuYRAV"
    "KxEEAwMCAwNTYnNhNksQFSYWAwMDAgICTEpRMDZhDBQbGQQDAwMDAi0vMjpQhgoTGhkDAgMCAgIqKz5IWogOEhwbAwMCAgMC"
    "MDhvZV6TGxEhGwQDAwMCAjFseUqDmhwRJRoDAwMDAgMuN11GS4chESUYAwIDAwICMzNcRC9NJRApFwMDAwMDAmVZYjAwTSUP"
    "MBYEAwIDAgJCOzY1UmwxETEUBAMCAgIDNztENnKBLBE6DwMCAwMDA3p+j5KNcC0ULgkEAwMCAwMvTm09GRoXAwICAwIDAgMC"
    "MDU5Qx0QHgcCAwICAwICAkZLPGkdDhsRAwMBAwMCAgItOzpGNg4VGgQDAgIBAwICKzM4PFILDx4HAwICAQICA0dXWEWNHxAZ"
    "EQMBAgICAQJafHVimjUTFBkEAgMCAwICSmJolX1EEhUjBQIDAwICAzpefWQ2QBEdLwkCAwMDAgJVRTYxQlYMESIIAwMCAgIC"
    "MCsyLzxbCBEjBwICAgICAzo3NC80OQoRJgcCAgECAgIuLjM4M0AKEicHAgICAgECLitPWU1pDBInBgMDAgICAi0rNktedA0T"
    "KgcBAgIDAwJRLzZVQUwUEisHAQMCAgICeWtrYSxLGBYrBgMDAgMCAztYUjksUx4YLAYDAwIDAwMzLS08XEEnFygEAwICAwID"
    "eldQhpQ0IyEeAwICAwMCAjlURCANIggDAwICAgECAQI3PkkgGBkRAgICAQICAgIBYGFmNR0QHAQDAwICAwICAjQ8W1oXDB8M"
    "AwICAgIDAgI3MzleLQkWFQMDAwEDAgICKTEvO2gKERgEAgEDAgICAjhROUGFFhAgCQMDAwIDAgItTnaGgRwRJhADAwQCAgIC"
    "OUt5SFgpEjUYBAMCAgMCAlRnOTNRLhAgGgMEAwECAgI2NENKRDMPHRcDAwMCAgECTVJjXlkvEB8WAwICAwICAS8xMTM7KA0g"
    "FQMCAgECAgJFQDUvOi8MJBMCAgMCAgICMTM6L0s3DiYTAwIDAwMCAmc3LThzPQ0nFQMCBAMCAgJsg2BsXjkVMBgDAwMDAwID"
    "LzlJNzw+JycTBAIDAgICAi9JLDNmNR4rEAMCAgICAgJqkz97VSYYMg8EAgQBAgMETlIcExcZAwMDAgMCAgICA1RXJR8KIQYC"
    "AgICAgICAQFdXk4cDx8OAwIDAgECAgIBQ1dYIBYTGQMDAgICAgICAkNTVjwSDB4FAwMDAgICAgIuOlRyHQYeCwMDAgICAgEC"
    "NDE0VkUPGxMDAwMCAgICAjs+XGVGFR4lBQMCAgMCAgIyO3NwWRgTIgcCAgEBAgICWnFaR1oUESkHAwMCAgICAnReWYhtExcr"
    "BwIDAwICAQJFVFJgfBEaJQYDAgIBAgICMzYyOE0SDSYEAwMCAgIDAlxvTDVUFg8mBQIBAgIDAQIvOFk4RxsPKgUCAgMCAQIC"
    "XUQ1TlscESgFAgMCAQICA32EdIVwHRcwBwMCAgMCAgIwMktfSxkVKAcCAwMCAQICMWQvPTcYFSUDAwICAQICAj2Nem0hHR8i"
    "BAICAgICAgJQGBcQHgcDAgMCAgIDAwECayAfCxkOAgICAgICAgIBA19FFxUQGgMCAgECAgMCAQJTfB8fDB8GAwMCAgICAgMC"
    "QFVPGAoaDgMDAgICAwEDAlM+VSsIEBgCAgICAgIBAQNfSD1VEg4gBQMCAwICAgIDZkc2ZRkTJwsCAwIDAwICA147V20bESEM"
    "BAMCAgMBAQJ2eZ5+IBImDQMCAwICAgIDT3CLnScSJQ8DAgMCAgICAjA1OWMqDiQSAgMDAgIBAQI3TjRNMA4rEQQCAgMCAgIC"
    "b4dQSCYVKxEDAwMCAgICAjM1WmggFiUQAgMCAgICAgJcWkaOIBsnFAICAgECAgIClnqPcR4WNhMDAgMCAQICAjowNlUXFScP"
    "AgMCAgIBAQIubFYzFRUqCwMCAQIBAgIBK1eDJRoXLAkBAgEBAgIDAhUXDR4MAgICAwICAwIBAgEaIQ4ZEwMCAgICAgIBAgIC"
    "Lh4YDh0HBAICAgIBAgICAlofHAwaDQICAgICAgICAgJQPxoNFBcCAgMCAgIBAgECSXQoDQ0eBQMDAgICAgICAkCEXhUKJAwD"
    "AwICAwICAgJDjG0nES0UAwMEAwICAgMCbpGCLRcXFgMDAwECAgIDAoqqdiEWGxoDAwIBAgICAgJCXotFERkdAgMCAgIDAgMC"
    "QjxPSREaHQMDAwICAQICAz6CWToTHR8EBAMCAgICAgJ8mIkxEh0kBAMDAgICAgECNjlzKxooJAQDAgICAgICAjp3ch4aJSAE"
    "AwMCAgIBAgKBlmYZFyweAwMBAgICAgMCb0Y7GR4yGQMDAgICAQICAktdMBkhLhQCAgMCAQECAgJMSB4cJy0RAgICAQIBAQEC";

class BytesSource final : public SliceSource {
 public:
  BytesSource(std::string bytes, int64_t nx, int64_t ny, int64_t nz, double spacing)
      : bytes_(std::move(bytes)) {
    info_.nx = nx;
    info_.ny = ny;
    info_.nz = nz;
    info_.dtype = DType::kUInt8;
    info_.spacing = {spacing, spacing, spacing};
  }
  const VolumeInfo& info() const override { return info_; }
  int64_t next_slice() const override { return k_; }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    if (k_ >= info_.nz) return absl::OutOfRangeError("end");
    const size_t n = static_cast<size_t>(info_.nx * info_.ny);
    bytes->assign(bytes_.begin() + static_cast<std::ptrdiff_t>(n * static_cast<size_t>(k_)),
                  bytes_.begin() + static_cast<std::ptrdiff_t>(n * static_cast<size_t>(k_ + 1)));
    ++k_;
    return absl::OkStatus();
  }

 private:
  std::string bytes_;
  VolumeInfo info_;
  int64_t k_ = 0;
};

// Two coincident corners of a zero-area triangle can each be handed out by another triangle
// before it seals; then neither may move, and the sealed mesh kept it (the head MR sealed at
// E0 6 and 24: 2 each, none unsealed). A chunk now also mends the zero-area triangles around
// the corners it hands out, moving only those. This cut reproduces the pair.
TEST(Sealing, ACornerIsMendedBeforeItIsHandedOut) {
  std::string bytes;
  ASSERT_TRUE(absl::Base64Unescape(kPinchVolumeBase64, &bytes));
  ASSERT_EQ(bytes.size(), 16u * 20 * 18);
  eval::TopologyReport plain;
  for (bool seal : {false, true}) {
    BytesSource src(bytes, 16, 20, 18, 4.0);
    SessionOptions o = Options(Schedule::kTandemLag, 6.0, seal);
    o.iso = 16;
    const SealRun run = RunSealed(src, o);
    EXPECT_EQ(CountDegenerate(run.mesh), 0) << "seal " << seal;  // sealed: 2 before
    const eval::TopologyReport t = eval::AnalyzeTopology(run.mesh);
    EXPECT_TRUE(t.IsManifold()) << "seal " << seal;
    EXPECT_LE(run.error_max, 6.0 * (1 + 1e-9)) << "seal " << seal;
    if (!seal) {
      plain = t;
    } else {
      EXPECT_EQ(t.euler, plain.euler);
      EXPECT_EQ(t.components, plain.components);
    }
  }
}

// The same cut with the finishing pass (SessionOptions::lockstep_error), unsealed: two sheets
// touch along a zero-length edge, with a zero-area triangle on each side of it. Moving a
// corner toward its neighbours, or across each sliver by the corner's own facing, turned one
// of the two the wrong way, so both stayed (the head MR at E0 4 kept such a pair too); each
// sliver's own side is asked of the step now (MoveApart).
TEST(Sealing, TwoSliversAlongAZeroLengthEdgePartEachToItsSide) {
  std::string bytes;
  ASSERT_TRUE(absl::Base64Unescape(kPinchVolumeBase64, &bytes));
  BytesSource src(bytes, 16, 20, 18, 4.0);
  SessionOptions o = Options(Schedule::kTandemLag, 6.0, false);
  o.iso = 16;
  o.lockstep_error = SessionOptions{}.lockstep_error;
  const SealRun run = RunSealed(src, o);
  EXPECT_EQ(CountDegenerate(run.mesh), 0);  // 2 before
  EXPECT_TRUE(eval::AnalyzeTopology(run.mesh).IsManifold());
  EXPECT_LE(run.error_max, 6.0 * (1 + 1e-9));
}

TEST(Sealing, MemoryFollowsTheFrontNotTheDepth) {
  for (bool seal : {true, false}) {
    PeriodicSource shallow(72, 48), deep(72, 8 * 48);
    const SealRun a = RunSealed(shallow, Options(Schedule::kTandemLag, 0.05, seal));
    const SealRun b = RunSealed(deep, Options(Schedule::kTandemLag, 0.05, seal));
    const double memory = static_cast<double>(b.peak_memory) / static_cast<double>(a.peak_memory);
    const double held = static_cast<double>(b.peak_held) / static_cast<double>(a.peak_held);
    if (seal) {
      EXPECT_LE(memory, 1.2) << a.peak_memory << " -> " << b.peak_memory;
      EXPECT_LE(held, 1.2) << a.peak_held << " -> " << b.peak_held;
      EXPECT_TRUE(eval::AnalyzeTopology(b.mesh).IsManifold());  // open at z = 0 and the last slice
    } else {
      EXPECT_GT(held, 3.0);  // what sealing removes: the mesh grows with the depth
    }
  }
}

// An unfrozen vertex costs the sealer its place in the unfrozen list (4 bytes, doubled) and
// nothing else: the id, chunk stamp and normal's slot are kept for the frozen vertices still
// in the store only (IdMap), not 12 bytes for every vertex id. A sealed vertex's id is
// retired and forgotten with it.
TEST(Sealing, UnfrozenVerticesCostOnlyTheirPlaceInTheList) {
  MeshStore store;
  Sealer sealer(&store, nullptr, 2.0, 0.0);
  std::vector<VertexId> verts;
  size_t worst = 0;  // the most bytes a vertex took, in 1/100 bytes
  for (int batch = 0; batch < 200; ++batch) {
    verts.clear();
    for (int i = 0; i < 1000; ++i) {
      verts.push_back(store.AddVertex({double(i), double(batch), 0}, batch, batch, 0));
    }
    sealer.AddVertices(verts);
    worst = std::max(worst, 100 * sealer.MemoryBytes() / store.vertex_capacity());
  }
  EXPECT_LE(worst, 850u);
  // A strip of triangles at the bottom, frozen and sealed: handed out, retired, forgotten.
  for (VertexId v = 0; v + 2 < 1000; ++v) store.AddTriangle(v, v + 1, v + 1000);
  sealer.Seal(10.0);
  SealedChunk chunk;
  ASSERT_TRUE(sealer.TakeChunk(&chunk));
  EXPECT_EQ(chunk.indices.size(), 3u * 998);
  EXPECT_EQ(chunk.ids.size(), 999u + 998);  // 0..998 and 1000..1997
  EXPECT_EQ(chunk.retired.size(), 999u + 998);
  EXPECT_FALSE(store.vertex_alive(0));
  EXPECT_EQ(sealer.id(0), kNoGlobalId);
  EXPECT_EQ(sealer.id(1000), kNoGlobalId);
}

// With slabs, the triangles at the seams wait for the merge, so what a sealed session holds
// grows with the depth, a small part of what the plain session's mesh grows by; and only up
// to seam_settle_slices behind the front, past which seam vertices freeze as they are
// (SettleSeams): from there on it follows the front again. The settled seams, sealed in two
// slabs under one id, weld into the mesh of the plain split session's topology. The seam
// tests settle at 64 slices, not the default 512: the same bookkeeping on a fifth of the
// slices (at 512 they took 7 of the sanitizer build's 21 ctest minutes).
constexpr int64_t kTestSettle = 64;
TEST(Sealing, SlabsHoldTheirSeamsUpToABoundedDepth) {
  const int64_t settle = kTestSettle;
  const int64_t depths[3] = {48, settle + 48, 2 * settle + 96};
  int64_t held[2][3] = {};  // plain, sealed
  SealRun settled[2];       // at settle + 48 slices: the seams of the first 48 are settled
  for (bool seal : {false, true}) {
    for (int d = 0; d < (seal ? 3 : 2); ++d) {
      PeriodicSource src(72, depths[d]);
      SessionOptions o = Options(Schedule::kTandemLag, 0.05, seal);
      o.parts = 4;
      o.seam_settle_slices = settle;
      SealRun r = RunSealed(src, o);
      ASSERT_EQ(r.parts, 4);
      held[seal][d] = r.peak_held;
      if (d == 1) settled[seal] = std::move(r);
    }
  }
  std::printf("held triangles at %lld / %lld / %lld slices: plain %lld %lld, sealed %lld %lld %lld\n",
              static_cast<long long>(depths[0]), static_cast<long long>(depths[1]),
              static_cast<long long>(depths[2]), static_cast<long long>(held[0][0]),
              static_cast<long long>(held[0][1]), static_cast<long long>(held[1][0]),
              static_cast<long long>(held[1][1]), static_cast<long long>(held[1][2]));
  EXPECT_LT(held[1][1] - held[1][0], (held[0][1] - held[0][0]) / 4);  // the seams only
  EXPECT_LE(held[1][2], held[1][1] + held[1][1] / 20);                // then flat
  const SealRun& plain = settled[0];
  const SealRun& sealed = settled[1];
  const eval::TopologyReport p = eval::AnalyzeTopology(plain.mesh),
                             s = eval::AnalyzeTopology(sealed.mesh);
  EXPECT_TRUE(s.IsManifold());  // open at z = 0 and the last slice
  EXPECT_EQ(s.euler, p.euler);
  EXPECT_EQ(s.boundary_edges > 0, p.boundary_edges > 0);
  EXPECT_LE(sealed.error_max, 0.05 * (1 + 1e-9));
  EXPECT_EQ(sealed.stats.sealed_vertices, static_cast<int64_t>(s.vertices));
  for (const SealedChunk& c : sealed.chunks) {  // ids sorted, each once a chunk
    EXPECT_EQ(std::adjacent_find(c.ids.begin(), c.ids.end(), std::greater_equal<uint32_t>()),
              c.ids.end()) << c.index;
  }
  // The settled seams were coarsened first, along themselves (SettledSeamsAreCoarsenedFirst).
  EXPECT_LT(static_cast<double>(s.triangles), 1.1 * static_cast<double>(p.triangles));
  // A settled seam vertex is retired once, with its second copy: the writer puts out each
  // vertex once, with the normal of all its triangles.
  const std::string path = ::testing::TempDir() + "/settled.ply";
  auto writer = io::ChunkedMeshWriter::Open(path);
  ASSERT_TRUE(writer.ok()) << writer.status();
  for (const SealedChunk& c : sealed.chunks) ASSERT_TRUE((*writer)->Add(c).ok());
  ASSERT_TRUE((*writer)->Finish().ok());
  auto read = io::ReadMesh(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->num_vertices(), sealed.mesh.num_vertices());
  EXPECT_EQ(TriangleSet(*read), TriangleSet(sealed.mesh));
}

// Triangles whose smallest height is under `h` (voxels): what a 16-bit Draco grid collapses.
int64_t CountNeedles(const IndexedMesh& m, double h) {
  int64_t count = 0;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    const Vec3 p = m.positions[m.indices[3 * t]], q = m.positions[m.indices[3 * t + 1]],
               r = m.positions[m.indices[3 * t + 2]];
    const double twice_area = Norm(Cross(q - p, r - p));
    const double longest = std::max({Norm(q - p), Norm(r - q), Norm(p - r)});
    count += twice_area < h * longest;
  }
  return count;
}

// The same chunks, bit for bit.
void ExpectSameChunks(const SealRun& a, const SealRun& b) {
  ASSERT_EQ(a.chunks.size(), b.chunks.size());
  for (size_t i = 0; i < b.chunks.size(); ++i) {
    EXPECT_EQ(a.chunks[i].ids, b.chunks[i].ids) << i;
    EXPECT_EQ(a.chunks[i].indices, b.chunks[i].indices) << i;
    EXPECT_EQ(a.chunks[i].retired, b.chunks[i].retired) << i;
    ASSERT_EQ(a.chunks[i].positions.size(), b.chunks[i].positions.size());
    EXPECT_EQ(std::memcmp(a.chunks[i].positions.data(), b.chunks[i].positions.data(),
                          b.chunks[i].positions.size() * sizeof(Vec3)),
              0) << i;
  }
}

// Before a seam settles, it is coarsened (CoarsenSettlingSeam): seam edges contract in both
// slabs at once to a point of the seam's plane, and vertices of one slab onto a seam vertex,
// under the welded mesh's link condition and E0 for both sides' planes. Without it the
// settled seams (the first 48 of 112 slices) kept their marching-cubes triangles: +4.8 %
// triangles at E0 = 0.1 and +16.6 % at 0.3 here (with it +0.7 % and +1.3 %), and ~170
// needles, which Draco's 16-bit grid collapses to zero area (the 2048² x 640 gyroid: 4,362
// of them).
TEST(Sealing, SettledSeamsAreCoarsenedFirst) {
  const int64_t depth = kTestSettle + 48;
  for (double e0 : {0.1, 0.3}) {
    SessionOptions plain_o = Options(Schedule::kTandemLag, e0, false);
    plain_o.parts = 4;
    plain_o.seam_settle_slices = kTestSettle;
    SessionOptions sealed_o = plain_o;
    sealed_o.seal = true;
    PeriodicSource a(72, depth), b(72, depth);
    const SealRun plain = RunSealed(a, plain_o);
    const SealRun sealed = RunSealed(b, sealed_o);
    const eval::TopologyReport p = eval::AnalyzeTopology(plain.mesh),
                               s = eval::AnalyzeTopology(sealed.mesh);
    const int64_t needles_plain = CountNeedles(plain.mesh, 1.0 / 64);
    const int64_t needles_sealed = CountNeedles(sealed.mesh, 1.0 / 64);
    std::printf("E0 %g: triangles plain %lld sealed %lld, needles plain %lld sealed %lld\n", e0,
                static_cast<long long>(p.triangles), static_cast<long long>(s.triangles),
                static_cast<long long>(needles_plain), static_cast<long long>(needles_sealed));
    EXPECT_TRUE(s.IsManifold()) << e0;  // open at z = 0 and the last slice
    EXPECT_EQ(s.euler, p.euler) << e0;
    EXPECT_EQ(s.boundary_edges > 0, p.boundary_edges > 0) << e0;
    // Error(K) counts the settled seam vertices with both sides' planes.
    EXPECT_LE(sealed.error_max, e0 * (1 + 1e-9));
    EXPECT_LT(static_cast<double>(s.triangles), 1.02 * static_cast<double>(p.triangles)) << e0;
    EXPECT_LE(needles_sealed, needles_plain + 2) << e0;
    if (e0 == 0.3) {  // the coarsening runs between steps: threads change nothing
      sealed_o.pipeline = false;
      PeriodicSource c(72, depth);
      ExpectSameChunks(sealed, RunSealed(c, sealed_o));
    }
  }
}

// The seam coarsening on a surface with many small components and grid values equal to the
// iso-value (several seam vertices at one grid point): the welded mesh keeps the plain
// session's topology, component by component, and the error bound. Without the coarsening
// it kept 3.6-4.4 % more triangles than the plain session at E0 = 0.2 and 23-30 % more at
// 0.6 (with it 1.2-1.4 % and 3.3-4.2 %: half of the 128 slices have settled seams).
TEST(Sealing, SeamCoarseningKeepsTheTopologyOfQuantisedTangles) {
  const int64_t depth = kTestSettle + 64;
  for (int seed = 0; seed < 2; ++seed) {
    for (double e0 : {0.2, 0.6}) {
      auto field = [seed](double i, double j, double k) { return QuantisedTangle(seed, i, j, k); };
      FieldSource plain_src(72, 40, depth, field), sealed_src(72, 40, depth, field);
      SessionOptions o = Options(Schedule::kTandemLag, e0, false);
      o.iso = 4.0;
      o.parts = 4;
      o.seam_settle_slices = kTestSettle;
      const SealRun plain = RunSealed(plain_src, o);
      o.seal = true;
      const SealRun sealed = RunSealed(sealed_src, o);
      const std::string what = "seed " + std::to_string(seed) + " E0 " + std::to_string(e0);
      const eval::TopologyReport p = eval::AnalyzeTopology(plain.mesh),
                                 s = eval::AnalyzeTopology(sealed.mesh);
      EXPECT_TRUE(s.IsManifold()) << what;
      EXPECT_EQ(s.euler, p.euler) << what;
      EXPECT_EQ(Sorted(s.component_euler), Sorted(p.component_euler)) << what;
      EXPECT_EQ(s.boundary_edges > 0, p.boundary_edges > 0) << what;
      EXPECT_LE(sealed.error_max, e0 * (1 + 1e-9)) << what;
      const double allowed = e0 < 0.5 ? 1.025 : 1.08;
      EXPECT_LT(static_cast<double>(s.triangles), allowed * static_cast<double>(p.triangles))
          << what;
      // Settled as they were, the seams kept 320-525 zero-area triangles here (iso-hits at
      // seam grid points); coarsened, 4-16, those at the grid's box or where the link
      // condition refuses (the plain session's final pass mends those: none here); with the
      // settling seam vertices moved apart (MendSettlingSeam) 0-7; with two seam vertices on
      // one face of the box contracted as two inside it are (at one point there, with a
      // third vertex: no move parts a triangle on the line where the seam meets the face)
      // 0-4, all of them a strip along the box's edge at the first slice, next to a seam:
      // two settled seam copies at one point of the box's edge, every triangle around them
      // degenerate, and the other slab holding only a sliver there. With the facing taken a
      // few rings out and the other copy's sliver facing as this slab does, none; the same
      // at the default settling, 512 slices (72 x 40 x 576).
      const int64_t degenerate_plain = CountDegenerate(plain.mesh);
      const int64_t degenerate_sealed = CountDegenerate(sealed.mesh);
      EXPECT_LE(degenerate_sealed, degenerate_plain) << what;
      std::printf("%s: triangles plain %zu sealed %zu, zero-area %lld / %lld\n", what.c_str(),
                  p.triangles, s.triangles, static_cast<long long>(degenerate_plain),
                  static_cast<long long>(degenerate_sealed));
    }
  }
}

// Until a vertex moves, its quadric is kept as the matrix of its planes alone, b and c
// following from its position (Simplifier::AddTriangles), so every move keeps it in full
// first: contractions, the sag correction, the tidying, the seams' mends and coarsening, and
// the merge carries both forms over. SessionOptions::check_quadrics keeps every quadric in
// full alongside and counts those read that differ: none, on sessions through all of those
// (without keeping a contraction's survivor in full, 131,000-282,000 reads a case differ;
// without the seam mend's, 7-8 on the settled tangles; simplifier_test.cc has the sag
// correction's and the tidying's).
TEST(Simplifier, QuadricsKeptAsMatricesAreTheFullSums) {
  struct Case {
    std::string what;
    std::function<double(double, double, double)> field;
    int64_t nx, ny, nz;
    double iso;
    SessionOptions o;
  };
  auto gyroid = [](double i, double j, double k) {
    const double s = 2 * std::numbers::pi / 16;
    return std::sin(i * s) * std::cos(j * s) + std::sin(j * s) * std::cos(k * s) +
           std::sin(k * s) * std::cos(i * s);
  };
  auto tangle = [](double i, double j, double k) { return QuantisedTangle(0, i, j, k); };
  std::vector<Case> cases;
  auto add = [&](std::string what, auto field, int64_t nx, int64_t ny, int64_t nz, double iso,
                 Schedule schedule, double e0, bool seal, int parts) {
    SessionOptions o = Options(schedule, e0, seal);
    o.parts = parts;
    o.seam_settle_slices = 8;
    cases.push_back({std::move(what), field, nx, ny, nz, iso, o});
  };
  add("gyroid, one part", gyroid, 48, 40, 36, 0.2, Schedule::kTandemLag, 0.3, false, 1);
  add("gyroid, 4 parts", gyroid, 72, 40, 36, 0.2, Schedule::kTandemLag, 0.3, false, 4);
  add("gyroid, sealed, 4 parts", gyroid, 72, 40, 36, 0.2, Schedule::kTandemLag, 0.3, true, 4);
  add("gyroid, tandem", gyroid, 48, 40, 36, 0.2, Schedule::kTandem, 0.3, false, 1);
  add("gyroid, classical", gyroid, 48, 40, 36, 0.2, Schedule::kClassical, 0.3, false, 1);
  add("tangle, one part", tangle, 72, 40, 40, 4.0, Schedule::kTandemLag, 0.6, false, 1);
  add("tangle, sealed, 4 parts", tangle, 72, 40, 40, 4.0, Schedule::kTandemLag, 0.6, true, 4);
  add("tangle, sealed, one part", tangle, 72, 40, 40, 4.0, Schedule::kTandemLag, 0.2, true, 1);
  for (int seed : {0, 1}) {
    for (double e0 : {0.2, 0.6}) {  // as SeamCoarseningKeepsTheTopologyOfQuantisedTangles
      auto field = [seed](double i, double j, double k) { return QuantisedTangle(seed, i, j, k); };
      add("tangle " + std::to_string(seed) + ", sealed, 4 parts, settled", field, 72, 40,
          kTestSettle + 64, 4.0, Schedule::kTandemLag, e0, true, 4);
      cases.back().o.seam_settle_slices = kTestSettle;
    }
  }
  cases.push_back(cases[0]);
  cases.back().what = "gyroid, alpha 0.3, 1,000 triangles";
  cases.back().o.alpha = 0.3;
  cases.back().o.target_triangles = 1000;
  cases.back().o.lockstep_error = 0.5;
  for (Case& c : cases) {
    FieldSource src(c.nx, c.ny, c.nz, c.field);
    c.o.iso = c.iso;
    c.o.check_quadrics = true;
    const SealRun r = RunSealed(src, c.o);
    EXPECT_GT(r.stats.contractions, 1000) << c.what;
    EXPECT_EQ(r.stats.quadric_mismatches, 0) << c.what;
    EXPECT_LE(r.error_max, std::max(c.o.error, r.stats.error_reached) * (1 + 1e-9)) << c.what;
  }
}

TEST(Sealing, OptionsAreChecked) {
  SessionOptions o = Options(Schedule::kTandemLag, 0.1, true);
  o.target_triangles = 100;
  EXPECT_EQ(o.Validate().code(), absl::StatusCode::kInvalidArgument);
  o.target_triangles = 0;
  o.seal_margin = -1;
  EXPECT_EQ(o.Validate().code(), absl::StatusCode::kInvalidArgument);
  o.seal_margin = std::nan("");
  EXPECT_EQ(o.Validate().code(), absl::StatusCode::kInvalidArgument);
  o.seal_margin = 2;
  o.seam_settle_slices = 0;
  EXPECT_EQ(o.Validate().code(), absl::StatusCode::kInvalidArgument);
  o.seam_settle_slices = 1;
  EXPECT_TRUE(o.Validate().ok());
  o.seam_hold_vertices = 0;
  EXPECT_EQ(OptionErrorOf(o.Validate())->field, "seam_hold_vertices");
  o.seam_hold_vertices = 1;
  EXPECT_TRUE(o.Validate().ok());
  // Sealing splits a wide grid as the plain session does.
  o.seal_margin = 2;
  o.parts = 0;
  VolumeInfo g;
  g.nx = 300;
  g.ny = 8;
  g.nz = 4;
  auto s = TandemSession::Create(g, o);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ((*s)->num_parts(), 4);
}

// Slabs seal side by side (sealer.h): each hands out ids of its own (p, p + P, ...), a seam
// vertex and the triangles around it wait for the merge, and so do the seam's neighbours, so
// that the schedule at the merge can still coarsen the seam. The welded chunks are the mesh
// the plain split session makes, to within a few triangles: without the neighbours kept,
// the link at E0 = 0.3 kept 12 % more. A vertex keeps the coordinates it was handed out
// with: the merge gives dead ids of the first slab to the others' vertices, frozen ones
// among them, which the last SEAL must not take for its own unfrozen ones (the pillow box
// at E0 = 0.1 moved one, by the sag correction).
TEST(Sealing, SlabsSealSideBySide) {
  for (eval::Shape shape : {eval::Shape::kLink, eval::Shape::kGyroid, eval::Shape::kPillowBox}) {
    for (double e0 : {0.05, 0.1, 0.3}) {
      const std::string what = std::string(eval::ShapeName(shape)) + " E0=" + std::to_string(e0);
      SessionOptions plain_o = Options(Schedule::kTandemLag, e0, false);
      plain_o.parts = 4;
      SessionOptions sealed_o = plain_o;
      sealed_o.seal = true;
      auto a = eval::MakeSyntheticSource(shape, 96, 80, 72);
      auto b = eval::MakeSyntheticSource(shape, 96, 80, 72);
      const SealRun plain = RunSealed(*a, plain_o);
      const SealRun sealed = RunSealed(*b, sealed_o);
      ASSERT_EQ(sealed.parts, 4) << what;
      const eval::TopologyReport s = ExpectSealedLikePlain(plain, sealed, e0, 0.03, what);
      EXPECT_EQ(sealed.stats.sealed_vertices, static_cast<int64_t>(s.vertices)) << what;
      // Chunks numbered in order, from every slab along the way; a vertex has one id.
      std::map<uint32_t, Vec3> seen;
      std::array<bool, 4> slab_seen{};
      for (size_t i = 0; i < sealed.chunks.size(); ++i) {
        const SealedChunk& c = sealed.chunks[i];
        EXPECT_EQ(c.index, static_cast<int64_t>(i)) << what;
        EXPECT_TRUE(std::is_sorted(c.ids.begin(), c.ids.end())) << what;
        EXPECT_LE(c.first_slice, c.last_slice) << what;
        for (size_t v = 0; v < c.ids.size(); ++v) {
          if (i < sealed.chunks_before_finish) slab_seen[c.ids[v] % 4] = true;
          auto [it, fresh] = seen.emplace(c.ids[v], c.positions[v]);
          if (!fresh) {
            EXPECT_EQ(std::memcmp(&it->second, &c.positions[v], sizeof(Vec3)), 0) << what;
          }
        }
      }
      EXPECT_EQ(seen.size(), s.vertices) << what;
      if (e0 < 0.1) {  // at 0.3 the pillow box's flat sides keep their reach to the end
        EXPECT_EQ(slab_seen, (std::array<bool, 4>{true, true, true, true})) << what;
        EXPECT_GT(sealed.chunks_before_finish, 8u) << what;
      }
    }
  }
}

// Whichever thread steps which slab, the chunks are the same (ids included).
TEST(Sealing, SlabsSealTheSameWithOrWithoutThreads) {
  SessionOptions o = Options(Schedule::kTandemLag, 0.1, true);
  o.parts = 4;
  auto a = eval::MakeSyntheticSource(eval::Shape::kLink, 96, 80, 72);
  auto b = eval::MakeSyntheticSource(eval::Shape::kLink, 96, 80, 72);
  const SealRun threads = RunSealed(*a, o);
  o.pipeline = false;
  const SealRun one = RunSealed(*b, o);
  ExpectSameChunks(threads, one);
}

// Between slices the CLI and the server take what the slabs' finished steps sealed
// (TakeSealedThrough), without waiting for the steps in flight: TakeSealed after every slice
// ran the slabs in lock-step (a dense 2048² stream on 2 cores: about 15 % longer). Taken slice by
// slice, kSlicesInFlight behind, the chunks are those TakeSealed gives right after each slice,
// settled seams included. With every thread of the executor held, so that a slice's steps
// cannot start, the slices before it are still taken, and that slice's steps do not run.
TEST(Sealing, FinishedStepsAreTakenWithoutWaitingForTheStepsInFlight) {
  const int64_t depth = kTestSettle + 48;
  SessionOptions o = Options(Schedule::kTandemLag, 0.3, true);
  o.parts = 4;
  o.seam_settle_slices = kTestSettle;
  PeriodicSource a(72, depth), b(72, depth);
  const SealRun reference = RunSealed(a, o);  // TakeSealed after every slice
  ASSERT_GT(reference.chunks_before_finish, 40u);

  ThreadPool executor(2);
  auto s = TandemSession::Create(b.info(), o, &executor);
  ASSERT_TRUE(s.ok()) << s.status();
  SealRun through;
  int64_t next = 0;
  auto take = [&](int64_t upto) {
    for (; next <= upto; ++next) {
      SealedChunk c;
      if ((*s)->TakeSealedThrough(next, &c)) through.chunks.push_back(std::move(c));
    }
  };
  constexpr int64_t kHeldAt = 40;  // not a slice where seams settle (every 16)
  std::vector<uint8_t> bytes;
  for (int64_t k = 0; b.ReadSlice(&bytes).ok(); ++k) {
    if (k != kHeldAt) {
      ASSERT_TRUE((*s)->AddSliceBytes(b.info().dtype, bytes.data()).ok());
      take(k - TandemSession::kSlicesInFlight);
      continue;
    }
    (void)(*s)->sealed_pending();  // every step so far has finished
    std::mutex m;
    std::condition_variable cv;
    int holding = 0;
    bool go = false;
    TaskGroup hold(&executor);
    for (int t = 0; t < executor.threads(); ++t) {
      hold.Run([&] {
        std::unique_lock<std::mutex> lock(m);
        ++holding;
        cv.notify_all();
        cv.wait(lock, [&] { return go; });
      });
    }
    {
      std::unique_lock<std::mutex> lock(m);
      cv.wait(lock, [&] { return holding == executor.threads(); });
    }
    ASSERT_TRUE((*s)->AddSliceBytes(b.info().dtype, bytes.data()).ok());  // its steps wait
    const TandemSession::Gauge g = (*s)->Peek();
    EXPECT_EQ(g.sealed_through, k - 1);
    EXPECT_GT(g.sealed_pending, 0);
    const size_t before = through.chunks.size();
    auto taken = std::async(std::launch::async, [&] { take(k - 1); });
    const bool returned = taken.wait_for(std::chrono::seconds(30)) == std::future_status::ready;
    // A wait for the pipeline runs the steps the threads have not started on the waiting
    // thread (TaskGroup helps): slice k's steps would be done now.
    EXPECT_EQ((*s)->Peek().sealed_through, k - 1) << "slice k's steps ran for the take";
    {
      std::lock_guard<std::mutex> lock(m);
      go = true;
    }
    cv.notify_all();
    hold.Wait();
    taken.wait();
    EXPECT_TRUE(returned) << "TakeSealedThrough waited for the steps of a later slice";
    int64_t handed = 0;
    for (size_t i = before; i < through.chunks.size(); ++i) {
      handed += static_cast<int64_t>(through.chunks[i].num_triangles());
    }
    EXPECT_EQ(handed, g.sealed_pending);
  }
  take(depth - 1);
  ASSERT_TRUE((*s)->Finish().ok());
  SealedChunk c;
  while ((*s)->TakeSealed(&c)) through.chunks.push_back(std::move(c));
  ExpectSameChunks(reference, through);
}

}  // namespace
}  // namespace tandem
