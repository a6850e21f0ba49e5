// Volume readers and writers: round trips through every format and dtype, byte order,
// geometry, error reporting on damaged files, and the shared real volumes.
#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "absl/strings/match.h"
#include "nlohmann/json.hpp"
#include "tandem/io/open_volume.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------
// Helpers.

VolumeInfo MakeInfo(DType t, int64_t nx = 37, int64_t ny = 21, int64_t nz = 5) {
  VolumeInfo info;
  info.nx = nx;
  info.ny = ny;
  info.nz = nz;
  info.dtype = t;
  info.spacing = {0.5, 1.25, 2.0};  // anisotropic
  info.origin = {-10.5, 3.25, 100.0};
  info.suggested_isovalues = {12.5, 100};
  info.description = "test volume";
  return info;
}

using testing::PatternValue;
using testing::StoreValue;

std::vector<uint8_t> PatternSlice(const VolumeInfo& info, int64_t k) {
  const size_t px = DTypeSize(info.dtype);
  std::vector<uint8_t> s(info.slice_bytes());
  for (int64_t j = 0; j < info.ny; ++j) {
    for (int64_t i = 0; i < info.nx; ++i) {
      StoreValue(info.dtype, PatternValue(info.dtype, i, j, k), &s[(j * info.nx + i) * px]);
    }
  }
  return s;
}

io::SliceFn PatternFn(const VolumeInfo& info) {
  return [info](int64_t z, std::vector<uint8_t>* bytes) {
    *bytes = PatternSlice(info, z);
    return absl::OkStatus();
  };
}

std::vector<uint8_t> PatternVolume(const VolumeInfo& info) {
  std::vector<uint8_t> all;
  for (int64_t k = 0; k < info.nz; ++k) {
    std::vector<uint8_t> s = PatternSlice(info, k);
    all.insert(all.end(), s.begin(), s.end());
  }
  return all;
}

// Opens and reads every slice; also checks that the source then reports OutOfRange.
absl::StatusOr<std::vector<uint8_t>> ReadAll(const std::string& path, VolumeInfo* info = nullptr) {
  absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(path);
  if (!src.ok()) return src.status();
  if (info != nullptr) *info = (*src)->info();
  std::vector<uint8_t> all, slice;
  for (int64_t k = 0; k < (*src)->info().nz; ++k) {
    EXPECT_EQ((*src)->next_slice(), k);
    absl::Status st = (*src)->ReadSlice(&slice);
    if (!st.ok()) return st;
    EXPECT_EQ(slice.size(), (*src)->info().slice_bytes());
    all.insert(all.end(), slice.begin(), slice.end());
  }
  absl::Status end = (*src)->ReadSlice(&slice);
  EXPECT_TRUE(absl::IsOutOfRange(end)) << end;
  return all;
}

// Expects opening or reading path to fail with a message that names the file and contains
// every one of `needles`.
void ExpectFails(const std::string& path, const std::vector<std::string>& needles) {
  absl::StatusOr<std::vector<uint8_t>> r = ReadAll(path);
  ASSERT_FALSE(r.ok()) << path << " unexpectedly read fine";
  const std::string msg(r.status().message());
  EXPECT_NE(msg.find(path), std::string::npos) << "message does not name the file: " << msg;
  for (const std::string& n : needles) {
    EXPECT_NE(msg.find(n), std::string::npos) << "message lacks \"" << n << "\": " << msg;
  }
}

std::vector<uint8_t> ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

void WriteBytes(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
}

std::string ReadText(const std::string& path) {
  std::vector<uint8_t> b = ReadBytes(path);
  return std::string(b.begin(), b.end());
}

void WriteText(const std::string& path, const std::string& text) {
  WriteBytes(path, std::vector<uint8_t>(text.begin(), text.end()));
}

// Replaces the first occurrence of `from` in the file (which must contain it).
void ReplaceInFile(const std::string& path, const std::string& from, const std::string& to) {
  std::string text = ReadText(path);
  const size_t pos = text.find(from);
  ASSERT_NE(pos, std::string::npos) << from << " not in " << path;
  text.replace(pos, from.size(), to);
  WriteText(path, text);
}

void Truncate(const std::string& path, uintmax_t remove) {
  fs::resize_file(path, fs::file_size(path) - remove);
}

void ExpectGeometryNear(const VolumeInfo& got, const VolumeInfo& want) {
  EXPECT_EQ(got.nx, want.nx);
  EXPECT_EQ(got.ny, want.ny);
  EXPECT_EQ(got.nz, want.nz);
  for (int a = 0; a < 3; ++a) {
    // NIfTI stores float32 and TIFF resolutions are float rationals.
    EXPECT_NEAR(got.spacing[a], want.spacing[a], 1e-6 * std::max(1.0, std::abs(want.spacing[a])))
        << "axis " << a;
    EXPECT_NEAR(got.origin[a], want.origin[a], 1e-6 * std::max(1.0, std::abs(want.origin[a])))
        << "axis " << a;
  }
}

template <typename T>
T Load(const uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}
template <typename T>
void Store(uint8_t* p, T v) {
  std::memcpy(p, &v, sizeof(T));
}

// A hand-made little-endian classic TIFF: one uncompressed strip per page, all directories
// first and all pixel data at the end (so a truncated tail cuts data, not directories).
struct HandPage {
  uint32_t width, height;
  uint16_t bits, sample_format, samples;
};
void WriteHandTiff(const std::string& path, const std::vector<HandPage>& pages,
                   const std::string& description = "") {
  auto data_bytes = [](const HandPage& p) {
    return size_t{p.width} * p.height * p.samples * p.bits / 8;
  };
  constexpr size_t kEntries = 12;
  const size_t ifd_size = 2 + 12 * kEntries + 4;
  const size_t desc_off = 8;
  const size_t desc_len = description.size() + 1;
  const size_t ifd0 = desc_off + desc_len + (desc_len & 1);
  size_t data_off = ifd0 + pages.size() * ifd_size;
  std::vector<uint8_t> file(data_off, 0);
  file[0] = 'I';
  file[1] = 'I';
  Store<uint16_t>(&file[2], 42);
  Store<uint32_t>(&file[4], static_cast<uint32_t>(ifd0));
  std::memcpy(&file[desc_off], description.c_str(), desc_len);
  for (size_t k = 0; k < pages.size(); ++k) {
    const HandPage& p = pages[k];
    uint8_t* ifd = &file[ifd0 + k * ifd_size];
    Store<uint16_t>(ifd, kEntries);
    size_t e = 0;
    auto entry = [&](uint16_t tag, uint16_t type, uint32_t count, uint32_t value) {
      uint8_t* q = ifd + 2 + 12 * e++;
      Store<uint16_t>(q, tag);
      Store<uint16_t>(q + 2, type);
      Store<uint32_t>(q + 4, count);
      if (type == 3 && count <= 2) {  // SHORTs are left-justified in the value field
        Store<uint16_t>(q + 8, static_cast<uint16_t>(value));
        if (count == 2) Store<uint16_t>(q + 10, static_cast<uint16_t>(value));
      } else {
        Store<uint32_t>(q + 8, value);
      }
    };
    const uint32_t n = static_cast<uint32_t>(data_bytes(p));
    entry(256, 4, 1, p.width);
    entry(257, 4, 1, p.height);
    entry(258, 3, p.samples, p.bits);
    entry(259, 3, 1, 1);  // no compression
    entry(262, 3, 1, 1);  // min-is-black
    if (description.empty()) {
      entry(266, 3, 1, 1);  // FillOrder (harmless filler keeps the entry count fixed)
    } else {
      entry(270, 2, static_cast<uint32_t>(desc_len), static_cast<uint32_t>(desc_off));
    }
    entry(273, 4, 1, static_cast<uint32_t>(data_off));
    entry(277, 3, 1, p.samples);
    entry(278, 4, 1, p.height);
    entry(279, 4, 1, n);
    entry(284, 3, 1, 1);  // planar contiguous
    entry(339, 3, p.samples, p.sample_format);
    Store<uint32_t>(ifd + 2 + 12 * kEntries,
                    k + 1 < pages.size() ? static_cast<uint32_t>(ifd0 + (k + 1) * ifd_size) : 0);
    data_off += n;
  }
  for (const HandPage& p : pages) {
    for (size_t b = 0; b < data_bytes(p); ++b) file.push_back(static_cast<uint8_t>(b * 31));
  }
  WriteBytes(path, file);
}

