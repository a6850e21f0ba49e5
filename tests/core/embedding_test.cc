// Outputs embedded at any iso-value: marching cubes keeps every surface point off the grid
// points (EdgeOffset, tandem/geometry.h), so that where grid values equal the iso-value (an
// integer scan at an integer iso-value) no output has a zero-area triangle or two vertices at
// one position, and welded by position, as STL readers and slicers weld, every output is the
// indexed mesh's manifold with its Euler characteristic.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "engine_testutil.h"
#include "layer_extractor.h"
#include "mesh_store.h"
#include "tandem/geometry.h"
#include "tandem/io/mesh_io.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/run_session.h"
#include "tandem/tandem.h"
#include "tandem/eval/topology.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"
#include "testutil/embedded.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

using testing::AsWritten;
using testing::ExpectEmbedded;
using testing::Phantom;
using testing::QuantisedSource;

// Twice the area over the squared edges, the least of the mesh's triangles.
double LeastAreaRatio(const IndexedMesh& m) {
  double least = 1;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    const Vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
               c = m.positions[m.indices[3 * t + 2]];
    least = std::min(least, Norm(TwiceAreaVector(a, b, c)) / SumSquaredEdges(a, b, c));
  }
  return least;
}

// One cube's surface: its eight corner values (x fastest, then y, then z) at iso 0.
IndexedMesh CubeSurface(const std::array<float, 8>& v, std::array<double, 3> spacing = {1, 1, 1},
                        double reach = 0) {
  MeshStore store;
  ExtractorConfig config{2, 2, 2, spacing, {0, 0, 0}, 0.0};
  config.reach = reach;
  LayerExtractor extractor(config, &store);
  EXPECT_TRUE(extractor.AddSlice(v.data()).ok());
  EXPECT_TRUE(extractor.AddSlice(v.data() + 4).ok());
  extractor.Finish();
  return store.Snapshot();
}

// Every cube whose corners are at, just below or just above the iso-value (3^8 of them),
// and the same with magnitudes 1 and 9 apart (5^8): the surface points stay at least δ off
// the corners, apart as written, and every triangle keeps 0.4 δ of its squared edges or more
// as twice its area, far above the written rule's 2e-6.
TEST(Embedding, EveryCubeOfValuesAtTheIsoKeepsItsPointsApartWithArea) {
  const double delta = EdgeOffset(0, 1);
  for (const std::vector<float>& values :
       {std::vector<float>{-1, 0, 1}, std::vector<float>{-9, -1, 0, 1, 9}}) {
    const int n = static_cast<int>(values.size());
    int cubes = 1;
    for (int c = 0; c < 8; ++c) cubes *= n;
    double least = 1;
    int64_t triangles = 0;
    for (int code = 0; code < cubes; ++code) {
      std::array<float, 8> v;
      for (int c = 0, rest = code; c < 8; ++c, rest /= n) v[c] = values[rest % n];
      const IndexedMesh m = AsWritten(CubeSurface(v));
      triangles += static_cast<int64_t>(m.num_triangles());
      for (const Vec3& p : m.positions) {
        // δ off the corners along its edge: at a corner's coordinate on two axes, δ from it
        // on the third.
        int on_grid = 0;
        double off = 1;
        for (int a = 0; a < 3; ++a) {
          const double d = std::min(std::fabs(p[a]), std::fabs(1 - p[a]));
          if (d == 0) {
            ++on_grid;
          } else {
            off = std::min(off, d);
          }
        }
        if (on_grid == 2) {
          ASSERT_GE(off, delta * (1 - 1e-6)) << "cube " << code;
        }
      }
      ASSERT_EQ(eval::CountDuplicatePositions(m), 0u) << "cube " << code;
      for (size_t t = 0; t < m.num_triangles(); ++t) {
        const Vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
                   c = m.positions[m.indices[3 * t + 2]];
        ASSERT_FALSE(IsWrittenDegenerate(a, b, c)) << "cube " << code << " triangle " << t;
      }
      least = std::min(least, LeastAreaRatio(m));
    }
    EXPECT_GT(triangles, cubes);
    EXPECT_GE(least, 0.4 * delta) << n << " values";
  }
}

