// Zarr / OME-Zarr: round trips through the writer for every version, codec and dtype,
// chunk layers deeper than one plane with edge chunks, fill values, byte order, OME axes
// and levels, damaged stores, and arrays written by an independent writer (zarr-python).
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"
#include "tandem/io/open_volume.h"
#include "tandem/volume.h"
#include "tandem/io/zarr.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

using testing::PatternValue;
using testing::StoreValue;
using testing::PatternSlices;
constexpr auto Load = testing::LoadValue;

VolumeInfo Grid(DType t, int64_t nx = 37, int64_t ny = 21, int64_t nz = 16) {
  VolumeInfo info;
  info.nx = nx;
  info.ny = ny;
  info.nz = nz;
  info.dtype = t;
  info.spacing = {0.5, 1.25, 2.0};
  info.origin = {-10.5, 3.25, 100.0};
  info.suggested_isovalues = {12.5};
  return info;
}

// Reads every slice and compares with the pattern; `fill` (if set) replaces the pattern for
// voxels where at(i, j, k) is true.
void ExpectPatternValue(SliceSource& src,
                        const std::function<bool(int64_t, int64_t, int64_t)>& at = {},
                        double fill = 0) {
  const VolumeInfo& info = src.info();
  const size_t es = DTypeSize(info.dtype);
  std::vector<uint8_t> slice;
  for (int64_t k = 0; k < info.nz; ++k) {
    ASSERT_TRUE(src.ReadSlice(&slice).ok()) << "slice " << k;
    ASSERT_EQ(slice.size(), info.slice_bytes());
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        const double want = at && at(i, j, k) ? fill : PatternValue(info.dtype, i, j, k);
        const double got = Load(info.dtype, slice.data() + (j * info.nx + i) * es);
        ASSERT_EQ(got, static_cast<double>(static_cast<float>(want)))
            << "voxel " << i << "," << j << "," << k;
      }
    }
  }
  EXPECT_TRUE(absl::IsOutOfRange(src.ReadSlice(&slice)));
}

json ReadJson(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return json::parse(ss.str());
}