// ---------------------------------------------------------------------------------------
// Basics.

TEST(DTypeTest, NamesSizesAndParsing) {
  for (DType t : {DType::kUInt8, DType::kUInt16, DType::kInt16, DType::kFloat32, DType::kInt8,
                  DType::kUInt32, DType::kInt32, DType::kUInt64, DType::kInt64}) {
    absl::StatusOr<DType> parsed = ParseDType(DTypeName(t));
    ASSERT_TRUE(parsed.ok()) << DTypeName(t);
    EXPECT_EQ(*parsed, t);
  }
  EXPECT_EQ(DTypeSize(DType::kUInt8), 1u);
  EXPECT_EQ(DTypeSize(DType::kUInt16), 2u);
  EXPECT_EQ(DTypeSize(DType::kInt16), 2u);
  EXPECT_EQ(DTypeSize(DType::kFloat32), 4u);
  EXPECT_EQ(DTypeSize(DType::kInt8), 1u);
  EXPECT_EQ(DTypeSize(DType::kUInt32), 4u);
  EXPECT_EQ(DTypeSize(DType::kInt32), 4u);
  EXPECT_EQ(DTypeSize(DType::kUInt64), 8u);
  EXPECT_EQ(DTypeSize(DType::kInt64), 8u);
  absl::StatusOr<DType> bad = ParseDType("float64");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("float64"), absl::string_view::npos);
}

TEST(DTypeTest, ConvertToFloatIsExactForIntegers) {
  const uint8_t u8[3] = {0, 128, 255};
  const uint16_t u16[3] = {0, 40000, 65535};
  const int16_t i16[3] = {-32768, -1, 32767};
  const float f32[3] = {-1.5f, 0.0f, 1e30f};
  float out[3];
  ConvertToFloat(DType::kUInt8, u8, 3, out);
  EXPECT_EQ(out[1], 128.0f);
  EXPECT_EQ(out[2], 255.0f);
  ConvertToFloat(DType::kUInt16, reinterpret_cast<const uint8_t*>(u16), 3, out);
  EXPECT_EQ(out[1], 40000.0f);
  EXPECT_EQ(out[2], 65535.0f);
  ConvertToFloat(DType::kInt16, reinterpret_cast<const uint8_t*>(i16), 3, out);
  EXPECT_EQ(out[0], -32768.0f);
  EXPECT_EQ(out[1], -1.0f);
  ConvertToFloat(DType::kFloat32, reinterpret_cast<const uint8_t*>(f32), 3, out);
  EXPECT_EQ(out[0], -1.5f);
  EXPECT_EQ(out[2], 1e30f);
  // Unaligned source.
  uint8_t unaligned[5] = {0, 0x34, 0x12, 0xff, 0xff};
  ConvertToFloat(DType::kUInt16, unaligned + 1, 2, out);
  EXPECT_EQ(out[0], 4660.0f);
  EXPECT_EQ(out[1], 65535.0f);
}

TEST(DTypeTest, RangeOfEqualsTheConvertedValuesExtremes) {
  // The definition: convert, then the extremes of the values that are not NaN.
  auto expected = [](DType t, const uint8_t* src, size_t n) {
    std::vector<float> f(n);
    ConvertToFloat(t, src, n, f.data());
    ValueRange r;
    for (float v : f) {
      if (v != v) continue;
      if (r.lo > r.hi) {
        r.lo = r.hi = v;
      } else {
        r.lo = std::min(r.lo, v);
        r.hi = std::max(r.hi, v);
      }
    }
    return r;
  };
  std::mt19937 rng(7);
  for (DType t : {DType::kUInt8, DType::kUInt16, DType::kInt16, DType::kFloat32}) {
    for (size_t n : {size_t{0}, size_t{1}, size_t{15}, size_t{17}, size_t{100}, size_t{300}}) {
      std::vector<uint8_t> raw(n * DTypeSize(t));
      for (uint8_t& b : raw) b = static_cast<uint8_t>(rng());
      if (t == DType::kFloat32) {  // random bits hold NaNs and infinities: keep some of each
        for (size_t i = 0; i < n; ++i) {
          float v = std::uniform_real_distribution<float>(-1e6f, 1e6f)(rng);
          if (i % 7 == 3) v = std::numeric_limits<float>::quiet_NaN();
          std::memcpy(raw.data() + i * 4, &v, 4);
        }
      }
      for (size_t offset : {size_t{0}, size_t{1}}) {  // aligned and not
        std::vector<uint8_t> buf(raw.size() + 1);
        std::copy(raw.begin(), raw.end(), buf.begin() + static_cast<ptrdiff_t>(offset));
        const ValueRange want = expected(t, buf.data() + offset, n);
        const ValueRange got = RangeOf(t, buf.data() + offset, n);
        EXPECT_EQ(got.lo, want.lo) << DTypeName(t) << " n=" << n << " offset=" << offset;
        EXPECT_EQ(got.hi, want.hi) << DTypeName(t) << " n=" << n << " offset=" << offset;
      }
    }
  }
  const float inf = std::numeric_limits<float>::infinity(), nan = std::nanf("");
  const float mixed[20] = {nan, 2.0f, -inf, nan, 5.0f, nan, nan, nan, nan, nan,
                           nan, nan, nan, nan, nan, nan, nan, 1.0f, nan, nan};
  ValueRange r = RangeOf(DType::kFloat32, reinterpret_cast<const uint8_t*>(mixed), 20);
  EXPECT_EQ(r.lo, -inf);  // infinities count
  EXPECT_EQ(r.hi, 5.0f);
  const float nans[18] = {nan, nan, nan, nan, nan, nan, nan, nan, nan,
                          nan, nan, nan, nan, nan, nan, nan, nan, nan};
  r = RangeOf(DType::kFloat32, reinterpret_cast<const uint8_t*>(nans), 18);
  EXPECT_GT(r.lo, r.hi);  // none
  const float ups[3] = {inf, nan, inf};
  r = RangeOf(DType::kFloat32, reinterpret_cast<const uint8_t*>(ups), 3);
  EXPECT_EQ(r.lo, inf);
  EXPECT_EQ(r.hi, inf);
  const int16_t ends[17] = {-32768, 32767, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, -32768};
  r = RangeOf(DType::kInt16, reinterpret_cast<const uint8_t*>(ends), 17);
  EXPECT_EQ(r.lo, -32768.0f);
  EXPECT_EQ(r.hi, 32767.0f);
}

