// Label maps through every reader that returns integers: int8 and the 32- and 64-bit types
// read back exactly (uint32 ids past float's 2^24, uint64 ids past double's 2^53), from the
// project's writers and from independent ones (libtiff, nifticlib, zarr-python, NRRD,
// MetaImage and raw sidecars written by hand per their specs); a wide-integer volume still
// meshes as an intensity volume; the types' names, ranges and conversion to label ids.
#include <gtest/gtest.h>
#include <nifti1_io.h>
#include <tiffio.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <type_traits>
#include <vector>

#include "tandem/io/open_volume.h"
#include "tandem/io/run_session.h"
#include "tandem/io/volume_writers.h"
#include "tandem/io/zarr.h"
#include "tandem/labels.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

constexpr int64_t kNx = 7, kNy = 5, kNz = 4;
constexpr DType kWide[] = {DType::kInt8, DType::kUInt32, DType::kInt32, DType::kUInt64,
                           DType::kInt64};

VolumeInfo Grid(DType t) {
  VolumeInfo info;
  info.nx = kNx;
  info.ny = kNy;
  info.nz = kNz;
  info.dtype = t;
  info.spacing = {0.5, 0.75, 2.0};
  return info;
}

// Voxel n's id, every byte of the type used: uint32 past 2^24, uint64 past 2^53 (neither a
// float nor a double holds them), negatives in the signed types.
template <typename T>
T IdOf(int64_t n) {
  if constexpr (sizeof(T) == 1) {
    return static_cast<T>((n * 37 + 11) % 256 - (std::is_signed_v<T> ? 128 : 0));
  } else {
    const uint64_t base = sizeof(T) == 4 ? (uint64_t{1} << 24) + 1 : (uint64_t{1} << 53) + 1;
    const uint64_t step = sizeof(T) == 4 ? 0x10203u : 0x1020304050607ull;
    T v = static_cast<T>(base + static_cast<uint64_t>(n) * step);
    if constexpr (std::is_signed_v<T>) {
      if (n % 3 == 1) v = static_cast<T>(-v);
    }
    return v;
  }
}

// The volume's bytes (host order), slice by slice.
std::vector<uint8_t> Bytes(DType t) {
  std::vector<uint8_t> out;
  const int64_t n = kNx * kNy * kNz;
  auto put = [&](auto v) {
    const auto* p = reinterpret_cast<const uint8_t*>(&v);
    out.insert(out.end(), p, p + sizeof v);
  };
  for (int64_t i = 0; i < n; ++i) {
    switch (t) {
      case DType::kInt8:
        put(IdOf<int8_t>(i));
        break;
      case DType::kUInt8:
        put(IdOf<uint8_t>(i));
        break;
      case DType::kUInt32:
        put(IdOf<uint32_t>(i));
        break;
      case DType::kInt32:
        put(IdOf<int32_t>(i));
        break;
      case DType::kUInt64:
        put(IdOf<uint64_t>(i));
        break;
      case DType::kInt64:
        put(IdOf<int64_t>(i));
        break;
      default:
        ADD_FAILURE() << "no label pattern for " << DTypeName(t);
    }
  }
  return out;
}

io::SliceFn Slices(DType t) {
  return [t](int64_t z, std::vector<uint8_t>* bytes) {
    const std::vector<uint8_t> all = Bytes(t);
    const size_t slice = static_cast<size_t>(kNx * kNy) * DTypeSize(t);
    bytes->assign(all.begin() + static_cast<std::ptrdiff_t>(z * slice),
                  all.begin() + static_cast<std::ptrdiff_t>((z + 1) * slice));
    return absl::OkStatus();
  };
}

