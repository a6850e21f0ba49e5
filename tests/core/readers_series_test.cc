// Folders of one file per slice: DICOM series written by GDCM (every transfer syntax the
// writer offers, shuffled file names, rescale to int16 and float32, rotated and flipped
// orientations) and numbered TIFF sequences written by libtiff; and the bad folders an
// instrument or a user produces (a second series, a duplicate or missing slice, a truncated
// or foreign file, mixed slice sizes), each refused with a message naming the files.
#include <gtest/gtest.h>
#include <tiffio.h>
#include <zlib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "dicom_worker_client.h"
#include "tandem/eval/distance.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/run_session.h"
#include "tandem/io/series.h"
#include "tandem/eval/synthetic.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"
#include "testutil/testutil.h"

// The reader process sets no address-space limit under ASan (it reserves terabytes).
#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define TANDEM_TEST_ASAN 1
#endif
#endif
#ifdef __SANITIZE_ADDRESS__
#define TANDEM_TEST_ASAN 1
#endif

namespace tandem {
namespace {

namespace fs = std::filesystem;
using testing::PatternValue;
using testing::StoreValue;
using testing::PatternSlices;
constexpr auto Load = testing::LoadValue;

VolumeInfo Grid(DType t, int64_t nx = 37, int64_t ny = 21, int64_t nz = 9) {
  VolumeInfo info;
  info.nx = nx;
  info.ny = ny;
  info.nz = nz;
  info.dtype = t;
  info.spacing = {0.5, 0.75, 2.5};
  info.origin = {-10.5, 3.25, 100.0};
  return info;
}

// Reads every slice and checks value(i, j, k) = expect(i, j, k) exactly.
template <typename F>
void ExpectVoxels(SliceSource& src, F expect) {
  const VolumeInfo& info = src.info();
  std::vector<uint8_t> bytes;
  const size_t es = DTypeSize(info.dtype);
  for (int64_t k = 0; k < info.nz; ++k) {
    ASSERT_TRUE(src.ReadSlice(&bytes).ok()) << "slice " << k;
    ASSERT_EQ(bytes.size(), info.slice_bytes());
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        ASSERT_EQ(Load(info.dtype, bytes.data() + (j * info.nx + i) * es), expect(i, j, k))
            << i << "," << j << "," << k;
      }
    }
  }
  EXPECT_TRUE(absl::IsOutOfRange(src.ReadSlice(&bytes)));
}

// Renames the files of dir to random names, so neither names nor listing order give the
// slice order (as files a PACS or a C-STORE receiver writes).
void ShuffleNames(const std::string& dir, uint32_t seed) {
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  std::vector<int> order(files.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::shuffle(order.begin(), order.end(), std::mt19937(seed));
  for (size_t i = 0; i < files.size(); ++i) {
    fs::rename(files[i], fs::path(dir) / absl::StrCat("tmp", i));
  }
  for (size_t i = 0; i < files.size(); ++i) {
    fs::rename(fs::path(dir) / absl::StrCat("tmp", i),
               fs::path(dir) / absl::StrCat("1.3.6.1.4.", order[i] * 7919 % 1000, ".", i));
  }
}

class DicomSyntaxTest : public ::testing::TestWithParam<io::DicomSyntax> {};

// 12-bit CT values: 0..4095.
double Ct12(int64_t i, int64_t j, int64_t k) { return static_cast<double>((i * 37 + j * 411 + k * 1009) % 4096); }

TEST_P(DicomSyntaxTest, RoundTripsTwelveBitCtAsInt16HounsfieldUnits) {
  // CT: uint16 with 12 bits stored, slope 1, intercept -1024 -> int16 Hounsfield units.
  const std::string dir = testing::MakeTempDir() + "/ct";
  VolumeInfo info = Grid(DType::kUInt16);
  io::DicomWriteOptions opts;
  opts.syntax = GetParam();
  opts.rescale_intercept = -1024;
  opts.bits_stored = 12;
  const io::SliceFn ct = [&](int64_t k, std::vector<uint8_t>* bytes) {
    bytes->resize(info.slice_bytes());
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        StoreValue(info.dtype, Ct12(i, j, k), bytes->data() + 2 * (j * info.nx + i));
      }
    }
    return absl::OkStatus();
  };
  ASSERT_TRUE(io::WriteDicomSeries(dir, info, ct, opts).ok());
  ShuffleNames(dir, 7);
  auto src = io::OpenVolume(dir);
  ASSERT_TRUE(src.ok()) << src.status();
  const VolumeInfo& got = (*src)->info();
  EXPECT_EQ(got.nx, info.nx);
  EXPECT_EQ(got.ny, info.ny);
  EXPECT_EQ(got.nz, info.nz);
  EXPECT_EQ(got.dtype, DType::kInt16);
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(got.spacing[a], info.spacing[a], 1e-9) << a;
    EXPECT_NEAR(got.origin[a], info.origin[a], 1e-9) << a;
  }
  EXPECT_TRUE(got.axis_aligned());
  EXPECT_TRUE(absl::StrContains(got.description, "DICOM CT series")) << got.description;
  ExpectVoxels(**src, [&](int64_t i, int64_t j, int64_t k) { return Ct12(i, j, k) - 1024; });
}

INSTANTIATE_TEST_SUITE_P(AllSyntaxes, DicomSyntaxTest,
                         ::testing::Values(io::DicomSyntax::kExplicitLittle,
                                           io::DicomSyntax::kImplicitLittle,
                                           io::DicomSyntax::kJpegLossless, io::DicomSyntax::kJpegLs,
                                           io::DicomSyntax::kJpeg2000, io::DicomSyntax::kRle));