void WriteText(const std::string& path, const std::string& text) {
  fs::create_directories(fs::path(path).parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

const char* CodecName(io::ZarrCompressor c) {
  switch (c) {
    case io::ZarrCompressor::kNone:
      return "none";
    case io::ZarrCompressor::kGzip:
      return "gzip";
    case io::ZarrCompressor::kZstd:
      return "zstd";
    case io::ZarrCompressor::kBloscLz4:
      return "blosclz4";
    case io::ZarrCompressor::kBloscZstd:
      return "bloscztd";
  }
  return "?";
}

// ---------------------------------------------------------------------------------------
// Round trips.

using RoundTripParam = std::tuple<int, io::ZarrCompressor, DType, int>;

class ZarrRoundTrip : public ::testing::TestWithParam<RoundTripParam> {};

TEST_P(ZarrRoundTrip, ReadsBackWhatTheWriterWrote) {
  const auto [version, codec, dtype, depth] = GetParam();
  const std::string dir = testing::MakeTempDir();
  const std::string path = dir + "/v.zarr";
  const VolumeInfo info = Grid(dtype);
  io::ZarrWriteOptions o;
  o.version = version;
  o.compressor = codec;
  o.chunks = {depth, 8, 16};  // 21 x 37 planes: edge chunks in y and x; 16 planes: in z for 7
  ASSERT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
  auto src = io::OpenVolume(path);
  ASSERT_TRUE(src.ok()) << src.status();
  const VolumeInfo& got = (*src)->info();
  EXPECT_EQ(got.nx, 37);
  EXPECT_EQ(got.ny, 21);
  EXPECT_EQ(got.nz, 16);
  EXPECT_EQ(got.dtype, dtype);
  EXPECT_EQ(got.spacing, info.spacing);  // OME scale
  EXPECT_EQ(got.origin, info.origin);    // OME translation
  EXPECT_EQ(got.suggested_isovalues, info.suggested_isovalues);
  ExpectPatternValue(**src);
}

INSTANTIATE_TEST_SUITE_P(
    AllCodecs, ZarrRoundTrip,
    ::testing::Combine(::testing::Values(2, 3),
                       ::testing::Values(io::ZarrCompressor::kNone, io::ZarrCompressor::kGzip,
                                         io::ZarrCompressor::kZstd, io::ZarrCompressor::kBloscLz4,
                                         io::ZarrCompressor::kBloscZstd),
                       ::testing::Values(DType::kUInt8, DType::kUInt16, DType::kInt16,
                                         DType::kFloat32),
                       ::testing::Values(1, 7)),
    [](const ::testing::TestParamInfo<RoundTripParam>& p) {
      return absl::StrCat("v", std::get<0>(p.param), "_", CodecName(std::get<1>(p.param)), "_",
                          std::string(DTypeName(std::get<2>(p.param))), "_z", std::get<3>(p.param));
    });

TEST(Zarr, BigEndianArraysAreSwapped) {
  for (int version : {2, 3}) {
    for (DType t : {DType::kUInt16, DType::kInt16, DType::kFloat32}) {
      const std::string path = testing::MakeTempDir() + "/be.zarr";
      const VolumeInfo info = Grid(t);
      io::ZarrWriteOptions o;
      o.version = version;
      o.big_endian = true;
      o.chunks = {3, 10, 10};
      ASSERT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
      if (version == 2) {
        EXPECT_EQ(ReadJson(path + "/0/.zarray")["dtype"].get<std::string>()[0], '>');
      } else {
        EXPECT_EQ(ReadJson(path + "/0/zarr.json")["codecs"][0]["configuration"]["endian"], "big");
      }
      auto src = io::OpenVolume(path);
      ASSERT_TRUE(src.ok()) << src.status();
      ExpectPatternValue(**src);
    }
  }
}

TEST(Zarr, PlainArrayWithSlashSeparatorHasUnitSpacing) {
  const std::string path = testing::MakeTempDir() + "/plain.zarr";
  const VolumeInfo info = Grid(DType::kUInt16);
  io::ZarrWriteOptions o;
  o.ome = false;
  o.dimension_separator = '/';
  o.chunks = {4, 0, 0};  // whole planes
  ASSERT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
  EXPECT_TRUE(fs::exists(path + "/.zarray"));
  EXPECT_TRUE(fs::exists(path + "/3/0/0"));  // nested chunk keys
  auto src = io::OpenVolume(path);
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_EQ((*src)->info().spacing, (std::array<double, 3>{1, 1, 1}));
  EXPECT_EQ((*src)->info().origin, (std::array<double, 3>{0, 0, 0}));
  ExpectPatternValue(**src);
}

TEST(Zarr, MissingChunksReadAsFillValue) {
  for (int version : {2, 3}) {
    const std::string path = testing::MakeTempDir() + "/fill.zarr";
    const VolumeInfo info = Grid(DType::kInt16);
    io::ZarrWriteOptions o;
    o.version = version;
    o.ome = false;
    o.compressor = io::ZarrCompressor::kZstd;
    o.chunks = {7, 8, 16};
    ASSERT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
    // Chunk (1, 2, 1): planes 7..13, rows 16..20 (edge), columns 16..31.
    const std::string meta = path + (version == 2 ? "/.zarray" : "/zarr.json");
    json j = ReadJson(meta);
    j["fill_value"] = -42;
    WriteText(meta, j.dump());
    ASSERT_TRUE(fs::remove(path + (version == 2 ? "/1.2.1" : "/c/1/2/1")));
    auto src = io::OpenVolume(path);
    ASSERT_TRUE(src.ok()) << src.status();
    ExpectPatternValue(
        **src,
        [](int64_t i, int64_t j, int64_t k) {
          return k >= 7 && k < 14 && j >= 16 && i >= 16 && i < 32;
        },
        -42);
  }
}

TEST(Zarr, DecodesOneChunkLayerAtATime) {
  // Damage chunk row 1 after opening: the 7 planes of row 0 still come out, then the error.
  const std::string path = testing::MakeTempDir() + "/layers.zarr";
  const VolumeInfo info = Grid(DType::kUInt8);
  io::ZarrWriteOptions o;
  o.ome = false;
  o.chunks = {7, 8, 16};
  ASSERT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
  auto src = io::OpenVolume(path);
  ASSERT_TRUE(src.ok()) << src.status();
  WriteText(path + "/1.0.0", "not blosc");
  std::vector<uint8_t> slice;
  for (int k = 0; k < 7; ++k) ASSERT_TRUE((*src)->ReadSlice(&slice).ok()) << k;
  absl::Status st = (*src)->ReadSlice(&slice);
  EXPECT_FALSE(st.ok());
  EXPECT_TRUE(absl::StrContains(st.message(), path + "/1.0.0")) << st;
  EXPECT_FALSE((*src)->ReadSlice(&slice).ok());  // stays failed
}

TEST(Zarr, AppenderShowsCompleteChunkLayersAsItGrows) {
  for (int version : {2, 3}) {
    SCOPED_TRACE(absl::StrCat("v", version));
    const std::string path = testing::MakeTempDir() + "/grow.zarr";
    VolumeInfo info = Grid(DType::kUInt16, 20, 12, 0);
    io::ZarrWriteOptions o;
    o.version = version;
    o.chunks = {4, 8, 8};
    const std::string meta = path + (version == 2 ? "/0/.zarray" : "/0/zarr.json");
    auto app = io::ZarrAppender::Create(path, info, o);
    ASSERT_TRUE(app.ok()) << app.status();
    EXPECT_EQ((*app)->array_path(), path + "/0");
    auto none = io::CountCompleteZarrPlanes(path);
    ASSERT_TRUE(none.ok()) << none.status();
    EXPECT_EQ(*none, 0);
    info.nz = 10;
    const io::SliceFn slices = PatternSlices(info);
    std::vector<uint8_t> plane;
    for (int64_t k = 0; k < 10; ++k) {
      ASSERT_TRUE(slices(k, &plane).ok());
      ASSERT_TRUE((*app)->Append(plane.data()).ok());
      const int64_t shape0 = ReadJson(meta)["shape"][0].get<int64_t>();
      EXPECT_EQ(shape0, (k + 1) / 4 * 4) << "after plane " << k;
      EXPECT_EQ((*app)->planes_visible(), shape0);
      auto complete = io::CountCompleteZarrPlanes(path);
      ASSERT_TRUE(complete.ok()) << complete.status();
      EXPECT_EQ(*complete, shape0);
      if (shape0 >= 4) {  // the visible part is readable while the array grows
        auto src = io::OpenVolume(path);
        ASSERT_TRUE(src.ok()) << src.status();
        EXPECT_EQ((*src)->info().nz, shape0);
      }
    }
    ASSERT_TRUE((*app)->Finish().ok());
    EXPECT_EQ(ReadJson(meta)["shape"][0].get<int64_t>(), 10);
    for (const auto& e : fs::recursive_directory_iterator(path)) {
      EXPECT_FALSE(e.path().string().ends_with(".tmp")) << e.path();
    }
    auto src = io::OpenVolume(path);
    ASSERT_TRUE(src.ok()) << src.status();
    ExpectPatternValue(**src);
    // A second store over the first is refused.
    EXPECT_TRUE(absl::IsAlreadyExists(io::ZarrAppender::Create(path, info, o).status()));
  }
}

TEST(Zarr, FollowerCountsCompleteRowsAndResumesAtAPlane) {
  // A writer that declares the final shape first and fills chunks as planes arrive: only
  // rows with every chunk on disk count.
  const std::string path = testing::MakeTempDir() + "/prealloc.zarr";
  const VolumeInfo info = Grid(DType::kFloat32, 20, 12, 11);
  io::ZarrWriteOptions o;
  o.ome = false;
  o.version = 3;
  o.chunks = {3, 8, 8};  // rows of 3 planes, 2 x 3 chunks each
  ASSERT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
  ASSERT_TRUE(fs::remove(path + "/c/2/1/2"));
  ASSERT_TRUE(fs::remove(path + "/c/3/0/0"));
  auto n = io::CountCompleteZarrPlanes(path);
  ASSERT_TRUE(n.ok()) << n.status();
  EXPECT_EQ(*n, 6);
  n = io::CountCompleteZarrPlanes(path, {}, 9);  // rows below 9 planes are not looked at
  ASSERT_TRUE(n.ok());
  EXPECT_EQ(*n, 9);
  n = io::CountCompleteZarrPlanes(testing::MakeTempDir() + "/nothing.zarr");
  EXPECT_FALSE(n.ok());
  // Resuming at plane 4 (inside the second row) reads 4..10 as they are.
  io::ZarrReadOptions from4;
  from4.first_plane = 4;
  fs::remove_all(path);
  ASSERT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
  auto src = io::OpenZarrVolume(path, from4);
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_EQ((*src)->next_slice(), 4);
  std::vector<uint8_t> slice;
  for (int64_t k = 4; k < 11; ++k) {
    ASSERT_TRUE((*src)->ReadSlice(&slice).ok());
    EXPECT_EQ(Load(DType::kFloat32, slice.data() + (5 * 20 + 7) * 4),
              static_cast<float>(PatternValue(DType::kFloat32, 7, 5, k)));
  }
  EXPECT_TRUE(absl::IsOutOfRange((*src)->ReadSlice(&slice)));
  from4.first_plane = 12;
  EXPECT_FALSE(io::OpenZarrVolume(path, from4).ok());
}

// ---------------------------------------------------------------------------------------
// OME-Zarr: axes, levels, selectors.

// A 5-axis (t, c, z, y, x) little-endian uint16 array with uncompressed chunks, written
// chunk by chunk as any Zarr writer lays it out; value = f(t, c, z, y, x).
uint16_t Value5(int64_t t, int64_t c, int64_t z, int64_t y, int64_t x) {
  return static_cast<uint16_t>(t * 20000 + c * 5000 + z * 300 + y * 17 + x);
}

void WriteFiveAxisImage(const std::string& root) {
  const int64_t shape[5] = {2, 3, 11, 9, 10}, chunks[5] = {1, 2, 4, 8, 8};
  WriteText(root + "/.zgroup", R"({"zarr_format": 2})");
  WriteText(root + "/.zattrs", R"({"multiscales": [{"version": "0.4", "name": "cells",
    "axes": [{"name": "t", "type": "time", "unit": "second"},
             {"name": "c", "type": "channel"},
             {"name": "z", "type": "space", "unit": "micrometer"},
             {"name": "y", "type": "space", "unit": "micrometer"},
             {"name": "x", "type": "space", "unit": "micrometer"}],
    "datasets": [{"path": "s0", "coordinateTransformations": [
                    {"type": "scale", "scale": [1, 1, 2.5, 0.5, 0.25]},
                    {"type": "translation", "translation": [0, 0, 10, -4, 7]}]}]}]})");
  WriteText(root + "/s0/.zarray", R"({"zarr_format": 2, "shape": [2, 3, 11, 9, 10],
    "chunks": [1, 2, 4, 8, 8], "dtype": "<u2", "compressor": null, "fill_value": 0,
    "order": "C", "filters": null})");
  int64_t n[5];
  for (int d = 0; d < 5; ++d) n[d] = (shape[d] + chunks[d] - 1) / chunks[d];
  for (int64_t a = 0; a < n[0]; ++a)
    for (int64_t b = 0; b < n[1]; ++b)
      for (int64_t cz = 0; cz < n[2]; ++cz)
        for (int64_t cy = 0; cy < n[3]; ++cy)
          for (int64_t cx = 0; cx < n[4]; ++cx) {
            std::vector<uint16_t> chunk;
            for (int64_t t = 0; t < chunks[0]; ++t)
              for (int64_t c = 0; c < chunks[1]; ++c)
                for (int64_t z = 0; z < chunks[2]; ++z)
                  for (int64_t y = 0; y < chunks[3]; ++y)
                    for (int64_t x = 0; x < chunks[4]; ++x) {
                      // Past the array's edge: garbage the reader must not use.
                      chunk.push_back(Value5(a * chunks[0] + t, b * chunks[1] + c,
                                             cz * chunks[2] + z, cy * chunks[3] + y,
                                             cx * chunks[4] + x));
                    }
            std::ofstream(absl::StrCat(root, "/s0/", a, ".", b, ".", cz, ".", cy, ".", cx),
                          std::ios::binary)
                .write(reinterpret_cast<const char*>(chunk.data()),
                       static_cast<std::streamsize>(chunk.size() * 2));
          }
}