// Reads `path` whole and checks its type and every byte.
void ExpectExact(const std::string& path, DType t) {
  SCOPED_TRACE(path);
  auto src = io::OpenVolume(path);
  ASSERT_TRUE(src.ok()) << src.status();
  const VolumeInfo& info = (*src)->info();
  EXPECT_EQ(info.dtype, t) << DTypeName(info.dtype);
  ASSERT_EQ(info.nx, kNx);
  ASSERT_EQ(info.ny, kNy);
  ASSERT_EQ(info.nz, kNz);
  std::vector<uint8_t> all, slice;
  for (int64_t z = 0; z < kNz; ++z) {
    ASSERT_TRUE((*src)->ReadSlice(&slice).ok()) << z;
    all.insert(all.end(), slice.begin(), slice.end());
  }
  EXPECT_TRUE(all == Bytes(t)) << "voxels differ";
  // And as label ids: the same values, exactly (negatives refused by ToLabelIds).
  if (!IsSignedDType(t)) {
    std::vector<uint64_t> ids(all.size() / DTypeSize(t));
    ASSERT_TRUE(ToLabelIds(t, all.data(), ids.size(), ids.data()).ok());
    if (t == DType::kUInt64) {
      EXPECT_EQ(ids[5], IdOf<uint64_t>(5));
    } else if (t == DType::kUInt32) {
      EXPECT_EQ(ids[5], IdOf<uint32_t>(5));
    }
  }
}

void WriteFile(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

std::string AsString(const std::vector<uint8_t>& b) { return std::string(b.begin(), b.end()); }

TEST(LabelReaders, TheProjectsWritersRoundTripEveryWideType) {
  const std::string dir = testing::MakeTempDir();
  io::VolumeWriteOptions big, gz, tiles;
  big.big_endian = true;
  gz.gzip = true;
  tiles.tiff_tile_size = 16;
  for (DType t : kWide) {
    const std::string n = std::string(DTypeName(t));
    const struct {
      std::string name;
      io::VolumeWriteOptions opts;
    } files[] = {{"a.json", {}},  {"b.json", big}, {"c.nrrd", {}},   {"d.nrrd", gz},
                 {"e.nrrd", big}, {"f.nhdr", {}},  {"g.nii", {}},    {"h.nii.gz", big},
                 {"i.tif", {}},   {"j.tif", big},  {"k.tif", tiles}, {"l.tif", gz},
                 {"m.mha", {}},   {"n.mhd", big},  {"o.zarr", {}}};
    for (const auto& f : files) {
      const std::string path = dir + "/" + n + "_" + f.name;
      ASSERT_TRUE(io::WriteVolume(path, Grid(t), Slices(t), f.opts).ok()) << path;
      ExpectExact(path, t);
    }
    for (int version : {2, 3}) {
      for (bool big_endian : {false, true}) {
        io::ZarrWriteOptions zo;
        zo.version = version;
        zo.big_endian = big_endian;
        zo.chunks = {3, 4, 4};
        zo.compressor = big_endian ? io::ZarrCompressor::kZstd : io::ZarrCompressor::kBloscLz4;
        const std::string path =
            dir + "/" + n + "_v" + std::to_string(version) + (big_endian ? "_be" : "") + ".zarr";
        ASSERT_TRUE(io::WriteZarr(path, Grid(t), Slices(t), zo).ok()) << path;
        ExpectExact(path, t);
      }
    }
  }
}

TEST(LabelReaders, TheSidecarsValueRangeIsExact) {
  const std::string dir = testing::MakeTempDir();
  ASSERT_TRUE(io::WriteVolume(dir + "/u.json", Grid(DType::kUInt64), Slices(DType::kUInt64)).ok());
  const std::string text = testing::FileBytes(dir + "/u.json");
  // The smallest id, 2^53 + 1, printed whole (a double would print 9007199254740992).
  EXPECT_NE(text.find("9007199254740993"), std::string::npos) << text;
  EXPECT_NE(text.find("\"dtype\": \"uint64\""), std::string::npos) << text;
}

TEST(LabelReaders, LibtiffWritten32And64BitSamples) {
  const std::string dir = testing::MakeTempDir();
  for (DType t : {DType::kUInt32, DType::kInt32, DType::kUInt64, DType::kInt64, DType::kInt8}) {
    const std::string path = dir + "/" + std::string(DTypeName(t)) + ".tif";
    TIFF* tif = TIFFOpen(path.c_str(), "w");
    ASSERT_NE(tif, nullptr);
    const std::vector<uint8_t> all = Bytes(t);
    const size_t row = static_cast<size_t>(kNx) * DTypeSize(t);
    for (int64_t z = 0; z < kNz; ++z) {
      TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, static_cast<uint32_t>(kNx));
      TIFFSetField(tif, TIFFTAG_IMAGELENGTH, static_cast<uint32_t>(kNy));
      TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, static_cast<uint16_t>(8 * DTypeSize(t)));
      TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT,
                   static_cast<uint16_t>(IsSignedDType(t) ? SAMPLEFORMAT_INT : SAMPLEFORMAT_UINT));
      TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, uint16_t{1});
      TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
      TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
      TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_LZW);
      TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, uint32_t{2});
      for (int64_t y = 0; y < kNy; ++y) {
        std::vector<uint8_t> line(
            all.begin() + static_cast<std::ptrdiff_t>((z * kNy + y) * row),
            all.begin() + static_cast<std::ptrdiff_t>((z * kNy + y + 1) * row));
        ASSERT_EQ(TIFFWriteScanline(tif, line.data(), static_cast<uint32_t>(y), 0), 1);
      }
      ASSERT_EQ(TIFFWriteDirectory(tif), 1);
    }
    TIFFClose(tif);
    ExpectExact(path, t);
  }
}

