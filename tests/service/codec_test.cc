// The Draco codec: counts kept exactly at every level, positions within the quantization
// step, order kept at level 0, deterministic output, clear errors on bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>

#include "absl/strings/str_cat.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/eval/synthetic.h"
#include "tandem/eval/topology.h"
#include "tandem/geometry.h"
#include "tandem/io/mesh_io.h"
#include "tandem/io/run_session.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"
#include "testutil/embedded.h"

namespace tandem::codec {
namespace {

IndexedMesh SphereMesh(Schedule schedule, int64_t n = 32) {
  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, n, n, n);
  SessionOptions options;
  options.schedule = schedule;
  options.error = 0.3;
  auto session = io::RunSession(*source, options);
  EXPECT_TRUE(session.ok()) << session.status();
  return (*session)->Snapshot();
}

// Largest per-coordinate difference between vertex i of a and vertex i of b.
double MaxIndexwiseError(const IndexedMesh& a, const IndexedMesh& b) {
  double worst = 0;
  for (size_t i = 0; i < a.num_vertices(); ++i) {
    for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(a.positions[i][c] - b.positions[i][c]));
  }
  return worst;
}

// Sorted positions, so reordered meshes can be compared coordinate-set-wise.
double MaxSortedError(const IndexedMesh& a, const IndexedMesh& b) {
  auto sorted = [](std::vector<Vec3> v) {
    std::sort(v.begin(), v.end(), [](const Vec3& p, const Vec3& q) {
      return std::tie(p.x, p.y, p.z) < std::tie(q.x, q.y, q.z);
    });
    return v;
  };
  double worst = 0;
  std::vector<Vec3> sa = sorted(a.positions), sb = sorted(b.positions);
  for (int c = 0; c < 3; ++c) {
    std::vector<double> ca, cb;
    for (const Vec3& p : sa) ca.push_back(p[c]);
    for (const Vec3& p : sb) cb.push_back(p[c]);
    std::sort(ca.begin(), ca.end());
    std::sort(cb.begin(), cb.end());
    for (size_t i = 0; i < ca.size(); ++i) worst = std::max(worst, std::abs(ca[i] - cb[i]));
  }
  return worst;
}

TEST(DracoCodec, SequentialLevelKeepsOrderAndPositions) {
  for (Schedule schedule : {Schedule::kNone, Schedule::kTandemLag}) {
    const IndexedMesh mesh = SphereMesh(schedule);
    ASSERT_GT(mesh.num_triangles(), 50u);  // simplified at E0 = 0.3: ~100 triangles
    for (int bits : {11, 16, 24}) {
      auto bytes = EncodeDraco(mesh, {bits, 0});
      ASSERT_TRUE(bytes.ok()) << bytes.status();
      auto decoded = DecodeDraco(*bytes);
      ASSERT_TRUE(decoded.ok()) << decoded.status();
      EXPECT_EQ(decoded->num_triangles(), mesh.num_triangles());
      EXPECT_EQ(decoded->num_vertices(), mesh.num_vertices());
      EXPECT_EQ(decoded->indices, mesh.indices) << "level 0 keeps the triangle list as is";
      EXPECT_LE(MaxIndexwiseError(mesh, *decoded), PositionTolerance(mesh, bits)) << bits;
    }
  }
}

TEST(DracoCodec, EdgebreakerKeepsCountsAndPositionsWithinStep) {
  for (Schedule schedule : {Schedule::kNone, Schedule::kTandemLag}) {
    const IndexedMesh mesh = SphereMesh(schedule);
    for (int level : {1, 7, 10}) {
      auto bytes = EncodeDraco(mesh, {16, level});
      ASSERT_TRUE(bytes.ok()) << bytes.status();
      auto decoded = DecodeDraco(*bytes);
      ASSERT_TRUE(decoded.ok()) << decoded.status();
      EXPECT_EQ(decoded->num_triangles(), mesh.num_triangles()) << level;
      EXPECT_EQ(decoded->num_vertices(), mesh.num_vertices()) << level;
      // Sorting each coordinate separately pairs values up in the only order-free way.
      EXPECT_LE(MaxSortedError(mesh, *decoded), PositionTolerance(mesh, 16)) << level;
    }
  }
}

