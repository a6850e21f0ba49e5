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
#include "tandem/codec/neuroglancer_draco.h"
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

// Triangles as position triples starting at the smallest corner (orientation kept).
std::multiset<std::array<std::array<uint32_t, 3>, 3>> Triangles(
    const std::vector<std::array<uint32_t, 3>>& p, const std::vector<uint32_t>& idx) {
  std::multiset<std::array<std::array<uint32_t, 3>, 3>> out;
  for (size_t t = 0; t + 2 < idx.size(); t += 3) {
    std::array<std::array<uint32_t, 3>, 3> tri = {p[idx[t]], p[idx[t + 1]], p[idx[t + 2]]};
    const size_t first = std::min_element(tri.begin(), tri.end()) - tri.begin();
    std::rotate(tri.begin(), tri.begin() + first, tri.end());
    out.insert(tri);
  }
  return out;
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

TEST(NeuroglancerExport, ReadsBackAsNeuroglancerDoes) {
  const std::string dir = testing::MakeTempDir() + "/ng";
  std::vector<NeuroglancerSegment> segments;
  for (LabelId id : {7u, 1000000007u, 3u}) {
    const Vec3 c{static_cast<float>(id % 13), 2.0f, -5.0f};
    segments.push_back({id, {Octahedron(c, 3, 3), Octahedron(c, 3, 2.5f), Octahedron(c, 3.1f, 2)}});
  }
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 20;
  grid.spacing = {4, 4, 40};
  NeuroglancerOptions options = DracoOptions();
  options.nm_per_unit = 2;
  ASSERT_TRUE(WriteNeuroglancer(dir, grid, segments, options).ok());

  const auto info = nlohmann::json::parse(ReadAll(dir + "/info"));
  EXPECT_EQ(info["type"], "segmentation");
  EXPECT_EQ(info["mesh"], "mesh");
  EXPECT_EQ(info["scales"][0]["resolution"], nlohmann::json({8.0, 8.0, 80.0}));
  const auto mesh_info = nlohmann::json::parse(ReadAll(dir + "/mesh/info"));
  EXPECT_EQ(mesh_info["@type"], "neuroglancer_multilod_draco");
  EXPECT_EQ(mesh_info["vertex_quantization_bits"], 16);
  EXPECT_EQ(mesh_info["transform"], nlohmann::json({2.0, 0, 0, 0, 0, 2.0, 0, 0, 0, 0, 2.0, 0}));

  for (const NeuroglancerSegment& seg : segments) {
    SCOPED_TRACE(seg.id);
    const Stored stored = ReadSegment(dir, seg.id);
    ASSERT_EQ(stored.fragments.size(), 3u);
    EXPECT_EQ(stored.lod_scales, std::vector<float>({4, 8, 16}));  // 2^k x finest spacing
    auto quantized = QuantizeSegment(seg, 16);
    ASSERT_TRUE(quantized.ok());
    EXPECT_EQ(stored.chunk_shape, quantized->chunk_shape);
    EXPECT_EQ(stored.grid_origin, quantized->grid_origin);
    for (size_t k = 0; k < 3; ++k) {
      // One node per level, at the grid's corner, holding the whole segment.
      ASSERT_EQ(stored.fragments[k].size(), 1u);
      EXPECT_EQ(stored.positions[k][0], (std::array<uint32_t, 3>{0, 0, 0}));
      const codec::IntegerMesh& got = stored.fragments[k][0];
      const NeuroglancerFragment& want = quantized->lods[k];
      EXPECT_EQ(Triangles(got.positions, got.indices), Triangles(want.positions, want.indices))
          << "level " << k;
      // The formula Neuroglancer applies gives back each vertex within half a step, so
      // nothing was clamped: every level fits its node, and levels > 0 its low octant.
      for (size_t v = 0; v < want.positions.size(); ++v) {
        const Vec3 p = DequantizePosition(*quantized, static_cast<int>(k), want.positions[v], 16);
        const Vec3& o = seg.lods[k].positions[v];
        auto step = [&](int j) {
          return std::ldexp(quantized->chunk_shape[j], static_cast<int>(k)) / 65535;
        };
        EXPECT_NEAR(p.x, o.x, step(0));
        EXPECT_NEAR(p.y, o.y, step(1));
        EXPECT_NEAR(p.z, o.z, step(2));
        if (k > 0) {
          for (int j = 0; j < 3; ++j) EXPECT_LE(want.positions[v][j], 32768u);
        }
      }
    }
  }
  EXPECT_TRUE(ReadSegment(dir, 8).fragments.empty());  // no such segment
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
      EXPECT_LT(stored.fragments[k][0].indices.size(), stored.fragments[k - 1][0].indices.size())
          << "level " << k;
    }
    if (id == 2) {
      EXPECT_LT(stored.fragments[0][0].indices.size(), previous_outer);
    }
    previous_outer = stored.fragments[0][0].indices.size();
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
    EXPECT_LT(targeted.fragments[k][0].indices.size(), targeted.fragments[k - 1][0].indices.size())
        << "level " << k;
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
  std::vector<std::unique_ptr<TandemSession>> sessions;
  std::vector<const TandemSession*> levels;
  for (double e0 : {0.3, 0.6}) {
    SessionOptions o;
    o.labels.enabled = true;
    o.error = e0;
    auto session = TandemSession::Create(grid, o);
    ASSERT_TRUE(session.ok()) << session.status();
    for (int64_t z = 0; z < grid.nz; ++z) {
      ASSERT_TRUE((*session)
                      ->AddSliceBytes(DType::kUInt16, reinterpret_cast<const uint8_t*>(
                                                          voxels.data() + z * grid.nx * grid.ny))
                      .ok());
    }
    ASSERT_TRUE((*session)->Finish().ok());
    levels.push_back(session->get());
    sessions.push_back(*std::move(session));
  }
  const std::string dir = testing::MakeTempDir() + "/ng";
  ASSERT_TRUE(app::WriteNeuroglancerLabels(dir, grid, levels, 0, 1, 7).ok());
  for (LabelId id : {5u, 9u}) {
    SCOPED_TRACE(id);
    const Stored stored = ReadSegment(dir, id);
    ASSERT_EQ(stored.fragments.size(), 2u);
    // Level 0 is the label's own surface from SplitByLabel, as quantized.
    for (const auto& [label, mesh] : SplitByLabel(levels[0]->SnapshotLabeled(), 0)) {
      if (label != id) continue;
      auto q = QuantizeSegment({id, {mesh}}, 16);
      ASSERT_TRUE(q.ok());
      EXPECT_GT(mesh.num_triangles(), 0u);
      EXPECT_EQ(Triangles(stored.fragments[0][0].positions, stored.fragments[0][0].indices).size(),
                mesh.num_triangles());
    }
    EXPECT_FALSE(stored.fragments[1][0].indices.empty());
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
  ASSERT_TRUE(io::WriteVolume(tmp + "/labels.nrrd", grid,
                          [&](int64_t z, std::vector<uint8_t>* bytes) {
                            const auto* b = reinterpret_cast<const uint8_t*>(
                                voxels.data() + z * grid.nx * grid.ny);
                            bytes->assign(b, b + grid.slice_bytes());
                            return absl::OkStatus();
                          })
                  .ok());
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
  o.vertex_quantization_bits = 12;
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, {}, o).message(),
            "vertex_quantization_bits must be 10 or 16, got 12");
  o = {};
  EXPECT_EQ(WriteNeuroglancer(tmp, grid, {}, o).message(),
            "neuroglancer export: no fragment encoder");
  EXPECT_FALSE(codec::EncodeNeuroglancerFragment({}, {}).ok());
  EXPECT_FALSE(codec::DecodeNeuroglancerFragment("not draco").ok());
}

}  // namespace
}  // namespace tandem::io