TEST(LabelReaders, NifticlibWrittenWideTypes) {
  const std::string dir = testing::MakeTempDir();
  const struct {
    DType t;
    int code;
  } cases[] = {{DType::kUInt32, NIFTI_TYPE_UINT32},
               {DType::kInt32, NIFTI_TYPE_INT32},
               {DType::kUInt64, NIFTI_TYPE_UINT64},
               {DType::kInt64, NIFTI_TYPE_INT64},
               {DType::kInt8, NIFTI_TYPE_INT8}};
  for (const auto& c : cases) {
    for (const char* ext : {".nii", ".nii.gz"}) {
      const std::string path = dir + "/" + std::string(DTypeName(c.t)) + ext;
      const int dims[8] = {
          3, static_cast<int>(kNx), static_cast<int>(kNy), static_cast<int>(kNz), 1, 1, 1, 1};
      nifti_image* nim = nifti_make_new_nim(dims, c.code, 1);
      ASSERT_NE(nim, nullptr);
      const std::vector<uint8_t> all = Bytes(c.t);
      ASSERT_EQ(nim->nvox * static_cast<size_t>(nim->nbyper), all.size());
      std::memcpy(nim->data, all.data(), all.size());
      ASSERT_EQ(nifti_set_filenames(nim, path.c_str(), 0, 1), 0);
      nifti_image_write(nim);
      nifti_image_free(nim);
      ExpectExact(path, c.t);
    }
  }
}

TEST(LabelReaders, NrrdMetaImageAndSidecarsWrittenByHand) {
  const std::string dir = testing::MakeTempDir();
  const std::string sizes =
      std::to_string(kNx) + " " + std::to_string(kNy) + " " + std::to_string(kNz);
  // NRRD's names (teem's nrrdTypeUInt ... nrrdTypeLLong spellings), little-endian raw.
  const struct {
    DType t;
    const char* nrrd;
    const char* meta;
  } cases[] = {{DType::kUInt32, "unsigned int", "MET_UINT"},
               {DType::kInt32, "int", "MET_INT"},
               {DType::kUInt64, "unsigned long long int", "MET_ULONG_LONG"},
               {DType::kInt64, "longlong", "MET_LONG_LONG"},
               {DType::kInt8, "signed char", "MET_CHAR"},
               {DType::kUInt32, "uint32_t", "MET_ULONG"},
               {DType::kInt32, "int32", "MET_LONG"}};
  int n = 0;
  for (const auto& c : cases) {
    const std::string data = AsString(Bytes(c.t));
    const std::string stem = dir + "/" + std::to_string(++n);
    WriteFile(stem + ".nrrd", std::string("NRRD0004\ntype: ") + c.nrrd + "\ndimension: 3\nsizes: " +
                                  sizes + "\nencoding: raw\nendian: little\n\n" + data);
    ExpectExact(stem + ".nrrd", c.t);
    WriteFile(stem + ".mha", std::string("ObjectType = Image\nNDims = 3\nDimSize = ") + sizes +
                                 "\nElementType = " + c.meta +
                                 "\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
                                 "ElementDataFile = LOCAL\n" +
                                 data);
    ExpectExact(stem + ".mha", c.t);
    WriteFile(stem + ".raw", data);
    WriteFile(stem + ".json", "{\"dims\": [" + std::to_string(kNx) + ", " + std::to_string(kNy) +
                                  ", " + std::to_string(kNz) + "], \"dtype\": \"" +
                                  std::string(DTypeName(c.t)) + "\"}");
    ExpectExact(stem + ".json", c.t);
  }
  WriteFile(dir + "/bad.nrrd",
            "NRRD0004\ntype: double\ndimension: 3\nsizes: " + sizes + "\nencoding: raw\n\n");
  auto bad = io::OpenVolume(dir + "/bad.nrrd");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("uint64"), absl::string_view::npos) << bad.status();
}