TEST(OmeZarr, FiveAxesPickTimeAndChannelAndScaleGivesSpacing) {
  const std::string root = testing::MakeTempDir() + "/cells.zarr";
  WriteFiveAxisImage(root);
  for (auto [t, c] : {std::pair<int64_t, int64_t>{0, 0}, {1, 2}, {0, 1}}) {
    io::ZarrReadOptions opts;
    opts.t = t;
    opts.c = c;
    auto src = io::OpenZarrVolume(root, opts);
    ASSERT_TRUE(src.ok()) << src.status();
    const VolumeInfo& info = (*src)->info();
    EXPECT_EQ(info.nx, 10);
    EXPECT_EQ(info.ny, 9);
    EXPECT_EQ(info.nz, 11);
    EXPECT_EQ(info.spacing, (std::array<double, 3>{0.25, 0.5, 2.5}));
    EXPECT_EQ(info.origin, (std::array<double, 3>{7, -4, 10}));
    EXPECT_TRUE(absl::StrContains(info.description, "micrometer")) << info.description;
    std::vector<uint8_t> slice;
    for (int64_t z = 0; z < 11; ++z) {
      ASSERT_TRUE((*src)->ReadSlice(&slice).ok());
      for (int64_t y = 0; y < 9; ++y) {
        for (int64_t x = 0; x < 10; ++x) {
          uint16_t v;
          std::memcpy(&v, slice.data() + (y * 10 + x) * 2, 2);
          ASSERT_EQ(v, Value5(t, c, z, y, x)) << t << c << z << y << x;
        }
      }
    }
  }
  // OpenVolume reads t = 0, c = 0; an index outside the axis is refused.
  auto dflt = io::OpenVolume(root);
  ASSERT_TRUE(dflt.ok()) << dflt.status();
  io::ZarrReadOptions bad;
  bad.c = 3;
  absl::StatusOr<std::unique_ptr<SliceSource>> st = io::OpenZarrVolume(root, bad);
  EXPECT_FALSE(st.ok());
  EXPECT_TRUE(absl::StrContains(st.status().message(), "index 3 on axis c")) << st.status();
}