TEST(DicomSeries, SlopeOrAWideRangeGivesFloat32AndUInt8StaysUInt8) {
  const std::string root = testing::MakeTempDir();
  // 16 stored bits shifted by -1024 do not fit int16: float32, exact.
  VolumeInfo s16 = Grid(DType::kInt16);
  io::DicomWriteOptions shift;
  shift.rescale_intercept = -1024;
  ASSERT_TRUE(io::WriteDicomSeries(root + "/s16", s16, PatternSlices(s16), shift).ok());
  auto src16 = io::OpenVolume(root + "/s16");
  ASSERT_TRUE(src16.ok()) << src16.status();
  EXPECT_EQ((*src16)->info().dtype, DType::kFloat32);
  ExpectVoxels(**src16, [&](int64_t i, int64_t j, int64_t k) {
    return PatternValue(DType::kInt16, i, j, k) - 1024;
  });

  VolumeInfo info = Grid(DType::kUInt16);
  io::DicomWriteOptions opts;
  opts.rescale_slope = 0.5;
  opts.rescale_intercept = 3;
  ASSERT_TRUE(io::WriteDicomSeries(root + "/mr", info, PatternSlices(info), opts).ok());
  auto src = io::OpenVolume(root + "/mr");
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_EQ((*src)->info().dtype, DType::kFloat32);
  ExpectVoxels(**src, [&](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(PatternValue(DType::kUInt16, i, j, k) * 0.5 + 3);
  });

  VolumeInfo u8 = Grid(DType::kUInt8);
  ASSERT_TRUE(io::WriteDicomSeries(root + "/u8", u8, PatternSlices(u8)).ok());
  auto src8 = io::OpenVolume(root + "/u8");
  ASSERT_TRUE(src8.ok()) << src8.status();
  EXPECT_EQ((*src8)->info().dtype, DType::kUInt8);
  ExpectVoxels(**src8, [&](int64_t i, int64_t j, int64_t k) {
    return PatternValue(DType::kUInt8, i, j, k);
  });
}

TEST(DicomSeries, FloatVolumeIsQuantizedWithinOneStep) {
  const std::string dir = testing::MakeTempDir() + "/f";
  VolumeInfo info = Grid(DType::kFloat32);
  ASSERT_TRUE(io::WriteDicomSeries(dir, info, PatternSlices(info)).ok());
  auto src = io::OpenVolume(dir);
  ASSERT_TRUE(src.ok()) << src.status();
  ASSERT_EQ((*src)->info().dtype, DType::kFloat32);
  double lo = 1e300, hi = -1e300;
  for (int64_t k = 0; k < info.nz; ++k) {
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        lo = std::min(lo, PatternValue(DType::kFloat32, i, j, k));
        hi = std::max(hi, PatternValue(DType::kFloat32, i, j, k));
      }
    }
  }
  const double step = (hi - lo) / 65534;
  std::vector<uint8_t> bytes;
  for (int64_t k = 0; k < info.nz; ++k) {
    ASSERT_TRUE((*src)->ReadSlice(&bytes).ok());
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        ASSERT_NEAR(Load(DType::kFloat32, bytes.data() + 4 * (j * info.nx + i)),
                    PatternValue(DType::kFloat32, i, j, k), step * 0.51 + 1e-6 * hi);
      }
    }
  }
}

// A synthetic link held in memory, and a SliceFn that serves it (any slice, any number of
// passes: the DICOM writer reads a float volume twice).
struct HeldVolume {
  VolumeInfo info;
  std::vector<std::vector<uint8_t>> slices;
  io::SliceFn fn() const {
    return [this](int64_t z, std::vector<uint8_t>* b) {
      *b = slices[z];
      return absl::OkStatus();
    };
  }
};

HeldVolume HeldLink(int64_t nx, int64_t ny, int64_t nz, std::array<double, 3> spacing) {
  auto src = eval::MakeSyntheticSource(eval::Shape::kLink, nx, ny, nz, spacing);
  HeldVolume v{src->info(), {}};
  v.slices.resize(v.info.nz);
  for (auto& s : v.slices) EXPECT_TRUE(src->ReadSlice(&s).ok());
  return v;
}

// The mesh of a rotated or mirrored series is the mesh of the same voxels on an axis-aligned
// grid, moved by the series' frame: checked against the transformed axis-aligned mesh.
TEST(DicomSeries, RotatedAndMirroredFramesPlaceTheMeshInTheWorld) {
  const std::string root = testing::MakeTempDir();
  const HeldVolume held = HeldLink(36, 30, 28, {0.8, 0.8, 1.5});
  const VolumeInfo info = held.info;
  const io::SliceFn fn = held.fn();
  SessionOptions o;
  o.iso = 0;
  o.error = 0.05;
  auto mesh_of = [&](const std::string& dir) -> IndexedMesh {
    auto src = io::OpenVolume(dir);
    EXPECT_TRUE(src.ok()) << src.status();
    if (!src.ok()) return {};
    auto run = io::RunSession(**src, o);
    EXPECT_TRUE(run.ok()) << run.status();
    return run.ok() ? (*run)->Snapshot() : IndexedMesh{};
  };
  ASSERT_TRUE(io::WriteDicomSeries(root + "/plain", info, fn).ok());
  const IndexedMesh plain = mesh_of(root + "/plain");
  ASSERT_GT(plain.num_triangles(), 100u);

  struct Frame {
    std::array<double, 3> origin;
    std::array<std::array<double, 3>, 3> d;
  };
  const double c = std::sqrt(0.5);
  const Frame frames[] = {
      // 90 degrees about z (x -> world y), shifted.
      {{10, -20, 30}, {{{0, 1, 0}, {-1, 0, 0}, {0, 0, 1}}}},
      // Oblique: 45 degrees about x.
      {{-5, 7, 11}, {{{1, 0, 0}, {0, c, c}, {0, -c, c}}}},
      // Slices written along -normal (feet first): the reader reverses them.
      {{0, 0, 50}, {{{1, 0, 0}, {0, 1, 0}, {0, 0, -1}}}},
  };
  int n = 0;
  for (const Frame& f : frames) {
    SCOPED_TRACE(n);
    VolumeInfo moved = info;
    moved.origin = f.origin;
    moved.directions = f.d;
    const std::string dir = absl::StrCat(root, "/frame", n++);
    ASSERT_TRUE(io::WriteDicomSeries(dir, moved, fn).ok());
    const IndexedMesh world = mesh_of(dir);
    // The axis-aligned mesh (origin 0) moved into the frame by hand.
    IndexedMesh expected = plain;
    for (Vec3& p : expected.positions) {
      Vec3 q{f.origin[0], f.origin[1], f.origin[2]};
      for (int a = 0; a < 3; ++a) q = q + Vec3{f.d[a][0], f.d[a][1], f.d[a][2]} * p[a];
      p = q;
    }
    const eval::Distances d = eval::MeasureDistances(expected, world, eval::DistanceOptions{});
    // Reversed slices are simplified in the other sweep direction, so the two meshes are
    // different simplifications of one surface; a wrong frame would be voxels away.
    EXPECT_LT(d.linf_max, 0.3) << "Hausdorff between the moved and the read mesh";
    // Same orientation: the signed volume keeps its sign (a mirror must flip the winding).
    auto volume = [](const IndexedMesh& m) {
      double v = 0;
      for (size_t t = 0; t < m.indices.size(); t += 3) {
        v += Dot(m.positions[m.indices[t]],
                 Cross(m.positions[m.indices[t + 1]], m.positions[m.indices[t + 2]]));
      }
      return v / 6;
    };
    EXPECT_NEAR(volume(world) / volume(plain), 1.0, 0.02);
  }
}