bool HavePythonZarr() {
  return std::system("/usr/bin/python3 -c 'import zarr, numcodecs' >/dev/null 2>&1") == 0;
}

TEST(LabelReaders, ZarrPythonWrittenLabelArrays) {
  if (!HavePythonZarr()) {
    GTEST_SKIP() << "/usr/bin/python3 with zarr and numcodecs not found "
                    "(apt-get install python3-zarr python3-numcodecs)";
  }
  const std::string dir = testing::MakeTempDir();
  // The same ids as IdOf, computed by numpy, in numpy's (z, y, x) order.
  WriteFile(dir + "/write.py", R"(
import sys, numpy as np, zarr, numcodecs
out = sys.argv[1]
n = np.arange(4 * 5 * 7, dtype=np.uint64).reshape(4, 5, 7)
u4 = ((1 << 24) + 1 + n * 0x10203).astype(np.uint32)
u8 = (np.uint64((1 << 53) + 1) + n * np.uint64(0x1020304050607)).astype(np.uint64)
i8 = u8.astype(np.int64); i8[n % 3 == 1] *= -1
i4 = u4.astype(np.int32); i4[n % 3 == 1] *= -1
i1 = ((n.astype(np.int64) * 37 + 11) % 256 - 128).astype(np.int8)
B = numcodecs.Blosc
for name, v, dt, comp in [('u4', u4, '<u4', B(cname='lz4', shuffle=B.SHUFFLE)),
                          ('u8', u8, '<u8', B(cname='zstd', shuffle=B.BITSHUFFLE)),
                          ('u8_be', u8, '>u8', numcodecs.GZip(5)),
                          ('i8', i8, '<i8', numcodecs.Zstd(3)),
                          ('i4', i4, '<i4', None),
                          ('i1', i1, '|i1', numcodecs.Zlib(4))]:
    z = zarr.open(out + '/' + name + '.zarr', mode='w', shape=v.shape, chunks=(3, 4, 4),
                  dtype=dt, compressor=comp, fill_value=int(v.flat[5]))
    z[:] = v
)");
  ASSERT_EQ(std::system(("/usr/bin/python3 " + dir + "/write.py " + dir).c_str()), 0);
  ExpectExact(dir + "/u4.zarr", DType::kUInt32);
  ExpectExact(dir + "/u8.zarr", DType::kUInt64);
  ExpectExact(dir + "/u8_be.zarr", DType::kUInt64);
  ExpectExact(dir + "/i8.zarr", DType::kInt64);
  ExpectExact(dir + "/i4.zarr", DType::kInt32);
  ExpectExact(dir + "/i1.zarr", DType::kInt8);
  // A uint64 fill_value past 2^53 (a missing chunk holds it exactly).
  const std::string meta = testing::FileBytes(dir + "/u8.zarr/.zarray");
  EXPECT_NE(meta.find(std::to_string(IdOf<uint64_t>(5))), std::string::npos) << meta;
  std::filesystem::remove(dir + "/u8.zarr/0.0.0");
  auto src = io::OpenVolume(dir + "/u8.zarr");
  ASSERT_TRUE(src.ok()) << src.status();
  std::vector<uint8_t> slice;
  ASSERT_TRUE((*src)->ReadSlice(&slice).ok());
  uint64_t v;
  std::memcpy(&v, slice.data(), 8);
  EXPECT_EQ(v, IdOf<uint64_t>(5));
}

