// The sweep's fields not made with the paper's formulas (fields_lib.h): the distance transform
// against brute force and the analytic sphere, the blur's symmetry, the CT-like noise's
// determinism, the files as tandem reads them, and the errors.
#include "fields_lib.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "tandem/io/open_volume.h"
#include "tandem/volume.h"

namespace fields {
namespace {

std::string ReadBytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

TEST(DistanceTest, SquaredDistanceIsExactAgainstBruteForce) {
  const Grid g{11};
  std::vector<uint8_t> feature(g.Size());
  for (size_t i = 0; i < feature.size(); ++i) feature[i] = SplitMix(i) % 97 == 0;
  feature[g.At(10, 0, 5)] = 1;
  const std::vector<float> d = SquaredDistance(g, feature);
  for (int z = 0; z < g.n; ++z)
    for (int y = 0; y < g.n; ++y)
      for (int x = 0; x < g.n; ++x) {
        int best = 1 << 30;
        for (int c = 0; c < g.n; ++c)
          for (int b = 0; b < g.n; ++b)
            for (int a = 0; a < g.n; ++a)
              if (feature[g.At(a, b, c)]) {
                best = std::min(best, (a - x) * (a - x) + (b - y) * (b - y) + (c - z) * (c - z));
              }
        ASSERT_EQ(d[g.At(x, y, z)], float(best)) << x << " " << y << " " << z;
      }
}

TEST(DistanceTest, SphereDistanceIsWithinHalfAVoxelOfTheAnalyticOne) {
  for (int n : {33, 48}) {
    FieldSpec spec{.shape = "sphere", .kind = "sdf", .size = n};
    auto f = MakeField(spec);
    ASSERT_TRUE(f.ok()) << f.status();
    const Grid g{n};
    const double c = 0.5 * (n - 1), radius = 0.8 * c;  // tandem generate's sphere
    double worst = 0;
    for (int z = 0; z < n; ++z)
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
          const double r = std::sqrt((x - c) * (x - c) + (y - c) * (y - c) + (z - c) * (z - c));
          worst = std::max(worst, std::abs(f->values[g.At(x, y, z)] - (r - radius)));
        }
    EXPECT_LE(worst, 0.5) << "size " << n;
    EXPECT_GT(worst, 0.05) << "size " << n << ": a mask's distance is not the analytic one";
    EXPECT_EQ(f->iso, 0);
  }
}

TEST(DistanceTest, SignFollowsTheMaskForTheLink) {
  const Grid g{40};
  auto inside = ShapeMask("link", g);
  ASSERT_TRUE(inside.ok());
  auto f = MakeField({.shape = "link", .kind = "sdf", .size = 40});
  ASSERT_TRUE(f.ok());
  size_t in = 0;
  for (size_t i = 0; i < g.Size(); ++i) {
    ASSERT_EQ(f->values[i] < 0, bool((*inside)[i])) << i;
    ASSERT_GE(std::abs(f->values[i]), 0.5f) << i;  // the nearest other side is a voxel away
    in += (*inside)[i];
  }
  EXPECT_GT(in, 1000u);
}

TEST(BlurTest, SmoothedMaskIsSymmetricAndCrossesHalfAtTheSurface) {
  const int n = 36;
  const Grid g{n};
  for (const char* shape : {"sphere", "pillowbox"}) {
    auto f = MakeField({.shape = shape, .kind = "mask", .size = n});
    ASSERT_TRUE(f.ok()) << f.status();
    EXPECT_EQ(f->iso, 0.5);
    const std::vector<float>& v = f->values;
    for (int z = 0; z < n; ++z)
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
          const float a = v[g.At(x, y, z)];
          // Reflections are exact (the blur sums mirrored pairs first)...
          ASSERT_EQ(a, v[g.At(n - 1 - x, y, z)]) << shape << " " << x << " " << y << " " << z;
          ASSERT_EQ(a, v[g.At(x, n - 1 - y, z)]) << shape;
          ASSERT_EQ(a, v[g.At(x, y, n - 1 - z)]) << shape;
          // ...swapping axes changes only the order of the passes.
          ASSERT_NEAR(a, v[g.At(y, x, z)], 1e-6) << shape;
          ASSERT_NEAR(a, v[g.At(z, y, x)], 1e-6) << shape;
          ASSERT_GE(a, 0.0f);
          ASSERT_LE(a, 1.0f + 1e-6f);
        }
    EXPECT_GT(v[g.At(n / 2, n / 2, n / 2)], 0.99f);
    EXPECT_LT(v[g.At(0, 0, 0)], 0.01f);
  }
  // On the sphere's axis the blurred mask crosses 0.5 within a voxel of the radius.
  auto f = MakeField({.shape = "sphere", .kind = "mask", .size = n});
  const double c = 0.5 * (n - 1), radius = 0.8 * c;
  int cross = -1;
  for (int x = n / 2; x < n - 1; ++x) {
    if (f->values[g.At(x, n / 2, n / 2)] >= 0.5f && f->values[g.At(x + 1, n / 2, n / 2)] < 0.5f) {
      cross = x;
    }
  }
  EXPECT_NEAR(cross + 0.5, c + radius, 1.0);
}