TEST(ValidateVolumeInfoTest, RejectsBadGeometry) {
  VolumeInfo ok = MakeInfo(DType::kUInt8);
  EXPECT_TRUE(ValidateVolumeInfo(ok).ok());
  VolumeInfo unknown_nz = ok;
  unknown_nz.nz = 0;
  EXPECT_TRUE(ValidateVolumeInfo(unknown_nz).ok());
  VolumeInfo v = ok;
  v.nx = 1;
  EXPECT_FALSE(ValidateVolumeInfo(v).ok());
  v = ok;
  v.nz = 1;
  EXPECT_FALSE(ValidateVolumeInfo(v).ok());
  v = ok;
  v.spacing[1] = 0;
  EXPECT_FALSE(ValidateVolumeInfo(v).ok());
  v = ok;
  v.spacing[2] = std::nan("");
  EXPECT_FALSE(ValidateVolumeInfo(v).ok());
  v = ok;
  v.origin[0] = INFINITY;
  EXPECT_FALSE(ValidateVolumeInfo(v).ok());
}

TEST(OpenVolumeTest, UnknownExtensionListsSupportedFormats) {
  const std::string path = tandem::testing::MakeTempDir() + "/volume.vtk";
  WriteText(path, "x");
  absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(path);
  ASSERT_FALSE(src.ok());
  EXPECT_EQ(src.status().code(), absl::StatusCode::kInvalidArgument);
  const std::string msg(src.status().message());
  EXPECT_NE(msg.find(path), std::string::npos) << msg;
  for (const char* ext : {".json", ".nrrd", ".nhdr", ".nii", ".nii.gz", ".tif", ".tiff"}) {
    EXPECT_NE(msg.find(ext), std::string::npos) << msg;
  }
}

TEST(OpenVolumeTest, MissingFileIsNotFound) {
  const std::string dir = tandem::testing::MakeTempDir();
  for (const char* name : {"a.json", "a.nrrd", "a.nii", "a.nii.gz", "a.tif"}) {
    const std::string path = dir + "/" + name;
    absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(path);
    ASSERT_FALSE(src.ok()) << name;
    EXPECT_EQ(src.status().code(), absl::StatusCode::kNotFound) << src.status();
    EXPECT_NE(src.status().message().find(path), absl::string_view::npos) << src.status();
  }
}

TEST(OpenVolumeTest, AnalyzePairsAreRejectedClearly) {
  const std::string path = tandem::testing::MakeTempDir() + "/brain.hdr";
  WriteText(path, std::string(348, '\0'));
  absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(path);
  ASSERT_FALSE(src.ok());
  EXPECT_NE(src.status().message().find(".hdr + .img"), absl::string_view::npos) << src.status();
}

// ---------------------------------------------------------------------------------------
// Round trips: every writer x every dtype, read back through OpenVolume.

struct Format {
  const char* name;
  const char* file;
  io::VolumeWriteOptions opts;
  bool keeps_isovalues;  // formats with a place for suggested_isovalues
};

io::VolumeWriteOptions Opts(bool gzip, bool big_endian, int tile = 0) {
  io::VolumeWriteOptions o;
  o.gzip = gzip;
  o.big_endian = big_endian;
  o.tiff_tile_size = tile;
  return o;
}

const Format kFormats[] = {
    {"json", "v.json", Opts(false, false), true},
    {"json_big", "v.json", Opts(false, true), true},
    {"nrrd_raw", "v.nrrd", Opts(false, false), true},
    {"nrrd_gzip", "v.nrrd", Opts(true, false), true},
    {"nrrd_big", "v.nrrd", Opts(false, true), true},
    {"nrrd_gzip_big", "v.nrrd", Opts(true, true), true},
    {"nhdr_raw", "v.nhdr", Opts(false, false), true},
    {"nhdr_gzip", "v.nhdr", Opts(true, false), true},
    {"nii", "v.nii", Opts(false, false), false},
    {"nii_gz", "v.nii.gz", Opts(false, false), false},
    {"nii_big", "v.nii", Opts(false, true), false},
    {"tif_strips", "v.tif", Opts(false, false), false},
    {"tiff_tiles", "v.tiff", Opts(false, false, 16), false},
    {"tif_deflate", "v.tif", Opts(true, false), false},
    {"tif_big", "v.tif", Opts(false, true), false},
};

class RoundTripTest : public ::testing::TestWithParam<std::tuple<int, DType>> {};

TEST_P(RoundTripTest, SameInfoAndVoxels) {
  const Format& f = kFormats[std::get<0>(GetParam())];
  const VolumeInfo info = MakeInfo(std::get<1>(GetParam()));
  const std::string path = tandem::testing::MakeTempDir() + "/" + f.file;
  ASSERT_TRUE(io::WriteVolume(path, info, PatternFn(info), f.opts).ok());

  VolumeInfo got;
  absl::StatusOr<std::vector<uint8_t>> voxels = ReadAll(path, &got);
  ASSERT_TRUE(voxels.ok()) << voxels.status();
  EXPECT_EQ(got.dtype, info.dtype);
  ExpectGeometryNear(got, info);
  EXPECT_TRUE(*voxels == PatternVolume(info)) << "voxels differ";
  if (f.keeps_isovalues) {
    EXPECT_EQ(got.suggested_isovalues, info.suggested_isovalues);
    EXPECT_EQ(got.description, info.description);
  }
}

// The zero-copy path (SliceSource::ViewSlice): plain files in host byte order are mapped and
// give the same voxels in place; compressed or byte-swapped data is not offered (nullptr,
// nothing consumed) and ReadSlice carries on from the first slice. Alternating ViewSlice and
// ReadSlice keeps one position.
TEST_P(RoundTripTest, ViewSliceGivesTheSameVoxelsWhereOffered) {
  const Format& f = kFormats[std::get<0>(GetParam())];
  const VolumeInfo info = MakeInfo(std::get<1>(GetParam()));
  const std::string path = tandem::testing::MakeTempDir() + "/" + f.file;
  ASSERT_TRUE(io::WriteVolume(path, info, PatternFn(info), f.opts).ok());
  const bool tiff = absl::EndsWith(f.file, ".tif") || absl::EndsWith(f.file, ".tiff");
  const bool swapped = f.opts.big_endian && DTypeSize(info.dtype) > 1;
  const bool gzip = f.opts.gzip || absl::EndsWith(f.file, ".gz");
  const bool offered = !tiff && !gzip && !swapped;

  absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(path);
  ASSERT_TRUE(src.ok()) << src.status();
  const std::vector<uint8_t> want = PatternVolume(info);
  const size_t sb = info.slice_bytes();
  std::vector<uint8_t> slice;
  for (int64_t k = 0; k < info.nz; ++k) {
    const uint8_t* view = reinterpret_cast<const uint8_t*>(&slice);  // must be overwritten
    if (k % 3 != 2) {
      ASSERT_TRUE((*src)->ViewSlice(&view).ok());
      if (!offered) {
        EXPECT_EQ(view, nullptr) << "slice " << k;
        EXPECT_EQ((*src)->next_slice(), k) << "nothing may be consumed";
      } else {
        ASSERT_NE(view, nullptr) << "slice " << k;
        EXPECT_EQ(std::memcmp(view, want.data() + k * sb, sb), 0) << "slice " << k;
        EXPECT_EQ((*src)->next_slice(), k + 1);
        continue;
      }
    }
    ASSERT_TRUE((*src)->ReadSlice(&slice).ok()) << "slice " << k;
    EXPECT_TRUE(std::equal(slice.begin(), slice.end(), want.begin() + k * sb)) << "slice " << k;
  }
  const uint8_t* view = nullptr;
  const absl::Status end = (*src)->ViewSlice(&view);
  if (offered) {
    EXPECT_TRUE(absl::IsOutOfRange(end)) << end;
  }
  EXPECT_TRUE(absl::IsOutOfRange((*src)->ReadSlice(&slice)));
}