// A wide-integer volume is an intensity volume too: meshed as its values converted to float.
TEST(LabelReaders, WideIntegersMeshAsTheirFloatValues) {
  const std::string dir = testing::MakeTempDir();
  constexpr int64_t n = 16;
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = n;
  auto ball = [&](DType t, double inside) -> io::SliceFn {
    return [=](int64_t z, std::vector<uint8_t>* bytes) {
      VolumeInfo g = grid;
      g.dtype = t;
      bytes->assign(g.slice_bytes(), 0);
      for (int64_t j = 0; j < n; ++j) {
        for (int64_t i = 0; i < n; ++i) {
          const double d = std::hypot(i - 7.3, j - 7.6, z - 7.1);
          testing::StoreValue(t, d < 5.2 ? inside : 0.0,
                              bytes->data() + static_cast<size_t>(j * n + i) * DTypeSize(t));
        }
      }
      return absl::OkStatus();
    };
  };
  SessionOptions opt;
  opt.iso = 500;
  opt.error = 0.1;
  std::vector<IndexedMesh> meshes;
  for (DType t : {DType::kFloat32, DType::kInt8, DType::kUInt32, DType::kInt32, DType::kUInt64,
                  DType::kInt64}) {
    SCOPED_TRACE(DTypeName(t));
    VolumeInfo g = grid;
    g.dtype = t;
    const std::string path = dir + "/" + std::string(DTypeName(t)) + ".json";
    // int8 holds 100 at most: its own iso, the same surface (the midpoints at half the step).
    ASSERT_TRUE(io::WriteVolume(path, g, ball(t, t == DType::kInt8 ? 100 : 1000)).ok());
    auto src = io::OpenVolume(path);
    ASSERT_TRUE(src.ok()) << src.status();
    SessionOptions o = opt;
    if (t == DType::kInt8) o.iso = 50;
    auto session = io::RunSession(**src, o);
    ASSERT_TRUE(session.ok()) << session.status();
    meshes.push_back((*session)->Snapshot());
    EXPECT_GT(meshes.back().num_triangles(), 100u);
    EXPECT_EQ(meshes.back().indices, meshes[0].indices);
    EXPECT_EQ(meshes.back().positions, meshes[0].positions);
  }
}

// ---- Label ids from voxels ----

TEST(ToLabelIdsTest, EveryIntegerTypeExactlyNegativesAndFloatsRefused) {
  const uint64_t big = (uint64_t{1} << 53) + 1;  // no double holds it
  uint8_t bytes[24];
  std::memcpy(bytes, &big, 8);
  const uint64_t top = ~uint64_t{0};
  std::memcpy(bytes + 8, &top, 8);
  uint64_t out[3] = {};
  ASSERT_TRUE(ToLabelIds(DType::kUInt64, bytes, 2, out).ok());
  EXPECT_EQ(out[0], big);
  EXPECT_EQ(out[1], top);
  const uint32_t u32[2] = {(1u << 24) + 1, 0xffffffffu};
  ASSERT_TRUE(ToLabelIds(DType::kUInt32, reinterpret_cast<const uint8_t*>(u32), 2, out).ok());
  EXPECT_EQ(out[0], (1u << 24) + 1);
  EXPECT_EQ(out[1], 0xffffffffu);
  const int32_t i32[3] = {7, 0x7fffffff, -3};
  absl::Status st = ToLabelIds(DType::kInt32, reinterpret_cast<const uint8_t*>(i32), 3, out);
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(st.message().find("voxel 2 holds -3"), absl::string_view::npos) << st;
  ASSERT_TRUE(ToLabelIds(DType::kInt32, reinterpret_cast<const uint8_t*>(i32), 2, out).ok());
  EXPECT_EQ(out[1], 0x7fffffffu);
  const int8_t i8[2] = {5, -128};
  st = ToLabelIds(DType::kInt8, reinterpret_cast<const uint8_t*>(i8), 2, out);
  EXPECT_NE(st.message().find("voxel 1 holds -128"), absl::string_view::npos) << st;
  const int64_t i64[1] = {int64_t{1} << 62};
  ASSERT_TRUE(ToLabelIds(DType::kInt64, reinterpret_cast<const uint8_t*>(i64), 1, out).ok());
  EXPECT_EQ(out[0], uint64_t{1} << 62);
  const float f[1] = {1.0f};
  st = ToLabelIds(DType::kFloat32, reinterpret_cast<const uint8_t*>(f), 1, out);
  EXPECT_NE(st.message().find("label ids must be integers; the voxels are float32"),
            absl::string_view::npos)
      << st;
  // Unaligned input.
  uint8_t shifted[17];
  std::memcpy(shifted + 1, &big, 8);
  ASSERT_TRUE(ToLabelIds(DType::kUInt64, shifted + 1, 1, out).ok());
  EXPECT_EQ(out[0], big);
}

