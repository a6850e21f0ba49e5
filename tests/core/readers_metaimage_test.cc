// ITK MetaImage (.mha / .mhd): round trips through tandem's writer, every header variant
// real files use written by hand (HeaderSize, CompressedData, byte order, the key synonyms,
// a detached data file), bad headers refused by name, and files written and read by ITK
// itself (its MetaImageIO: the direction convention, when libinsighttoolkit5-dev is there).
#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "tandem/io/open_volume.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"
#include "testutil/testutil.h"

#ifdef TANDEM_HAVE_ITK
#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkImageFileWriter.h>
#include <itkImageRegionIterator.h>
#include <itkMetaImageIO.h>
#endif

namespace tandem {
namespace {

namespace fs = std::filesystem;
using testing::PatternSlices;
using testing::PatternValue;
constexpr auto Load = testing::LoadValue;

VolumeInfo Grid(DType t) {
  VolumeInfo info;
  info.nx = 13;
  info.ny = 7;
  info.nz = 5;
  info.dtype = t;
  info.spacing = {0.5, 0.75, 2.5};
  info.origin = {-10.5, 3.25, 100.0};
  return info;
}

// Every voxel of src equals the readers' test pattern of its type.
void ExpectPattern(SliceSource& src) {
  const VolumeInfo& info = src.info();
  std::vector<uint8_t> bytes;
  const size_t es = DTypeSize(info.dtype);
  for (int64_t k = 0; k < info.nz; ++k) {
    ASSERT_TRUE(src.ReadSlice(&bytes).ok()) << k;
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        ASSERT_EQ(Load(info.dtype, bytes.data() + (j * info.nx + i) * es),
                  static_cast<double>(static_cast<float>(PatternValue(info.dtype, i, j, k))))
            << i << "," << j << "," << k;
      }
    }
  }
  EXPECT_TRUE(absl::IsOutOfRange(src.ReadSlice(&bytes)));
}

// path opens with info's type and geometry, and every voxel is the pattern's.
void ExpectVolume(const std::string& path, const VolumeInfo& info) {
  auto src = io::OpenVolume(path);
  ASSERT_TRUE(src.ok()) << src.status();
  const VolumeInfo& got = (*src)->info();
  EXPECT_EQ(got.dtype, info.dtype);
  EXPECT_EQ(got.spacing, info.spacing);
  EXPECT_EQ(got.origin, info.origin);
  EXPECT_EQ(got.directions, info.directions);
  EXPECT_EQ(got.frame, "MetaImage physical space (ITK's LPS)");
  EXPECT_EQ(got.suggested_isovalues, info.suggested_isovalues);
  ExpectPattern(**src);
}

// The pattern's voxels as stored: every slice, in the given byte order.
std::string PatternBytes(const VolumeInfo& info, bool big_endian) {
  std::string out;
  std::vector<uint8_t> slice;
  const io::SliceFn fn = PatternSlices(info);
  const size_t es = DTypeSize(info.dtype);
  for (int64_t z = 0; z < info.nz; ++z) {
    EXPECT_TRUE(fn(z, &slice).ok());
    if (big_endian) {
      for (size_t i = 0; i < slice.size(); i += es) std::reverse(&slice[i], &slice[i] + es);
    }
    out.append(reinterpret_cast<const char*>(slice.data()), slice.size());
  }
  return out;
}