// Anisotropic voxels: the offset is δ smallest spacings along every axis, and δ grows with
// the anisotropy A (EdgeOffset), so that twice a triangle's area stays above 0.4 δ / A of its
// squared edges, three times the written rule's 2e-6 or more.
TEST(Embedding, AnisotropicCubesKeepTheirAreasAsWritten) {
  const std::vector<float> values{-9, -1, 0, 1, 9};
  for (std::array<double, 3> spacing :
       {std::array<double, 3>{1, 1, 4}, {1, 3, 10}, {0.5, 0.5, 500}, {1e-3, 1, 1}}) {
    const double smallest = std::min({spacing[0], spacing[1], spacing[2]});
    const double anisotropy = std::max({spacing[0], spacing[1], spacing[2]}) / smallest;
    const double delta = EdgeOffset(0, anisotropy);
    double least = 1;
    for (int code = 0; code < 390625; ++code) {  // 5^8
      std::array<float, 8> v;
      for (int c = 0, rest = code; c < 8; ++c, rest /= 5) v[c] = values[rest % 5];
      least = std::min(least, LeastAreaRatio(AsWritten(CubeSurface(v, spacing))));
    }
    EXPECT_GE(least, 0.4 * delta / anisotropy) << anisotropy;
    EXPECT_GE(least, 3 * 2e-6) << anisotropy;
  }
}

using SourceMaker = std::function<std::unique_ptr<SliceSource>()>;
constexpr int64_t kNx = 96, kNy = 48, kNz = 40;  // two parts' width

struct Mode {
  const char* name;
  Schedule schedule;
  int parts;
  bool seal;
  int64_t target;
};
constexpr Mode kModes[] = {
    {"full resolution", Schedule::kNone, 1, false, 0},
    {"full resolution, 2 parts", Schedule::kNone, 2, false, 0},
    {"full resolution, sealed", Schedule::kNone, 1, true, 0},
    {"simplified", Schedule::kTandemLag, 1, false, 0},
    {"simplified, 2 parts", Schedule::kTandemLag, 2, false, 0},
    {"classical", Schedule::kClassical, 1, false, 0},
    {"sealed", Schedule::kTandemLag, 1, true, 0},
    {"sealed, 2 parts", Schedule::kTandemLag, 2, true, 0},
    {"target 1500", Schedule::kTandemLag, 1, false, 1500},
    {"target 1500, 2 parts", Schedule::kTandemLag, 2, false, 1500},
};

// Runs `mode` over the source at `iso`: every output the session gives (its mesh, or its
// sealed chunks welded by id, and a snapshot halfway, a preview's mesh) is embedded.
void ExpectModeEmbedded(const SourceMaker& make, double iso, const Mode& mode,
                        const std::string& what) {
  std::unique_ptr<SliceSource> src = make();
  SessionOptions o;
  o.iso = iso;
  o.schedule = mode.schedule;
  o.parts = mode.parts;
  o.seal = mode.seal;
  o.target_triangles = mode.target;
  if (mode.schedule != Schedule::kNone) {
    o.error = SessionOptions::kDefaultErrorVoxels *
              std::min({src->info().spacing[0], src->info().spacing[1], src->info().spacing[2]});
  }
  const std::string name = what + ", " + mode.name;
  auto s = TandemSession::Create(src->info(), o);
  ASSERT_TRUE(s.ok()) << name << ": " << s.status();
  ASSERT_EQ((*s)->num_parts(), mode.parts) << name;
  std::vector<SealedChunk> chunks;
  auto take = [&] {
    SealedChunk c;
    while ((*s)->TakeSealed(&c)) chunks.push_back(std::move(c));
  };
  std::vector<uint8_t> bytes;
  while (src->ReadSlice(&bytes).ok()) {
    ASSERT_TRUE((*s)->AddSliceBytes(src->info().dtype, bytes.data()).ok()) << name;
    if (mode.seal) take();
    // A preview's mesh; sealed, the band only.
    if (src->next_slice() == src->info().nz / 2) {
      ExpectEmbedded((*s)->Snapshot(), name + ", halfway", !mode.seal);
    }
  }
  ASSERT_TRUE((*s)->Finish().ok()) << name;
  take();
  const IndexedMesh mesh = mode.seal ? WeldChunks(chunks) : (*s)->Snapshot();
  ASSERT_GT(mesh.num_triangles(), 100u) << name;
  ExpectEmbedded(mesh, name);
}