// A mapped file that shrinks while it is read must give an error, not SIGBUS.
TEST(ViewSliceTest, FileTruncatedWhileMappedIsAnError) {
  const std::string dir = tandem::testing::MakeTempDir();
  const VolumeInfo info = MakeInfo(DType::kFloat32, 40, 30, 8);
  const std::string path = dir + "/v.json";
  ASSERT_TRUE(io::WriteVolume(path, info, PatternFn(info)).ok());
  absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(path);
  ASSERT_TRUE(src.ok()) << src.status();
  const uint8_t* view = nullptr;
  ASSERT_TRUE((*src)->ViewSlice(&view).ok());
  ASSERT_NE(view, nullptr);
  std::filesystem::resize_file(dir + "/v.raw", 3 * info.slice_bytes() + 10);
  ASSERT_TRUE((*src)->ViewSlice(&view).ok());  // slices 1 and 2 are still whole
  ASSERT_TRUE((*src)->ViewSlice(&view).ok());
  absl::Status st = (*src)->ViewSlice(&view);
  EXPECT_TRUE(absl::IsDataLoss(st)) << st;
  EXPECT_NE(st.message().find("truncated"), absl::string_view::npos) << st;
  EXPECT_NE(st.message().find(path), absl::string_view::npos) << st;
  std::vector<uint8_t> slice;
  EXPECT_TRUE(absl::IsDataLoss((*src)->ReadSlice(&slice)));  // and it stays failed
}

std::string RoundTripName(const ::testing::TestParamInfo<std::tuple<int, DType>>& p) {
  return std::string(kFormats[std::get<0>(p.param)].name) + "_" +
         std::string(DTypeName(std::get<1>(p.param)));
}

INSTANTIATE_TEST_SUITE_P(AllFormats, RoundTripTest,
                         ::testing::Combine(::testing::Range(0,
                                                             static_cast<int>(std::size(kFormats))),
                                            ::testing::Values(DType::kUInt8, DType::kUInt16,
                                                              DType::kInt16, DType::kFloat32)),
                         RoundTripName);

TEST(WriteVolumeTest, JsonSidecarHasTheSharedKeysAndAChecksum) {
  const VolumeInfo info = MakeInfo(DType::kInt16);
  const std::string dir = tandem::testing::MakeTempDir();
  ASSERT_TRUE(io::WriteVolume(dir + "/head.json", info, PatternFn(info)).ok());
  ASSERT_TRUE(fs::exists(dir + "/head.raw"));
  const nlohmann::json j = nlohmann::json::parse(ReadText(dir + "/head.json"));
  for (const char* key : {"dims", "dtype", "spacing", "origin", "byte_order", "layout", "source",
                          "license", "suggested_isovalues", "description", "modality",
                          "value_range", "raw_file", "raw_bytes", "sha256"}) {
    EXPECT_TRUE(j.contains(key)) << key;
  }
  EXPECT_EQ(j["raw_file"], "head.raw");
  EXPECT_EQ(j["raw_bytes"].get<uint64_t>(), fs::file_size(dir + "/head.raw"));
  EXPECT_EQ(j["value_range"][0].get<int>(), static_cast<int>(PatternValue(DType::kInt16, 0, 0, 0)));
  EXPECT_EQ(j["value_range"][1].get<int>(),
            static_cast<int>(PatternValue(DType::kInt16, 36, 20, 4)));
  EXPECT_EQ(j["sha256"].get<std::string>().size(), 64u);
}

TEST(WriteVolumeTest, Sha256MatchesAKnownDigest) {
  // 2x2x2 uint8 voxels "abcdefgh": sha256("abcdefgh") is a published test value.
  VolumeInfo info = MakeInfo(DType::kUInt8, 2, 2, 2);
  const std::string dir = tandem::testing::MakeTempDir();
  ASSERT_TRUE(io::WriteVolume(dir + "/t.json", info, [](int64_t z, std::vector<uint8_t>* b) {
                const char* s = z == 0 ? "abcd" : "efgh";
                b->assign(s, s + 4);
                return absl::OkStatus();
              }).ok());
  const nlohmann::json j = nlohmann::json::parse(ReadText(dir + "/t.json"));
  EXPECT_EQ(j["sha256"], "9c56cc51b374c3ba189210d5b6d4bf57790d351c96c47c02190ecf1e430635ab");
}

TEST(WriteVolumeTest, BigEndianReallyStoresBigEndian) {
  VolumeInfo info = MakeInfo(DType::kUInt16, 2, 2, 2);
  const std::string dir = tandem::testing::MakeTempDir();
  auto fn = [](int64_t, std::vector<uint8_t>* b) {
    const uint16_t v[4] = {0x0102, 0x0304, 0x0506, 0x0708};
    b->resize(8);
    std::memcpy(b->data(), v, 8);
    return absl::OkStatus();
  };
  ASSERT_TRUE(io::WriteVolume(dir + "/b.json", info, fn, Opts(false, true)).ok());
  const std::vector<uint8_t> raw = ReadBytes(dir + "/b.raw");
  ASSERT_EQ(raw.size(), 16u);
  EXPECT_EQ(raw[0], 0x01);
  EXPECT_EQ(raw[1], 0x02);
  ASSERT_TRUE(io::WriteVolume(dir + "/b.nii", info, fn, Opts(false, true)).ok());
  const std::vector<uint8_t> nii = ReadBytes(dir + "/b.nii");
  EXPECT_EQ(nii[3], 0x5c);  // sizeof_hdr 348 = 0x15c, big-endian
  EXPECT_EQ(nii[352], 0x01);
}

TEST(WriteVolumeTest, RejectsBadInputs) {
  const std::string dir = tandem::testing::MakeTempDir();
  VolumeInfo info = MakeInfo(DType::kUInt8);
  absl::Status st = io::WriteVolume(dir + "/v.obj", info, PatternFn(info));
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message().find(".nrrd"), absl::string_view::npos) << st;
  // A slice of the wrong size.
  st = io::WriteVolume(dir + "/v.nrrd", info, [](int64_t, std::vector<uint8_t>* b) {
    b->assign(3, 0);
    return absl::OkStatus();
  });
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message().find("expected"), absl::string_view::npos) << st;
  // slice_fn errors are passed on.
  st = io::WriteVolume(dir + "/v.nii", info, [](int64_t, std::vector<uint8_t>*) {
    return absl::UnavailableError("source gone");
  });
  EXPECT_EQ(st.code(), absl::StatusCode::kUnavailable);
  // Unknown nz, bad spacing.
  VolumeInfo bad = info;
  bad.nz = 0;
  EXPECT_FALSE(io::WriteVolume(dir + "/v.tif", bad, PatternFn(info)).ok());
  bad = info;
  bad.spacing[0] = -1;
  EXPECT_FALSE(io::WriteVolume(dir + "/v.json", bad, PatternFn(info)).ok());
}

// ---------------------------------------------------------------------------------------
// Raw + JSON sidecar errors.

class RawJsonTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = tandem::testing::MakeTempDir();
    json_ = dir_ + "/vol.json";
    raw_ = dir_ + "/vol.raw";
    info_ = MakeInfo(DType::kUInt16);
    ASSERT_TRUE(io::WriteVolume(json_, info_, PatternFn(info_)).ok());
  }
  void EditSidecar(const std::function<void(nlohmann::json&)>& edit) {
    nlohmann::json j = nlohmann::json::parse(ReadText(json_));
    edit(j);
    WriteText(json_, j.dump(1));
  }
  std::string dir_, json_, raw_;
  VolumeInfo info_;
};

TEST_F(RawJsonTest, TruncatedRawFile) {
  Truncate(raw_, 1000);
  ExpectFails(json_, {"truncated", "expected 7770 bytes of voxel data", "file has 6770"});
}

TEST_F(RawJsonTest, UnsupportedDtype) {
  EditSidecar([](nlohmann::json& j) { j["dtype"] = "float64"; });
  ExpectFails(json_, {"unsupported dtype 'float64'"});
}

TEST_F(RawJsonTest, DimsLargerThanData) {
  EditSidecar([](nlohmann::json& j) {
    j["dims"][2] = 6;
    j.erase("raw_bytes");
  });
  ExpectFails(json_, {"truncated"});
}

TEST_F(RawJsonTest, DimsSmallerThanData) {
  EditSidecar([](nlohmann::json& j) {
    j["dims"][2] = 4;
    j.erase("raw_bytes");
  });
  ExpectFails(json_, {"size mismatch"});
}

TEST_F(RawJsonTest, RawBytesDisagreesWithDims) {
  EditSidecar([](nlohmann::json& j) { j["raw_bytes"] = 1234; });
  ExpectFails(json_, {"raw_bytes", "1234"});
}

TEST_F(RawJsonTest, EmptyFiles) {
  WriteText(raw_, "");
  ExpectFails(json_, {"truncated", "file has 0"});
  WriteText(json_, "");
  ExpectFails(json_, {"empty file"});
}

TEST_F(RawJsonTest, MalformedSidecars) {
  WriteText(json_, "{\"dims\": [1, 2");
  ExpectFails(json_, {"invalid JSON"});
  WriteText(json_, "[1, 2, 3]");
  ExpectFails(json_, {"object"});
  WriteText(json_, R"({"dims": [37, 21], "dtype": "uint16"})");
  ExpectFails(json_, {"dims"});
  WriteText(json_, R"({"dims": [37, 21, 5], "dtype": "uint16", "spacing": [1, "a", 1]})");
  ExpectFails(json_, {"spacing"});
  WriteText(json_, R"({"dims": [37, 21, 5], "dtype": "uint16", "spacing": [1, 0, 1]})");
  ExpectFails(json_, {"spacing"});
  WriteText(json_, R"({"dims": [37, 21, 5], "dtype": "uint16", "byte_order": "middle"})");
  ExpectFails(json_, {"byte_order"});
  WriteText(json_, R"({"dims": [37, 21, 5], "dtype": 7})");
  ExpectFails(json_, {"dtype"});
}

TEST_F(RawJsonTest, MissingRawFileIsNamed) {
  EditSidecar([](nlohmann::json& j) { j["raw_file"] = "elsewhere.raw"; });
  ExpectFails(json_, {"elsewhere.raw"});
}

TEST_F(RawJsonTest, RawFileDefaultsToStemAndMinimalSidecarWorks) {
  // Only dims and dtype: raw_file defaults to vol.raw, spacing to 1, origin to 0.
  WriteText(json_, R"({"dims": [37, 21, 5], "dtype": "uint16"})");
  VolumeInfo got;
  absl::StatusOr<std::vector<uint8_t>> v = ReadAll(json_, &got);
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_TRUE(*v == PatternVolume(info_));
  EXPECT_EQ(got.spacing, (std::array<double, 3>{1, 1, 1}));
  EXPECT_EQ(got.origin, (std::array<double, 3>{0, 0, 0}));
}

TEST_F(RawJsonTest, SlicesAreStreamedOneAtATime) {
  absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(json_);
  ASSERT_TRUE(src.ok()) << src.status();
  std::vector<uint8_t> slice;
  for (int64_t k = 0; k < info_.nz; ++k) {
    ASSERT_TRUE((*src)->ReadSlice(&slice).ok());
    EXPECT_TRUE(slice == PatternSlice(info_, k)) << "slice " << k;
  }
  EXPECT_TRUE(absl::IsOutOfRange((*src)->ReadSlice(&slice)));
  EXPECT_TRUE(absl::IsOutOfRange((*src)->ReadSlice(&slice)));
}

// ---------------------------------------------------------------------------------------
// NRRD.

const char kSmallNrrdBigEndian[] =
    "NRRD0004\n"
    "# hand-written\n"
    "type: unsigned short\n"
    "dimension: 3\n"
    "sizes: 2 2 2\n"
    "spacings: 0.5 -1.5 3\n"
    "endian: big\n"
    "encoding: raw\n"
    "\n";

TEST(NrrdTest, HandWrittenBigEndianWithSpacings) {
  const std::string path = tandem::testing::MakeTempDir() + "/h.nrrd";
  std::string text = kSmallNrrdBigEndian;
  for (int v = 0; v < 8; ++v) {
    text.push_back(static_cast<char>(v + 1));
    text.push_back(static_cast<char>(0x10 * v));
  }
  WriteText(path, text);
  VolumeInfo info;
  absl::StatusOr<std::vector<uint8_t>> v = ReadAll(path, &info);
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_EQ(info.dtype, DType::kUInt16);
  EXPECT_EQ(info.spacing, (std::array<double, 3>{0.5, 1.5, 3}));
  for (int i = 0; i < 8; ++i) {
    EXPECT_EQ(Load<uint16_t>(v->data() + 2 * i), (i + 1) * 256 + 0x10 * i) << i;
  }
}

TEST(NrrdTest, TypeAliasesAndByteSkip) {
  const std::string dir = tandem::testing::MakeTempDir();
  const std::pair<const char*, DType> aliases[] = {
      {"uchar", DType::kUInt8},        {"unsigned char", DType::kUInt8},
      {"uint8_t", DType::kUInt8},      {"ushort", DType::kUInt16},
      {"uint16_t", DType::kUInt16},    {"short", DType::kInt16},
      {"signed short", DType::kInt16}, {"int16_t", DType::kInt16},
      {"float", DType::kFloat32}};
  for (const auto& [name, t] : aliases) {
    const std::string path = dir + "/a.nrrd";
    std::string text =
        std::string("NRRD0005\ntype: ") + name +
        "\ndimension: 3\nsizes: 2 2 2\nendian: little\nencoding: raw\nbyte skip: 3\n\n";
    text.append(3 + 8 * DTypeSize(t), '\x01');
    WriteText(path, text);
    VolumeInfo info;
    absl::StatusOr<std::vector<uint8_t>> v = ReadAll(path, &info);
    ASSERT_TRUE(v.ok()) << name << ": " << v.status();
    EXPECT_EQ(info.dtype, t) << name;
    EXPECT_EQ(v->size(), 8 * DTypeSize(t));
  }
}