TEST(OmeZarr, LevelAndArraySelection) {
  const std::string root = testing::MakeTempDir() + "/pyr.zarr";
  io::ZarrWriteOptions o;
  o.ome = false;
  o.chunks = {3, 8, 8};
  const VolumeInfo l0 = Grid(DType::kUInt8, 40, 30, 20), l1 = Grid(DType::kUInt8, 20, 15, 10);
  ASSERT_TRUE(io::WriteZarr(root + "/0", l0, PatternSlices(l0), o).ok());
  ASSERT_TRUE(io::WriteZarr(root + "/1", l1, PatternSlices(l1), o).ok());
  const VolumeInfo lab = Grid(DType::kUInt16, 12, 11, 5);
  ASSERT_TRUE(io::WriteZarr(root + "/labels/nuclei", lab, PatternSlices(lab), o).ok());
  WriteText(root + "/.zgroup", R"({"zarr_format": 2})");
  WriteText(root + "/.zattrs", R"({"multiscales": [{"version": "0.4",
    "axes": ["z", "y", "x"],
    "datasets": [
      {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [3, 1, 1]}]},
      {"path": "1", "coordinateTransformations": [{"type": "scale", "scale": [6, 2, 2]}]}],
    "coordinateTransformations": [{"type": "scale", "scale": [0.5, 0.5, 0.5]}]}]})");
  auto level0 = io::OpenVolume(root);
  ASSERT_TRUE(level0.ok()) << level0.status();
  EXPECT_EQ((*level0)->info().nx, 40);
  EXPECT_EQ((*level0)->info().spacing, (std::array<double, 3>{0.5, 0.5, 1.5}));
  auto level1 = io::OpenVolume(root + "#1");
  ASSERT_TRUE(level1.ok()) << level1.status();
  EXPECT_EQ((*level1)->info().nx, 20);
  EXPECT_EQ((*level1)->info().spacing, (std::array<double, 3>{1, 1, 3}));
  ExpectPatternValue(**level1);
  auto labels = io::OpenVolume(root + "#labels/nuclei");
  ASSERT_TRUE(labels.ok()) << labels.status();
  EXPECT_EQ((*labels)->info().dtype, DType::kUInt16);
  EXPECT_EQ((*labels)->info().spacing, (std::array<double, 3>{1, 1, 1}));
  ExpectPatternValue(**labels);
  absl::Status missing = io::OpenVolume(root + "#2").status();
  EXPECT_TRUE(absl::StrContains(missing.message(), "level 2 does not exist")) << missing;
  // A group without multiscales says how to pick an array.
  const std::string bare = testing::MakeTempDir() + "/bare.zarr";
  ASSERT_TRUE(io::WriteZarr(bare + "/a", l1, PatternSlices(l1), o).ok());
  WriteText(bare + "/.zgroup", R"({"zarr_format": 2})");
  absl::Status group = io::OpenVolume(bare).status();
  EXPECT_TRUE(absl::StrContains(group.message(), "#PATH")) << group;
  EXPECT_TRUE(io::OpenVolume(bare + "#a").ok());
  ASSERT_TRUE(io::WriteZarr(bare + "/1", l0, PatternSlices(l0), o).ok());  // a number, not a level
  auto one = io::OpenVolume(bare + "#1");
  ASSERT_TRUE(one.ok()) << one.status();
  EXPECT_EQ((*one)->info().nx, 40);
}

absl::Status ReadAll(const std::string& path);

// A v3 array in shards of 4 x 8 x 16 made of 2 x 4 x 8 inner chunks (uint16, raw), the
// index (with a crc32c slot) at the end or the start; inner chunk `skip` (z, y, x inner
// indices) is left out of the index (fill value 7). value = z * 1000 + y * 37 + x.
uint16_t Value3(int64_t z, int64_t y, int64_t x) {
  return static_cast<uint16_t>(z * 1000 + y * 37 + x);
}