std::string WriteSeries(const std::string& dir, const VolumeInfo& info,
                        const io::DicomWriteOptions& opts = {}) {
  EXPECT_TRUE(io::WriteDicomSeries(dir, info, PatternSlices(info), opts).ok());
  return dir;
}

// What a reader sets aside, one note line each.
struct Notes {
  std::vector<std::string> lines;
  io::OpenOptions Options(const std::string& series = "") {
    return io::OpenOptions{.dicom_series = series,
                       .note = [this](const std::string& line) { lines.push_back(line); }};
  }
  std::string all() const { return absl::StrJoin(lines, "\n"); }
};

// A folder holding more than one series: a stray image or two of another series is a scout
// beside the stack (set aside with a note); two slice stacks are refused, listing each and
// pointing to --series, which picks one.
TEST(DicomSeries, ScoutsAreSetAsideAndTwoStacksNeedSeries) {
  const std::string root = testing::MakeTempDir();
  VolumeInfo info = Grid(DType::kInt16);
  io::DicomWriteOptions a, b;
  a.series_uid = "1.2.826.0.1.3680043.2.1125.1";
  a.series_description = "axial";
  b.series_uid = "1.2.826.0.1.3680043.2.1125.2";
  b.series_description = "bone";
  WriteSeries(root + "/s", info, a);
  VolumeInfo other = info;
  other.nz = 3;
  WriteSeries(root + "/b", other, b);
  fs::copy_file(root + "/b/IM00002.dcm", root + "/s/zz_other.dcm");
  Notes stray;
  auto src = io::OpenVolume(root + "/s", stray.Options());
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_EQ((*src)->info().nz, info.nz);
  ASSERT_EQ(stray.lines.size(), 1u) << stray.all();
  EXPECT_EQ(stray.lines[0], "ignoring DICOM series " + b.series_uid +
                                " 'bone' (1 image, e.g. zz_other.dcm): a scout (1 or 2 images "
                                "beside the main stack)");

  for (const char* f : {"IM00001.dcm", "IM00003.dcm"}) {
    fs::copy_file(root + "/b/" + f, root + "/s/zz_" + f);
  }
  auto two = io::OpenVolume(root + "/s");
  ASSERT_FALSE(two.ok());
  const std::string msg(two.status().message());
  EXPECT_TRUE(absl::StrContains(msg, "holds 2 DICOM slice stacks")) << msg;
  EXPECT_TRUE(absl::StrContains(msg, a.series_uid + " 'axial' (9 images, e.g. IM00001.dcm)"))
      << msg;
  EXPECT_TRUE(absl::StrContains(msg, b.series_uid + " 'bone' (3 images, e.g. zz_IM00001.dcm)"))
      << msg;
  EXPECT_TRUE(absl::StrContains(msg, "pick one with --series UID")) << msg;

  Notes picked;
  auto bone = io::OpenVolume(root + "/s", picked.Options(b.series_uid));
  ASSERT_TRUE(bone.ok()) << bone.status();
  EXPECT_EQ((*bone)->info().nz, 3);
  EXPECT_EQ(picked.all(),
            "ignoring DICOM series " + a.series_uid +
                " 'axial' (9 images, e.g. IM00001.dcm): not the series --series picks");
  auto wrong = io::OpenVolume(root + "/s", io::OpenOptions{.dicom_series = "1.2.3"});
  ASSERT_FALSE(wrong.ok());
  EXPECT_TRUE(absl::StrContains(wrong.status().message(), "no DICOM series 1.2.3 (--series)"))
      << wrong.status();
  EXPECT_TRUE(absl::StrContains(wrong.status().message(), b.series_uid)) << wrong.status();
  auto tiff = io::OpenVolume(root + "/t.tif", io::OpenOptions{.dicom_series = a.series_uid});
  EXPECT_TRUE(absl::StrContains(tiff.status().message(), "not one")) << tiff.status();
}

// A CT's localizer (ImageType LOCALIZER) beside its stack is set aside with a note; a
// localizer alone is an error naming it; a dose report (no image) is skipped with a note.
TEST(DicomSeries, LocalizersAndDoseReportsAreSetAside) {
  const std::string root = testing::MakeTempDir();
  VolumeInfo info = Grid(DType::kInt16);
  WriteSeries(root + "/ct", info);
  auto plain = io::OpenVolume(root + "/ct");
  ASSERT_TRUE(plain.ok()) << plain.status();
  const std::string scout = testing::WriteLocalizer(root + "/ct", info);
  testing::WriteDoseReport(root + "/ct/dose.dcm", "1.2.826.0.1.3680043.2.1125.3");
  Notes notes;
  auto src = io::OpenVolume(root + "/ct", notes.Options());
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_EQ((*src)->info().nz, info.nz);
  EXPECT_EQ((*src)->info().origin, (*plain)->info().origin);
  ASSERT_EQ(notes.lines.size(), 2u) << notes.all();
  EXPECT_TRUE(absl::StrContains(notes.all(), "dose.dcm: DICOM file without an image"))
      << notes.all();
  EXPECT_TRUE(absl::StrContains(notes.all(), "ignoring DICOM series " + scout +
                                                 " 'Scout' (2 images, e.g. scout1.dcm): a "
                                                 "localizer (ImageType LOCALIZER)"))
      << notes.all();

  const std::string alone = testing::MakeTempDir();
  testing::WriteLocalizer(alone, info);
  auto only = io::OpenVolume(alone);
  ASSERT_FALSE(only.ok());
  EXPECT_EQ(only.status().message(),
            alone + ": no slice stack to read, only " + scout +
                " 'Scout' (2 images, e.g. scout1.dcm): a localizer (ImageType LOCALIZER) "
                "(--series UID reads one anyway)");
}

