// Tests of PLY/OBJ reading and writing (mesh_io.h): exact round trips, the PLY variants
// other tools write (ASCII, big-endian, double coordinates, extra properties, polygons),
// OBJ face forms, and errors that name the file and the problem.
#include "tandem/io/mesh_io.h"

#include <gtest/gtest.h>

#include <bit>
#include <cstring>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include "testutil/testutil.h"

namespace tandem {
namespace {

// GoogleTest without gMock (the test targets do not link it): a substring check that
// prints the whole text on failure.
::testing::AssertionResult Contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "'" << part << "' not found in '" << text << "'";
}

// A bumpy nx × ny grid, with coordinates chosen to be exactly representable as float32 so
// that a PLY round trip (float32 positions) must reproduce them bit for bit.
IndexedMesh BumpyGrid(int nx, int ny, bool float_exact, uint64_t seed = 5) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> z(-3.0, 3.0);
  IndexedMesh m;
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i <= nx; ++i) {
      Vec3 p{0.1 * i - 7.3, 1e3 + 0.37 * j, z(rng)};
      if (float_exact) {
        for (int k = 0; k < 3; ++k) p[k] = static_cast<float>(p[k]);
      }
      m.positions.push_back(p);
    }
  }
  auto id = [&](int i, int j) { return static_cast<uint32_t>(j * (nx + 1) + i); };
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  return m;
}

void WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class MeshIoTest : public ::testing::Test {
 protected:
  std::string Path(const std::string& name) const { return dir_ + "/" + name; }
  std::string dir_ = testing::MakeTempDir();
};

// Expects an error whose message names the file and contains `problem`.
void ExpectError(const absl::StatusOr<IndexedMesh>& result, const std::string& path,
                 absl::StatusCode code, const std::string& problem) {
  ASSERT_FALSE(result.ok()) << "reading " << path << " should fail";
  EXPECT_EQ(result.status().code(), code) << result.status();
  EXPECT_TRUE(Contains(std::string(result.status().message()), path));
  EXPECT_TRUE(Contains(std::string(result.status().message()), problem));
}

TEST_F(MeshIoTest, BinaryPlyRoundTripIsExact) {
  const IndexedMesh mesh = BumpyGrid(40, 30, /*float_exact=*/true);
  const std::string path = Path("grid.ply");
  ASSERT_TRUE(io::WriteMesh(path, mesh).ok());
  // Header as documented: binary little-endian, float xyz, uchar/int faces.
  const std::string bytes = ReadFile(path);
  EXPECT_EQ(bytes.rfind("ply\nformat binary_little_endian 1.0\n", 0), 0u);
  EXPECT_TRUE(Contains(bytes, "element vertex 1271\n"));
  EXPECT_TRUE(Contains(bytes, "property float x\n"));
  EXPECT_TRUE(Contains(bytes, "property float nz\n"));  // area-weighted vertex normals
  EXPECT_TRUE(Contains(bytes, "element face 2400\nproperty list uchar int vertex_indices\n"));
  const size_t header = bytes.find("end_header\n") + 11;
  EXPECT_EQ(bytes.size(), header + 1271 * 24 + 2400 * 13);
  io::MeshWriteOptions bare;
  bare.normals = false;
  ASSERT_TRUE(io::WriteMesh(Path("bare.ply"), mesh, bare).ok());
  EXPECT_EQ(ReadFile(Path("bare.ply")).size(), header + 1271 * 12 + 2400 * 13 -
                                                    std::string("property float nx\n").size() * 3);

  const absl::StatusOr<IndexedMesh> back = io::ReadMesh(path);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->positions, mesh.positions);
  EXPECT_EQ(back->indices, mesh.indices);
}

TEST_F(MeshIoTest, BinaryPlyRoundsDoublesToFloat) {
  const IndexedMesh mesh = BumpyGrid(5, 5, /*float_exact=*/false);
  const std::string path = Path("doubles.PLY");  // extension case does not matter
  ASSERT_TRUE(io::WriteMesh(path, mesh).ok());
  const absl::StatusOr<IndexedMesh> back = io::ReadMesh(path);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->positions.size(), mesh.positions.size());
  for (size_t v = 0; v < mesh.positions.size(); ++v) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(back->positions[v][k],
                static_cast<double>(static_cast<float>(mesh.positions[v][k])));
    }
  }
}