void WriteShardedArray(const std::string& root, bool index_at_start, std::array<int64_t, 3> skip) {
  const json bytes = {{"name", "bytes"}, {"configuration", {{"endian", "little"}}}};
  json meta = {
      {"zarr_format", 3},
      {"node_type", "array"},
      {"shape", {11, 10, 20}},
      {"data_type", "uint16"},
      {"chunk_grid", {{"name", "regular"}, {"configuration", {{"chunk_shape", {4, 8, 16}}}}}},
      {"chunk_key_encoding", {{"name", "default"}}},
      {"fill_value", 7},
      {"codecs",
       {{{"name", "sharding_indexed"},
         {"configuration",
          {{"chunk_shape", {2, 4, 8}},
           {"codecs", {bytes}},
           {"index_codecs", {bytes, {{"name", "crc32c"}}}},
           {"index_location", index_at_start ? "start" : "end"}}}}}}};
  WriteText(root + "/zarr.json", meta.dump());
  constexpr uint64_t kIndexBytes = 8 * 16 + 4;
  for (int64_t sz = 0; sz < 3; ++sz) {
    for (int64_t sy = 0; sy < 2; ++sy) {
      for (int64_t sx = 0; sx < 2; ++sx) {
        std::string body;
        std::vector<uint64_t> index;
        for (int64_t iz = 0; iz < 2; ++iz) {
          for (int64_t iy = 0; iy < 2; ++iy) {
            for (int64_t ix = 0; ix < 2; ++ix) {
              const int64_t gz = sz * 2 + iz, gy = sy * 2 + iy, gx = sx * 2 + ix;
              if (std::array<int64_t, 3>{gz, gy, gx} == skip) {
                index.insert(index.end(), {~uint64_t{0}, ~uint64_t{0}});
                continue;
              }
              index.insert(index.end(), {(index_at_start ? kIndexBytes : 0) + body.size(), 128});
              for (int64_t z = 0; z < 2; ++z) {
                for (int64_t y = 0; y < 4; ++y) {
                  for (int64_t x = 0; x < 8; ++x) {
                    const uint16_t v = Value3(gz * 2 + z, gy * 4 + y, gx * 8 + x);
                    body.append(reinterpret_cast<const char*>(&v), 2);
                  }
                }
              }
            }
          }
        }
        std::string idx(reinterpret_cast<const char*>(index.data()), index.size() * 8);
        idx.append(4, '\0');  // crc32c slot (not verified)
        WriteText(absl::StrCat(root, "/c/", sz, "/", sy, "/", sx),
                  index_at_start ? idx + body : body + idx);
      }
    }
  }
}

TEST(Zarr, ShardedV3ArraysReadInnerChunksFromTheirShards) {
  for (bool at_start : {false, true}) {
    SCOPED_TRACE(at_start ? "index at start" : "index at end");
    const std::string root = testing::MakeTempDir() + "/sharded.zarr";
    WriteShardedArray(root, at_start, {2, 1, 2});  // planes 4-5, rows 4-7, columns 16-19
    auto src = io::OpenVolume(root);
    ASSERT_TRUE(src.ok()) << src.status();
    ASSERT_EQ((*src)->info().nz, 11);
    std::vector<uint8_t> slice;
    for (int64_t z = 0; z < 11; ++z) {
      ASSERT_TRUE((*src)->ReadSlice(&slice).ok()) << z;
      for (int64_t y = 0; y < 10; ++y) {
        for (int64_t x = 0; x < 20; ++x) {
          uint16_t v;
          std::memcpy(&v, slice.data() + (y * 20 + x) * 2, 2);
          const bool skipped = z >= 4 && z < 6 && y >= 4 && y < 8 && x >= 16;
          ASSERT_EQ(v, skipped ? 7 : Value3(z, y, x)) << z << "," << y << "," << x;
        }
      }
    }
    auto planes = io::CountCompleteZarrPlanes(root);
    ASSERT_TRUE(planes.ok()) << planes.status();
    EXPECT_EQ(*planes, 11);
    // A truncated shard and an index entry past the shard's end name the shard file.
    const std::string shard = root + "/c/1/0/1";
    fs::resize_file(shard, 100);
    absl::Status st = ReadAll(root);
    EXPECT_TRUE(absl::IsDataLoss(st)) << st;
    EXPECT_TRUE(absl::StrContains(st.message(), shard)) << st;
    WriteShardedArray(root, at_start, {-1, -1, -1});
    std::string bytes(fs::file_size(shard), '\0');
    std::fstream f(shard, std::ios::in | std::ios::out | std::ios::binary);
    const uint64_t far = 1 << 30;
    f.seekp(at_start ? 0 : static_cast<std::streamoff>(bytes.size() - (8 * 16 + 4)));
    f.write(reinterpret_cast<const char*>(&far), 8);
    f.close();
    st = ReadAll(root);
    EXPECT_TRUE(absl::IsDataLoss(st)) << st;
    EXPECT_TRUE(absl::StrContains(st.message(), "outside the shard")) << st;
  }
}

// ---------------------------------------------------------------------------------------
// Bad input: clear errors naming the file, never a crash.

// A small v2 array (one plane per chunk) whose metadata the tests then damage.
std::string SmallArray(int version, io::ZarrCompressor codec) {
  const std::string path = testing::MakeTempDir() + "/bad.zarr";
  const VolumeInfo info = Grid(DType::kUInt16, 10, 8, 4);
  io::ZarrWriteOptions o;
  o.version = version;
  o.ome = false;
  o.compressor = codec;
  o.chunks = {1, 8, 10};
  EXPECT_TRUE(io::WriteZarr(path, info, PatternSlices(info), o).ok());
  return path;
}

absl::Status ReadAll(const std::string& path) {
  auto src = io::OpenVolume(path);
  if (!src.ok()) return src.status();
  std::vector<uint8_t> slice;
  for (;;) {
    absl::Status st = (*src)->ReadSlice(&slice);
    if (absl::IsOutOfRange(st)) return absl::OkStatus();
    if (!st.ok()) return st;
  }
}

TEST(ZarrBadInput, CorruptAndTruncatedChunksNameTheChunkFile) {
  for (int version : {2, 3}) {
    for (io::ZarrCompressor codec :
         {io::ZarrCompressor::kNone, io::ZarrCompressor::kGzip, io::ZarrCompressor::kZstd,
          io::ZarrCompressor::kBloscLz4, io::ZarrCompressor::kBloscZstd}) {
      SCOPED_TRACE(absl::StrCat("v", version, " ", CodecName(codec)));
      const std::string path = SmallArray(version, codec);
      const std::string chunk = path + (version == 2 ? "/2.0.0" : "/c/2/0/0");
      ASSERT_TRUE(fs::exists(chunk));
      // Truncated: the first half of the chunk file.
      const auto size = fs::file_size(chunk);
      fs::resize_file(chunk, size / 2);
      absl::Status st = ReadAll(path);
      EXPECT_TRUE(absl::IsDataLoss(st)) << st;
      EXPECT_TRUE(absl::StrContains(st.message(), chunk)) << st;
      if (codec == io::ZarrCompressor::kNone) continue;  // raw bytes of the right size are data
      // Garbage of the right length.
      WriteText(chunk, std::string(size, '\x5a'));
      st = ReadAll(path);
      EXPECT_TRUE(absl::IsDataLoss(st)) << st;
      EXPECT_TRUE(absl::StrContains(st.message(), chunk)) << st;
    }
  }
}

