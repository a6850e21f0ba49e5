// Checks of an output as its readers see it: positions as written (float32), triangles with
// no area as written (kWrittenSquared), vertices sharing a position, and the mesh welded by
// position (as STL readers and 3D-printer slicers weld) against the indexed mesh's topology;
// and integer volumes whose values meet integer iso-values at many grid points.
// Header-only; GLB reading needs nlohmann_json linked.
#ifndef TANDEM_TESTS_TESTUTIL_EMBEDDED_H_
#define TANDEM_TESTS_TESTUTIL_EMBEDDED_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tandem/geometry.h"
#include "tandem/mesh.h"
#include "tandem/eval/topology.h"
#include "tandem/volume.h"
#include "testutil/testutil.h"

namespace tandem::testing {

// The mesh as written: positions rounded to float32.
inline IndexedMesh AsWritten(IndexedMesh m) {
  for (Vec3& p : m.positions) {
    p = Vec3{static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)};
  }
  return m;
}

// The triangles for which rule(a, b, c) holds (IsWrittenDegenerate, IsDegenerateTriangle).
template <typename Rule>
int64_t CountTrianglesWhere(const IndexedMesh& m, Rule rule) {
  int64_t n = 0;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    n += rule(m.positions[m.indices[3 * t]], m.positions[m.indices[3 * t + 1]],
              m.positions[m.indices[3 * t + 2]]);
  }
  return n;
}
inline int64_t CountWrittenDegenerate(const IndexedMesh& m) {
  return CountTrianglesWhere(m, IsWrittenDegenerate);
}

// `written` (float32 positions) has no triangle without an area as written and no two
// vertices at one position, and welded by position it has the indexed mesh's topology
// (`indexed`: its vertices, edges, boundary, non-manifold places and Euler characteristic).
inline void ExpectEmbedded(const IndexedMesh& written, const eval::TopologyReport& indexed,
                           const std::string& what) {
  EXPECT_EQ(CountWrittenDegenerate(written), 0) << what;
  EXPECT_EQ(eval::CountDuplicatePositions(written), 0u) << what;
  const eval::TopologyReport welded = eval::AnalyzeTopology(eval::WeldByPosition(written));
  EXPECT_EQ(welded.IsManifold(), indexed.IsManifold()) << what;
  EXPECT_EQ(welded.nonmanifold_edges, indexed.nonmanifold_edges) << what;
  EXPECT_EQ(welded.nonmanifold_vertices, indexed.nonmanifold_vertices) << what;
  EXPECT_EQ(welded.vertices, indexed.vertices) << what;
  EXPECT_EQ(welded.edges, indexed.edges) << what;
  EXPECT_EQ(welded.triangles, indexed.triangles) << what;
  EXPECT_EQ(welded.boundary_edges, indexed.boundary_edges) << what;
  EXPECT_EQ(welded.euler, indexed.euler) << what;
}
// The same for an indexed mesh in doubles, written as float32; a manifold unless said
// otherwise (a sealed session's band, cut from what it sealed, may pinch at the cut).
inline void ExpectEmbedded(const IndexedMesh& indexed, const std::string& what,
                           bool manifold = true) {
  const eval::TopologyReport topology = eval::AnalyzeTopology(indexed);
  if (manifold) {
    EXPECT_TRUE(topology.IsManifold()) << what;
  }
  ExpectEmbedded(AsWritten(indexed), topology, what);
}

// A GLB file as WriteMesh writes it: its mesh (positions and indices), or with
// KHR_draco_mesh_compression the Draco buffer (`draco`, the mesh left empty).
struct Glb {
  IndexedMesh mesh;
  std::string draco;
};
inline Glb ReadGlb(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string bytes = ss.str();
  Glb glb;
  auto u32 = [&](size_t at) {
    uint32_t v = 0;
    if (at + 4 <= bytes.size()) std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  const size_t json_len = u32(12), bin = 20 + json_len + 8;
  EXPECT_LE(bin, bytes.size()) << path;
  if (bin > bytes.size()) return glb;
  const nlohmann::json j = nlohmann::json::parse(bytes.substr(20, json_len));
  const auto& primitive = j["meshes"][0]["primitives"][0];
  if (primitive.contains("extensions")) {
    const size_t length = j["bufferViews"][0]["byteLength"].get<size_t>();
    glb.draco = bytes.substr(bin, length);
    return glb;
  }
  const size_t nv = j["accessors"][0]["count"].get<size_t>();
  const size_t ni = j["accessors"][2]["count"].get<size_t>();
  const size_t indices_at = bin + j["bufferViews"][2]["byteOffset"].get<size_t>();
  for (size_t v = 0; v < nv; ++v) {
    float p[3];
    std::memcpy(p, bytes.data() + bin + 12 * v, 12);
    glb.mesh.positions.push_back(Vec3{p[0], p[1], p[2]});
  }
  for (size_t i = 0; i < ni; ++i) glb.mesh.indices.push_back(u32(indices_at + 4 * i));
  return glb;
}

// A volume of `dtype` from a formula, each value rounded and held in the type's range.
class QuantisedSource : public SliceSource {
 public:
  QuantisedSource(DType dtype, int64_t nx, int64_t ny, int64_t nz,
                  std::function<double(double, double, double)> f,
                  std::array<double, 3> spacing = {1, 1, 1},
                  std::array<double, 3> origin = {0, 0, 0})
      : f_(std::move(f)) {
    info_.nx = nx;
    info_.ny = ny;
    info_.nz = nz;
    info_.dtype = dtype;
    info_.spacing = spacing;
    info_.origin = origin;
  }
  const VolumeInfo& info() const override { return info_; }
  int64_t next_slice() const override { return k_; }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    if (k_ >= info_.nz) return absl::OutOfRangeError("end of volume");
    bytes->resize(info_.slice_bytes());
    const size_t size = DTypeSize(info_.dtype);
    for (int64_t j = 0; j < info_.ny; ++j) {
      for (int64_t i = 0; i < info_.nx; ++i) {
        StoreValue(info_.dtype, Value(i, j, k_),
                   bytes->data() + static_cast<size_t>(j * info_.nx + i) * size);
      }
    }
    ++k_;
    return absl::OkStatus();
  }
  double Value(int64_t i, int64_t j, int64_t k) const {
    double v =
        std::round(f_(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
    if (info_.dtype == DType::kUInt8) v = std::clamp(v, 0.0, 255.0);
    if (info_.dtype == DType::kInt16) v = std::clamp(v, -32768.0, 32767.0);
    return v;
  }

 private:
  VolumeInfo info_;
  std::function<double(double, double, double)> f_;
  int64_t k_ = 0;
};

// A CT-like phantom of a grid nx x ny x nz: two overlapping bumpy balls whose values rise 8
// a voxel inward from 120 at their rims, so that an integer iso-value near 120 meets about
// one grid point in eight of the surface exactly, and where the balls meet, sheets touch.
double Phantom(double nx, double ny, double nz, double i, double j, double k) {
  const double r = 0.3 * std::min(ny, nz);
  auto ball = [&](double cx) {
    return r - std::sqrt((i - cx) * (i - cx) + (j - ny / 2) * (j - ny / 2) +
                         (k - nz / 2) * (k - nz / 2));
  };
  return 120 + 8 * std::max(ball(0.36 * nx), ball(0.64 * nx)) +
         5 * std::sin(0.5 * i) * std::sin(0.45 * j) * std::sin(0.4 * k);
}

}  // namespace tandem::testing

#endif  // TANDEM_TESTS_TESTUTIL_EMBEDDED_H_