TEST(NrrdTest, DetachedHeaderNamesAMissingDataFile) {
  const std::string dir = tandem::testing::MakeTempDir();
  const VolumeInfo info = MakeInfo(DType::kInt16);
  ASSERT_TRUE(io::WriteVolume(dir + "/d.nhdr", info, PatternFn(info)).ok());
  EXPECT_NE(ReadText(dir + "/d.nhdr").find("data file: d.raw"), std::string::npos);
  fs::remove(dir + "/d.raw");
  ExpectFails(dir + "/d.nhdr", {"d.raw"});
}

class NrrdErrorTest : public ::testing::TestWithParam<bool> {  // param: gzip
 protected:
  void SetUp() override {
    path_ = tandem::testing::MakeTempDir() + "/vol.nrrd";
    info_ = MakeInfo(DType::kUInt16);
    ASSERT_TRUE(io::WriteVolume(path_, info_, PatternFn(info_), Opts(GetParam(), false)).ok());
  }
  std::string path_;
  VolumeInfo info_;
};

TEST_P(NrrdErrorTest, Truncated) {
  Truncate(path_, 200);
  ExpectFails(path_, {"truncated", "expected 7770 bytes of voxel data"});
}

TEST_P(NrrdErrorTest, UnsupportedType) {
  ReplaceInFile(path_, "type: uint16", "type: double");
  ExpectFails(path_, {"unsupported type 'double'"});
}

TEST_P(NrrdErrorTest, DimsLargerThanData) {
  ReplaceInFile(path_, "sizes: 37 21 5", "sizes: 37 21 6");
  ExpectFails(path_, {"truncated"});
}

TEST_P(NrrdErrorTest, DimsSmallerThanData) {
  ReplaceInFile(path_, "sizes: 37 21 5", "sizes: 37 21 4");
  ExpectFails(path_, {"size mismatch"});
}

TEST_P(NrrdErrorTest, HeaderProblems) {
  const std::string original = ReadText(path_);
  const std::pair<std::string, std::string> edits[] = {
      {"dimension: 3", "dimension: 4"},
      {"encoding: ", "encoding: bzip2\nold: "},
      {"space directions: (0.5,0,0)", "space directions: (0.5,0.5,0)"},
      {"NRRD0004", "NRRX0004"},
      {"sizes: 37 21 5", "sizes: 37 21"},
      {"endian: little", "endian: middle"},
  };
  const char* needles[] = {"dimension is 4", "unsupported encoding 'bzip2'",
                           "orthonormal",    "not a NRRD file",
                           "sizes",          "endian"};
  for (size_t i = 0; i < std::size(edits); ++i) {
    WriteText(path_, original);
    ReplaceInFile(path_, edits[i].first, edits[i].second);
    ExpectFails(path_, {needles[i]});
  }
}

TEST_P(NrrdErrorTest, EmptyFile) {
  WriteText(path_, "");
  ExpectFails(path_, {"empty file"});
}

INSTANTIATE_TEST_SUITE_P(RawAndGzip, NrrdErrorTest, ::testing::Bool(),
                         [](const ::testing::TestParamInfo<bool>& p) {
                           return p.param ? "gzip" : "raw";
                         });

TEST(NrrdTest, CorruptGzipData) {
  const std::string path = tandem::testing::MakeTempDir() + "/c.nrrd";
  const VolumeInfo info = MakeInfo(DType::kFloat32);
  ASSERT_TRUE(io::WriteVolume(path, info, PatternFn(info), Opts(true, false)).ok());
  std::vector<uint8_t> bytes = ReadBytes(path);
  for (size_t i = bytes.size() - 300; i < bytes.size() - 200; ++i) bytes[i] ^= 0x5a;
  WriteBytes(path, bytes);
  ExpectFails(path, {});
}

// ---------------------------------------------------------------------------------------
// NIfTI.

class NiftiTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = tandem::testing::MakeTempDir();
    path_ = dir_ + "/vol.nii";
    info_ = MakeInfo(DType::kInt16);
    ASSERT_TRUE(io::WriteVolume(path_, info_, PatternFn(info_)).ok());
    bytes_ = ReadBytes(path_);
    ASSERT_EQ(bytes_.size(), 352 + 7770u);
  }
  // Rewrites the file with a patched header.
  template <typename T>
  void Patch(size_t offset, T v) {
    Store<T>(&bytes_[offset], v);
    WriteBytes(path_, bytes_);
  }
  std::string dir_, path_;
  VolumeInfo info_;
  std::vector<uint8_t> bytes_;
};

TEST_F(NiftiTest, Truncated) {
  Truncate(path_, 100);
  ExpectFails(path_, {"truncated", "expected 7770 bytes of voxel data", "file has 7670"});
  WriteBytes(path_, std::vector<uint8_t>(bytes_.begin(), bytes_.begin() + 200));
  ExpectFails(path_, {"truncated", "348 bytes"});
}

TEST_F(NiftiTest, TruncatedGzip) {
  const std::string gz = dir_ + "/vol.nii.gz";
  ASSERT_TRUE(io::WriteVolume(gz, info_, PatternFn(info_)).ok());
  Truncate(gz, 40);
  ExpectFails(gz, {"truncated", "expected 7770 bytes of voxel data"});
}

TEST_F(NiftiTest, UnsupportedDatatypeIsNamed) {
  Patch<int16_t>(70, 64);  // float64
  Patch<int16_t>(72, 64);
  ExpectFails(path_, {"unsupported NIfTI datatype 64 (float64)"});
  Patch<int16_t>(70, 32);  // complex64
  Patch<int16_t>(72, 64);
  ExpectFails(path_, {"datatype 32 (complex64)"});
}

TEST_F(NiftiTest, DimsMismatch) {
  Patch<int16_t>(40 + 6, 6);  // dim[3]: 5 -> 6
  ExpectFails(path_, {"truncated"});
  Patch<int16_t>(40 + 6, 4);  // dim[3]: 5 -> 4
  ExpectFails(path_, {"size mismatch"});
}

TEST_F(NiftiTest, DimsMismatchGzip) {
  // gzip the patched header + data with zlib directly (WriteVolume cannot write a mismatch).
  const std::string gz = dir_ + "/vol.nii.gz";
  for (int16_t nz : {4, 6}) {
    Store<int16_t>(&bytes_[40 + 6], nz);
    gzFile f = gzopen(gz.c_str(), "wb");
    ASSERT_NE(f, nullptr);
    ASSERT_EQ(gzwrite(f, bytes_.data(), static_cast<unsigned>(bytes_.size())),
              static_cast<int>(bytes_.size()));
    ASSERT_EQ(gzclose(f), Z_OK);
    ExpectFails(gz, {nz == 4 ? "size mismatch" : "truncated"});
  }
}

TEST_F(NiftiTest, FourDimensionalHeaders) {
  Patch<int16_t>(40, 4);      // dim[0]
  Patch<int16_t>(40 + 8, 3);  // dim[4]: three time points
  ExpectFails(path_, {"dim[4] is 3"});
  Patch<int16_t>(40 + 8, 1);  // 4-D with a single time point is a 3-D volume
  absl::StatusOr<std::vector<uint8_t>> v = ReadAll(path_);
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_TRUE(*v == PatternVolume(info_));
  Patch<int16_t>(40, 2);
  ExpectFails(path_, {"dim[0] is 2"});
}

TEST_F(NiftiTest, EmptyFile) {
  WriteBytes(path_, {});
  ExpectFails(path_, {"empty file"});
  const std::string gz = dir_ + "/e.nii.gz";
  WriteBytes(gz, {});
  ExpectFails(gz, {"empty file"});
}