// A label session takes every integer type as it is: uint64 ids past 2^53 come out of
// SplitByLabel exactly, and a negative int32 id is refused naming its voxel.
TEST(LabelSessionTypes, WideIdsExactlyAndNegativesRefused) {
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 6;
  SessionOptions opt;
  opt.labels.enabled = true;
  opt.error = 0.2;
  const uint64_t big = (uint64_t{1} << 60) + 12345;
  for (DType t : {DType::kUInt64, DType::kInt32}) {
    SCOPED_TRACE(DTypeName(t));
    grid.dtype = t;
    auto session = TandemSession::Create(grid, opt);
    ASSERT_TRUE(session.ok()) << session.status();
    absl::Status st;
    for (int64_t k = 0; k < 6 && st.ok(); ++k) {
      std::vector<uint8_t> slice(36 * DTypeSize(t), 0);
      for (int64_t j = 2; j < 4; ++j) {
        for (int64_t i = 2; i < 4; ++i) {
          if (k < 2 || k > 3) continue;
          if (t == DType::kUInt64) {
            std::memcpy(slice.data() + (j * 6 + i) * 8, &big, 8);
          } else {
            const int32_t v = i == 3 && j == 3 && k == 3 ? -4 : 9;
            std::memcpy(slice.data() + (j * 6 + i) * 4, &v, 4);
          }
        }
      }
      st = (*session)->AddSliceBytes(t, slice.data());
    }
    if (t == DType::kInt32) {
      EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument);
      EXPECT_NE(st.message().find("voxel (3, 3, 3) of the label volume is -4"),
                absl::string_view::npos)
          << st;
      continue;
    }
    ASSERT_TRUE(st.ok()) << st;
    ASSERT_TRUE((*session)->Finish().ok());
    const auto surfaces = SplitByLabel((*session)->SnapshotLabeled());
    ASSERT_EQ(surfaces.size(), 1u);
    EXPECT_EQ(surfaces[0].first, big);
    EXPECT_GT(surfaces[0].second.num_triangles(), 0u);
  }
}

TEST(DTypes, NamesSizesAndRanges) {
  for (DType t : kAllDTypes) {
    auto parsed = ParseDType(DTypeName(t));
    ASSERT_TRUE(parsed.ok());
    EXPECT_EQ(*parsed, t);
  }
  EXPECT_EQ(DTypeSize(DType::kInt8), 1u);
  EXPECT_EQ(DTypeSize(DType::kUInt32), 4u);
  EXPECT_EQ(DTypeSize(DType::kInt64), 8u);
  EXPECT_EQ(DTypeNames(), "uint8, int8, uint16, int16, uint32, int32, uint64, int64, float32");
  EXPECT_NE(ParseDType("float64").status().message().find("uint64"), absl::string_view::npos);
  // The float conversion and the range of the wide types (for the iso-surface path).
  const int64_t v[3] = {-5, int64_t{1} << 40, 7};
  const ValueRange r = RangeOf(DType::kInt64, reinterpret_cast<const uint8_t*>(v), 3);
  EXPECT_EQ(r.lo, -5.0f);
  EXPECT_EQ(r.hi, static_cast<float>(int64_t{1} << 40));
  std::vector<uint32_t> many(1000, 3);
  many[777] = 4000000000u;
  const ValueRange u = RangeOf(DType::kUInt32, reinterpret_cast<const uint8_t*>(many.data()), 1000);
  EXPECT_EQ(u.lo, 3.0f);
  EXPECT_EQ(u.hi, 4e9f);
  const int8_t s8[20] = {0, 1, -100, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 120};
  const ValueRange e = RangeOf(DType::kInt8, reinterpret_cast<const uint8_t*>(s8), 20);
  EXPECT_EQ(e.lo, -100.0f);
  EXPECT_EQ(e.hi, 120.0f);
  float f[3];
  ConvertToFloat(DType::kInt64, reinterpret_cast<const uint8_t*>(v), 3, f);
  EXPECT_EQ(f[0], -5.0f);
  EXPECT_EQ(f[2], 7.0f);
}

}  // namespace
}  // namespace tandem