TEST(DicomSeries, DuplicateAndMissingSlicesAreRefusedNamingTheFiles) {
  const std::string root = testing::MakeTempDir();
  VolumeInfo info = Grid(DType::kInt16);
  WriteSeries(root + "/dup", info);
  fs::copy_file(root + "/dup/IM00004.dcm", root + "/dup/copy_of_4.dcm");
  auto dup = io::OpenVolume(root + "/dup");
  ASSERT_FALSE(dup.ok());
  EXPECT_TRUE(absl::StrContains(dup.status().message(), "same position")) << dup.status();
  EXPECT_TRUE(absl::StrContains(dup.status().message(), "copy_of_4.dcm")) << dup.status();

  WriteSeries(root + "/gap", info);
  fs::remove(root + "/gap/IM00005.dcm");
  auto gap = io::OpenVolume(root + "/gap");
  ASSERT_FALSE(gap.ok());
  const std::string msg(gap.status().message());
  EXPECT_TRUE(absl::StrContains(msg, "gap between IM00004.dcm and IM00006.dcm")) << msg;
}

TEST(DicomSeries, TruncatedForeignAndMismatchedFilesAreRefusedNamingThem) {
  const std::string root = testing::MakeTempDir();
  VolumeInfo info = Grid(DType::kInt16);
  // A slice cut short while being written: refused at open or when read, never a crash.
  WriteSeries(root + "/cut", info);
  const std::string victim = root + "/cut/IM00003.dcm";
  fs::resize_file(victim, fs::file_size(victim) - 200);
  auto cut = io::OpenVolume(root + "/cut");
  absl::Status st = cut.status();
  if (cut.ok()) {
    std::vector<uint8_t> bytes;
    while ((st = (*cut)->ReadSlice(&bytes)).ok()) {
    }
  }
  EXPECT_FALSE(absl::IsOutOfRange(st)) << "truncation went unnoticed";
  EXPECT_TRUE(absl::StrContains(st.message(), "IM00003.dcm")) << st;

  // A file that is not DICOM is skipped with a note naming it; hidden files and files still
  // being written under a temporary name are not the series' business.
  WriteSeries(root + "/txt", info);
  std::ofstream(root + "/txt/notes.txt") << "scanned on Tuesday\n";
  std::ofstream(root + "/txt/.DS_Store") << "x";
  std::ofstream(root + "/txt/IM00010.dcm.part") << "DICM";
  std::ofstream(root + "/txt/IM00011.dcm.tmp") << "DICM";
  Notes notes;
  auto txt = io::OpenVolume(root + "/txt", notes.Options());
  ASSERT_TRUE(txt.ok()) << txt.status();
  EXPECT_EQ((*txt)->info().nz, info.nz);
  EXPECT_EQ(notes.all(), "skipping " + root + "/txt/notes.txt: not a DICOM file");
  // A file that is DICOM but does not parse is an error naming it.
  std::ofstream(root + "/txt/broken.dcm", std::ios::binary)
      << std::string(128, '\0') << "DICM" << std::string(64, '\xff');
  auto broken = io::OpenVolume(root + "/txt");
  ASSERT_FALSE(broken.ok());
  EXPECT_TRUE(absl::StrContains(broken.status().message(), "broken.dcm")) << broken.status();

  // One series whose slices differ in size.
  io::DicomWriteOptions one;
  one.series_uid = "1.2.826.0.1.3680043.2.1125.4";
  WriteSeries(root + "/size", info, one);
  VolumeInfo small = info;
  small.nx = 20;
  WriteSeries(root + "/small", small, one);
  fs::remove(root + "/size/IM00009.dcm");
  fs::copy_file(root + "/small/IM00009.dcm", root + "/size/IM00009.dcm");
  auto size = io::OpenVolume(root + "/size");
  ASSERT_FALSE(size.ok());
  EXPECT_TRUE(absl::StrContains(size.status().message(), "IM00009.dcm")) << size.status();
  EXPECT_TRUE(absl::StrContains(size.status().message(), "differ in size")) << size.status();

  auto empty = io::OpenVolume(testing::MakeTempDir());
  ASSERT_FALSE(empty.ok());
  EXPECT_TRUE(absl::StrContains(empty.status().message(), "empty folder")) << empty.status();
}

std::string Slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}
void Spit(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}
std::string U32Le(uint32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); }

// Reads a series folder to the end: the status that ended it (OutOfRange: every slice read).
absl::Status ReadToEnd(const std::string& dir) {
  auto src = io::OpenVolume(dir);
  if (!src.ok()) return src.status();
  std::vector<uint8_t> slice;
  absl::Status st;
  while ((st = (*src)->ReadSlice(&slice)).ok()) {
  }
  return st;
}

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// An RLE fragment header whose segment count GDCM's decoder divides by (0) or follows past
// the header (0xFFFFFFFF) killed the process with SIGFPE / SIGSEGV. Each is refused, naming
// the file and the rule, before GDCM sees it; the program goes on reading other series.
TEST(DicomSeries, CraftedRleHeadersAreRefusedNamingTheFile) {
  const std::string root = testing::MakeTempDir();
  io::DicomWriteOptions rle;
  rle.syntax = io::DicomSyntax::kRle;
  const VolumeInfo info = Grid(DType::kInt16);
  for (uint32_t segments : {0u, 0xffffffffu, 16u, 1u}) {
    const std::string dir = WriteSeries(absl::StrCat(root, "/s", segments), info, rle);
    const std::string victim = dir + "/IM00005.dcm";
    std::string bytes = Slurp(victim);
    // Pixel data (OB, undefined length), the offset table item, then the first fragment's
    // item header: its first 4 bytes are the segment count.
    const size_t pixels = bytes.find(std::string("\xe0\x7f\x10\x00OB\0\0\xff\xff\xff\xff", 12));
    ASSERT_NE(pixels, std::string::npos);
    uint32_t table = 0;
    std::memcpy(&table, bytes.data() + pixels + 16, 4);
    const size_t header = pixels + 12 + 8 + table + 8;
    ASSERT_EQ(bytes.substr(header - 8, 4), std::string("\xfe\xff\x00\xe0", 4));
    bytes.replace(header, 4, U32Le(segments));
    Spit(victim, bytes);
    const auto t0 = std::chrono::steady_clock::now();
    const absl::Status st = ReadToEnd(dir);
    EXPECT_LT(SecondsSince(t0), 1.0);
    EXPECT_TRUE(absl::StrContains(st.message(), victim)) << st;
    EXPECT_TRUE(absl::StrContains(st.message(), "corrupt RLE pixel data")) << st;
    EXPECT_TRUE(absl::StrContains(
        st.message(), segments == 1 ? "1 segment(s), 16-bit samples need 2" : "segments (1..15)"))
        << st;
  }
  EXPECT_TRUE(absl::IsOutOfRange(ReadToEnd(WriteSeries(root + "/good", info, rle))));
}