void Spit(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

std::string Zlib(const std::string& raw) {
  uLongf n = compressBound(static_cast<uLong>(raw.size()));
  std::string out(n, '\0');
  EXPECT_EQ(
      compress2(reinterpret_cast<Bytef*>(out.data()), &n,
                reinterpret_cast<const Bytef*>(raw.data()), static_cast<uLong>(raw.size()), 6),
      Z_OK);
  out.resize(n);
  return out;
}

TEST(MetaImage, RoundTripsEveryTypeBothFormsAndByteOrders) {
  const std::string dir = testing::MakeTempDir();
  for (DType t : {DType::kUInt8, DType::kUInt16, DType::kInt16, DType::kFloat32}) {
    for (const char* ext : {".mha", ".mhd"}) {
      for (bool big : {false, true}) {
        const std::string name(DTypeName(t));
        SCOPED_TRACE(absl::StrCat(name, ext, big ? " big" : " little"));
        VolumeInfo info = Grid(t);
        const double c = std::sqrt(0.5);
        info.directions = {{{c, c, 0}, {-c, c, 0}, {0, 0, -1}}};  // rotated and flipped
        info.suggested_isovalues = {12.5, -3};
        const std::string path = absl::StrCat(dir, "/v", name, big, ext);
        io::VolumeWriteOptions o;
        o.big_endian = big;
        ASSERT_TRUE(io::WriteVolume(path, info, PatternSlices(info), o).ok());
        if (std::string(ext) == ".mhd") {
          EXPECT_TRUE(fs::exists(path.substr(0, path.size() - 4) + ".raw"));
        }
        ExpectVolume(path, info);
      }
    }
  }
  io::VolumeWriteOptions gzip;
  gzip.gzip = true;
  absl::Status gz = io::WriteVolume(dir + "/c.mha", Grid(DType::kUInt8),
                                    PatternSlices(Grid(DType::kUInt8)), gzip);
  EXPECT_TRUE(absl::StrContains(gz.message(), "MetaImage is written uncompressed")) << gz;
}

// The header variants of MetaIO and the programs that write it, each written by hand.
TEST(MetaImage, ReadsEveryHeaderVariantRealFilesUse) {
  const std::string dir = testing::MakeTempDir();
  const VolumeInfo info = Grid(DType::kInt16);
  const std::string little = PatternBytes(info, false), big = PatternBytes(info, true);
  const std::string common = "ObjectType = Image\nNDims = 3\nDimSize = 13 7 5\n";
  struct Case {
    std::string name, header, data;
    std::string raw_name = "", raw = "";  // a detached data file
  };
  const std::string z = Zlib(little);
  const std::vector<Case> cases = {
      {"synonyms.mha",
       common + "ElementType = MET_SHORT\nElementSize = 0.5 0.75 2.5\nPosition = -10.5 3.25 100\n"
                "Rotation = 1 0 0 0 1 0 0 0 1\nElementDataFile = LOCAL\n",
       little},
      {"msb.mha",
       common + "ElementByteOrderMSB = True\nElementSpacing = 0.5 0.75 2.5\nOrigin = -10.5 3.25 "
                "100\nElementType = MET_SHORT\nElementDataFile = LOCAL\n",
       big},
      {"zlib.mha",
       common + "CompressedData = True\nCompressedDataSize = " + std::to_string(z.size()) +
           "\nElementSpacing = 0.5 0.75 2.5\nOffset = -10.5 3.25 100\nElementType = "
           "MET_SHORT\nElementDataFile = LOCAL\n",
       z},
      {"tail.mhd",
       common + "HeaderSize = -1\nElementSpacing = 0.5 0.75 2.5\nOffset = -10.5 3.25 100\n"
                "ElementType = MET_SHORT\nElementDataFile = tail.raw\n",
       "", "tail.raw", std::string(123, 'x') + little},
      {"skip.mhd",
       common + "HeaderSize = 64\nBinaryDataByteOrderMSB = False\nElementSpacing = 0.5 0.75 "
                "2.5\nOffset = -10.5 3.25 100\nAnatomicalOrientation = RAI\nElementType = "
                "MET_SHORT\nElementDataFile = data/skip.img\n",
       "", "data/skip.img", std::string(64, '\0') + little},
      {"zlib.mhd",
       common + "CompressedData = True\nElementSpacing = 0.5 0.75 2.5\nOffset = -10.5 3.25 100\n"
                "ElementType = MET_SHORT\nElementDataFile = zlib.zraw\n",
       "", "zlib.zraw", z},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    Spit(dir + "/" + c.name, c.header + c.data);
    if (!c.raw_name.empty()) {
      fs::create_directories(fs::path(dir + "/" + c.raw_name).parent_path());
      Spit(dir + "/" + c.raw_name, c.raw);
    }
    auto src = io::OpenVolume(dir + "/" + c.name);
    ASSERT_TRUE(src.ok()) << src.status();
    EXPECT_EQ((*src)->info().spacing, info.spacing);
    EXPECT_EQ((*src)->info().origin, info.origin);
    ExpectPattern(**src);
  }
  auto oriented = io::OpenVolume(dir + "/skip.mhd");
  ASSERT_TRUE(oriented.ok());
  EXPECT_TRUE(absl::StrContains((*oriented)->info().description, "AnatomicalOrientation RAI"));
}

TEST(MetaImage, BadHeadersAndDataAreRefusedByName) {
  const std::string dir = testing::MakeTempDir();
  const VolumeInfo info = Grid(DType::kUInt8);
  const std::string data = PatternBytes(info, false);
  const std::string ok = "NDims = 3\nDimSize = 13 7 5\nElementType = MET_UCHAR\n";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"NDims = 2\nDimSize = 13 7\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n",
       "NDims = 2: only 3-D images are read"},
      {"NDims = 3\nDimSize = 13 7 5\nElementType = MET_DOUBLE\nElementDataFile = LOCAL\n",
       "ElementType MET_DOUBLE is not supported"},
      {ok + "ElementNumberOfChannels = 3\nElementDataFile = LOCAL\n", "only one channel"},
      {"NDims = 3\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", "missing DimSize"},
      {ok + "ElementDataFile = LIST\n", "only LOCAL or one data file"},
      {ok + "ObjectType = Mesh\nElementDataFile = LOCAL\n", "only Image is supported"},
      {ok + "BinaryData = False\nElementDataFile = LOCAL\n", "text voxels"},
      {ok + "ElementSpacing = 1 1\nElementDataFile = LOCAL\n", "\"ElementSpacing\" needs 3 values"},
      {ok + "TransformMatrix = 1 0 0 1 0 0 0 0 1\nElementDataFile = LOCAL\n", "orthonormal"},
      {ok + "CompressedData = Maybe\nElementDataFile = LOCAL\n", "expected True or False"},
      {ok + "HeaderSize = -2\nElementDataFile = LOCAL\n", "HeaderSize = -2"},
      {ok, "no ElementDataFile line"},
      {"this is not a header\n", "not a MetaImage header line"},
  };
  for (const auto& [header, words] : cases) {
    const std::string path = dir + "/bad.mha";
    Spit(path, header + data);
    absl::Status st = io::OpenVolume(path).status();
    EXPECT_TRUE(absl::StrContains(st.message(), path + ": ")) << st;
    EXPECT_TRUE(absl::StrContains(st.message(), words)) << words << ": " << st;
  }
  // Data: cut short, and a corrupt zlib stream (found while reading).
  Spit(dir + "/cut.mha", ok + "ElementDataFile = LOCAL\n" + data.substr(0, 100));
  absl::Status cut = io::OpenVolume(dir + "/cut.mha").status();
  EXPECT_TRUE(absl::IsDataLoss(cut)) << cut;
  EXPECT_TRUE(absl::StrContains(cut.message(), "truncated")) << cut;
  Spit(dir + "/zbad.mha", ok + "CompressedData = True\nElementDataFile = LOCAL\n" +
                              Zlib(data).substr(0, 40) + std::string(200, 'q'));
  auto zbad = io::OpenVolume(dir + "/zbad.mha");
  ASSERT_TRUE(zbad.ok()) << zbad.status();
  std::vector<uint8_t> slice;
  absl::Status st;
  while ((st = (*zbad)->ReadSlice(&slice)).ok()) {
  }
  EXPECT_TRUE(absl::IsDataLoss(st)) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), dir + "/zbad.mha")) << st;
}