TEST(CtTest, SameSeedSameBytesAnotherSeedOtherNoise) {
  const std::string dir = ::testing::TempDir() + "/fields_lib_test";
  std::filesystem::create_directories(dir);
  const FieldSpec spec{.shape = "pillowbox", .kind = "ct", .size = 24, .seed = 7};
  FieldSpec other = spec;
  other.seed = 8;
  for (const auto& [name, s] : {std::pair{"a", spec}, {"b", spec}, {"c", other}}) {
    auto f = MakeField(s);
    ASSERT_TRUE(f.ok()) << f.status();
    ASSERT_TRUE(WriteField(dir + "/" + name + ".json", s, *f).ok());
  }
  const std::string a = ReadBytes(dir + "/a.raw");
  ASSERT_EQ(a.size(), 24u * 24 * 24 * sizeof(float));
  EXPECT_EQ(a, ReadBytes(dir + "/b.raw"));
  std::string b_json = ReadBytes(dir + "/b.json");  // the same but for its raw file's name
  b_json.replace(b_json.find("\"b.raw\""), 7, "\"a.raw\"");
  EXPECT_EQ(ReadBytes(dir + "/a.json"), b_json);
  EXPECT_NE(a, ReadBytes(dir + "/c.raw"));
  // The noise is white with the asked-for standard deviation: the field less its noise-free one.
  auto f = MakeField(spec);
  FieldSpec quiet = spec;
  quiet.noise = 0;
  auto clean = MakeField(quiet);
  double sum = 0, sum2 = 0, lag1 = 0;
  const size_t n = f->values.size();
  for (size_t i = 0; i < n; ++i) {
    const double e = f->values[i] - clean->values[i];
    sum += e;
    sum2 += e * e;
    if (i > 0) lag1 += e * (f->values[i - 1] - clean->values[i - 1]);
  }
  EXPECT_NEAR(sum / n, 0, 2);
  EXPECT_NEAR(std::sqrt(sum2 / n), 40, 1);
  EXPECT_NEAR(lag1 / sum2, 0, 0.05);
  EXPECT_EQ(clean->values[0], -1000.0f);
  EXPECT_EQ(f->iso, -300);
}

TEST(FileTest, TandemReadsTheFieldWithItsIsoValue) {
  const std::string dir = ::testing::TempDir() + "/fields_lib_test";
  std::filesystem::create_directories(dir);
  const FieldSpec spec{.shape = "roundcube", .kind = "field", .size = 16};
  auto f = MakeField(spec);
  ASSERT_TRUE(f.ok());
  EXPECT_FLOAT_EQ(f->values[Grid{16}.At(0, 7, 7)], float(RoundCube(16, 0, 7, 7)));
  for (const char* ext : {".json", ".nrrd"}) {
    const std::string path = dir + "/roundcube" + ext;
    ASSERT_TRUE(WriteField(path, spec, *f).ok());
    auto vol = tandem::io::OpenVolume(path);
    ASSERT_TRUE(vol.ok()) << vol.status();
    const tandem::VolumeInfo& info = (*vol)->info();
    EXPECT_EQ(info.nx, 16);
    EXPECT_EQ(info.nz, 16);
    EXPECT_EQ(info.dtype, tandem::DType::kFloat32);
    EXPECT_EQ(info.suggested_isovalues, std::vector<double>{0.0});
  }
}

TEST(ErrorTest, BadSpecsNameTheCulprit) {
  auto f = MakeField({.shape = "gyroid", .kind = "sdf", .size = 16});
  EXPECT_NE(f.status().message().find("unknown shape 'gyroid'"), std::string::npos);
  f = MakeField({.shape = "sphere", .kind = "blur", .size = 16});
  EXPECT_NE(f.status().message().find("unknown kind 'blur'"), std::string::npos);
  f = MakeField({.shape = "sphere", .kind = "field", .size = 16});
  EXPECT_NE(f.status().message().find("rounded cube's formula only"), std::string::npos);
  f = MakeField({.shape = "sphere", .kind = "sdf", .size = 4});
  EXPECT_NE(f.status().message().find("size 4 is outside"), std::string::npos);
  f = MakeField({.shape = "sphere", .kind = "mask", .size = 16, .sigma = -1});
  EXPECT_NE(f.status().message().find("sigma"), std::string::npos);
}

}  // namespace
}  // namespace fields