// `depth` sequences (0040,A730) nested in one another, with undefined or defined lengths,
// as an explicit VR little endian element stream.
std::string NestedSequences(int depth, bool undefined) {
  const std::string inner = std::string("\x08\x00\x00\x01SH\x02\x00XX", 10);
  const std::string sq = std::string("\x40\x00\x30\xa7SQ\0\0", 8);
  const std::string item = std::string("\xfe\xff\x00\xe0", 4);
  std::string out;
  if (undefined) {
    for (int d = 0; d < depth; ++d) out += sq + U32Le(0xffffffffu) + item + U32Le(0xffffffffu);
    out += inner;
    for (int d = 0; d < depth; ++d) {
      out += std::string("\xfe\xff\x0d\xe0", 4) + U32Le(0) + std::string("\xfe\xff\xdd\xe0", 4) +
             U32Le(0);
    }
    return out;
  }
  std::vector<uint32_t> item_size(depth);  // from the innermost level out
  uint32_t size = static_cast<uint32_t>(inner.size());
  for (int d = 0; d < depth; ++d) {
    item_size[d] = size;
    size += 8 + 12;
  }
  for (int d = depth - 1; d >= 0; --d)
    out += sq + U32Le(item_size[d] + 8) + item + U32Le(item_size[d]);
  return out + inner;
}

// Puts `elements` into a GDCM-written explicit VR file right before its pixel data.
void InsertBeforePixels(const std::string& file, const std::string& elements) {
  std::string bytes = Slurp(file);
  const size_t pixels = bytes.rfind(std::string("\xe0\x7f\x10\x00", 4));
  ASSERT_NE(pixels, std::string::npos);
  bytes.insert(pixels, elements);
  Spit(file, bytes);
}

// GDCM parses sequences recursively: 4,000 undefined-length levels (or 50,000 defined ones)
// overflowed its stack, and 15 undefined-length levels took over a minute (GDCM's length
// of such a data set is exponential in the depth). Deep files are refused before GDCM
// parses them, naming the file; a real image's few levels read at once.
TEST(DicomSeries, DeepSequencesAreRefusedBeforeParsingAndShallowOnesReadAtOnce) {
  const std::string root = testing::MakeTempDir();
  const VolumeInfo info = Grid(DType::kInt16);
  struct Case {
    int depth;
    bool undefined;
    bool refused;
  };
  for (const Case& c : {Case{15, true, false}, Case{15, false, false}, Case{4000, true, true},
                        Case{50000, false, true}}) {
    const std::string dir = WriteSeries(absl::StrCat(root, "/d", c.depth, c.undefined), info);
    InsertBeforePixels(dir + "/IM00004.dcm", NestedSequences(c.depth, c.undefined));
    const auto t0 = std::chrono::steady_clock::now();
    const absl::Status st = ReadToEnd(dir);
    EXPECT_LT(SecondsSince(t0), 1.0) << c.depth;
    if (c.refused) {
      EXPECT_TRUE(absl::StrContains(st.message(), dir + "/IM00004.dcm")) << st;
      EXPECT_TRUE(absl::StrContains(st.message(), "sequences nested more than 32 deep")) << st;
    } else {
      EXPECT_TRUE(absl::IsOutOfRange(st)) << st;
    }
  }
}

// A declared length past the end of the file (GDCM would allocate it, then pad) and more
// elements than any slice holds are refused before GDCM parses the file.
TEST(DicomSeries, LengthsPastTheEndShortPixelsAndMillionsOfElementsAreRefused) {
  const std::string root = testing::MakeTempDir();
  const VolumeInfo info = Grid(DType::kInt16);
  const std::string big = WriteSeries(root + "/big", info) + "/IM00002.dcm";
  InsertBeforePixels(big, std::string("\x09\x00\x10\x10OB\0\0", 8) + U32Le(0xfffffff0u));
  absl::Status st = ReadToEnd(root + "/big");
  EXPECT_TRUE(absl::IsDataLoss(st)) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), big + ": truncated: element (0009,1010)")) << st;

  const std::string many = WriteSeries(root + "/many", info) + "/IM00002.dcm";
  std::string elements;
  for (int i = 0; i < (1 << 20) + 1; ++i) elements += std::string("\x09\x00\x10\x10LO\0\0", 8);
  InsertBeforePixels(many, elements);
  const auto t0 = std::chrono::steady_clock::now();
  st = ReadToEnd(root + "/many");
  EXPECT_LT(SecondsSince(t0), 2.0);
  EXPECT_TRUE(absl::StrContains(st.message(), many + ": more than 1048576 data elements")) << st;

  // Pixel data shorter than the image: GDCM would pad it to the image's size (a few bytes
  // claiming gigabytes); refused before it reads them.
  const std::string cut = WriteSeries(root + "/cut", info) + "/IM00003.dcm";
  std::string bytes = Slurp(cut);
  const size_t pixels = bytes.rfind(std::string("\xe0\x7f\x10\x00OW\0\0", 8));
  ASSERT_NE(pixels, std::string::npos);
  Spit(cut, bytes.substr(0, pixels + 8) + U32Le(10) + std::string(10, '\0'));
  st = ReadToEnd(root + "/cut");
  EXPECT_TRUE(absl::IsDataLoss(st)) << st;
  EXPECT_TRUE(absl::StrContains(
      st.message(),
      absl::StrCat(cut, ": pixel data holds 10 bytes, the image needs ", info.slice_bytes())))
      << st;
}