TEST_F(MeshIoTest, ObjRoundTripIsExactAtFloatPrecision) {
  const IndexedMesh mesh = BumpyGrid(20, 10, /*float_exact=*/false);
  const std::string path = Path("grid.obj");
  ASSERT_TRUE(io::WriteMesh(path, mesh).ok());
  const absl::StatusOr<IndexedMesh> back = io::ReadMesh(path);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->indices, mesh.indices);
  ASSERT_EQ(back->positions.size(), mesh.positions.size());
  for (size_t v = 0; v < mesh.positions.size(); ++v) {
    for (int k = 0; k < 3; ++k) {
      // The written decimal reads back as the same float32; in double it is within float
      // precision of the original.
      EXPECT_EQ(static_cast<float>(back->positions[v][k]),
                static_cast<float>(mesh.positions[v][k]));
      EXPECT_NEAR(back->positions[v][k], mesh.positions[v][k],
                  1e-7 * std::abs(mesh.positions[v][k]));
    }
  }
  const std::string text = ReadFile(path);
  EXPECT_TRUE(Contains(text, "\nf 1//1 2//2 23//23\n"));  // 1-based corners, normal i of vertex i
  EXPECT_TRUE(Contains(text, "\nvn "));
  EXPECT_TRUE(Contains(text, "\nv -7.3 1000 "));  // shortest float32 decimals
}

TEST_F(MeshIoTest, LargeMeshCrossesTheWriteBuffer) {
  const IndexedMesh mesh = BumpyGrid(300, 300, /*float_exact=*/true);  // 180k triangles
  for (const char* name : {"large.ply", "large.obj"}) {
    ASSERT_TRUE(io::WriteMesh(Path(name), mesh).ok());
    const absl::StatusOr<IndexedMesh> back = io::ReadMesh(Path(name));
    ASSERT_TRUE(back.ok()) << back.status();
    EXPECT_EQ(back->indices, mesh.indices) << name;
    ASSERT_EQ(back->positions.size(), mesh.positions.size()) << name;
    size_t mismatches = 0;  // compared as float32, the precision of both formats
    for (size_t v = 0; v < mesh.positions.size(); ++v) {
      for (int k = 0; k < 3; ++k) {
        mismatches +=
            static_cast<float>(back->positions[v][k]) != static_cast<float>(mesh.positions[v][k]);
      }
    }
    EXPECT_EQ(mismatches, 0u) << name;
  }
}

TEST_F(MeshIoTest, EmptyMeshRoundTrips) {
  for (const char* name : {"empty.ply", "empty.obj"}) {
    ASSERT_TRUE(io::WriteMesh(Path(name), IndexedMesh{}).ok());
    const absl::StatusOr<IndexedMesh> back = io::ReadMesh(Path(name));
    ASSERT_TRUE(back.ok()) << back.status();
    EXPECT_EQ(back->num_vertices(), 0u);
    EXPECT_EQ(back->num_triangles(), 0u);
  }
}

TEST_F(MeshIoTest, AsciiPlyWithExtraPropertiesAndPolygons) {
  const std::string path = Path("ascii.ply");
  WriteFile(path,
            "ply\r\n"
            "format ascii 1.0\r\n"
            "comment made by hand\r\n"
            "obj_info nothing\r\n"
            "element vertex 5\r\n"
            "property double x\r\n"
            "property uchar red\r\n"
            "property double y\r\n"
            "property double z\r\n"
            "property list uchar float texcoord\r\n"
            "element face 2\r\n"
            "property int flags\r\n"
            "property list int uint vertex_indices\r\n"
            "element extra 1\r\n"
            "property list uchar int stuff\r\n"
            "end_header\r\n"
            "0 255 0 0 2 0.5 0.5\r\n"
            "1.5 0 0 0 0\r\n"
            "1 1 1 0 0\n"
            "0   7 1 -2.5e-1  1 9\n"
            "+0.5 0 2 3 0\n"
            "7 4 0 1 2 3\n"
            "8 3 1 4 2\n"
            "3 1 2 3\n");
  const absl::StatusOr<IndexedMesh> m = io::ReadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status();
  ASSERT_EQ(m->num_vertices(), 5u);
  EXPECT_EQ(m->positions[1], (Vec3{1.5, 0, 0}));
  EXPECT_EQ(m->positions[3], (Vec3{0, 1, -0.25}));
  EXPECT_EQ(m->positions[4], (Vec3{0.5, 2, 3}));
  // The quad is fanned into (0 1 2) (0 2 3); then the triangle.
  EXPECT_EQ(m->indices, (std::vector<uint32_t>{0, 1, 2, 0, 2, 3, 1, 4, 2}));
}