void ExpectMetadataError(const std::string& path, const std::string& meta,
                         const std::function<void(json&)>& edit, const std::string& words) {
  json j = ReadJson(meta);
  const json saved = j;
  edit(j);
  WriteText(meta, j.dump());
  absl::Status st = ReadAll(path);
  EXPECT_FALSE(st.ok()) << words;
  EXPECT_TRUE(absl::StrContains(st.message(), words)) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), meta)) << st;
  WriteText(meta, saved.dump());
}

TEST(ZarrBadInput, MetadataProblemsAreNamed) {
  const std::string v2 = SmallArray(2, io::ZarrCompressor::kBloscLz4);
  const std::string m2 = v2 + "/.zarray";
  ASSERT_TRUE(ReadAll(v2).ok());
  ExpectMetadataError(
      v2, m2, [](json& j) { j["dtype"] = "<f8"; }, "unsupported dtype '<f8'");
  ExpectMetadataError(
      v2, m2, [](json& j) { j["dtype"] = "<x2"; }, "unsupported dtype");
  ExpectMetadataError(
      v2, m2,
      [](json& j) {
        j["chunks"] = {1, 8};
      },
      "inconsistent metadata: shape has 3 dimensions but chunks has 2");
  ExpectMetadataError(
      v2, m2,
      [](json& j) {
        j["chunks"] = {0, 8, 10};
      },
      "inconsistent metadata");
  ExpectMetadataError(
      v2, m2,
      [](json& j) {
        j["compressor"] = {{"id", "lzma"}};
      },
      "unsupported compressor 'lzma'");
  ExpectMetadataError(
      v2, m2, [](json& j) { j["order"] = "F"; }, "only C order");
  ExpectMetadataError(
      v2, m2,
      [](json& j) {
        j["filters"] = {{{"id", "delta"}}};
      },
      "filters are not supported");
  ExpectMetadataError(
      v2, m2, [](json& j) { j["fill_value"] = 70000; }, "does not fit");
  ExpectMetadataError(
      v2, m2, [](json& j) { j["shape"] = "big"; }, "'shape' must be a list");
  ExpectMetadataError(
      v2, m2,
      [](json& j) {
        j["shape"] = {4, 8};
      },
      "inconsistent metadata");
  ExpectMetadataError(
      v2, m2,
      [](json& j) {
        j["chunks"] = {100000, 100000, 100000};
      },
      "too large");
  WriteText(m2, "{\"zarr_format\": 2, ");
  absl::Status st = ReadAll(v2);
  EXPECT_TRUE(absl::StrContains(st.message(), "invalid JSON")) << st;

  const std::string v3 = SmallArray(3, io::ZarrCompressor::kZstd);
  const std::string m3 = v3 + "/zarr.json";
  ASSERT_TRUE(ReadAll(v3).ok());
  ExpectMetadataError(
      v3, m3,
      [](json& j) {
        j["codecs"] = {{{"name", "sharding_indexed"}, {"configuration", json::object()}}};
      },
      "sharding_indexed needs chunk_shape and codecs");
  ExpectMetadataError(
      v3, m3,
      [](json& j) {
        j["codecs"].push_back({{"name", "transpose"}});
      },
      "more than one compression codec");
  ExpectMetadataError(
      v3, m3, [](json& j) { j["codecs"][1]["name"] = "transpose"; },
      "unsupported codec 'transpose'");
  ExpectMetadataError(
      v3, m3, [](json& j) { j["codecs"][1]["name"] = "lz4hc"; }, "unsupported codec 'lz4hc'");
  ExpectMetadataError(
      v3, m3, [](json& j) { j["data_type"] = "complex64"; }, "unsupported data_type 'complex64'");
  ExpectMetadataError(
      v3, m3, [](json& j) { j["chunk_grid"]["name"] = "rectilinear"; }, "unsupported chunk_grid");

  absl::Status not_zarr = ReadAll(testing::MakeTempDir() + "/empty.zarr");
  EXPECT_TRUE(absl::IsNotFound(not_zarr)) << not_zarr;
  const std::string dir = testing::MakeTempDir() + "/d.zarr";
  fs::create_directories(dir);
  absl::Status empty = ReadAll(dir);
  EXPECT_TRUE(absl::StrContains(empty.message(), "not a Zarr array or group")) << empty;
}

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Every chunk is a file to open: a store of 1x1x1 chunks (or metadata alone claiming
// billions of them, all missing) took minutes to hours. Arrays of at most 65536 chunks, or
// of chunks holding 4096 voxels or more on average, are read; others are refused at once,
// saying which chunking works.
TEST(ZarrBadInput, TinyChunksAreReadUpTo65536AndRefusedBeyondSayingWhatWorks) {
  const std::string root = testing::MakeTempDir();
  io::ZarrWriteOptions o;
  o.ome = false;
  o.compressor = io::ZarrCompressor::kNone;
  o.chunks = {1, 1, 1};
  const VolumeInfo small = Grid(DType::kUInt8, 24, 24, 24);
  ASSERT_TRUE(io::WriteZarr(root + "/small.zarr", small, PatternSlices(small), o).ok());
  auto src = io::OpenVolume(root + "/small.zarr");
  ASSERT_TRUE(src.ok()) << src.status();
  ExpectPatternValue(**src);

  // Metadata alone: 64^3 one-voxel chunks; 10^9 voxels in 10^6 chunks of 1000 per plane.
  WriteText(root + "/claim.zarr/.zarray",
            R"({"zarr_format": 2, "shape": [64, 64, 64], "chunks": [1, 1, 1],
                "dtype": "|u1", "compressor": null, "fill_value": 0})");
  WriteText(root + "/plane.zarr/.zarray",
            R"({"zarr_format": 2, "shape": [1000, 1000, 1000], "chunks": [1000, 1, 1],
                "dtype": "|u1", "compressor": null, "fill_value": 0})");
  const auto t0 = std::chrono::steady_clock::now();
  absl::Status st = ReadAll(root + "/claim.zarr");
  EXPECT_TRUE(absl::StrContains(st.message(), root + "/claim.zarr/.zarray: chunks of 1x1x1 voxels"))
      << st;
  EXPECT_TRUE(absl::StrContains(st.message(), "lie in 262144 chunks")) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), "1x64x64, 16x16x16 or larger")) << st;
  st = ReadAll(root + "/plane.zarr");
  EXPECT_TRUE(absl::StrContains(st.message(), "1000000 chunks per chunk row")) << st;
  EXPECT_LT(SecondsSince(t0), 1.0);
}