// A GDCM-written explicit VR little endian file rewritten as Deflated Explicit VR Little
// Endian (1.2.840.10008.1.2.1.99): the meta group's transfer syntax (and group length)
// changed, the data set after it deflated (raw deflate, PS3.5 A.5).
void Deflate(const std::string& file) {
  std::string bytes = Slurp(file);
  uint32_t group = 0;
  std::memcpy(&group, bytes.data() + 140, 4);  // (0002,0000) after the preamble and "DICM"
  const size_t data_set = 144 + group;
  const std::string ts = std::string("\x02\x00\x10\x00UI", 6);
  const size_t at = bytes.find(ts);
  ASSERT_LT(at, data_set);
  uint16_t len = 0;
  std::memcpy(&len, bytes.data() + at + 6, 2);
  const std::string uid("1.2.840.10008.1.2.1.99", 22);
  std::string meta = bytes.substr(0, data_set);
  meta.replace(at + 6, 2 + len, std::string("\x16\x00", 2) + uid);
  const uint32_t new_group = group + 22 - len;
  std::memcpy(meta.data() + 140, &new_group, 4);
  z_stream zs{};
  ASSERT_EQ(deflateInit2(&zs, 6, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY), Z_OK);
  std::string raw = bytes.substr(data_set), out(deflateBound(&zs, raw.size()), '\0');
  zs.next_in = reinterpret_cast<Bytef*>(raw.data());
  zs.avail_in = static_cast<uInt>(raw.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  ASSERT_EQ(deflate(&zs, Z_FINISH), Z_STREAM_END);
  out.resize(zs.total_out);
  deflateEnd(&zs);
  Spit(file, meta + out);
}

// A deflated data set is walked inflated, with the same bounds.
TEST(DicomSeries, DeflatedDataSetsAreBoundedToo) {
  const std::string root = testing::MakeTempDir();
  const VolumeInfo info = Grid(DType::kInt16);
  const std::string dir = WriteSeries(root + "/s", info);
  Deflate(dir + "/IM00003.dcm");
  EXPECT_TRUE(absl::IsOutOfRange(ReadToEnd(dir))) << ReadToEnd(dir);
  InsertBeforePixels(dir + "/IM00005.dcm", NestedSequences(4000, true));
  Deflate(dir + "/IM00005.dcm");
  const absl::Status st = ReadToEnd(dir);
  EXPECT_TRUE(absl::StrContains(st.message(), dir + "/IM00005.dcm: sequences nested more than 32"))
      << st;
}

// What no check can foresee costs the reader process, not the program: a crash, a hang
// (stopped at the time limit) and an allocation without bound each give an error, and the
// next series reads with a fresh process.
TEST(DicomReaderProcess, CrashHangAndRunawayMemoryCostTheReaderNotTheProgram) {
  const std::string dir = WriteSeries(testing::MakeTempDir() + "/s", Grid(DType::kUInt16));
  EXPECT_TRUE(absl::IsOutOfRange(ReadToEnd(dir)));
  absl::Status st = io::dicom::testing::Misbehave(1);
  EXPECT_TRUE(absl::StrContains(st.message(), "the DICOM reader process died reading this file"))
      << st;
  EXPECT_TRUE(absl::StrContains(st.message(), "signal 11")) << st;
  EXPECT_TRUE(absl::IsOutOfRange(ReadToEnd(dir)));

  io::dicom::testing::SetTimeLimit(0.5);
  const auto t0 = std::chrono::steady_clock::now();
  st = io::dicom::testing::Misbehave(2);
  io::dicom::testing::SetTimeLimit(0);
  EXPECT_LT(SecondsSince(t0), 5.0);
  EXPECT_TRUE(absl::StrContains(st.message(), "took more than 0.5 s on this file and was stopped"))
      << st;
  EXPECT_TRUE(absl::IsOutOfRange(ReadToEnd(dir)));

#ifndef TANDEM_TEST_ASAN
  st = io::dicom::testing::Misbehave(3);  // the address-space limit (not set under ASan)
  EXPECT_TRUE(absl::IsResourceExhausted(st)) << st;
  EXPECT_TRUE(absl::IsOutOfRange(ReadToEnd(dir)));
#endif
}

// Files that trip assertions inside Debian's GDCM (built with them on; found by fuzz_dicom)
// are an error naming the file, not an abort of the process. Each input is the fuzzer's
// [u32 LE size of a][a][b].
TEST(DicomSeries, FilesThatTripGdcmAssertionsAreErrorsNotAborts) {
  int n = 0;
  for (const auto& e : fs::directory_iterator(TANDEM_FUZZ_CRASHES "/fuzz_dicom")) {
    std::ifstream in(e.path(), std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ASSERT_GE(bytes.size(), 4u);
    uint32_t a = 0;
    std::memcpy(&a, bytes.data(), 4);
    a = std::min<uint32_t>(a, static_cast<uint32_t>(bytes.size() - 4));
    const std::string dir = testing::MakeTempDir();
    std::ofstream(dir + "/a", std::ios::binary) << bytes.substr(4, a);
    std::ofstream(dir + "/b", std::ios::binary) << bytes.substr(4 + a);
    auto src = io::OpenVolume(dir);
    absl::Status st = src.status();
    if (src.ok()) {
      std::vector<uint8_t> slice;
      while ((st = (*src)->ReadSlice(&slice)).ok()) {
      }
    }
    EXPECT_FALSE(absl::IsOutOfRange(st)) << e.path();
    EXPECT_TRUE(absl::StrContains(st.message(), dir)) << st;
    ++n;
  }
  EXPECT_GE(n, 1);
}

TEST(Directions, TheSidecarCarriesThemAndTheMeshMovesExactly) {
  const std::string root = testing::MakeTempDir();
  const HeldVolume held = HeldLink(30, 28, 26, {0.5, 0.5, 0.5});
  const VolumeInfo info = held.info;
  const io::SliceFn fn = held.fn();
  ASSERT_TRUE(io::WriteVolume(root + "/plain.json", info, fn).ok());
  VolumeInfo turned = info;
  turned.directions = {{{0, 0, 1}, {1, 0, 0}, {0, 1, 0}}};  // a cyclic permutation: exact
  ASSERT_TRUE(io::WriteVolume(root + "/turned.json", turned, fn).ok());
  auto plain = io::OpenVolume(root + "/plain.json");
  auto moved = io::OpenVolume(root + "/turned.json");
  ASSERT_TRUE(plain.ok() && moved.ok());
  EXPECT_EQ((*moved)->info().directions, turned.directions);
  SessionOptions o;
  o.iso = 0;
  o.error = 0.05;
  auto a = io::RunSession(**plain, o);
  auto b = io::RunSession(**moved, o);
  ASSERT_TRUE(a.ok() && b.ok());
  const IndexedMesh ma = (*a)->Snapshot(), mb = (*b)->Snapshot();
  ASSERT_EQ(ma.indices, mb.indices);
  for (size_t i = 0; i < ma.positions.size(); ++i) {
    const Vec3 p = ma.positions[i];
    ASSERT_EQ(mb.positions[i], (Vec3{p.y, p.z, p.x})) << i;
  }
  // NRRD "space directions" carry the same frame (and a mirrored one flips the winding).
  for (const char* ext : {".nrrd", ".nhdr"}) {
    SCOPED_TRACE(ext);
    ASSERT_TRUE(io::WriteVolume(root + "/turned" + ext, turned, fn).ok());
    auto nrrd = io::OpenVolume(root + "/turned" + ext);
    ASSERT_TRUE(nrrd.ok()) << nrrd.status();
    EXPECT_EQ((*nrrd)->info().directions, turned.directions);
    auto c = io::RunSession(**nrrd, o);
    ASSERT_TRUE(c.ok());
    const IndexedMesh mc = (*c)->Snapshot();
    EXPECT_EQ(mc.indices, mb.indices);
    EXPECT_EQ(mc.positions, mb.positions);
  }
  // A sidecar with sheared or malformed directions is refused, naming the key.
  std::ofstream(root + "/bad.json") << R"({"dims": [30, 28, 26], "dtype": "float32",
      "raw_file": "plain.raw", "directions": [[1, 0, 0], [1, 1, 0], [0, 0, 1]]})";
  auto bad = io::OpenVolume(root + "/bad.json");
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(absl::StrContains(bad.status().message(), "orthonormal")) << bad.status();
  std::ofstream(root + "/bad2.json") << R"({"dims": [30, 28, 26], "dtype": "float32",
      "raw_file": "plain.raw", "directions": [1, 0, 0]})";
  auto bad2 = io::OpenVolume(root + "/bad2.json");
  ASSERT_FALSE(bad2.ok());
  EXPECT_TRUE(absl::StrContains(bad2.status().message(), "directions")) << bad2.status();
}