// The GLB primitive (KHR_draco_mesh_compression): it decodes to the mesh, with the counts,
// bounds and attribute ids it reports for the glTF accessors; what Draco cannot carry is
// refused.
TEST(DracoCodec, GlbPrimitiveReportsWhatItDecodesTo) {
  const IndexedMesh mesh = SphereMesh(Schedule::kTandemLag);
  const std::vector<Vec3> normals = io::VertexNormals(mesh);
  auto p = codec::EncodeGlbPrimitive(mesh, normals);
  ASSERT_TRUE(p.ok()) << p.status();
  auto decoded = codec::DecodeDraco(p->bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  EXPECT_EQ(p->vertices, mesh.num_vertices());
  EXPECT_EQ(p->indices, mesh.indices.size());
  EXPECT_EQ(decoded->num_triangles(), mesh.num_triangles());
  EXPECT_NE(p->position_id, p->normal_id);
  for (int a = 0; a < 3; ++a) {
    double lo = decoded->positions[0][a], hi = lo;
    for (const Vec3& v : decoded->positions) {
      lo = std::min(lo, v[a]);
      hi = std::max(hi, v[a]);
    }
    EXPECT_EQ(p->lo[a], lo);
    EXPECT_EQ(p->hi[a], hi);
  }
  EXPECT_EQ(codec::EncodeGlbPrimitive(IndexedMesh{}, {})->vertices, 0u);
  IndexedMesh points;
  points.positions = {{0, 0, 0}, {1, 0, 0}};
  EXPECT_EQ(codec::EncodeGlbPrimitive(points, {{0, 0, 1}, {0, 0, 1}}).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(codec::EncodeGlbPrimitive(mesh, {}).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(DracoCodec, EdgebreakerIsSmallerThanSequential) {
  const IndexedMesh mesh = SphereMesh(Schedule::kNone);
  auto seq = EncodeDraco(mesh, {16, 0});
  auto eb = EncodeDraco(mesh, {16, 7});
  ASSERT_TRUE(seq.ok() && eb.ok());
  EXPECT_LT(eb->size(), seq->size());
}

TEST(DracoCodec, SameInputGivesIdenticalBytes) {
  const IndexedMesh mesh = SphereMesh(Schedule::kTandemLag);
  const IndexedMesh copy = mesh;
  for (int level : {0, 7}) {
    auto a = EncodeDraco(mesh, {16, level});
    auto b = EncodeDraco(copy, {16, level});
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_EQ(*a, *b) << level;
  }
}

// Connectivity Edgebreaker cannot carry as is: the encoder must keep the counts anyway.
TEST(DracoCodec, AwkwardConnectivityKeepsCounts) {
  IndexedMesh bowtie;  // two triangles sharing one vertex only: a non-manifold vertex
  bowtie.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {-1, 0, 0}, {0, -1, 0}};
  bowtie.indices = {0, 1, 2, 0, 3, 4};
  IndexedMesh isolated = bowtie;  // plus a vertex no triangle uses
  isolated.positions.push_back({5, 5, 5});
  IndexedMesh degenerate = bowtie;  // plus a triangle with a repeated corner
  degenerate.indices.insert(degenerate.indices.end(), {1, 1, 2});
  IndexedMesh duplicate;  // two vertices at the same place, not merged
  duplicate.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 0}, {1, 0, 1}};
  duplicate.indices = {0, 1, 2, 3, 2, 4};
  IndexedMesh fan;  // three triangles on one edge: a non-manifold edge
  fan.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}};
  fan.indices = {0, 1, 2, 1, 0, 3, 0, 1, 4};
  IndexedMesh single;
  single.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  single.indices = {0, 1, 2};
  IndexedMesh points;  // vertices, no triangles
  points.positions = {{0, 0, 0}, {1, 2, 3}};
  const IndexedMesh empty;
  for (const auto& [name, mesh] :
       {std::pair{"bowtie", bowtie}, std::pair{"isolated", isolated},
        std::pair{"degenerate", degenerate}, std::pair{"duplicate", duplicate},
        std::pair{"fan", fan}, std::pair{"single", single}, std::pair{"points", points},
        std::pair{"empty", empty}}) {
    for (int level : {0, 7}) {
      auto bytes = EncodeDraco(mesh, {16, level});
      ASSERT_TRUE(bytes.ok()) << name << ": " << bytes.status();
      auto decoded = DecodeDraco(*bytes);
      ASSERT_TRUE(decoded.ok()) << name << ": " << decoded.status();
      EXPECT_EQ(decoded->num_triangles(), mesh.num_triangles()) << name << " level " << level;
      EXPECT_EQ(decoded->num_vertices(), mesh.num_vertices()) << name << " level " << level;
      if (decoded->num_vertices() == mesh.num_vertices()) {
        EXPECT_LE(MaxSortedError(mesh, *decoded), PositionTolerance(mesh, 16)) << name << " level " << level;
      }
    }
  }
}