// Integer volumes at integer iso-values, and float volumes with grid values equal to the
// iso-value, in every mode: full resolution, simplified, split into parts, sealed, to a
// target count.
TEST(Embedding, EveryModeKeepsSheetsApartWhereValuesEqualTheIso) {
  struct Volume {
    std::string name;
    double iso;
    SourceMaker make;
    int64_t hits;  // grid values equal to the iso-value, at least
  };
  const std::vector<Volume> volumes = {
      {"uint8 phantom at 120", 120,
       []() -> std::unique_ptr<SliceSource> {
         return std::make_unique<QuantisedSource>(
             DType::kUInt8, kNx, kNy, kNz,
             [](double i, double j, double k) { return Phantom(kNx, kNy, kNz, i, j, k); });
       },
       300},
      {"int16 phantom at -400", -400,
       []() -> std::unique_ptr<SliceSource> {
         return std::make_unique<QuantisedSource>(
             DType::kInt16, kNx, kNy, kNz, [](double i, double j, double k) {
               return 3 * (Phantom(kNx, kNy, kNz, i, j, k) - 120) - 400;
             });
       },
       100},
      {"float quantised tangle at 4", 4,
       []() -> std::unique_ptr<SliceSource> {
         return std::make_unique<QuantisedSource>(
             DType::kFloat32, kNx, kNy, kNz,
             [](double i, double j, double k) { return QuantisedTangle(2, i, j, k); });
       },
       10000},
  };
  for (const Volume& v : volumes) {
    std::unique_ptr<SliceSource> src = v.make();
    auto* q = static_cast<QuantisedSource*>(src.get());
    int64_t hits = 0;
    for (int64_t k = 0; k < kNz; ++k)
      for (int64_t j = 0; j < kNy; ++j)
        for (int64_t i = 0; i < kNx; ++i) hits += q->Value(i, j, k) == v.iso;
    ASSERT_GE(hits, v.hits) << v.name;  // the case this is about
    for (const Mode& mode : kModes) ExpectModeEmbedded(v.make, v.iso, mode, v.name);
  }
}

// Far from the origin float32 holds fewer digits: 50 m off at 1 mm voxels, a float32 step
// is 4e-3 voxels, four times the floor of the offset, which grows with it (EdgeOffset) so
// that the sheets stay apart as written.
TEST(Embedding, FarFromTheOriginTheOffsetGrowsWithTheFloat32Step) {
  const SourceMaker make = []() -> std::unique_ptr<SliceSource> {
    return std::make_unique<QuantisedSource>(
        DType::kUInt8, kNx, kNy, kNz,
        [](double i, double j, double k) { return Phantom(kNx, kNy, kNz, i, j, k); },
        std::array<double, 3>{1, 1, 1}, std::array<double, 3>{5e4, -4.5e4, 4e4});
  };
  ASSERT_GT(EdgeOffset(5e4, 1), 16 * EdgeOffset(0, 1));
  for (const Mode& mode : kModes) ExpectModeEmbedded(make, 120, mode, "50 m off");
}