// Big-endian bytes of integers and floating-point numbers, for a hand-made PLY.
template <typename T>
void AppendBig(std::string& out, T value) {
  using U =
      std::conditional_t<sizeof(T) == 8, uint64_t,
                         std::conditional_t<sizeof(T) == 4, uint32_t,
                                            std::conditional_t<sizeof(T) == 2, uint16_t, uint8_t>>>;
  const U bits = std::bit_cast<U>(value);
  for (int i = sizeof(T) - 1; i >= 0; --i)
    out.push_back(static_cast<char>((bits >> (8 * i)) & 0xff));
}

TEST_F(MeshIoTest, BigEndianPlyWithDoublesAndUintIndices) {
  std::string bytes =
      "ply\nformat binary_big_endian 1.0\n"
      "element vertex 4\nproperty float64 x\nproperty float64 y\nproperty float64 z\n"
      "property float confidence\n"
      "element face 1\nproperty list ushort uint vertex_index\nproperty short tag\n"
      "end_header\n";
  const double xyz[4][3] = {{0.1, 0.2, 0.3}, {1e10, -2, 3}, {-0.0, 5, 6}, {7, 8, 9.125}};
  for (const auto& p : xyz) {
    for (double c : p) AppendBig(bytes, c);
    AppendBig(bytes, 0.5f);
  }
  AppendBig(bytes, uint16_t{4});
  for (uint32_t i : {3u, 2u, 1u, 0u}) AppendBig(bytes, i);
  AppendBig(bytes, int16_t{-1});
  const std::string path = Path("big.ply");
  WriteFile(path, bytes);
  const absl::StatusOr<IndexedMesh> m = io::ReadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status();
  ASSERT_EQ(m->num_vertices(), 4u);
  for (int v = 0; v < 4; ++v) EXPECT_EQ(m->positions[v], (Vec3{xyz[v][0], xyz[v][1], xyz[v][2]}));
  EXPECT_EQ(m->indices, (std::vector<uint32_t>{3, 2, 1, 3, 1, 0}));
}

TEST_F(MeshIoTest, LittleEndianPlyWithDoublesAndIntCounts) {
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\n"
      "element vertex 3\nproperty double x\nproperty double y\nproperty double z\n"
      "element face 1\nproperty list int int vertex_indices\nend_header\n";
  auto append_le = [&](const void* p, size_t n) {
    // The test host is little-endian (x86/ARM); check rather than assume.
    ASSERT_EQ(std::endian::native, std::endian::little);
    bytes.append(static_cast<const char*>(p), n);
  };
  const double xyz[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0.1};
  append_le(xyz, sizeof xyz);
  const int32_t face[4] = {3, 0, 1, 2};
  append_le(face, sizeof face);
  const std::string path = Path("le.ply");
  WriteFile(path, bytes);
  const absl::StatusOr<IndexedMesh> m = io::ReadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->positions[2], (Vec3{0, 1, 0.1}));
  EXPECT_EQ(m->indices, (std::vector<uint32_t>{0, 1, 2}));
}