// NIfTI: the sform (else the qform, through nifticlib's quaternion) places the grid; a flip
// puts the mesh where the image is (a negative x step from x = 90 covers 90 down to 90 -
// (nx-1) sx, not 90 up), a rotation turns it.
TEST(Directions, NiftiSformAndQformPlaceTheMesh) {
  const std::string root = testing::MakeTempDir();
  const HeldVolume held = HeldLink(30, 28, 26, {0.5, 0.5, 0.5});
  const VolumeInfo info = held.info;
  const io::SliceFn fn = held.fn();
  SessionOptions o;
  o.iso = 0;
  o.error = 0.05;
  auto mesh_of = [&](const std::string& path) {
    auto src = io::OpenVolume(path);
    EXPECT_TRUE(src.ok()) << src.status();
    auto run = io::RunSession(**src, o);
    EXPECT_TRUE(run.ok());
    return (*run)->Snapshot();
  };
  ASSERT_TRUE(io::WriteVolume(root + "/plain.json", info, fn).ok());
  const IndexedMesh plain = mesh_of(root + "/plain.json");
  struct Case {
    std::array<double, 3> origin;
    std::array<std::array<double, 3>, 3> d;
  };
  const double c = std::sqrt(0.5);
  const Case cases[] = {{{90, -126, -72}, {{{-1, 0, 0}, {0, 1, 0}, {0, 0, 1}}}},  // LAS storage
                        {{10, 20, 30}, {{{c, c, 0}, {-c, c, 0}, {0, 0, 1}}}}};
  for (const Case& k : cases) {
    VolumeInfo moved = info;
    moved.origin = k.origin;
    moved.directions = k.d;
    const std::string nii = root + "/m.nii";
    ASSERT_TRUE(io::WriteVolume(nii, moved, fn).ok());
    auto src = io::OpenVolume(nii);
    ASSERT_TRUE(src.ok()) << src.status();
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) EXPECT_NEAR((*src)->info().directions[a][b], k.d[a][b], 1e-6);
      EXPECT_NEAR((*src)->info().spacing[a], 0.5, 1e-6);
    }
    // Expected: the plain mesh moved into the frame.
    IndexedMesh want = plain;
    for (Vec3& p : want.positions) {
      Vec3 q{k.origin[0], k.origin[1], k.origin[2]};
      for (int a = 0; a < 3; ++a) q = q + Vec3{k.d[a][0], k.d[a][1], k.d[a][2]} * p[a];
      p = q;
    }
    const Vec3 d0{k.d[0][0], k.d[0][1], k.d[0][2]}, d1{k.d[1][0], k.d[1][1], k.d[1][2]},
        d2{k.d[2][0], k.d[2][1], k.d[2][2]};
    if (Dot(Cross(d0, d1), d2) < 0) {  // a mirror keeps normals outward by a reversed winding
      for (size_t t = 0; t < want.indices.size(); t += 3) {
        std::swap(want.indices[t + 1], want.indices[t + 2]);
      }
    }
    for (bool qform_only : {false, true}) {
      SCOPED_TRACE(qform_only ? "qform" : "sform");
      if (qform_only) {  // sform_code (byte 254) = 0: the quaternion alone
        std::fstream f(nii, std::ios::in | std::ios::out | std::ios::binary);
        f.seekp(254);
        const char zero[2] = {0, 0};
        f.write(zero, 2);
      }
      const IndexedMesh got = mesh_of(nii);
      ASSERT_EQ(got.indices, want.indices);
      for (size_t i = 0; i < got.positions.size(); ++i) {
        for (int a = 0; a < 3; ++a) ASSERT_NEAR(got.positions[i][a], want.positions[i][a], 2e-5);
      }
    }
  }
  // The flipped case lands at x in [90 - 29 * 0.5, 90].
  const IndexedMesh flipped = [&] {
    VolumeInfo moved = info;
    moved.origin = cases[0].origin;
    moved.directions = cases[0].d;
    EXPECT_TRUE(io::WriteVolume(root + "/f.nii.gz", moved, fn).ok());
    return mesh_of(root + "/f.nii.gz");
  }();
  for (const Vec3& p : flipped.positions) {
    ASSERT_LE(p.x, 90.0 + 1e-4);
    ASSERT_GE(p.x, 90.0 - 29 * 0.5 - 1e-4);
  }
}