// The shared integer scans at the iso-values their users pick (extra coverage: skipped
// without ../shared/data): full resolution, simplified in two parts, sealed in two parts, and
// to a target count.
TEST(Embedding, SharedIntegerScansAtIntegerIsoValues) {
  const struct {
    const char* file;
    std::vector<double> isos;
  } scans[] = {{"ct_engine_256x256x128_uint8.json", {60, 120, 200}},
               {"mr_head_48x62x42_uint8.json", {16, 64}},
               {"mri_avg152T1_91x109x91_uint8.json", {40, 150}},
               {"ct_head_headsq_64x64x93_int16.json", {500, 1150}}};
  const Mode modes[] = {{"full resolution", Schedule::kNone, 1, false, 0},
                        {"simplified, 2 parts", Schedule::kTandemLag, 2, false, 0},
                        {"sealed, 2 parts", Schedule::kTandemLag, 2, true, 0},
                        {"target 5000", Schedule::kTandemLag, 1, false, 5000}};
  for (const auto& scan : scans) {
    TANDEM_SHARED_OR_SKIP(path, scan.file);
    const SourceMaker make = [&path]() -> std::unique_ptr<SliceSource> {
      auto source = io::OpenVolume(path);
      EXPECT_TRUE(source.ok()) << source.status();
      return source.ok() ? *std::move(source) : nullptr;
    };
    for (double iso : scan.isos) {
      for (const Mode& mode : modes) {
        ExpectModeEmbedded(make, iso, mode,
                           std::string(scan.file) + " at " + std::to_string(int(iso)));
      }
    }
  }
}

// Runs the `tandem` executable; false (and the output reported) when it fails.
bool RunTandem(const std::string& args) {
  const std::string command = testing::BinPath("tandem") + " " + args + " 2>&1";
  FILE* p = popen(command.c_str(), "r");
  if (p == nullptr) return false;
  std::string text;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) text.append(buf, n);
  const int status = pclose(p);
  EXPECT_EQ(status, 0) << args << "\n" << text;
  return status == 0;
}

// Every file format the CLI writes, in every mode, read back as its readers read it (PLY
// and OBJ indexed, STL welded by position by its reader, GLB's buffers): no zero-area
// triangle as written, no two vertices at one position, and welded by position the PLY's
// topology. The volume: the uint8 phantom at iso 120, anisotropic, off the origin.
TEST(Embedding, EveryFileFormatWeldsToTheIndexedMesh) {
  const std::string dir = testing::MakeTempDir();
  QuantisedSource phantom(
      DType::kUInt8, kNx, kNy, kNz,
      [](double i, double j, double k) { return Phantom(kNx, kNy, kNz, i, j, k); }, {0.7, 0.7, 1.2},
      {-130.5, 42.25, 300});
  const std::string volume = dir + "/phantom.json";
  ASSERT_TRUE(io::WriteVolume(volume, phantom.info(), [&](int64_t, std::vector<uint8_t>* bytes) {
                return phantom.ReadSlice(bytes);
              }).ok());
  for (const std::string mode : {"--no-simplify", "--no-simplify --seal", "", "--parts 2", "--seal",
                                 "--seal --parts 2", "--target-triangles 1500"}) {
    const std::string run = "extract --input " + volume + " --iso 120 --quiet " + mode;
    for (const char* ext : {"ply", "obj", "stl", "glb"}) {
      ASSERT_TRUE(RunTandem(run + " --out " + dir + "/out." + ext)) << mode;
    }
    const std::string what = "'" + mode + "'";
    auto ply = io::ReadMesh(dir + "/out.ply");
    ASSERT_TRUE(ply.ok()) << ply.status();
    ASSERT_GT(ply->num_triangles(), 200u) << what;
    const eval::TopologyReport indexed = eval::AnalyzeTopology(*ply);
    EXPECT_TRUE(indexed.IsManifold()) << what;
    ExpectEmbedded(*ply, indexed, what + " .ply");
    for (const char* ext : {"obj", "stl"}) {
      auto mesh = io::ReadMesh(dir + "/out." + ext);
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      ExpectEmbedded(*mesh, indexed, what + " ." + ext);
    }
    ExpectEmbedded(testing::ReadGlb(dir + "/out.glb").mesh, indexed, what + " .glb");
  }
}

}  // namespace
}  // namespace tandem