TEST_F(MeshIoTest, ObjFaceFormsAndNegativeIndices) {
  const std::string path = Path("forms.obj");
  WriteFile(path,
            "# a comment\r\n"
            "mtllib x.mtl\r\n"
            "o thing\n"
            "v 0 0 0\n"
            "v 1 0 0 1.0\n"
            "vt 0 0\n"
            "vn 0 0 1\n"
            "v 1 1 0   # trailing comment\n"
            "v\t0 1 0\n"
            "g group\n"
            "s off\n"
            "usemtl m\n"
            "f 1/1/1 2/2/1 3/3/1\n"
            "f 1//1 3//1 4//1\n"
            "f -4/1 -3/1 -2/1 -1/1\n"
            "v 2 2 2\n"
            "f -1 1 2\n"
            "f 1 2\n");  // a degenerate 2-corner face is dropped
  const absl::StatusOr<IndexedMesh> m = io::ReadMesh(path);
  ASSERT_TRUE(m.ok()) << m.status();
  ASSERT_EQ(m->num_vertices(), 5u);
  EXPECT_EQ(m->positions[1], (Vec3{1, 0, 0}));
  EXPECT_EQ(m->positions[3], (Vec3{0, 1, 0}));
  EXPECT_EQ(m->indices, (std::vector<uint32_t>{0, 1, 2, 0, 2, 3, 0, 1, 2, 0, 2, 3, 4, 0, 1}));
}

