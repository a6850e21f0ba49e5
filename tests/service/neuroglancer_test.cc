// The Neuroglancer precomputed export (tandem/io/neuroglancer.h with the codec's Draco
// fragments): the sharding hash against MurmurHash3's own check value and Neuroglancer's
// values, shard and manifest bytes by hand, and a written export read back the way
// Neuroglancer reads it (shard index, gzip minishard index, manifest, Draco fragments).
#include "tandem/io/neuroglancer.h"

#include <sys/wait.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "apps/tandem/neuroglancer_export.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "service/neuroglancer_sheet.h"
#include "tandem/codec/neuroglancer_draco.h"
#include "tandem/eval/topology.h"
#include "tandem/io/volume_writers.h"
#include "tandem/tandem.h"
#include "testutil/testutil.h"

namespace tandem::io {
namespace {

uint64_t U64(const std::string& s, size_t at) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = v << 8 | static_cast<uint8_t>(s[at + i]);
  return v;
}
uint32_t U32(const std::string& s, size_t at) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = v << 8 | static_cast<uint8_t>(s[at + i]);
  return v;
}
float F32(const std::string& s, size_t at) { return std::bit_cast<float>(U32(s, at)); }

std::string Gunzip(const std::string& in) {
  z_stream z;
  std::memset(&z, 0, sizeof(z));
  EXPECT_EQ(inflateInit2(&z, 15 + 16), Z_OK);
  std::string out(1 << 20, '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
  z.avail_in = static_cast<uInt>(in.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  EXPECT_EQ(inflate(&z, Z_FINISH), Z_STREAM_END);
  out.resize(z.total_out);
  inflateEnd(&z);
  return out;
}

std::string ReadAll(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(NeuroglancerHash, MurmurHash3PassesSmhasherVerification) {
  // SMHasher's check: hash keys {0}, {0,1}, ... of lengths 0..255 with seed 256 - length,
  // hash the concatenated results with seed 0; the first word is 0xB3ECE62A for x86_128.
  uint8_t key[256];
  std::vector<uint8_t> hashes(256 * 16);
  for (int i = 0; i < 256; ++i) {
    key[i] = static_cast<uint8_t>(i);
    const auto h = MurmurHash3X86_128(std::span<const uint8_t>(key, i), 256 - i);
    std::memcpy(&hashes[16 * i], h.data(), 16);
  }
  EXPECT_EQ(MurmurHash3X86_128(hashes, 0)[0], 0xB3ECE62Au);
}

TEST(NeuroglancerHash, ChunkIdHashMatchesNeuroglancer) {
  // Values of murmurHash3_x86_128Hash64Bits_Bigint(0, id) in Neuroglancer's util/hash.
  NeuroglancerSharding s;
  EXPECT_EQ(HashChunkId(0, s), 0x4772b084e028ae41u);
  EXPECT_EQ(HashChunkId(1, s), 0xe8bd67d616d4ce9au);
  EXPECT_EQ(HashChunkId(42, s), 0xc20b94f95119f47au);
  EXPECT_EQ(HashChunkId(123456789, s), 0x126576fc191a1827u);
  EXPECT_EQ(HashChunkId(~uint64_t{0}, s), 0x574f66bd212b5d1au);
  s.preshift_bits = 1;  // hash(id >> 1)
  EXPECT_EQ(HashChunkId(84, s), 0xc20b94f95119f47au);
  s.murmurhash = false;
  EXPECT_EQ(HashChunkId(84, s), 42u);
}

TEST(NeuroglancerHash, ShardAndMinishardAreTheHashBits) {
  NeuroglancerSharding s;
  s.minishard_bits = 3;
  s.shard_bits = 2;
  // 0x...7a: minishard = bits 0..2 = 2, shard = bits 3..4 = 3.
  const ShardLocation at = LocateChunk(42, s);
  EXPECT_EQ(at.minishard, 2u);
  EXPECT_EQ(at.shard, 3u);
  EXPECT_EQ(ShardFileName(3, s), "3.shard");
  s.shard_bits = 9;
  EXPECT_EQ(ShardFileName(0x1f, s), "01f.shard");
  s.shard_bits = 0;
  EXPECT_EQ(ShardFileName(0, s), "0.shard");
  EXPECT_EQ(ChooseSharding(10).shard_bits, 0);
  EXPECT_EQ(ChooseSharding(1000000).shard_bits, 6);  // 2^20 / 2^14
}

TEST(NeuroglancerShard, BytesByHand) {
  NeuroglancerSharding s;
  s.murmurhash = false;
  s.minishard_bits = 1;
  s.gzip_minishard_index = false;
  // Minishard 0: id 2; minishard 1: ids 5 and 7 (in id order whatever the input order).
  auto shard = BuildShard({{7, "c", "DD"}, {2, "", "Q"}, {5, "ab", "XYZ"}}, s);
  ASSERT_TRUE(shard.ok()) << shard.status();
  std::string want;
  auto put = [&](uint64_t v) {
    for (int i = 0; i < 8; ++i) want.push_back(static_cast<char>(v >> (8 * i)));
  };
  put(9), put(33), put(33), put(81);  // minishard index ranges after the 32-byte index
  want +=
      "Q"
      "ab"
      "XYZ"
      "c"
      "DD";
  put(2), put(0), put(1);  // id 2 at 0, 1 byte
  // ids 5, 7 (delta 2); starts 3 and 7 (7 - (3 + 3) = 1 after the previous end); sizes.
  put(5), put(2), put(3), put(1), put(3), put(2);
  EXPECT_EQ(*shard, want);
  EXPECT_FALSE(BuildShard({{1, "", "a"}, {1, "", "b"}}, s).ok());
  // gzip data: the chunk (the manifest) is compressed, the prefix (the fragments) is not.
  s.gzip_data = true;
  s.minishard_bits = 0;
  auto zipped = BuildShard({{4, "frag", "manifest"}}, s);
  ASSERT_TRUE(zipped.ok());
  const uint64_t index_at = 16 + U64(*zipped, 0), index_end = 16 + U64(*zipped, 8);
  const uint64_t start = 16 + U64(*zipped, index_at + 8), size = U64(*zipped, index_at + 16);
  EXPECT_EQ(index_at, start + size);
  EXPECT_EQ(index_end, index_at + 24);
  EXPECT_EQ(zipped->substr(start - 4, 4), "frag");
  EXPECT_EQ(Gunzip(zipped->substr(start, size)), "manifest");
}

TEST(NeuroglancerManifest, BytesByHand) {
  NeuroglancerManifest m;
  m.chunk_shape = {2, 4, 8};
  m.grid_origin = {-1, 0.5f, 3};
  m.lod_scales = {1, 2};
  m.vertex_offsets = {{0, 0, 0}, {0.25f, 0, 0}};
  m.positions = {{{0, 0, 0}, {1, 0, 0}}, {{0, 0, 0}}};
  m.sizes = {{10, 20}, {30}};
  const std::string b = EncodeManifest(m);
  ASSERT_EQ(b.size(), 12u + 12 + 4 + 2 * 4 + 2 * 12 + 2 * 4 + 2 * 16 + 16);
  EXPECT_EQ(F32(b, 0), 2.0f);
  EXPECT_EQ(F32(b, 8), 8.0f);
  EXPECT_EQ(F32(b, 12), -1.0f);
  EXPECT_EQ(F32(b, 16), 0.5f);
  EXPECT_EQ(U32(b, 24), 2u);          // num_lods
  EXPECT_EQ(F32(b, 32), 2.0f);        // lod_scales[1]
  EXPECT_EQ(F32(b, 36 + 12), 0.25f);  // vertex_offsets[1][0]
  EXPECT_EQ(U32(b, 60), 2u);          // fragments at level 0
  EXPECT_EQ(U32(b, 64), 1u);          // and at level 1
  // Level 0: x = [0, 1], y = [0, 0], z = [0, 0], sizes [10, 20]; level 1: 0, 0, 0, 30.
  const uint32_t rest[] = {0, 1, 0, 0, 0, 0, 10, 20, 0, 0, 0, 30};
  for (size_t i = 0; i < 12; ++i) EXPECT_EQ(U32(b, 68 + 4 * i), rest[i]) << i;
}

// An octahedron around `c` of radius r; coarser: the same with a flattened top.
IndexedMesh Octahedron(Vec3 c, float r, float top) {
  IndexedMesh m;
  m.positions = {{c.x + r, c.y, c.z}, {c.x - r, c.y, c.z},   {c.x, c.y + r, c.z},
                 {c.x, c.y - r, c.z}, {c.x, c.y, c.z + top}, {c.x, c.y, c.z - r}};
  m.indices = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5};
  return m;
}

NeuroglancerOptions DracoOptions() {
  NeuroglancerOptions o;
  o.encode = [](const NeuroglancerFragment& f) {
    return codec::EncodeNeuroglancerFragment(f.positions, f.indices);
  };
  return o;
}

// A segment as Neuroglancer reads it from DIR/mesh: the shard by the id's hash, the
// minishard index (gzip), the manifest, the fragments just before it. Empty if missing.
struct Stored {
  std::array<float, 3> chunk_shape{}, grid_origin{};
  std::vector<float> lod_scales;
  std::vector<std::vector<std::array<uint32_t, 3>>> positions;  // per level
  std::vector<std::vector<codec::IntegerMesh>> fragments;       // per level
};
Stored ReadSegment(const std::string& dir, uint64_t want) {
  Stored out;
  const auto mesh_info = nlohmann::json::parse(ReadAll(dir + "/mesh/info"));
  const auto& sh = mesh_info["sharding"];
  EXPECT_EQ(sh["@type"], "neuroglancer_uint64_sharded_v1");
  EXPECT_EQ(sh["hash"], "murmurhash3_x86_128");
  EXPECT_EQ(sh["minishard_index_encoding"], "gzip");
  EXPECT_EQ(sh["data_encoding"], "raw");
  NeuroglancerSharding sharding;
  sharding.minishard_bits = sh["minishard_bits"];
  sharding.shard_bits = sh["shard_bits"];
  sharding.preshift_bits = sh["preshift_bits"];
  const ShardLocation at = LocateChunk(want, sharding);
  const std::string shard =
      ReadAll(std::filesystem::path(dir) / "mesh" / ShardFileName(at.shard, sharding));
  const size_t index_end = 16u << sharding.minishard_bits;
  if (shard.size() < index_end) return out;
  const uint64_t lo = U64(shard, 16 * at.minishard), hi = U64(shard, 16 * at.minishard + 8);
  if (lo == hi) return out;
  const std::string index = Gunzip(shard.substr(index_end + lo, hi - lo));
  EXPECT_EQ(index.size() % 24, 0u);
  const size_t n = index.size() / 24;
  uint64_t id = 0, end = 0, start = 0, size = 0;
  bool found = false;
  for (size_t i = 0; i < n && !found; ++i) {
    id += U64(index, 8 * i);
    start = end + U64(index, 8 * (n + i));
    size = U64(index, 8 * (2 * n + i));
    end = start + size;
    found = id == want;
  }
  if (!found) return out;
  const std::string m = shard.substr(index_end + start, size);
  for (int j = 0; j < 3; ++j)
    out.chunk_shape[j] = F32(m, 4 * j), out.grid_origin[j] = F32(m, 12 + 4 * j);
  const size_t lods = U32(m, 24);
  size_t at_byte = 28;
  for (size_t k = 0; k < lods; ++k) out.lod_scales.push_back(F32(m, at_byte)), at_byte += 4;
  at_byte += 12 * lods;  // vertex offsets
  std::vector<uint32_t> counts;
  for (size_t k = 0; k < lods; ++k) counts.push_back(U32(m, at_byte)), at_byte += 4;
  std::vector<std::vector<uint32_t>> sizes(lods);
  uint64_t total = 0;
  out.positions.resize(lods);
  for (size_t k = 0; k < lods; ++k) {
    for (uint32_t f = 0; f < counts[k]; ++f) {
      out.positions[k].push_back({U32(m, at_byte + 4 * f), U32(m, at_byte + 4 * (counts[k] + f)),
                                  U32(m, at_byte + 4 * (2 * counts[k] + f))});
      sizes[k].push_back(U32(m, at_byte + 4 * (3 * counts[k] + f)));
      total += sizes[k].back();
    }
    at_byte += 16 * counts[k];
  }
  EXPECT_EQ(at_byte, m.size());
  size_t frag = index_end + start - total;
  out.fragments.resize(lods);
  for (size_t k = 0; k < lods; ++k) {
    for (uint32_t bytes : sizes[k]) {
      if (bytes == 0) {  // an empty node
        out.fragments[k].emplace_back();
        continue;
      }
      auto decoded = codec::DecodeNeuroglancerFragment(shard.substr(frag, bytes));
      EXPECT_TRUE(decoded.ok()) << decoded.status();
      out.fragments[k].push_back(decoded.ok() ? *decoded : codec::IntegerMesh{});
      frag += bytes;
    }
  }
  return out;
}

// A sphere of radius r around c as a latitude-longitude mesh of `n` bands (outward).
IndexedMesh Sphere(Vec3 c, double r, int n) {
  IndexedMesh m;
  const double pi = std::acos(-1.0);
  m.positions.push_back({c.x, c.y, c.z + r});
  for (int i = 1; i < n; ++i) {
    for (int j = 0; j < 2 * n; ++j) {
      const double t = pi * i / n, f = pi * j / n;
      m.positions.push_back({c.x + r * std::sin(t) * std::cos(f),
                             c.y + r * std::sin(t) * std::sin(f), c.z + r * std::cos(t)});
    }
  }
  m.positions.push_back({c.x, c.y, c.z - r});
  const uint32_t south = static_cast<uint32_t>(m.positions.size() - 1);
  auto at = [&](int i, int j) { return static_cast<uint32_t>(1 + (i - 1) * 2 * n + j % (2 * n)); };
  for (int j = 0; j < 2 * n; ++j) {
    m.indices.insert(m.indices.end(), {0, at(1, j), at(1, j + 1)});
    for (int i = 1; i + 1 < n; ++i) {
      m.indices.insert(m.indices.end(), {at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      m.indices.insert(m.indices.end(), {at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
    m.indices.insert(m.indices.end(), {at(n - 1, j), south, at(n - 1, j + 1)});
  }
  return m;
}

double Area(Vec3 a, Vec3 b, Vec3 c) { return 0.5 * Norm(Cross(b - a, c - a)); }

// Distance from p to triangle (a, b, c).
double PointTriangle(Vec3 p, Vec3 a, Vec3 b, Vec3 c) {
  const Vec3 n = Cross(b - a, c - a);
  const double nn = Dot(n, n);
  if (nn > 0) {
    const Vec3 q = p - n * (Dot(p - a, n) / nn);
    const bool in = Dot(Cross(b - a, q - a), n) >= 0 && Dot(Cross(c - b, q - b), n) >= 0 &&
                    Dot(Cross(a - c, q - c), n) >= 0;
    if (in) return Norm(p - q);
  }
  auto seg = [&](Vec3 u, Vec3 v) {
    const double l = Dot(v - u, v - u);
    const double t = l > 0 ? std::clamp(Dot(p - u, v - u) / l, 0.0, 1.0) : 0.0;
    return Norm(p - (u + (v - u) * t));
  };
  return std::min({seg(a, b), seg(b, c), seg(c, a)});
}

// A level's fragments as triangles in mesh units (meshes.md's formula).
std::vector<std::array<Vec3, 3>> Dequantized(const Stored& s, size_t k) {
  NeuroglancerGrid g{s.chunk_shape, s.grid_origin};
  std::vector<std::array<Vec3, 3>> out;
  for (size_t f = 0; f < s.fragments[k].size(); ++f) {
    const codec::IntegerMesh& m = s.fragments[k][f];
    for (size_t t = 0; t + 2 < m.indices.size(); t += 3) {
      std::array<Vec3, 3> tri;
      for (int c = 0; c < 3; ++c) {
        tri[c] = DequantizePosition(g, static_cast<int>(k), s.positions[k][f],
                                    m.positions[m.indices[t + c]], 16);
      }
      out.push_back(tri);
    }
  }
  return out;
}

// A flat 12 x 12 sheet at height z, normal +z.
IndexedMesh Sheet(double z) {
  IndexedMesh m;
  m.positions = {{0, 0, z}, {12, 0, z}, {12, 12, z}, {0, 12, z}};
  m.indices = {0, 1, 2, 0, 2, 3};
  return m;
}

// Two levels of a flat sheet 1.2 units apart (normal +z: strips hang down), cut by nodes of 4
// units: the upper level's strips reach down to the lower level's cut and half a strip
// beyond (within two strips for two levels), so that the crack between the two cuts is
// covered; the lower level's strips, with no other cut below them, stay one strip deep.
TEST(NeuroglancerExport, StripsReachAnotherLevelsCut) {
  NeuroglancerSegment segment{1, {Sheet(5), Sheet(6.2)}};
  const NeuroglancerGrid grid{{4, 4, 4}, {-0.5f, -0.5f, -0.5f}};
  auto tree = BuildOctree(segment, grid, 16, 1.0);
  ASSERT_TRUE(tree.ok()) << tree.status();
  for (int k = 0; k < 2; ++k) {
    double lowest = 1e9;
    size_t triangles = 0;
    for (const NeuroglancerNode& node : (*tree)[k]) {
      for (const auto& q : node.fragment.positions) {
        lowest = std::min(lowest, DequantizePosition(grid, k, node.position, q, 16).z);
      }
      const auto& f = node.fragment;
      for (size_t t = 0; t + 2 < f.indices.size(); t += 3, ++triangles) {
        // No corner repeated by position (a strip's wedge where it would have no area).
        EXPECT_FALSE(f.positions[f.indices[t]] == f.positions[f.indices[t + 1]] ||
                     f.positions[f.indices[t + 1]] == f.positions[f.indices[t + 2]] ||
                     f.positions[f.indices[t]] == f.positions[f.indices[t + 2]]);
      }
    }
    EXPECT_GT(triangles, 0u);
    EXPECT_NEAR(lowest, k == 0 ? 4.0 : 4.5, 1e-3) << "level " << k;  // 6.2 - 1.7
  }
}

// A level's triangles (dequantized) with a corner kept per triangle, straight from the octree.
std::vector<std::array<Vec3, 3>> OctreeTriangles(
    const std::vector<std::vector<NeuroglancerNode>>& tree, const NeuroglancerGrid& grid, int k) {
  std::vector<std::array<Vec3, 3>> out;
  for (const NeuroglancerNode& node : tree[k]) {
    const auto& f = node.fragment;
    for (size_t t = 0; t + 2 < f.indices.size(); t += 3) {
      std::array<Vec3, 3> tri;
      for (int c = 0; c < 3; ++c) {
        tri[c] = DequantizePosition(grid, k, node.position, f.positions[f.indices[t + c]], 16);
      }
      out.push_back(tri);
    }
  }
  return out;
}

// Whether point p of the plane x = p.x lies on a triangle of `tris` lying in that plane.
bool CoveredInPlaneX(const std::vector<std::array<Vec3, 3>>& tris, Vec3 p) {
  for (const auto& t : tris) {
    if (std::abs(t[0].x - p.x) > 1e-3 || std::abs(t[1].x - p.x) > 1e-3 ||
        std::abs(t[2].x - p.x) > 1e-3) {
      continue;
    }
    auto side = [&](Vec3 a, Vec3 b) {
      return (b.y - a.y) * (p.z - a.z) - (b.z - a.z) * (p.y - a.y);
    };
    const double s0 = side(t[0], t[1]), s1 = side(t[1], t[2]), s2 = side(t[2], t[0]);
    if ((s0 >= 0 && s1 >= 0 && s2 >= 0) || (s0 <= 0 && s1 <= 0 && s2 <= 0)) return true;
  }
  return false;
}

// A sheet just above a cell's lower face (z = 7.52 over the face z = 7.5, nodes of 4) and a
// coarser level lower (7.2): the finer level's strips, which must reach down past 7.2, leave
// their cell after 0.02 and go on in the cell below, so that the band between the two cuts
// is covered on every cut face (else Neuroglancer shows the background through it).
TEST(NeuroglancerExport, StripsGoOnInTheCellTheyReach) {
  NeuroglancerSegment segment{1, {Sheet(7.52), Sheet(7.2)}};
  const NeuroglancerGrid grid{{4, 4, 4}, {-0.5f, -0.5f, -0.5f}};
  auto tree = BuildOctree(segment, grid, 16, 1.0);
  ASSERT_TRUE(tree.ok()) << tree.status();
  const std::vector<std::array<Vec3, 3>> fine = OctreeTriangles(*tree, grid, 0);
  for (double x : {3.5, 7.5}) {
    for (double y : {1.5, 5.5, 9.5}) {
      for (double z : {7.25, 7.4, 7.51}) {
        EXPECT_TRUE(CoveredInPlaneX(fine, {x, y, z})) << x << " " << y << " " << z;
      }
    }
  }
}

// A closed slab thinner than a strip (z in [5, 5.6]) and a coarser, thicker one: no strip
// leaves the solid it hangs into, though the other level's cut would take it deeper.
TEST(NeuroglancerExport, StripsStayInsideAWallThinnerThanThem) {
  auto box = [](double z0, double z1) {
    IndexedMesh m;
    const double x0 = 0.3, x1 = 11.7;
    for (int i = 0; i < 8; ++i) {
      m.positions.push_back({i & 1 ? x1 : x0, i & 2 ? x1 : x0, i & 4 ? z1 : z0});
    }
    // Outward: -z, +z, -y, +y, -x, +x.
    m.indices = {0, 2, 3, 0, 3, 1, 4, 5, 7, 4, 7, 6, 0, 1, 5, 0, 5, 4,
                 2, 6, 7, 2, 7, 3, 0, 4, 6, 0, 6, 2, 1, 3, 7, 1, 7, 5};
    return m;
  };
  const double lo[2] = {5.0, 4.9}, hi[2] = {5.6, 5.7};
  NeuroglancerSegment segment{1, {box(lo[0], hi[0]), box(lo[1], hi[1])}};
  const NeuroglancerGrid grid{{4, 4, 4}, {-0.5f, -0.5f, -0.5f}};
  auto tree = BuildOctree(segment, grid, 16, 1.0);
  ASSERT_TRUE(tree.ok()) << tree.status();
  for (int k = 0; k < 2; ++k) {
    double low = 1e9, high = -1e9;
    size_t in_faces = 0;
    for (const auto& t : OctreeTriangles(*tree, grid, k)) {
      for (const Vec3& p : t) low = std::min(low, p.z), high = std::max(high, p.z);
      in_faces += std::abs(t[0].x - 3.5) < 1e-3 && std::abs(t[1].x - 3.5) < 1e-3 &&
                  std::abs(t[2].x - 3.5) < 1e-3;
    }
    EXPECT_GT(in_faces, 0u) << "level " << k << " has strips on the face x = 3.5";
    EXPECT_GT(low, lo[k] - 1e-3) << "level " << k;
    EXPECT_LT(high, hi[k] + 1e-3) << "level " << k;
  }
}

uint64_t ZCode(const std::array<uint32_t, 3>& p) {
  uint64_t code = 0;
  for (int b = 0; b < 21; ++b) {
    for (int j = 0; j < 3; ++j) code |= static_cast<uint64_t>(p[j] >> b & 1) << (3 * b + j);
  }
  return code;
}

// Two spheres at three levels over nodes of 4 voxels (4 x 4 x 8 units: anisotropic), read
// back as Neuroglancer reads them; with skirts off, the fragments are the levels cut.
TEST(NeuroglancerExport, OctreeReadsBackAsNeuroglancerDoes) {
  std::vector<NeuroglancerSegment> segments;
  for (LabelId id : {7u, 1000000007u}) {
    const Vec3 c{10.0 + static_cast<double>(id % 13), 20.0, 30.0};
    segments.push_back({id, {Sphere(c, 9, 16), Sphere(c, 9, 10), Sphere(c, 9, 6)}});
  }
  VolumeInfo grid;
  grid.nx = grid.ny = 40;
  grid.nz = 20;
  grid.spacing = {1, 1, 2};
  for (double skirt : {0.0, -1.0}) {
    SCOPED_TRACE(skirt);
    const std::string dir = testing::MakeTempDir() + "/ng";
    NeuroglancerOptions options = DracoOptions();
    options.nm_per_unit = 2;
    options.chunk_voxels = 4;
    options.skirt = skirt;
    ASSERT_TRUE(WriteNeuroglancer(dir, grid, segments, options).ok());
    const auto info = nlohmann::json::parse(ReadAll(dir + "/info"));
    EXPECT_EQ(info["type"], "segmentation");
    EXPECT_EQ(info["scales"][0]["resolution"], nlohmann::json({2.0, 2.0, 4.0}));
    const auto mesh_info = nlohmann::json::parse(ReadAll(dir + "/mesh/info"));
    EXPECT_EQ(mesh_info["@type"], "neuroglancer_multilod_draco");
    EXPECT_EQ(mesh_info["vertex_quantization_bits"], 16);

    std::set<std::array<float, 3>> origins;
    for (const NeuroglancerSegment& seg : segments) {
      SCOPED_TRACE(seg.id);
      const Stored stored = ReadSegment(dir, seg.id);
      ASSERT_EQ(stored.fragments.size(), 3u);
      EXPECT_EQ(stored.lod_scales, std::vector<float>({1, 2, 4}));
      EXPECT_EQ(stored.chunk_shape, (std::array<float, 3>{4, 4, 8}));
      origins.insert(stored.grid_origin);
      for (size_t k = 0; k < 3; ++k) {
        SCOPED_TRACE(k);
        // A real octree: several nodes, in z-order, each with its parent one level up.
        EXPECT_GT(stored.positions[k].size(), k == 2 ? 1u : 8u);
        for (size_t f = 1; f < stored.positions[k].size(); ++f) {
          EXPECT_LT(ZCode(stored.positions[k][f - 1]), ZCode(stored.positions[k][f]));
        }
        if (k + 1 < 3) {
          for (const auto& p : stored.positions[k]) {
            const std::array<uint32_t, 3> up = {p[0] >> 1, p[1] >> 1, p[2] >> 1};
            EXPECT_NE(std::find(stored.positions[k + 1].begin(), stored.positions[k + 1].end(), up),
                      stored.positions[k + 1].end());
          }
        }
        // Levels > 0: no triangle crosses a node's middle plane (2^15, which both sides may
        // touch), where Neuroglancer partitions a fragment into its octants.
        for (const codec::IntegerMesh& m : stored.fragments[k]) {
          for (size_t t = 0; k > 0 && t + 2 < m.indices.size(); t += 3) {
            for (int j = 0; j < 3; ++j) {
              int below = 0, above = 0;
              for (int c = 0; c < 3; ++c) {
                const uint32_t v = m.positions[m.indices[t + c]][j];
                below += v<32768, above += v> 32768;
              }
              EXPECT_TRUE(below == 0 || above == 0) << "a triangle crosses a middle plane";
            }
          }
        }
        // Every triangle of the level is in the union of its fragments (its centroid lies on
        // one of them), and with no skirt the fragments hold nothing else (equal area).
        const std::vector<std::array<Vec3, 3>> got = Dequantized(stored, k);
        const IndexedMesh& want = seg.lods[k];
        double want_area = 0, got_area = 0;
        for (const auto& t : got) got_area += Area(t[0], t[1], t[2]);
        size_t missing = 0;
        for (size_t t = 0; t + 2 < want.indices.size(); t += 3) {
          const Vec3 a = want.positions[want.indices[t]], b = want.positions[want.indices[t + 1]],
                     c = want.positions[want.indices[t + 2]];
          want_area += Area(a, b, c);
          const Vec3 centroid = (a + b + c) * (1.0 / 3);
          double best = 1e9;
          for (const auto& g : got)
            best = std::min(best, PointTriangle(centroid, g[0], g[1], g[2]));
          missing += best > 1e-3;
        }
        EXPECT_EQ(missing, 0u);
        if (skirt == 0) {
          EXPECT_NEAR(got_area, want_area, 1e-3 * want_area);
        } else {
          EXPECT_GT(got_area, want_area * 1.01) << "skirts add strips";
        }
        // Level 0 has no empty node (a coarser one may be empty, as a finer node's parent).
        for (const codec::IntegerMesh& m : stored.fragments[k]) {
          EXPECT_TRUE(k > 0 || !m.indices.empty());
        }
      }
    }
    EXPECT_EQ(origins.size(), 1u) << "one octree grid for every segment";
    EXPECT_TRUE(ReadSegment(dir, 8).fragments.empty());  // no such segment
  }
}

TEST(NeuroglancerExport, ManySegmentsSpreadOverShards) {
  const std::string dir = testing::MakeTempDir() + "/ng";
  std::vector<NeuroglancerSegment> segments;
  for (LabelId id = 1; id <= 40; ++id) {
    segments.push_back({id * 0x9e3779b97f4a7c15u, {Octahedron({float(id), 0, 0}, 0.5f, 0.5f)}});
  }
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 8;
  NeuroglancerOptions options = DracoOptions();
  options.chunk_voxels = 64;  // one node holds them all
  options.choose_sharding = false;
  options.sharding.shard_bits = 2;
  options.sharding.minishard_bits = 2;
  ASSERT_TRUE(WriteNeuroglancer(dir, grid, segments, options).ok());
  size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir + "/mesh")) {
    files += e.path().extension() == ".shard";
  }
  EXPECT_EQ(files, 4u);
  for (const NeuroglancerSegment& seg : segments) {
    const Stored stored = ReadSegment(dir, seg.id);
    ASSERT_EQ(stored.fragments.size(), 1u) << seg.id;
    EXPECT_EQ(stored.fragments[0][0].indices.size(), 24u) << seg.id;
  }
}

// Index count of level k over all its fragments.
size_t Indices(const Stored& s, size_t k) {
  size_t n = 0;
  for (const codec::IntegerMesh& m : s.fragments[k]) n += m.indices.size();
  return n;
}

// Runs a shell command line, stderr with stdout; the exit status.
int Shell(const std::string& command, std::string* output) {
  FILE* p = popen((command + " 2>&1").c_str(), "r");
  if (p == nullptr) return -1;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof(buf), p)) > 0) output->append(buf, n);
  const int status = pclose(p);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(NeuroglancerExport, ExtractWritesEachSurfaceWithCoarserSweeps) {
  const std::string tmp = testing::MakeTempDir(), tandem = testing::BinPath("tandem");
  std::string out;
  ASSERT_EQ(Shell(tandem + " generate sphere --size 32 --out " + tmp + "/s.nrrd", &out), 0) << out;
  ASSERT_EQ(Shell(tandem + " extract --input " + tmp + "/s.nrrd --iso 0,0.3 --quiet --out " + tmp +
                      "/s_{iso}.ply --neuroglancer " + tmp + "/ng --neuroglancer-lods 4",
                  &out),
            0)
      << out;
  size_t previous_outer = 0;
  for (uint64_t id : {1, 2}) {
    SCOPED_TRACE(id);
    const Stored stored = ReadSegment(tmp + "/ng", id);
    ASSERT_EQ(stored.fragments.size(), 4u);
    // Sweeps at E0, 2 E0, 4 E0, 8 E0: each level coarser than the one before.
    for (size_t k = 1; k < 4; ++k) {
      EXPECT_LT(Indices(stored, k), Indices(stored, k - 1)) << "level " << k;
    }
    if (id == 2) {
      EXPECT_LT(Indices(stored, 0), previous_outer);
    }
    previous_outer = Indices(stored, 0);
  }
  EXPECT_TRUE(ReadSegment(tmp + "/ng", 3).fragments.empty());
  // With a triangle target, each level asks for half the triangles of the one before.
  ASSERT_EQ(
      Shell(tandem + " extract --input " + tmp + "/s.nrrd --quiet --target-triangles 1200 --out " +
                tmp + "/t.ply --neuroglancer " + tmp + "/ngt --neuroglancer-lods 3",
            &out),
      0)
      << out;
  const Stored targeted = ReadSegment(tmp + "/ngt", 1);
  ASSERT_EQ(targeted.fragments.size(), 3u);
  for (size_t k = 1; k < 3; ++k) {
    EXPECT_LT(Indices(targeted, k), Indices(targeted, k - 1)) << "level " << k;
  }
  // Flag mistakes name the flag and exit 2.
  out.clear();
  EXPECT_EQ(Shell(tandem + " extract --input " + tmp + "/s.nrrd --out " + tmp +
                      "/x.ply --neuroglancer " + tmp + "/ng --neuroglancer-lods 0",
                  &out),
            2);
  EXPECT_NE(out.find("--neuroglancer-lods must be in [1, 8], got 0"), std::string::npos) << out;
  out.clear();
  EXPECT_EQ(Shell(tandem + " extract --input " + tmp + "/s.nrrd --out " + tmp +
                      "/x.ply --neuroglancer-lods 2",
                  &out),
            2);
  EXPECT_NE(out.find("go with --neuroglancer DIR"), std::string::npos) << out;
  out.clear();
  EXPECT_EQ(Shell(tandem + " extract --input " + tmp + "/s.nrrd --out " + tmp +
                      "/x.ply --neuroglancer " + tmp + "/ng --neuroglancer-chunk 0",
                  &out),
            2);
  EXPECT_NE(out.find("--neuroglancer-chunk must be in [1, 4096], got 0"), std::string::npos) << out;
}

TEST(NeuroglancerExport, JoinLevelsGivesEachLabelAllItsLevels) {
  const IndexedMesh a = Octahedron({0, 0, 0}, 1, 1), b = Octahedron({5, 0, 0}, 1, 1),
                    c = Octahedron({5, 0, 0}, 2, 2);
  std::vector<std::vector<std::pair<LabelId, IndexedMesh>>> levels(2);
  levels[0] = {{3, a}, {9, b}};
  levels[1] = {{9, c}};  // label 3 gone at the coarser level
  const auto joined = JoinLevels(std::move(levels));
  ASSERT_EQ(joined.size(), 2u);
  EXPECT_EQ(joined[0].first, 3u);
  ASSERT_EQ(joined[0].second.size(), 2u);
  EXPECT_EQ(joined[0].second[0].num_triangles(), 8u);
  EXPECT_EQ(joined[0].second[1].num_triangles(), 0u);
  EXPECT_EQ(joined[1].first, 9u);
  EXPECT_EQ(joined[1].second[1].positions[0].x, 7.0f);
  // An empty level writes an empty node, and the other levels stay readable.
  const std::string dir = testing::MakeTempDir() + "/ng";
  std::vector<NeuroglancerSegment> segments;
  for (const auto& [id, lods] : joined) segments.push_back({id, lods});
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 8;
  ASSERT_TRUE(WriteNeuroglancer(dir, grid, segments, DracoOptions()).ok());
  const Stored three = ReadSegment(dir, 3);
  ASSERT_EQ(three.fragments.size(), 2u);
  EXPECT_EQ(three.fragments[0][0].indices.size(), 24u);
  EXPECT_TRUE(three.fragments[1][0].indices.empty());
}

// Two touching boxes of labels 5 and 9 in background 0, meshed by label sessions at E0 and
// 2 E0 and exported as the CLI's label mode does: one segment per label, both levels.
// Two touching boxes of labels 5 and 9 in a background of 0, as uint16.
struct TwoLabels {
  VolumeInfo grid;
  std::vector<uint16_t> voxels;
};
TwoLabels TwoTouchingLabels() {
  TwoLabels t;
  VolumeInfo& grid = t.grid;
  grid.nx = 14, grid.ny = 10, grid.nz = 10;
  grid.dtype = DType::kUInt16;
  t.voxels.assign(grid.nx * grid.ny * grid.nz, 0);
  for (int64_t z = 2; z < 8; ++z) {
    for (int64_t y = 2; y < 8; ++y) {
      for (int64_t x = 2; x < 12; ++x) t.voxels[(z * grid.ny + y) * grid.nx + x] = x < 7 ? 5 : 9;
    }
  }
  return t;
}

TEST(NeuroglancerExport, LabelSessionsBecomeOneSegmentPerLabel) {
  const TwoLabels two = TwoTouchingLabels();
  const VolumeInfo& grid = two.grid;
  const std::vector<uint16_t>& voxels = two.voxels;
  std::vector<LabeledMesh> complexes;
  for (double e0 : {0.3, 0.6}) {
    absl::StatusOr<LabeledMesh> complex =
        testing::MeshLabels(grid, reinterpret_cast<const uint8_t*>(voxels.data()), e0);
    ASSERT_TRUE(complex.ok()) << complex.status();
    complexes.push_back(*std::move(complex));
  }
  const std::vector<const LabeledMesh*> levels{&complexes[0], &complexes[1]};
  const std::string dir = testing::MakeTempDir() + "/ng";
  // Nodes of 4 voxels: the interface is cut by node faces at 3.5 and 7.5.
  ASSERT_TRUE(app::WriteNeuroglancerLabels(dir, grid, levels, 0, 1, 7, {4, -1}).ok());
  for (LabelId id : {5u, 9u}) {
    SCOPED_TRACE(id);
    const Stored stored = ReadSegment(dir, id);
    ASSERT_EQ(stored.fragments.size(), 2u);
    EXPECT_GT(Indices(stored, 0), 0u);
    EXPECT_GT(Indices(stored, 1), 0u);
  }
  // Where the two labels touch, each level's fragments hold the same triangles for both
  // (cut and quantized alike, up to orientation): all of the interface x = 6.5.
  const Stored five = ReadSegment(dir, 5), nine = ReadSegment(dir, 9);
  for (size_t k = 0; k < 2; ++k) {
    SCOPED_TRACE(k);
    auto unoriented = [&](const Stored& s) {
      std::multiset<std::array<std::array<uint32_t, 3>, 3>> out;
      for (size_t f = 0; f < s.fragments[k].size(); ++f) {
        const codec::IntegerMesh& m = s.fragments[k][f];
        for (size_t t = 0; t + 2 < m.indices.size(); t += 3) {
          std::array<std::array<uint32_t, 3>, 3> tri;
          for (int c = 0; c < 3; ++c) {
            tri[c] = m.positions[m.indices[t + c]];
            for (int j = 0; j < 3; ++j) tri[c][j] += 65536 * s.positions[k][f][j];
          }
          std::sort(tri.begin(), tri.end());
          out.insert(tri);
        }
      }
      return out;
    };
    const auto a5 = unoriented(five), a9 = unoriented(nine);
    std::vector<std::array<std::array<uint32_t, 3>, 3>> common;
    std::set_intersection(a5.begin(), a5.end(), a9.begin(), a9.end(), std::back_inserter(common));
    const NeuroglancerGrid g{five.chunk_shape, five.grid_origin};
    double shared = 0;
    for (const auto& tri : common) {
      Vec3 p[3];
      for (int c = 0; c < 3; ++c) {
        std::array<uint32_t, 3> node, q;
        for (int j = 0; j < 3; ++j) node[j] = tri[c][j] / 65536, q[j] = tri[c][j] % 65536;
        p[c] = DequantizePosition(g, static_cast<int>(k), node, q, 16);
      }
      shared += Area(p[0], p[1], p[2]);
    }
    // The interface in the sweep's own output: the triangles both labels' surfaces hold.
    std::map<std::array<double, 9>, int> seen;
    double interface = 0;
    for (const auto& [label, mesh] : SplitByLabel(*levels[k], 0)) {
      for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
        std::array<Vec3, 3> v = {mesh.positions[mesh.indices[t]],
                                 mesh.positions[mesh.indices[t + 1]],
                                 mesh.positions[mesh.indices[t + 2]]};
        std::array<std::array<double, 3>, 3> key;
        for (int c = 0; c < 3; ++c) key[c] = {v[c].x, v[c].y, v[c].z};
        std::sort(key.begin(), key.end());
        std::array<double, 9> flat;
        for (int c = 0; c < 9; ++c) flat[c] = key[c / 3][c % 3];
        if (++seen[flat] == 2) interface += Area(v[0], v[1], v[2]);
      }
    }
    EXPECT_GT(interface, 20.0);
    EXPECT_NEAR(shared, interface, 1e-3 * interface) << "the interface, cut alike for both";
  }
  EXPECT_TRUE(ReadSegment(dir, 0).fragments.empty());  // the background has no segment
}

TEST(NeuroglancerExport, ExtractLabelsWritesOneSegmentPerLabelWithItsLevels) {
  // tandem extract --labels --neuroglancer: the label map's labels as segments of their ids,
  // each with its coarser sweeps, beside the per-label files.
  const TwoLabels two = TwoTouchingLabels();
  const VolumeInfo& grid = two.grid;
  const std::vector<uint16_t>& voxels = two.voxels;
  const std::string tmp = testing::MakeTempDir(), tandem = testing::BinPath("tandem");
  ASSERT_TRUE(
      io::WriteVolume(tmp + "/labels.nrrd", grid, [&](int64_t z, std::vector<uint8_t>* bytes) {
        const auto* b = reinterpret_cast<const uint8_t*>(voxels.data() + z * grid.nx * grid.ny);
        bytes->assign(b, b + grid.slice_bytes());
        return absl::OkStatus();
      }).ok());
  std::string out;
  ASSERT_EQ(Shell(tandem + " extract --input " + tmp + "/labels.nrrd --labels --error 0.3 --quiet" +
                      " --out " + tmp + "/cells/ --neuroglancer " + tmp + "/ng" +
                      " --neuroglancer-lods 2",
                  &out),
            0)
      << out;
  for (uint64_t id : {5, 9}) {
    SCOPED_TRACE(id);
    EXPECT_TRUE(std::filesystem::exists(tmp + "/cells/" + std::to_string(id) + ".ply"));
    const Stored stored = ReadSegment(tmp + "/ng", id);
    ASSERT_EQ(stored.fragments.size(), 2u);
    EXPECT_FALSE(stored.fragments[0][0].indices.empty());
    EXPECT_FALSE(stored.fragments[1][0].indices.empty());
  }
  EXPECT_TRUE(ReadSegment(tmp + "/ng", 0).fragments.empty());  // the background has none
}

// A label sheet under a wavy surface, cut into nodes of 8 voxels: quantization collapses a few
// slivers and strips to nothing, and the corners they leave must go with them. Otherwise a
// level-0 fragment of one triangle and three unused corners was coded sequentially and no
// Draco decoder read it back: Neuroglancer marked the node failed and never became ready.
TEST(NeuroglancerExport, EveryFragmentDecodesWithEveryCornerInATriangle) {
  const testing::LabelSheet sheet = testing::WavyLabelSheet();
  const VolumeInfo& grid = sheet.grid;
  const std::vector<uint8_t>& voxels = sheet.voxels;
  const std::string tmp = testing::MakeTempDir(), tandem = testing::BinPath("tandem");
  ASSERT_TRUE(
      io::WriteVolume(tmp + "/sheet.nrrd", grid, [&](int64_t z, std::vector<uint8_t>* bytes) {
        const uint8_t* b = voxels.data() + z * grid.nx * grid.ny;
        bytes->assign(b, b + grid.slice_bytes());
        return absl::OkStatus();
      }).ok());
  std::string out;
  ASSERT_EQ(Shell(tandem + " extract --input " + tmp + "/sheet.nrrd --labels --quiet --out " + tmp +
                      "/sheet/ --neuroglancer " + tmp + "/ng --neuroglancer-chunk 8",
                  &out),
            0)
      << out;
  const Stored stored = ReadSegment(tmp + "/ng", 1);  // expects every fragment to decode
  ASSERT_EQ(stored.fragments.size(), 3u);
  EXPECT_GT(stored.fragments[0].size(), 300u);
  size_t fragments = 0;
  for (size_t k = 0; k < stored.fragments.size(); ++k) {
    for (size_t f = 0; f < stored.fragments[k].size(); ++f) {
      const codec::IntegerMesh& m = stored.fragments[k][f];
      if (m.indices.empty()) continue;  // an empty parent
      ++fragments;
      std::vector<bool> used(m.positions.size(), false);
      for (uint32_t v : m.indices) used[v] = true;
      EXPECT_EQ(std::count(used.begin(), used.end(), false), 0)
          << "level " << k << " node " << f << ": corners in no triangle";
    }
  }
  EXPECT_GT(fragments, 450u);
}

// --labels --seal --neuroglancer: each level cut from its sweep's welded chunks. Both exports
// load (every label at both levels, fragments decoding) and the sealed one's level 0 has,
// label by label, the unsealed one's topology: a box, a torus, a box around a cavity, the
// cavity's voxel. Nodes of 64 voxels hold the whole 10 x 10 x 40 volume: level 0 is one
// fragment, the label's surface quantized, and reads back as a mesh.
TEST(NeuroglancerExport, SealedLabelsExportAsTheUnsealedDo) {
  VolumeInfo grid;
  grid.nx = grid.ny = 10;
  grid.nz = 40;
  grid.dtype = DType::kUInt16;
  const std::string tmp = testing::MakeTempDir(), tandem = testing::BinPath("tandem");
  ASSERT_TRUE(
      io::WriteVolume(tmp + "/stack.nrrd", grid, [](int64_t z, std::vector<uint8_t>* bytes) {
        std::vector<uint16_t> ids(100, 0);
        for (int64_t j = 1; j < 9; ++j) {
          for (int64_t i = 1; i < 9; ++i) {
            uint16_t id = z < 2 || z >= 34 ? 0 : static_cast<uint16_t>(1 + (z - 2) / 8);
            if (id == 2 && i >= 4 && i < 6 && j >= 4 && j < 6) id = 0;
            if (id == 3 && i == 5 && j == 5 && z == 21) id = 9;
            ids[j * 10 + i] = id;
          }
        }
        const auto* b = reinterpret_cast<const uint8_t*>(ids.data());
        bytes->assign(b, b + 200);
        return absl::OkStatus();
      }).ok());
  std::map<uint64_t, eval::TopologyReport> level0[2];
  for (int sealed = 0; sealed < 2; ++sealed) {
    SCOPED_TRACE(sealed ? "sealed" : "unsealed");
    const std::string ng = tmp + (sealed ? "/ng-sealed" : "/ng");
    std::string out;
    ASSERT_EQ(Shell(tandem + " extract --input " + tmp + "/stack.nrrd --labels --error 0.3" +
                        " --quiet --out " + tmp + (sealed ? "/sealed/" : "/whole/") +
                        " --neuroglancer " + ng + " --neuroglancer-lods 2" +
                        " --neuroglancer-chunk 64" + (sealed ? " --seal" : ""),
                    &out),
              0)
        << out;
    for (uint64_t id : {1, 2, 3, 4, 9}) {
      SCOPED_TRACE(id);
      const Stored stored = ReadSegment(ng, id);
      ASSERT_EQ(stored.fragments.size(), 2u);
      ASSERT_EQ(stored.fragments[0].size(), 1u);
      for (size_t k = 0; k < 2; ++k) {
        size_t triangles = 0;
        for (const codec::IntegerMesh& m : stored.fragments[k]) triangles += m.indices.size() / 3;
        EXPECT_GT(triangles, 0u) << "level " << k;
      }
      const codec::IntegerMesh& m = stored.fragments[0][0];
      IndexedMesh mesh;
      for (const auto& q : m.positions)
        mesh.positions.push_back({double(q[0]), double(q[1]), double(q[2])});
      mesh.indices = m.indices;
      level0[sealed][id] = eval::AnalyzeTopology(mesh);
    }
    EXPECT_TRUE(ReadSegment(ng, 0).fragments.empty());
  }
  for (const auto& [id, whole] : level0[0]) {
    SCOPED_TRACE(id);
    const eval::TopologyReport& t = level0[1].at(id);
    EXPECT_TRUE(t.IsClosedManifold());
    EXPECT_EQ(t.euler, whole.euler);
    EXPECT_EQ(t.components, whole.components);
  }
  EXPECT_EQ(level0[1].at(1).euler, 2);
  EXPECT_EQ(level0[1].at(2).euler, 0);  // the tunnel: a torus
  EXPECT_EQ(level0[1].at(3).euler, 4);  // a box around a cavity
  EXPECT_EQ(level0[1].at(9).euler, 2);
}

TEST(NeuroglancerExport, RefusesWhatNeuroglancerCannotTake) {
  const std::string tmp = testing::MakeTempDir();
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 4;
  const IndexedMesh m = Octahedron({1, 1, 1}, 1, 1);
  NeuroglancerOptions o = DracoOptions();
  std::vector<NeuroglancerSegment> twice = {{5, {m}}, {5, {m}}};
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, twice, o).message(), "two segments with id 5");
  std::vector<NeuroglancerSegment> uneven = {{1, {m, m}}, {2, {m}}};
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, uneven, o).message(),
            "segment 2: 1 levels of detail, the first segment has 2");
  IndexedMesh bad = m;
  bad.indices[4] = 99;
  std::vector<NeuroglancerSegment> out_of_range = {{3, {bad}}};
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, out_of_range, o).message(),
            "segment 3 level 0: index 99 out of range");
  o.chunk_voxels = 0;
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, {}, o).message(),
            "chunk_voxels must be in [1, 4096], got 0");
  o.chunk_voxels = 32;
  o.vertex_quantization_bits = 12;
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, {}, o).message(),
            "vertex_quantization_bits must be 10 or 16, got 12");
  o = {};
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, {}, o).message(),
            "neuroglancer export: no fragment encoder");
  EXPECT_FALSE(codec::EncodeNeuroglancerFragment({}, {}).ok());
  // One triangle and three corners of nothing: Draco's own decoder refuses its sequential
  // coding of such a mesh, which the Edgebreaker fallback would write.
  const std::vector<std::array<uint32_t, 3>> six = {{61439, 8192, 0},  {61439, 4096, 0},
                                                    {53247, 12288, 0}, {60074, 12288, 0},
                                                    {65535, 4096, 0},  {65535, 24576, 0}};
  const std::vector<uint32_t> one = {1, 4, 0};
  EXPECT_EQ(codec::EncodeNeuroglancerFragment(six, one).status().message(),
            "vertex 2 is in no triangle");
  EXPECT_FALSE(codec::DecodeNeuroglancerFragment("not draco").ok());
}

}  // namespace
}  // namespace tandem::io