TEST_F(NiftiTest, RejectsNifti2AndPairHeaders) {
  std::vector<uint8_t> n2(600, 0);
  Store<int32_t>(&n2[0], 540);
  WriteBytes(path_, n2);
  ExpectFails(path_, {"NIfTI-2"});
  WriteBytes(path_, bytes_);
  std::memcpy(&bytes_[344], "ni1\0", 4);
  WriteBytes(path_, bytes_);
  ExpectFails(path_, {".hdr/.img"});
}

TEST_F(NiftiTest, OriginFromSformWhenNoQform) {
  Patch<int16_t>(252, 0);     // qform_code
  Patch<float>(268, 999.0f);  // qoffset_x must now be ignored
  VolumeInfo got;
  ASSERT_TRUE(ReadAll(path_, &got).ok());
  ExpectGeometryNear(got, info_);
  Patch<int16_t>(254, 0);  // no sform either: origin 0
  ASSERT_TRUE(ReadAll(path_, &got).ok());
  EXPECT_EQ(got.origin, (std::array<double, 3>{0, 0, 0}));
}

TEST_F(NiftiTest, NegativePixdimGivesPositiveSpacing) {
  Patch<float>(76 + 4, -0.5f);
  VolumeInfo got;
  ASSERT_TRUE(ReadAll(path_, &got).ok());
  EXPECT_EQ(got.spacing[0], 0.5);
}

TEST_F(NiftiTest, VoxOffsetIsHonoured) {
  // Same header with vox_offset 400, 48 filler bytes, then the voxels.
  std::vector<uint8_t> moved(400 + (bytes_.size() - 352), 0xee);
  std::memcpy(moved.data(), bytes_.data(), 352);
  std::memcpy(moved.data() + 400, bytes_.data() + 352, bytes_.size() - 352);
  Store<float>(&moved[108], 400.0f);
  WriteBytes(path_, moved);
  absl::StatusOr<std::vector<uint8_t>> v = ReadAll(path_);
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_TRUE(*v == PatternVolume(info_));
}

TEST_F(NiftiTest, ScalingDeliversFloat32) {
  for (const char* name : {"s.nii", "s.nii.gz"}) {
    const std::string path = dir_ + "/" + name;
    io::VolumeWriteOptions o;
    o.nifti_scl_slope = 2.0f;
    o.nifti_scl_inter = -1.5f;
    ASSERT_TRUE(io::WriteVolume(path, info_, PatternFn(info_), o).ok());
    VolumeInfo got;
    absl::StatusOr<std::vector<uint8_t>> v = ReadAll(path, &got);
    ASSERT_TRUE(v.ok()) << v.status();
    EXPECT_EQ(got.dtype, DType::kFloat32);
    ASSERT_EQ(v->size(), 37u * 21 * 5 * 4);
    for (int64_t k : {0, 4}) {
      for (int64_t i : {0, 36}) {
        const float f = Load<float>(v->data() + ((k * 21 + 20) * 37 + i) * 4);
        EXPECT_EQ(f, PatternValue(DType::kInt16, i, 20, k) * 2.0 - 1.5);
      }
    }
  }
  // slope 1, inter 0 is the identity: the stored dtype is kept.
  io::VolumeWriteOptions identity;
  identity.nifti_scl_slope = 1.0f;
  const std::string path = dir_ + "/i.nii";
  ASSERT_TRUE(io::WriteVolume(path, info_, PatternFn(info_), identity).ok());
  VolumeInfo got;
  ASSERT_TRUE(ReadAll(path, &got).ok());
  EXPECT_EQ(got.dtype, DType::kInt16);
}

TEST_F(NiftiTest, GzipDetectedFromContentNotName) {
  const std::string gz = dir_ + "/vol.nii.gz";
  ASSERT_TRUE(io::WriteVolume(gz, info_, PatternFn(info_)).ok());
  const std::string renamed = dir_ + "/really_gzip.nii";
  fs::rename(gz, renamed);
  absl::StatusOr<std::vector<uint8_t>> v = ReadAll(renamed);
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_TRUE(*v == PatternVolume(info_));
}

// ---------------------------------------------------------------------------------------
// TIFF.

TEST(TiffTest, ManyStripsAndEdgeTiles) {
  const std::string dir = tandem::testing::MakeTempDir();
  const VolumeInfo info = MakeInfo(DType::kFloat32, 1000, 150, 3);  // ~16 rows per strip
  for (int tile : {0, 48}) {
    const std::string path = dir + "/wide" + std::to_string(tile) + ".tif";
    ASSERT_TRUE(io::WriteVolume(path, info, PatternFn(info), Opts(false, false, tile)).ok());
    absl::StatusOr<std::vector<uint8_t>> v = ReadAll(path);
    ASSERT_TRUE(v.ok()) << v.status();
    EXPECT_TRUE(*v == PatternVolume(info)) << "tile " << tile;
  }
}

TEST(TiffTest, HandMadeStackWithoutImageJHasUnitSpacing) {
  const std::string path = tandem::testing::MakeTempDir() + "/plain.tif";
  WriteHandTiff(path, {{6, 4, 16, 2, 1}, {6, 4, 16, 2, 1}, {6, 4, 16, 2, 1}}, "a microscope");
  VolumeInfo info;
  absl::StatusOr<std::vector<uint8_t>> v = ReadAll(path, &info);
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_EQ(info.dtype, DType::kInt16);
  EXPECT_EQ(info.nz, 3);
  EXPECT_EQ(info.spacing, (std::array<double, 3>{1, 1, 1}));
  EXPECT_EQ(info.description, "a microscope");
}

TEST(TiffTest, Truncated) {
  const std::string dir = tandem::testing::MakeTempDir();
  const std::string hand = dir + "/hand.tif";
  WriteHandTiff(hand, {{8, 8, 8, 1, 1}, {8, 8, 8, 1, 1}, {8, 8, 8, 1, 1}});
  Truncate(hand, 10);
  ExpectFails(hand, {"truncated", "page 2"});

  const VolumeInfo info = MakeInfo(DType::kUInt16);
  // (Cutting only the last directory's out-of-line tag values, e.g. 20 bytes, leaves every voxel
  // intact and libtiff ignores those tags; 300 bytes reaches the last page's directory and data.)
  for (uintmax_t cut : {uintmax_t{300}, uintmax_t{5000}}) {
    const std::string path = dir + "/w" + std::to_string(cut) + ".tif";
    ASSERT_TRUE(io::WriteVolume(path, info, PatternFn(info)).ok());
    Truncate(path, cut);
    ExpectFails(path, {"truncated"});
  }
}

// Sets every entry of `tag` in every directory of a little-endian classic TIFF to value.
void PatchTiffTag(const std::string& path, uint16_t tag, uint32_t value) {
  std::vector<uint8_t> b = ReadBytes(path);
  ASSERT_EQ(b[0], 'I');
  uint32_t ifd = Load<uint32_t>(&b[4]);
  int patched = 0;
  while (ifd != 0 && ifd + 2 <= b.size()) {
    const uint16_t n = Load<uint16_t>(&b[ifd]);
    for (uint16_t e = 0; e < n; ++e) {
      uint8_t* q = &b[ifd + 2 + 12 * e];
      if (Load<uint16_t>(q) != tag) continue;
      if (Load<uint16_t>(q + 2) == 3) {
        Store<uint16_t>(q + 8, static_cast<uint16_t>(value));
      } else {
        Store<uint32_t>(q + 8, value);
      }
      ++patched;
    }
    ifd = Load<uint32_t>(&b[ifd + 2 + 12 * n]);
  }
  ASSERT_GT(patched, 0) << "no tag " << tag;
  WriteBytes(path, b);
}