// A chunk a few bytes long whose codec claims a huge chunk is refused before a buffer of
// the chunk's size is allocated for it (deflate expands at most 1032 times, blosc and zstd
// 65536 times).
TEST(ZarrBadInput, TinyChunksClaimingHugeOnesAreRefusedBeforeDecoding) {
  const std::string root = testing::MakeTempDir();
  for (const char* codec : {"gzip", "blosc"}) {
    const std::string store = absl::StrCat(root, "/", codec, ".zarr");
    WriteText(
        store + "/.zarray",
        absl::StrCat(R"({"zarr_format": 2, "shape": [2, 4096, 8192], "chunks": [1, 4096, 8192],
                "dtype": "<u2", "fill_value": 0, "compressor": {"id": ")",
                     codec, R"("}})"));
    std::string chunk;
    if (std::string(codec) == "gzip") {
      chunk = std::string("\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03", 10) + std::string(90, '\0');
    } else {  // a blosc header: version 2, lz4 1, byte shuffle, typesize 2, 64 MiB, 100 bytes
      const uint32_t nbytes = 64u << 20, blocksize = 1u << 16, cbytes = 100;
      chunk = std::string("\x02\x01\x01\x02", 4);
      for (uint32_t v : {nbytes, blocksize, cbytes}) {
        chunk.append(reinterpret_cast<const char*>(&v), 4);
      }
      chunk.resize(cbytes, '\0');
    }
    WriteText(store + "/0.0.0", chunk);
    const absl::Status st = ReadAll(store);
    EXPECT_TRUE(absl::IsDataLoss(st)) << st;
    EXPECT_TRUE(absl::StrContains(st.message(), store + "/0.0.0: chunk (0, 0, 0)")) << st;
    EXPECT_TRUE(
        absl::StrContains(st.message(), " data of 100 bytes cannot hold the chunk's 67108864"))
        << st;
  }
}

// Shapes and shard shapes beyond any volume, and metadata nested thousands deep (which
// nlohmann's recursive dump would follow into a stack overflow), are refused by name.
TEST(ZarrBadInput, OutlandishMetadataIsRefusedBeforeAnyArithmetic) {
  const std::string v2 = SmallArray(2, io::ZarrCompressor::kNone);
  const std::string m2 = v2 + "/.zarray";
  ExpectMetadataError(
      v2, m2,
      [](json& j) {
        j["shape"] = {int64_t{1} << 50, 8, 10};
      },
      "is beyond any volume");
  ExpectMetadataError(
      v2, m2,
      [](json& j) { j["dtype"] = json::parse(std::string(5000, '[') + std::string(5000, ']')); },
      "JSON nested more than 64 levels deep");
  const std::string root = testing::MakeTempDir() + "/sharded.zarr";
  WriteShardedArray(root, false, {-1, -1, -1});
  ExpectMetadataError(
      root, root + "/zarr.json",
      [](json& j) {
        j["chunk_grid"]["configuration"]["chunk_shape"] = {int64_t{1} << 40, int64_t{1} << 40,
                                                           int64_t{1} << 40};
        j["codecs"][0]["configuration"]["chunk_shape"] = {1, 1, 1};
      },
      "more than 2^24 inner chunks per shard");
}

// OME-Zarr dataset paths and array selectors name arrays inside the store: "..", absolute
// paths and symlinks leading out of it are refused, naming the path.
TEST(OmeZarr, PathsOutsideTheStoreAreRefused) {
  const std::string root = testing::MakeTempDir();
  io::ZarrWriteOptions o;
  o.ome = false;
  const VolumeInfo info = Grid(DType::kUInt8, 20, 15, 10);
  ASSERT_TRUE(io::WriteZarr(root + "/outside", info, PatternSlices(info), o).ok());
  const std::string store = root + "/img.zarr";
  ASSERT_TRUE(io::WriteZarr(store + "/0", info, PatternSlices(info), o).ok());
  fs::create_symlink(root + "/outside", store + "/link");
  WriteText(store + "/.zgroup", R"({"zarr_format": 2})");
  const auto multiscale = [&](const std::string& path) {
    WriteText(store + "/.zattrs",
              absl::StrCat(R"({"multiscales": [{"version": "0.4", "datasets": [{"path": ")", path,
                           R"("}]}]})"));
  };
  multiscale("0");
  ASSERT_TRUE(ReadAll(store).ok());
  for (const auto& [path, why] :
       std::vector<std::pair<std::string, std::string>>{{"../outside", "goes up with .."},
                                                        {root + "/outside", "is absolute"},
                                                        {"link", "leads outside the group"}}) {
    multiscale(path);
    absl::Status st = ReadAll(store);
    EXPECT_TRUE(absl::IsInvalidArgument(st)) << st;
    EXPECT_TRUE(absl::StrContains(st.message(), "multiscales dataset path '" + path + "' " + why))
        << st;
    EXPECT_TRUE(absl::StrContains(st.message(), store + "/.zattrs")) << st;
    st = ReadAll(store + "#" + path);
    EXPECT_TRUE(absl::StrContains(st.message(), "array path '" + path + "' " + why)) << st;
  }
}