#ifdef TANDEM_HAVE_ITK
using Image3 = itk::Image<float, 3>;

// An ITK image of the pattern (as float), with spacing, origin and a direction matrix D
// whose columns are the grid axes' world directions (not symmetric: a transposed reading
// shows).
template <typename T>
typename itk::Image<T, 3>::Pointer ItkPattern(const VolumeInfo& info) {
  using Image = itk::Image<T, 3>;
  auto image = Image::New();
  typename Image::RegionType region;
  region.SetSize({static_cast<itk::SizeValueType>(info.nx),
                  static_cast<itk::SizeValueType>(info.ny),
                  static_cast<itk::SizeValueType>(info.nz)});
  image->SetRegions(region);
  image->Allocate();
  image->SetSpacing(info.spacing.data());
  image->SetOrigin(info.origin.data());
  typename Image::DirectionType d;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) d(r, c) = info.directions[c][r];  // column c = axis c
  }
  image->SetDirection(d);
  for (itk::ImageRegionIterator<Image> it(image, region); !it.IsAtEnd(); ++it) {
    const auto idx = it.GetIndex();
    it.Set(static_cast<T>(PatternValue(info.dtype, idx[0], idx[1], idx[2])));
  }
  return image;
}

VolumeInfo Rotated(DType t) {
  VolumeInfo info = Grid(t);
  // A rotation about (1, 1, 1) by 120 degrees: x -> y -> z -> x (not symmetric).
  info.directions = {{{0, 1, 0}, {0, 0, 1}, {1, 0, 0}}};
  return info;
}