// A tiny tiled page that declares tiles of 65520 x 65520 pixels (17 GB each as float32;
// found by fuzz_tiff): refused before anything that size is allocated.
TEST(TiffTest, HugeTilesAreRefused) {
  const std::string path = tandem::testing::MakeTempDir() + "/tiles.tif";
  const VolumeInfo info = MakeInfo(DType::kFloat32, 32, 32, 3);
  ASSERT_TRUE(io::WriteVolume(path, info, PatternFn(info), Opts(false, false, 16)).ok());
  PatchTiffTag(path, 322, 65520);  // TileWidth
  PatchTiffTag(path, 323, 65520);  // TileLength
  ExpectFails(path, {"tile", "65520"});
}

TEST(TiffTest, UnsupportedPixelTypes) {
  const std::string dir = tandem::testing::MakeTempDir();
  const std::string path = dir + "/t.tif";
  WriteHandTiff(path, {{4, 4, 64, 3, 1}, {4, 4, 64, 3, 1}});
  ExpectFails(path, {"unsupported pixel type", "64-bit floating-point"});
  WriteHandTiff(path, {{4, 4, 24, 1, 1}, {4, 4, 24, 1, 1}});
  ExpectFails(path, {"unsupported pixel type", "24-bit unsigned integer"});
  WriteHandTiff(path, {{4, 4, 16, 1, 2}, {4, 4, 16, 1, 2}});
  ExpectFails(path, {"2 samples per pixel"});
}

TEST(TiffTest, MismatchedPages) {
  const std::string path = tandem::testing::MakeTempDir() + "/m.tif";
  WriteHandTiff(path, {{8, 8, 8, 1, 1}, {8, 8, 8, 1, 1}, {8, 6, 8, 1, 1}});
  ExpectFails(path, {"size mismatch", "page 2 is 8x6"});
  WriteHandTiff(path, {{8, 8, 8, 1, 1}, {8, 8, 16, 1, 1}});
  ExpectFails(path, {"size mismatch", "page 1"});
}

TEST(TiffTest, EmptyAndSinglePageFiles) {
  const std::string dir = tandem::testing::MakeTempDir();
  WriteText(dir + "/e.tif", "");
  ExpectFails(dir + "/e.tif", {"empty file"});
  WriteText(dir + "/junk.tiff", "this is not a tiff at all");
  ExpectFails(dir + "/junk.tiff", {"TIFF"});
  WriteHandTiff(dir + "/one.tif", {{8, 8, 8, 1, 1}});
  ExpectFails(dir + "/one.tif", {"at least 2 pages"});
}

TEST(TiffTest, ImageJHyperstacksAreRefused) {
  const std::string path = tandem::testing::MakeTempDir() + "/h.tif";
  WriteHandTiff(path, {{4, 4, 8, 1, 1}, {4, 4, 8, 1, 1}},
                "ImageJ=1.53t\nimages=2\nchannels=2\nslices=1\n");
  ExpectFails(path, {"hyperstack"});
}

// ---------------------------------------------------------------------------------------
// The shared real volumes.

class SharedVolumeTest : public ::testing::TestWithParam<const char*> {};

TEST_P(SharedVolumeTest, MatchesSidecarAndRawBytes) {
  TANDEM_SHARED_OR_SKIP(json_path, std::string(GetParam()) + ".json");
  const nlohmann::json j = nlohmann::json::parse(ReadText(json_path));
  absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(json_path);
  ASSERT_TRUE(src.ok()) << src.status();
  const VolumeInfo& info = (*src)->info();
  EXPECT_EQ(info.nx, j["dims"][0].get<int64_t>());
  EXPECT_EQ(info.ny, j["dims"][1].get<int64_t>());
  EXPECT_EQ(info.nz, j["dims"][2].get<int64_t>());
  EXPECT_EQ(DTypeName(info.dtype), j["dtype"].get<std::string>());
  for (int a = 0; a < 3; ++a) EXPECT_EQ(info.spacing[a], j["spacing"][a].get<double>());
  EXPECT_EQ(info.origin, (std::array<double, 3>{0, 0, 0}));
  EXPECT_EQ(info.suggested_isovalues, j["suggested_isovalues"].get<std::vector<double>>());
  EXPECT_EQ(info.description, j["description"].get<std::string>());
  EXPECT_EQ(info.slice_bytes() * info.nz, j["raw_bytes"].get<size_t>());

  const std::string raw_path =
      (fs::path(json_path).parent_path() / j["raw_file"].get<std::string>()).string();
  std::ifstream raw(raw_path, std::ios::binary);
  const std::vector<int64_t> check = {0, 1, info.nz / 2, info.nz - 1};
  std::vector<uint8_t> slice, expected(info.slice_bytes());
  for (int64_t k = 0; k < info.nz; ++k) {
    ASSERT_TRUE((*src)->ReadSlice(&slice).ok()) << "slice " << k;
    if (std::find(check.begin(), check.end(), k) == check.end()) continue;
    raw.seekg(static_cast<std::streamoff>(k * info.slice_bytes()));
    raw.read(reinterpret_cast<char*>(expected.data()),
             static_cast<std::streamsize>(expected.size()));
    ASSERT_TRUE(raw.good());
    EXPECT_TRUE(slice == expected) << "slice " << k << " differs from the raw file";
  }
  EXPECT_TRUE(absl::IsOutOfRange((*src)->ReadSlice(&slice)));
}

// Converting a real volume to every format, streaming source slice -> writer, is lossless.
TEST_P(SharedVolumeTest, ConvertsLosslesslyToEveryFormat) {
  TANDEM_SHARED_OR_SKIP(json_path, std::string(GetParam()) + ".json");
  absl::StatusOr<std::vector<uint8_t>> original = ReadAll(json_path);
  ASSERT_TRUE(original.ok()) << original.status();
  const std::string dir = tandem::testing::MakeTempDir();
  for (const char* name : {"c.nrrd", "c.nii.gz", "c.tif"}) {
    absl::StatusOr<std::unique_ptr<SliceSource>> src = io::OpenVolume(json_path);
    ASSERT_TRUE(src.ok());
    SliceSource* s = src->get();
    const std::string out = dir + "/" + name;
    ASSERT_TRUE(io::WriteVolume(
                    out, s->info(),
                    [s](int64_t, std::vector<uint8_t>* b) { return s->ReadSlice(b); },
                    Opts(true, false))
                    .ok())
        << name;
    VolumeInfo got;
    absl::StatusOr<std::vector<uint8_t>> copy = ReadAll(out, &got);
    ASSERT_TRUE(copy.ok()) << copy.status();
    ExpectGeometryNear(got, s->info());
    EXPECT_TRUE(*copy == *original) << name;
  }
}

INSTANTIATE_TEST_SUITE_P(Shared, SharedVolumeTest,
                         ::testing::Values("ct_head_headsq_64x64x93_int16",
                                           "mr_head_48x62x42_uint8", "mri_avg152T1_91x109x91_uint8",
                                           "ct_engine_256x256x128_uint8"),
                         [](const ::testing::TestParamInfo<const char*>& p) {
                           return std::string(p.param).substr(0, std::string(p.param).find('_', 3));
                         });

}  // namespace
}  // namespace tandem