// ---------------------------------------------------------------------------------------
// An independent writer and reader: zarr-python (Debian's python3-zarr, Zarr v2).

bool HavePythonZarr() {
  return std::system("/usr/bin/python3 -c 'import zarr, numcodecs' >/dev/null 2>&1") == 0;
}

constexpr char kPythonWrite[] = R"(
import sys, numpy as np, zarr, numcodecs
out = sys.argv[1]
k, j, i = np.meshgrid(np.arange(13), np.arange(21), np.arange(37), indexing='ij')
u16 = ((40000 + i * 301 + j * 17 + k * 1009) % 65536).astype(np.uint16)
f32 = (-3.25 + i * 0.5 + j * 1.125 + k * 100.0625).astype(np.float32)
B = numcodecs.Blosc
cases = [
  ('blosc_lz4', B(cname='lz4', clevel=5, shuffle=B.SHUFFLE), '<u2', u16, '.'),
  ('blosc_zstd', B(cname='zstd', clevel=3, shuffle=B.BITSHUFFLE), '<u2', u16, '/'),
  ('blosc_blosclz_f4', B(cname='blosclz', clevel=9, shuffle=B.NOSHUFFLE), '<f4', f32, '.'),
  ('gzip_be', numcodecs.GZip(5), '>u2', u16, '.'),
  ('zstd', numcodecs.Zstd(3), '<u2', u16, '.'),
  ('zlib_i2', numcodecs.Zlib(4), '<i2', u16.view(np.int16), '.'),
]
for name, comp, dt, v, sep in cases:
    z = zarr.open(out + '/' + name + '.zarr', mode='w', shape=v.shape, chunks=(4, 8, 16),
                  dtype=dt, compressor=comp, dimension_separator=sep, fill_value=0)
    z[:] = v
)";

TEST(ZarrPython, ReadsArraysWrittenByZarrPython) {
  if (!HavePythonZarr()) {
    GTEST_SKIP() << "/usr/bin/python3 with zarr and numcodecs not found "
                    "(apt-get install python3-zarr python3-numcodecs)";
  }
  const std::string dir = testing::MakeTempDir();
  WriteText(dir + "/write.py", kPythonWrite);
  ASSERT_EQ(std::system(("/usr/bin/python3 " + dir + "/write.py " + dir).c_str()), 0);
  for (const char* name :
       {"blosc_lz4", "blosc_zstd", "blosc_blosclz_f4", "gzip_be", "zstd", "zlib_i2"}) {
    SCOPED_TRACE(name);
    auto src = io::OpenVolume(dir + "/" + name + ".zarr");
    ASSERT_TRUE(src.ok()) << src.status();
    const VolumeInfo& info = (*src)->info();
    ASSERT_EQ(info.nx, 37);
    ASSERT_EQ(info.ny, 21);
    ASSERT_EQ(info.nz, 13);
    std::vector<uint8_t> slice;
    for (int64_t k = 0; k < 13; ++k) {
      ASSERT_TRUE((*src)->ReadSlice(&slice).ok()) << k;
      for (int64_t j = 0; j < 21; ++j) {
        for (int64_t i = 0; i < 37; ++i) {
          const uint8_t* p = slice.data() + (j * 37 + i) * DTypeSize(info.dtype);
          if (info.dtype == DType::kFloat32) {
            ASSERT_EQ(Load(info.dtype, p),
                      static_cast<float>(PatternValue(DType::kFloat32, i, j, k)));
          } else {
            uint16_t v;  // int16 holds the same bits
            std::memcpy(&v, p, 2);
            ASSERT_EQ(v, PatternValue(DType::kUInt16, i, j, k)) << i << "," << j << "," << k;
          }
        }
      }
    }
  }
}

constexpr char kPythonCheck[] = R"(
import sys, numpy as np, zarr
z = zarr.open(sys.argv[1], mode='r')
k, j, i = np.meshgrid(np.arange(16), np.arange(21), np.arange(37), indexing='ij')
want = ((40000 + i * 301 + j * 17 + k * 1009) % 65536).astype(np.uint16)
a = z['0'][:]
attrs = z.attrs.asdict()
ok = a.shape == want.shape and (a == want).all() and \
     attrs['multiscales'][0]['datasets'][0]['coordinateTransformations'][0]['scale'] == [2.0, 1.25, 0.5]
sys.exit(0 if ok else 1)
)";

TEST(ZarrPython, ZarrPythonReadsWhatTheWriterWrote) {
  if (!HavePythonZarr()) {
    GTEST_SKIP() << "/usr/bin/python3 with zarr and numcodecs not found "
                    "(apt-get install python3-zarr python3-numcodecs)";
  }
  for (io::ZarrCompressor codec :
       {io::ZarrCompressor::kBloscLz4, io::ZarrCompressor::kBloscZstd, io::ZarrCompressor::kZstd,
        io::ZarrCompressor::kGzip, io::ZarrCompressor::kNone}) {
    SCOPED_TRACE(CodecName(codec));
    const std::string dir = testing::MakeTempDir();
    const VolumeInfo info = Grid(DType::kUInt16);
    io::ZarrWriteOptions o;
    o.compressor = codec;
    o.chunks = {7, 8, 16};
    ASSERT_TRUE(io::WriteZarr(dir + "/ours.zarr", info, PatternSlices(info), o).ok());
    WriteText(dir + "/check.py", kPythonCheck);
    EXPECT_EQ(std::system(("/usr/bin/python3 " + dir + "/check.py " + dir + "/ours.zarr").c_str()),
              0);
  }
}

}  // namespace
}  // namespace tandem