template <typename T>
void ItkWritesTandemReads(DType t, const std::string& path, bool compress) {
  SCOPED_TRACE(path);
  const VolumeInfo info = Rotated(t);
  using Writer = itk::ImageFileWriter<itk::Image<T, 3>>;
  auto writer = Writer::New();
  writer->SetImageIO(itk::MetaImageIO::New());
  writer->SetFileName(path);
  writer->SetInput(ItkPattern<T>(info));
  writer->SetUseCompression(compress);
  writer->Update();
  ExpectVolume(path, info);
}

// ITK's own MetaImageIO writes every type, both forms, compressed or not, with a rotated
// direction matrix: tandem reads the voxels and the geometry exactly.
TEST(MetaImageItk, TandemReadsWhatItkWrites) {
  const std::string dir = testing::MakeTempDir();
  for (bool compress : {false, true}) {
    for (const char* ext : {".mha", ".mhd"}) {
      const std::string stem = absl::StrCat(dir, "/itk", compress ? "_z" : "");
      ItkWritesTandemReads<uint8_t>(DType::kUInt8, stem + "_u8" + ext, compress);
      ItkWritesTandemReads<uint16_t>(DType::kUInt16, stem + "_u16" + ext, compress);
      ItkWritesTandemReads<int16_t>(DType::kInt16, stem + "_i16" + ext, compress);
      ItkWritesTandemReads<float>(DType::kFloat32, stem + "_f32" + ext, compress);
    }
  }
}

// And ITK reads what tandem writes: the same voxels, spacing, origin and direction matrix.
TEST(MetaImageItk, ItkReadsWhatTandemWrites) {
  const std::string dir = testing::MakeTempDir();
  for (const char* ext : {".mha", ".mhd"}) {
    for (bool big : {false, true}) {
      VolumeInfo info = Rotated(DType::kInt16);
      info.suggested_isovalues = {100};  // tandem's own field: ITK keeps it as metadata
      const std::string path = absl::StrCat(dir, "/t", big, ext);
      io::VolumeWriteOptions o;
      o.big_endian = big;
      ASSERT_TRUE(io::WriteVolume(path, info, PatternSlices(info), o).ok());
      auto reader = itk::ImageFileReader<itk::Image<int16_t, 3>>::New();
      reader->SetImageIO(itk::MetaImageIO::New());
      reader->SetFileName(path);
      reader->Update();
      auto image = reader->GetOutput();
      const auto size = image->GetLargestPossibleRegion().GetSize();
      ASSERT_EQ(size[0], 13u);
      ASSERT_EQ(size[2], 5u);
      for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(image->GetSpacing()[a], info.spacing[a]);
        EXPECT_EQ(image->GetOrigin()[a], info.origin[a]);
        for (int b = 0; b < 3; ++b) EXPECT_EQ(image->GetDirection()(b, a), info.directions[a][b]);
      }
      for (itk::ImageRegionIterator<itk::Image<int16_t, 3>> it(image,
                                                               image->GetLargestPossibleRegion());
           !it.IsAtEnd(); ++it) {
        const auto idx = it.GetIndex();
        ASSERT_EQ(it.Get(), PatternValue(DType::kInt16, idx[0], idx[1], idx[2]));
      }
    }
  }
}
#else
TEST(MetaImageItk, TandemReadsWhatItkWrites) {
  GTEST_SKIP() << "ITK not found at build time (apt-get install libinsighttoolkit5-dev), or "
                  "not a GCC build (Debian's ITK headers accept only GCC)";
}
#endif

}  // namespace
}  // namespace tandem