// Sealed chunks: two pieces of one mesh, encoded on one explicit grid with their vertex ids,
// decode a vertex they share to bit-identical coordinates, and every id comes back with
// its vertex (Edgebreaker may reorder vertices and split a non-manifold one into copies).
TEST(DracoCodec, ExplicitGridAndIdsMakeSharedVerticesBitIdentical) {
  const IndexedMesh sphere = SphereMesh(Schedule::kTandemLag, 40);
  // Split the triangles by the height of their first corner; ids = the sphere's indices.
  IndexedMesh part[2];
  std::vector<uint32_t> ids[2];
  for (int k = 0; k < 2; ++k) {
    std::vector<uint32_t> local(sphere.num_vertices(), kInvalid);
    for (size_t t = 0; t < sphere.num_triangles(); ++t) {
      if ((sphere.positions[sphere.indices[3 * t]].z < 20) != (k == 0)) continue;
      for (int c = 0; c < 3; ++c) {
        const uint32_t v = sphere.indices[3 * t + c];
        if (local[v] == kInvalid) {
          local[v] = static_cast<uint32_t>(part[k].positions.size());
          part[k].positions.push_back(sphere.positions[v]);
          ids[k].push_back(v);
        }
        part[k].indices.push_back(local[v]);
      }
    }
  }
  for (int level : {0, 7}) {
    DracoOptions o{14, level};
    o.grid_origin = {-10, -10, -10};
    o.grid_range = 60;
    std::map<uint32_t, Vec3> seen;
    size_t shared = 0;
    for (int k = 0; k < 2; ++k) {
      auto bytes = EncodeDraco(part[k], o, ids[k]);
      ASSERT_TRUE(bytes.ok()) << bytes.status();
      std::vector<uint32_t> got_ids;
      auto decoded = DecodeDraco(*bytes, &got_ids);
      ASSERT_TRUE(decoded.ok()) << decoded.status();
      ASSERT_EQ(got_ids.size(), decoded->num_vertices());
      EXPECT_EQ(decoded->num_triangles(), part[k].num_triangles());
      EXPECT_GE(decoded->num_vertices(), part[k].num_vertices());
      const double step = 60.0 / ((1 << 14) - 1);
      for (size_t v = 0; v < got_ids.size(); ++v) {
        ASSERT_LT(got_ids[v], sphere.num_vertices());
        const Vec3 want = sphere.positions[got_ids[v]];
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(decoded->positions[v][c], want[c], step);
        auto [it, fresh] = seen.emplace(got_ids[v], decoded->positions[v]);
        if (!fresh && k == 1 && part[0].num_vertices() > 0) {
          ++shared;
          EXPECT_EQ(std::memcmp(&it->second, &decoded->positions[v], sizeof(Vec3)), 0);
        }
      }
    }
    EXPECT_GT(shared, 10u);
    // Without ids a decoder asking for them is told so.
    auto plain = EncodeDraco(part[0], o);
    ASSERT_TRUE(plain.ok());
    std::vector<uint32_t> none;
    EXPECT_EQ(DecodeDraco(*plain, &none).status().code(), absl::StatusCode::kInvalidArgument);
  }
  // One id per vertex, or none.
  std::vector<uint32_t> short_ids(2, 0);
  EXPECT_EQ(EncodeDraco(part[0], {}, short_ids).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// Needle triangles whose apex lies a fifth of a grid step off their base, on a grid line:
// quantized as they are, their three corners fall on one line of the grid (zero area, which
// breaks normals, slicers and some viewers; issue 24). A thin quad's two triangles as well.
// A large triangle sets the box: 100 units on 8 bits, a step of 100 / 255.
IndexedMesh NeedlesOnTheGrid(size_t* needles) {
  const float step = 100.0f / 255.0f;
  IndexedMesh m;
  m.positions = {{0, 0, 0}, {100, 0, 0}, {0, 100, 100}};
  m.indices = {0, 1, 2};
  for (int k = 0; k < 12; ++k) {
    const double x = 10 + 6 * k, y = step * static_cast<float>(40 + 11 * k), z = 30 + 3 * k;
    const uint32_t b = static_cast<uint32_t>(m.positions.size());
    m.positions.push_back({x, y, z});
    m.positions.push_back({x + 5, y, z});
    m.positions.push_back({x + 2.5, y + 0.2 * step, z});
    m.indices.insert(m.indices.end(), {b, b + 1, b + 2});
  }
  const double y = step * 200.0f;  // the quad: (a, b, c) and (a, c, d)
  const uint32_t b = static_cast<uint32_t>(m.positions.size());
  m.positions.push_back({20, y, 60});
  m.positions.push_back({40, y, 60});
  m.positions.push_back({40, y + 0.2 * step, 60});
  m.positions.push_back({20, y + 0.2 * step, 60});
  m.indices.insert(m.indices.end(), {b, b + 1, b + 2, b, b + 2, b + 3});
  *needles = 14;
  return m;
}

bool NoArea(Vec3 a, Vec3 b, Vec3 c) {  // as written: mesh_check's and the engine's rule
  return AreaAtMost(4e-12, TwiceAreaVector(a, b, c), SumSquaredEdges(a, b, c));
}
size_t CountNoArea(const IndexedMesh& m) {
  size_t n = 0;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    const uint32_t* v = &m.indices[3 * t];
    n += NoArea(m.positions[v[0]], m.positions[v[1]], m.positions[v[2]]);
  }
  return n;
}

// No triangle that has an area loses it on the grid or turns over: a corner of each such
// triangle steps to a neighbouring grid point instead (listed in `moved`, decoded exactly
// there), within two steps of where it was. Corners that may not move (`fixed`) stay on
// their nearest grid point, and then the needles do lose their area.
TEST(DracoCodec, ThinTrianglesKeepAnAreaOnTheGrid) {
  size_t needles = 0;
  const IndexedMesh mesh = NeedlesOnTheGrid(&needles);
  ASSERT_EQ(CountNoArea(mesh), 0u);
  const double step = 100.0 / 255, rounding = 4 * 100 * std::numeric_limits<float>::epsilon();
  for (int level : {0, 7}) {
    MovedCorners moved;
    auto bytes = EncodeDraco(mesh, {8, level}, {}, {}, &moved);
    ASSERT_TRUE(bytes.ok()) << bytes.status();
    auto decoded = DecodeDraco(*bytes);
    ASSERT_TRUE(decoded.ok()) << decoded.status();
    ASSERT_EQ(decoded->num_triangles(), mesh.num_triangles()) << level;
    EXPECT_EQ(CountNoArea(*decoded), 0u) << level;
    EXPECT_GE(moved.size(), needles / 2) << level;  // the quad may need one corner for both
    EXPECT_LE(MaxSortedError(mesh, *decoded), PositionTolerance(mesh, 8)) << level;
    if (level != 0) continue;
    // Level 0 keeps the order: each triangle faces as it did, the moved corners are where
    // `moved` says, the others on their nearest grid point.
    for (size_t t = 0; t < mesh.num_triangles(); ++t) {
      const uint32_t* v = &mesh.indices[3 * t];
      const Vec3 before = TwiceAreaVector(mesh.positions[v[0]], mesh.positions[v[1]],
                                          mesh.positions[v[2]]);
      const Vec3 after = TwiceAreaVector(decoded->positions[v[0]], decoded->positions[v[1]],
                                         decoded->positions[v[2]]);
      EXPECT_GT(Dot(before, after), 0) << t;
    }
    std::vector<bool> was_moved(mesh.num_vertices(), false);
    for (const auto& [v, at] : moved) {
      ASSERT_LT(v, mesh.num_vertices());
      was_moved[v] = true;
      EXPECT_EQ(decoded->positions[v], at) << v;
      for (int c = 0; c < 3; ++c) EXPECT_LE(std::abs(at[c] - mesh.positions[v][c]), 1.5 * step + rounding);
    }
    for (size_t v = 0; v < mesh.num_vertices(); ++v) {
      if (was_moved[v]) continue;
      for (int c = 0; c < 3; ++c) {
        EXPECT_LE(std::abs(decoded->positions[v][c] - mesh.positions[v][c]), 0.5 * step + rounding);
      }
    }
  }
  // Every corner fixed: nothing moves, and the needles lose their area.
  const std::vector<uint8_t> all(mesh.num_vertices(), 1);
  MovedCorners moved;
  auto bytes = EncodeDraco(mesh, {8, 0}, {}, all, &moved);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  auto decoded = DecodeDraco(*bytes);
  ASSERT_TRUE(decoded.ok());
  EXPECT_TRUE(moved.empty());
  EXPECT_EQ(CountNoArea(*decoded), needles);
  EXPECT_LE(MaxIndexwiseError(mesh, *decoded), 0.5 * step + rounding);
  // One flag per vertex, or none.
  EXPECT_EQ(EncodeDraco(mesh, {8, 0}, {}, std::vector<uint8_t>(2, 0)).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// Two sheets touching at a point (a grid point on the iso-value, the extractor's offset
// keeping them a hair apart): two fans, each a cone, whose apexes lie closer than a grid
// step. On the grid the apexes would be one point, which a reader welding by position joins
// (a non-manifold vertex); one of them steps to a free neighbouring grid point, where its
// triangles keep their areas and facing. With `avoid` (another buffer's vertex there) both
// move off it; fixed, they stay on it.
TEST(DracoCodec, VerticesOnOneGridPointStepApart) {
  IndexedMesh mesh;
  // A step is 1.9 / 255 (the box's largest extent, y); the apexes, 0.5 over its lowest z,
  // lie inside one, on grid point 67 of z.
  const double hair = 1e-4;
  for (const double side : {1.0, -0.5}) {
    const uint32_t apex = static_cast<uint32_t>(mesh.positions.size());
    mesh.positions.push_back({0, 0, side > 0 ? hair : -hair});
    for (int k = 0; k < 5; ++k) {
      const double a = 2 * 3.141592653589793 * k / 5;
      mesh.positions.push_back({std::cos(a), std::sin(a), side});
    }
    for (uint32_t k = 0; k < 5; ++k) {
      const uint32_t b = apex + 1 + k, c = apex + 1 + (k + 1) % 5;
      mesh.indices.insert(mesh.indices.end(), {apex, side > 0 ? b : c, side > 0 ? c : b});
    }
  }
  auto check = [&](const std::vector<Vec3>& avoid, const std::vector<uint8_t>& fixed,
                   size_t duplicates, size_t apexes_moved, const std::string& what) {
    for (int level : {0, 7}) {
      MovedCorners moved;
      auto bytes = EncodeDraco(mesh, {8, level}, {}, fixed, &moved, avoid);
      ASSERT_TRUE(bytes.ok()) << bytes.status();
      auto decoded = DecodeDraco(*bytes);
      ASSERT_TRUE(decoded.ok()) << decoded.status();
      EXPECT_EQ(eval::CountDuplicatePositions(*decoded), duplicates) << what << level;
      EXPECT_EQ(CountNoArea(*decoded), 0u) << what << level;
      EXPECT_LE(MaxSortedError(mesh, *decoded), PositionTolerance(mesh, 8)) << what << level;
      EXPECT_EQ(moved.size(), apexes_moved) << what << level;
      for (const auto& [v, at] : moved) EXPECT_TRUE(v == 0 || v == 6) << what << v;
    }
  };
  check({}, {}, 0, 1, "apart ");
  check({{0, 0, 0}}, {}, 0, 2, "avoiding the apexes' point ");
  std::vector<uint8_t> fixed(mesh.num_vertices(), 0);
  fixed[0] = fixed[6] = 1;
  check({}, fixed, 1, 0, "fixed ");
}

// The full-resolution surface of an integer scan at an integer iso-value (surface points a
// hair off the grid points on it, closer together than a grid step at every depth below 16
// bits) keeps its vertices apart and its triangles' areas on the grid, down to 8 bits: welded
// by position, the decoded mesh is the indexed one.
TEST(DracoCodec, AnIntegerScansFullSurfaceKeepsItsVerticesApartAtEveryDepth) {
  constexpr int64_t nx = 96, ny = 48, nz = 40;
  testing::QuantisedSource phantom(
      DType::kUInt8, nx, ny, nz,
      [](double i, double j, double k) { return testing::Phantom(nx, ny, nz, i, j, k); },
      {0.7, 0.7, 1.2}, {-130.5, 42.25, 300});
  SessionOptions o;
  o.iso = 120;
  o.schedule = Schedule::kNone;
  auto session = io::RunSession(phantom, o);
  ASSERT_TRUE(session.ok()) << session.status();
  const IndexedMesh mesh = (*session)->Snapshot();
  const eval::TopologyReport indexed = eval::AnalyzeTopology(mesh);
  ASSERT_TRUE(indexed.IsManifold());
  for (int bits : {16, 14, 12, 10, 8}) {
    for (int level : {0, 7}) {
      auto bytes = EncodeDraco(mesh, {bits, level});
      ASSERT_TRUE(bytes.ok()) << bytes.status();
      auto decoded = DecodeDraco(*bytes);
      ASSERT_TRUE(decoded.ok()) << decoded.status();
      testing::ExpectEmbedded(*decoded, indexed, absl::StrCat(bits, " bits, level ", level));
      EXPECT_LE(MaxSortedError(mesh, *decoded), PositionTolerance(mesh, bits)) << bits;
    }
  }
}

TEST(DracoCodec, RejectsBadMeshesAndOptions) {
  IndexedMesh bad;
  bad.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  bad.indices = {0, 1, 3};
  EXPECT_EQ(EncodeDraco(bad).status().code(), absl::StatusCode::kInvalidArgument);
  bad.indices = {0, 1};
  EXPECT_EQ(EncodeDraco(bad).status().code(), absl::StatusCode::kInvalidArgument);
  bad.indices = {0, 1, 2};
  bad.positions[1].x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(EncodeDraco(bad).status().code(), absl::StatusCode::kInvalidArgument);
  const IndexedMesh ok = SphereMesh(Schedule::kTandemLag, 12);
  EXPECT_EQ(EncodeDraco(ok, {0, 7}).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeDraco(ok, {31, 7}).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeDraco(ok, {16, 11}).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeDraco(ok, {16, -1}).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(DracoCodec, RejectsGarbageAndTruncatedBuffers) {
  EXPECT_FALSE(DecodeDraco("").ok());
  EXPECT_FALSE(DecodeDraco("definitely not draco").ok());
  const IndexedMesh mesh = SphereMesh(Schedule::kTandemLag, 16);
  auto bytes = EncodeDraco(mesh);
  ASSERT_TRUE(bytes.ok());
  for (size_t keep : {size_t{10}, bytes->size() / 2, bytes->size() - 1}) {
    auto decoded = DecodeDraco(std::string_view(*bytes).substr(0, keep));
    EXPECT_FALSE(decoded.ok() && decoded->num_triangles() == mesh.num_triangles())
        << "a buffer cut to " << keep << " bytes must not decode to the whole mesh";
  }
}

TEST(DracoCodec, PositionToleranceIsTwoStepsOfTheLargestExtentPlusRounding) {
  IndexedMesh m;
  m.positions = {{0, 0, 0}, {2, 1, 0.5}};
  const double rounding = 4 * 2 * static_cast<double>(std::numeric_limits<float>::epsilon());
  EXPECT_DOUBLE_EQ(PositionTolerance(m, 16), 2 * 2.0 / 65535 + rounding);
  EXPECT_EQ(PositionTolerance(IndexedMesh{}, 16), 0);
}

}  // namespace
}  // namespace tandem::codec