TEST_F(MeshIoTest, MissingFileAndUnknownExtension) {
  const std::string missing = Path("nope.ply");
  ExpectError(io::ReadMesh(missing), missing, absl::StatusCode::kNotFound, "cannot open");
  const std::string off = Path("mesh.off");
  WriteFile(off, "OFF\n");
  ExpectError(io::ReadMesh(off), off, absl::StatusCode::kInvalidArgument, "'.off'");
  EXPECT_EQ(io::WriteMesh(off, IndexedMesh{}).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(io::IsMeshOutputPath(off));
  EXPECT_TRUE(io::IsMeshOutputPath(Path("MESH.GLB")));
  const std::string glb = Path("mesh.glb");
  ASSERT_TRUE(io::WriteMesh(glb, BumpyGrid(2, 2, true)).ok());
  ExpectError(io::ReadMesh(glb), glb, absl::StatusCode::kInvalidArgument, "reading .glb");
}

TEST_F(MeshIoTest, VertexNormalsAreAreaWeighted) {
  // A unit square's corner shared by a big and a small triangle in perpendicular planes.
  IndexedMesh m;
  m.positions = {{0, 0, 0}, {2, 0, 0}, {0, 2, 0}, {0, 0, 1}, {0, 0, 0}};
  m.indices = {0, 1, 2,   // area 2 in z = 0, normal +z
               0, 3, 1};  // area 1 in y = 0, normal +y... (0,0,1)x(2,0,0) = (0,2,0)
  const std::vector<Vec3> n = io::VertexNormals(m);
  ASSERT_EQ(n.size(), 5u);
  // Vertex 0: 2 (0,0,1) + 1 (0,1,0), normalised.
  EXPECT_NEAR(n[0].x, 0, 1e-15);
  EXPECT_NEAR(n[0].y, 1 / std::sqrt(5.0), 1e-15);
  EXPECT_NEAR(n[0].z, 2 / std::sqrt(5.0), 1e-15);
  EXPECT_NEAR(n[2].z, 1, 1e-15);
  EXPECT_EQ(n[4].x, 0);  // unused vertex
  EXPECT_EQ(n[4].z, 0);
}

TEST_F(MeshIoTest, BinaryStlRoundTripWeldsTheCorners) {
  const IndexedMesh mesh = BumpyGrid(30, 20, /*float_exact=*/true);
  const std::string path = Path("grid.stl");
  ASSERT_TRUE(io::WriteMesh(path, mesh).ok());
  const std::string bytes = ReadFile(path);
  ASSERT_EQ(bytes.size(), 84u + 50u * 1200);
  EXPECT_NE(bytes.rfind("solid", 0), 0u);  // an ASCII reader must not take it for ASCII STL
  uint32_t count;
  std::memcpy(&count, bytes.data() + 80, 4);
  EXPECT_EQ(count, 1200u);
  float normal[3];  // the first facet's: unit, and along the triangle's area vector
  std::memcpy(normal, bytes.data() + 84, 12);
  EXPECT_NEAR(std::hypot(normal[0], normal[1], normal[2]), 1.0, 1e-6);
  const absl::StatusOr<IndexedMesh> back = io::ReadMesh(path);
  ASSERT_TRUE(back.ok()) << back.status();
  // Welded: the grid's vertex count, each triangle with its corners (ids in order of first
  // appearance).
  EXPECT_EQ(back->positions.size(), mesh.positions.size());
  ASSERT_EQ(back->indices.size(), mesh.indices.size());
  for (size_t i = 0; i < mesh.indices.size(); ++i) {
    EXPECT_EQ(back->positions[back->indices[i]], mesh.positions[mesh.indices[i]]) << i;
  }

  WriteFile(Path("cut.stl"), bytes.substr(0, bytes.size() - 7));
  ExpectError(io::ReadMesh(Path("cut.stl")), Path("cut.stl"), absl::StatusCode::kDataLoss,
              "binary STL of 1200 triangles needs 60084 bytes");
  WriteFile(Path("ascii.stl"), "solid x\nfacet normal 0 0 1\nendsolid x\n");
  ExpectError(io::ReadMesh(Path("ascii.stl")), Path("ascii.stl"),
              absl::StatusCode::kInvalidArgument, "ASCII STL is not supported");
}

// The GLB container and its accessors as glTF 2.0 lays them out (the Khronos validator
// checks the rest in tests/formats).
TEST_F(MeshIoTest, GlbHoldsPositionsNormalsAndIndices) {
  const IndexedMesh mesh = BumpyGrid(4, 3, /*float_exact=*/true);
  const std::string path = Path("grid.glb");
  ASSERT_TRUE(io::WriteMesh(path, mesh).ok());
  const std::string bytes = ReadFile(path);
  auto u32 = [&](size_t at) {
    uint32_t v;
    std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  ASSERT_GE(bytes.size(), 20u);
  EXPECT_EQ(u32(0), 0x46546C67u);
  EXPECT_EQ(u32(4), 2u);
  EXPECT_EQ(u32(8), bytes.size());
  const uint32_t json_len = u32(12);
  EXPECT_EQ(u32(16), 0x4E4F534Au);
  EXPECT_EQ(json_len % 4, 0u);
  const std::string json = bytes.substr(20, json_len);
  EXPECT_TRUE(Contains(json, "\"POSITION\":0"));
  EXPECT_TRUE(Contains(json, "\"NORMAL\":1"));
  EXPECT_TRUE(Contains(json, "\"count\":72"));  // 24 triangles x 3 indices
  const size_t bin = 20 + json_len;
  const size_t nv = mesh.num_vertices();
  ASSERT_EQ(u32(bin), nv * 24 + mesh.indices.size() * 4);
  EXPECT_EQ(u32(bin + 4), 0x004E4942u);
  for (size_t v = 0; v < nv; ++v) {
    float p[3];
    std::memcpy(p, bytes.data() + bin + 8 + 12 * v, 12);
    EXPECT_EQ(p[0], static_cast<float>(mesh.positions[v].x)) << v;
    EXPECT_EQ(p[2], static_cast<float>(mesh.positions[v].z)) << v;
  }
  EXPECT_EQ(u32(bin + 8 + nv * 24), mesh.indices[0]);
  EXPECT_EQ(u32(bytes.size() - 4), mesh.indices.back());
}

TEST_F(MeshIoTest, TruncatedBinaryPly) {
  const IndexedMesh mesh = BumpyGrid(4, 4, true);
  const std::string path = Path("cut.ply");
  ASSERT_TRUE(io::WriteMesh(path, mesh).ok());
  const std::string bytes = ReadFile(path);
  // Cut inside the faces, then inside the vertices.
  WriteFile(path, bytes.substr(0, bytes.size() - 5));
  ExpectError(io::ReadMesh(path), path, absl::StatusCode::kDataLoss, "truncated");
  ExpectError(io::ReadMesh(path), path, absl::StatusCode::kDataLoss, "'face' 31 of 32");
  WriteFile(path, bytes.substr(0, bytes.find("end_header\n") + 11 + 60));  // 24 B a vertex
  ExpectError(io::ReadMesh(path), path, absl::StatusCode::kDataLoss, "'vertex' 2 of 25");
  // Cut inside the header.
  WriteFile(path, bytes.substr(0, 60));
  ExpectError(io::ReadMesh(path), path, absl::StatusCode::kInvalidArgument, "end_header");
}

TEST_F(MeshIoTest, TruncatedAsciiPlyAndBadNumbers) {
  const std::string path = Path("cut_ascii.ply");
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
  WriteFile(path, header + "0 0 0\n1 0 0\n0 1 0\n3 0 1\n");
  ExpectError(io::ReadMesh(path), path, absl::StatusCode::kDataLoss, "truncated");
  WriteFile(path, header + "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n");
  ExpectError(io::ReadMesh(path), path, absl::StatusCode::kInvalidArgument, "bad number 'zero'");
  ExpectError(io::ReadMesh(path), path, absl::StatusCode::kInvalidArgument, "line 11");
}

TEST_F(MeshIoTest, GarbageFiles) {
  std::string garbage(4096, '\0');
  std::mt19937 rng(1);
  for (char& c : garbage) c = static_cast<char>(rng() & 0xff);
  const std::string ply = Path("garbage.ply");
  WriteFile(ply, garbage);
  ExpectError(io::ReadMesh(ply), ply, absl::StatusCode::kInvalidArgument, "not a PLY file");
  const std::string obj = Path("garbage.obj");
  WriteFile(obj, garbage);
  ExpectError(io::ReadMesh(obj), obj, absl::StatusCode::kInvalidArgument, "not a text OBJ file");

  const std::string bad_header = Path("bad_header.ply");
  WriteFile(bad_header, "ply\nformat binary_middle_endian 1.0\nend_header\n");
  ExpectError(io::ReadMesh(bad_header), bad_header, absl::StatusCode::kInvalidArgument,
              "unknown format");
  WriteFile(bad_header,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
            "end_header\n0\n");
  ExpectError(io::ReadMesh(bad_header), bad_header, absl::StatusCode::kInvalidArgument,
              "lacks scalar x, y and z");
  WriteFile(bad_header,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty quaternion x\n"
            "end_header\n");
  ExpectError(io::ReadMesh(bad_header), bad_header, absl::StatusCode::kInvalidArgument,
              "unknown property type 'quaternion'");

  const std::string bad_obj = Path("bad.obj");
  WriteFile(bad_obj, "v 0 0 0\nv 1 zero 0\n");
  ExpectError(io::ReadMesh(bad_obj), bad_obj, absl::StatusCode::kInvalidArgument, "line 2");
  WriteFile(bad_obj, "v 0 0 0\nf 1 x 1\n");
  ExpectError(io::ReadMesh(bad_obj), bad_obj, absl::StatusCode::kInvalidArgument,
              "bad face corner 'x'");
}

TEST_F(MeshIoTest, IndexOutOfRange) {
  const std::string ply = Path("range.ply");
  WriteFile(ply,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
            "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 3\n");
  ExpectError(io::ReadMesh(ply), ply, absl::StatusCode::kInvalidArgument,
              "face 1: vertex index 3 out of range (3 vertices)");
  WriteFile(ply,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n");
  ExpectError(io::ReadMesh(ply), ply, absl::StatusCode::kInvalidArgument,
              "face 0: invalid vertex index -1");
  const std::string obj = Path("range.obj");
  WriteFile(obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n");
  ExpectError(io::ReadMesh(obj), obj, absl::StatusCode::kInvalidArgument,
              "line 5: vertex index 4 out of range (3 vertices)");
  WriteFile(obj, "v 0 0 0\nv 1 0 0\nf -1 -2 -3\n");
  ExpectError(io::ReadMesh(obj), obj, absl::StatusCode::kInvalidArgument, "line 3");
}

TEST_F(MeshIoTest, WriteRejectsInvalidMeshesAndUnwritablePaths) {
  IndexedMesh bad;
  bad.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  bad.indices = {0, 1, 3};
  const std::string path = Path("bad.ply");
  const absl::Status s = io::WriteMesh(path, bad);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(std::string(s.message()), "out of range"));
  EXPECT_FALSE(std::filesystem::exists(path));  // validated before creating the file
  bad.indices = {0, 1};
  EXPECT_EQ(io::WriteMesh(path, bad).code(), absl::StatusCode::kInvalidArgument);

  const std::string nowhere = Path("no/such/dir/mesh.obj");
  const absl::Status w = io::WriteMesh(nowhere, BumpyGrid(2, 2, true));
  EXPECT_FALSE(w.ok());
  EXPECT_TRUE(Contains(std::string(w.message()), nowhere));
}

}  // namespace
}  // namespace tandem