TEST(Directions, MustBeOrthonormal) {
  VolumeInfo info = Grid(DType::kUInt8);
  info.directions = {{{1, 0, 0}, {0.5, 1, 0}, {0, 0, 1}}};
  absl::Status st = ValidateVolumeInfo(info);
  EXPECT_FALSE(st.ok());
  EXPECT_TRUE(absl::StrContains(st.message(), "orthonormal")) << st;
  info.directions[1] = {0, std::nan(""), 0};
  EXPECT_FALSE(ValidateVolumeInfo(info).ok());
  info.directions = {{{0, 0, 1}, {1, 0, 0}, {0, 1, 0}}};
  EXPECT_TRUE(ValidateVolumeInfo(info).ok());
}

TEST(TiffSequence, RoundTripsEveryTypeInNaturalOrder) {
  for (DType t : {DType::kUInt8, DType::kUInt16, DType::kInt16, DType::kFloat32}) {
    SCOPED_TRACE(DTypeName(t));
    const std::string dir = testing::MakeTempDir() + "/seq";
    VolumeInfo info = Grid(t, 37, 21, 12);
    ASSERT_TRUE(io::WriteTiffSequence(dir, info, PatternSlices(info)).ok());
    // Unpadded numbers, as some reconstruction tools write: s2 must come before s10.
    for (int64_t z = 0; z < info.nz; ++z) {
      char name[32];
      std::snprintf(name, sizeof(name), "slice_%05lld.tif", static_cast<long long>(z));
      fs::rename(fs::path(dir) / name, fs::path(dir) / absl::StrCat("recon_", z, ".tif"));
    }
    auto src = io::OpenVolume(dir);
    ASSERT_TRUE(src.ok()) << src.status();
    const VolumeInfo& got = (*src)->info();
    EXPECT_EQ(got.nz, info.nz);
    EXPECT_EQ(got.dtype, t);
    for (int a = 0; a < 3; ++a) {
      EXPECT_NEAR(got.spacing[a], info.spacing[a], 1e-6) << a;
      EXPECT_NEAR(got.origin[a], info.origin[a], 1e-6) << a;
    }
    ExpectVoxels(**src, [&](int64_t i, int64_t j, int64_t k) {
      return static_cast<float>(PatternValue(t, i, j, k));
    });
  }
}

TEST(TiffSequence, ResolutionInCentimetresGivesMillimetres) {
  // A plain TIFF (no ImageJ description) with XResolution 200 per cm = 0.05 mm pixels.
  const std::string dir = testing::MakeTempDir();
  for (int z = 0; z < 3; ++z) {
    TIFF* tif = TIFFOpen((dir + "/img" + std::to_string(z) + ".tiff").c_str(), "w");
    ASSERT_NE(tif, nullptr);
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 8u);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 4u);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, uint16_t{16});
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, uint16_t{1});
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 4u);
    TIFFSetField(tif, TIFFTAG_RESOLUTIONUNIT, RESUNIT_CENTIMETER);
    TIFFSetField(tif, TIFFTAG_XRESOLUTION, 200.0f);
    TIFFSetField(tif, TIFFTAG_YRESOLUTION, 200.0f);
    std::vector<uint16_t> px(32, static_cast<uint16_t>(1000 * z));
    ASSERT_EQ(TIFFWriteEncodedStrip(tif, 0, px.data(), 64), 64);
    TIFFClose(tif);
  }
  auto src = io::OpenVolume(dir);
  ASSERT_TRUE(src.ok()) << src.status();
  const VolumeInfo& got = (*src)->info();
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(got.spacing[a], 0.05, 1e-6) << a;
  ExpectVoxels(**src, [](int64_t, int64_t, int64_t k) { return 1000.0 * k; });
}

TEST(TiffSequence, MixedSizesAndStacksAreRefusedNamingTheFile) {
  const std::string dir = testing::MakeTempDir();
  VolumeInfo info = Grid(DType::kUInt16, 16, 8, 4);
  ASSERT_TRUE(io::WriteTiffSequence(dir, info, PatternSlices(info)).ok());
  VolumeInfo other = Grid(DType::kUInt16, 15, 8, 1);
  std::vector<uint8_t> bytes(other.slice_bytes(), 0);
  ASSERT_TRUE(io::WriteTiffSlice(dir + "/slice_00004.tif", other, 0, bytes).ok());
  auto src = io::OpenVolume(dir);
  ASSERT_TRUE(src.ok()) << src.status();  // the header of the first file sets the geometry
  std::vector<uint8_t> out;
  absl::Status st;
  while ((st = (*src)->ReadSlice(&out)).ok()) {
  }
  EXPECT_TRUE(absl::StrContains(st.message(), "slice_00004.tif")) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), "15x8")) << st;
  EXPECT_EQ((*src)->next_slice(), 4);
}

}  // namespace
}  // namespace tandem
