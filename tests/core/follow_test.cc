// Following an acquisition: a writer thread plays the instrument (libtiff writing numbered
// slices in place, ZarrAppender growing an OME-Zarr array chunk row by chunk row) while
// FollowVolume + RunSession mesh it. The followed mesh must be exactly the mesh of the
// finished volume, and the first slice must be read before the last one is written. Ends:
// --expect-slices, a done-file, settling; errors: an acquisition that stops short, a slice
// file that arrives out of name order.
#include "tandem/io/follow.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <thread>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "tandem/eval/distance.h"
#include "tandem/geometry.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/run_session.h"
#include "tandem/io/series.h"
#include "tandem/eval/synthetic.h"
#include "tandem/tandem.h"
#include "tandem/eval/topology.h"
#include "tandem/io/zarr.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

namespace fs = std::filesystem;

struct Volume {
  VolumeInfo info;
  std::vector<std::vector<uint8_t>> slices;
};

Volume Link(int64_t n = 36) {
  auto src = eval::MakeSyntheticSource(eval::Shape::kLink, n, n - 4, n - 6, {0.5, 0.5, 0.75});
  Volume v{src->info(), {}};
  v.slices.resize(v.info.nz);
  for (auto& s : v.slices) EXPECT_TRUE(src->ReadSlice(&s).ok());
  return v;
}

SessionOptions Options() {
  SessionOptions o;
  o.iso = 0;
  o.error = 0.1;
  return o;
}

IndexedMesh MeshOf(SliceSource& src) {
  auto run = io::RunSession(src, Options());
  EXPECT_TRUE(run.ok()) << run.status();
  return run.ok() ? (*run)->Snapshot() : IndexedMesh{};
}

void ExpectSameMesh(const IndexedMesh& a, const IndexedMesh& b) {
  ASSERT_GT(a.num_triangles(), 100u);
  ASSERT_EQ(a.indices, b.indices);
  ASSERT_EQ(a.positions.size(), b.positions.size());
  for (size_t i = 0; i < a.positions.size(); ++i) ASSERT_EQ(a.positions[i], b.positions[i]) << i;
}

io::FollowOptions Fast() {
  io::FollowOptions f;
  f.stable_s = 0.05;
  f.poll_s = 0.01;
  f.settle_s = 5;
  return f;
}

std::string SliceName(const std::string& dir, int64_t z) {
  char name[32];
  std::snprintf(name, sizeof(name), "slice_%05lld.tif", static_cast<long long>(z));
  return dir + "/" + name;
}

TEST(Follow, TiffSlicesWrittenWhileFollowedGiveTheFinishedVolumesMesh) {
  const Volume v = Link();
  const std::string dir = testing::MakeTempDir() + "/acq";
  std::atomic<int64_t> written{0};
  std::atomic<int64_t> written_at_first_read{-1};
  std::thread instrument([&] {
    fs::create_directories(dir);
    for (int64_t z = 0; z < v.info.nz; ++z) {
      EXPECT_TRUE(io::WriteTiffSlice(SliceName(dir, z), v.info, z, v.slices[z]).ok());
      written = z + 1;
      std::this_thread::sleep_for(std::chrono::milliseconds(15));
    }
    std::ofstream(dir + "/SCAN_DONE") << "";
  });
  io::FollowOptions f = Fast();
  f.done_file = "SCAN_DONE";
  f.progress = [&](int64_t, int64_t read) {
    if (read == 1) written_at_first_read = written.load();
  };
  auto followed = io::FollowVolume(dir, f);  // the folder does not exist yet: it waits
  ASSERT_TRUE(followed.ok()) << followed.status();
  EXPECT_EQ((*followed)->info().nz, 0) << "the count is not known while following";
  const IndexedMesh live = MeshOf(**followed);
  instrument.join();
  EXPECT_GE(written_at_first_read.load(), 1);
  EXPECT_LT(written_at_first_read.load(), v.info.nz) << "the first slice waited for the last";
  EXPECT_EQ((*followed)->next_slice(), v.info.nz);
  auto finished = io::OpenVolume(dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live);
}

TEST(Follow, GrowingZarrArrayGivesTheFinishedVolumesMesh) {
  const Volume v = Link();
  const std::string store = testing::MakeTempDir() + "/acq.zarr";
  std::atomic<int64_t> written{0};
  std::atomic<int64_t> written_at_first_read{-1};
  std::thread instrument([&] {
    io::ZarrWriteOptions zo;
    zo.chunks = {4, 16, 16};  // planes become visible four at a time
    zo.version = 3;
    zo.compressor = io::ZarrCompressor::kZstd;
    auto w = io::ZarrAppender::Create(store, v.info, zo);
    ASSERT_TRUE(w.ok()) << w.status();
    for (int64_t z = 0; z < v.info.nz; ++z) {
      ASSERT_TRUE((*w)->Append(v.slices[z].data()).ok());
      written = z + 1;
      std::this_thread::sleep_for(std::chrono::milliseconds(15));
    }
    ASSERT_TRUE((*w)->Finish().ok());
  });
  io::FollowOptions f = Fast();
  f.expect_slices = v.info.nz;
  f.progress = [&](int64_t, int64_t read) {
    if (read == 1) written_at_first_read = written.load();
  };
  auto followed = io::FollowVolume(store, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  EXPECT_EQ((*followed)->info().nz, v.info.nz);
  const IndexedMesh live = MeshOf(**followed);
  instrument.join();
  EXPECT_LT(written_at_first_read.load(), v.info.nz);
  auto finished = io::OpenVolume(store);
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live);
}

TEST(Follow, AnAcquisitionThatStopsShortOfExpectSlicesFailsClearly) {
  const Volume v = Link(24);
  const std::string dir = testing::MakeTempDir();
  for (int64_t z = 0; z < 6; ++z) {
    ASSERT_TRUE(io::WriteTiffSlice(SliceName(dir, z), v.info, z, v.slices[z]).ok());
  }
  io::FollowOptions f = Fast();
  f.expect_slices = 10;
  f.settle_s = 0.4;
  auto followed = io::FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  auto run = io::RunSession(**followed, Options());
  ASSERT_FALSE(run.ok());
  EXPECT_TRUE(absl::StrContains(run.status().message(), "stopped after 6 of 10")) << run.status();

  // Without --expect-slices, settling ends the scan: the 6 slices are the volume.
  f.expect_slices = 0;
  auto settled = io::FollowVolume(dir, f);
  ASSERT_TRUE(settled.ok()) << settled.status();
  auto run2 = io::RunSession(**settled, Options());
  ASSERT_TRUE(run2.ok()) << run2.status();
  EXPECT_EQ((*settled)->next_slice(), 6);
}

TEST(Follow, ASliceFileArrivingOutOfOrderIsAnErrorNamingIt) {
  const Volume v = Link(24);
  const std::string dir = testing::MakeTempDir();
  for (int64_t z : {0, 1, 3}) {
    ASSERT_TRUE(io::WriteTiffSlice(SliceName(dir, z), v.info, z, v.slices[z]).ok());
  }
  io::FollowOptions f = Fast();
  f.settle_s = 5;  // the error comes when the file is seen; a short settle could end first
  auto followed = io::FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  std::vector<uint8_t> bytes;
  for (int i = 0; i < 3; ++i) ASSERT_TRUE((*followed)->ReadSlice(&bytes).ok()) << i;
  ASSERT_TRUE(io::WriteTiffSlice(SliceName(dir, 2), v.info, 2, v.slices[2]).ok());
  absl::Status st = (*followed)->ReadSlice(&bytes);
  ASSERT_FALSE(st.ok());
  EXPECT_TRUE(absl::StrContains(st.message(), "slice_00002.tif")) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), "name order")) << st;
}

// Float range of a volume, for the DICOM writer's quantization.
io::DicomWriteOptions DicomFor(const Volume& v) {
  io::DicomWriteOptions o;
  float lo = 1e30f, hi = -1e30f;
  for (const auto& s : v.slices) {
    for (size_t i = 0; i < s.size() / 4; ++i) {
      float f;
      std::memcpy(&f, s.data() + 4 * i, 4);
      lo = std::min(lo, f);
      hi = std::max(hi, f);
    }
  }
  o.float_min = lo;
  o.float_max = hi;
  return o;
}

// The first files of a shuffled burst can be every other slice (0, 2, 4): their gaps look
// like a step of two. The InstanceNumbers say they are not neighbours, so the follower
// waits for 1 and 3 instead of meshing 0, 2, 4 and then failing on 1 "below" them (the
// demo's 100 slices/s DICOM scan hit this).
TEST(Follow, DicomBurstWhoseFirstFilesAreEveryOtherSliceWaitsForTheRest) {
  const Volume v = Link();
  const std::string dir = testing::MakeTempDir() + "/ct";
  fs::create_directories(dir);
  auto writer = io::DicomSliceWriter::Create(v.info, DicomFor(v));
  ASSERT_TRUE(writer.ok()) << writer.status();
  auto write = [&](int64_t z) {
    EXPECT_TRUE(writer->Write(absl::StrCat(dir, "/1.3.6.", (z * 7919) % 10007), z, v.slices[z]).ok());
  };
  for (int64_t z : {0, 2, 4}) write(z);
  std::thread scanner([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(600));
    for (int64_t z : {1, 3}) write(z);
    for (int64_t z = 5; z < v.info.nz; ++z) write(z);
    std::ofstream(dir + "/DONE") << "";
  });
  io::FollowOptions f = Fast();
  f.done_file = "DONE";
  f.settle_s = 5;
  auto followed = io::FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  const IndexedMesh live = MeshOf(**followed);
  scanner.join();
  EXPECT_EQ((*followed)->next_slice(), v.info.nz);
  auto finished = io::OpenVolume(dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  EXPECT_EQ((*followed)->info().spacing, (*finished)->info().spacing);
  ExpectSameMesh(MeshOf(**finished), live);
}

TEST(Follow, DicomSliceBelowMeshedOnesOrAGapThatNeverClosesIsAnError) {
  const Volume v = Link(24);
  auto writer = io::DicomSliceWriter::Create(v.info, DicomFor(v));
  ASSERT_TRUE(writer.ok()) << writer.status();
  io::FollowOptions f = Fast();
  f.settle_s = 5;  // the error comes when the file is seen; a short settle could end first

  // Slices 2..6 arrive and are meshed; then slice 0 turns up below them.
  const std::string below = testing::MakeTempDir();
  for (int64_t z = 2; z < 7; ++z) {
    ASSERT_TRUE(writer->Write(absl::StrCat(below, "/s", z), z, v.slices[z]).ok());
  }
  auto followed = io::FollowVolume(below, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  std::vector<uint8_t> bytes;
  for (int i = 0; i < 5; ++i) ASSERT_TRUE((*followed)->ReadSlice(&bytes).ok()) << i;
  ASSERT_TRUE(writer->Write(below + "/late", 0, v.slices[0]).ok());
  absl::Status st = (*followed)->ReadSlice(&bytes);
  EXPECT_TRUE(absl::StrContains(st.message(), "late arrived at or below")) << st;

  // Slice 3 never comes: slices 4.. are held back, and the end names the gap.
  f.settle_s = 0.4;
  const std::string gap = testing::MakeTempDir();
  for (int64_t z : {0, 1, 2, 4, 5}) {
    ASSERT_TRUE(writer->Write(absl::StrCat(gap, "/s", z), z, v.slices[z]).ok());
  }
  auto held = io::FollowVolume(gap, f);
  ASSERT_TRUE(held.ok()) << held.status();
  auto run = io::RunSession(**held, Options());
  ASSERT_FALSE(run.ok());
  EXPECT_TRUE(absl::StrContains(run.status().message(), "gap between s2 and s4")) << run.status();
  EXPECT_TRUE(absl::StrContains(run.status().message(),
                                "a missing slice at ImagePositionPatient (0, 0, 2.25)"))
      << run.status();
  EXPECT_EQ((*held)->next_slice(), 3);
}

// InstanceNumbers as series carry them: in position order, or renumbered by an anonymizer
// or a reconstruction (shuffled, restarted every acquisition of 4 slices, counting down,
// all the same), or left out.
enum class Numbering { kOrdered, kRandom, kRestarted, kReversed, kEqual, kAbsent };

std::vector<int64_t> Numbers(Numbering how, int64_t nz) {
  std::vector<int64_t> n(static_cast<size_t>(nz));
  for (int64_t z = 0; z < nz; ++z) {
    int64_t& v = n[static_cast<size_t>(z)];
    switch (how) {
      case Numbering::kOrdered:
      case Numbering::kRandom:
        v = z + 1;
        break;
      case Numbering::kRestarted:
        v = z % 4 + 1;
        break;
      case Numbering::kReversed:
        v = nz - z;
        break;
      case Numbering::kEqual:
        v = 1;
        break;
      case Numbering::kAbsent:
        v = io::DicomSliceWriter::kNoInstanceNumber;
        break;
    }
  }
  if (how == Numbering::kRandom) std::shuffle(n.begin(), n.end(), std::mt19937(11));
  return n;
}

// A scanner: the slices in bursts of 4, each burst's files in shuffled order, one every `ms`,
// under names that say nothing about position, then DONE. `temp`: each file goes in under
// a temporary name (suffix: NAME.part, hidden: .NAME.tmp), half of it, then the rest
// `half_ms` later, then it is renamed into place.
struct Scanner {
  const Volume& v;
  const io::DicomSliceWriter& writer;
  std::string dir;
  std::vector<int64_t> numbers;
  int ms = 40;
  std::string temp = "";
  int half_ms = 80;
  // Head to feet: the last slice first (numbers counted in that order: 1 at the top).
  bool descending = false;
  std::atomic<int64_t> written{0};

  void Run() {
    fs::create_directories(dir);
    const std::string scratch = testing::MakeTempDir();
    std::mt19937 rng(5);
    for (int64_t b = 0; b < v.info.nz; b += 4) {
      std::vector<int64_t> burst;
      for (int64_t a = b; a < std::min(b + 4, v.info.nz); ++a) burst.push_back(a);
      std::shuffle(burst.begin(), burst.end(), rng);
      for (int64_t a : burst) {
        const int64_t z = descending ? v.info.nz - 1 - a : a;
        const size_t k = static_cast<size_t>(z);
        const int64_t number = numbers[static_cast<size_t>(a)];
        const std::string name = absl::StrCat("1.2.840.", (z * 7919) % 10007, ".dcm");
        if (temp.empty()) {
          EXPECT_TRUE(writer.Write(dir + "/" + name, z, v.slices[k], number).ok());
        } else {
          EXPECT_TRUE(writer.Write(scratch + "/" + name, z, v.slices[k], number).ok());
          const std::string bytes = testing::FileBytes(scratch + "/" + name);
          const std::string part =
              dir + "/" + (temp == "suffix" ? name + ".part" : "." + name + ".tmp");
          std::ofstream(part, std::ios::binary) << bytes.substr(0, bytes.size() / 2);
          std::this_thread::sleep_for(std::chrono::milliseconds(half_ms));
          std::ofstream(part, std::ios::binary | std::ios::app) << bytes.substr(bytes.size() / 2);
          fs::rename(part, dir + "/" + name);
        }
        ++written;
        std::this_thread::sleep_for(std::chrono::milliseconds(ms));
      }
    }
    std::ofstream(dir + "/DONE") << "";
  }
};

std::string Joined(const std::vector<std::string>& lines) { return absl::StrJoin(lines, "\n"); }

int64_t CountContaining(const std::vector<std::string>& lines, const std::string& what) {
  return std::count_if(lines.begin(), lines.end(),
                       [&](const std::string& l) { return absl::StrContains(l, what); });
}

// Follows the scanner's series to its end: the mesh, and how many files were written when
// the first slice was handed over.
struct Followed {
  IndexedMesh mesh;
  int64_t written_at_first_read = -1;
  std::vector<std::string> notes;
  std::unique_ptr<SliceSource> source;
};

Followed FollowScanner(Scanner& scanner, io::FollowOptions f = Fast(),
                       const SessionOptions& options = Options()) {
  Followed out;
  std::atomic<int64_t> first{-1};
  std::thread thread([&] { scanner.Run(); });
  f.done_file = "DONE";
  f.note = [&](const std::string& line) { out.notes.push_back(line); };
  f.progress = [&](int64_t, int64_t read) {
    if (read == 1) first = scanner.written.load();
  };
  auto followed = io::FollowVolume(scanner.dir, f);
  EXPECT_TRUE(followed.ok()) << followed.status();
  if (followed.ok()) {
    auto run = io::RunSession(**followed, options);
    EXPECT_TRUE(run.ok()) << run.status();
    if (run.ok()) out.mesh = (*run)->Snapshot();
    out.source = *std::move(followed);
  }
  thread.join();
  out.written_at_first_read = first;
  return out;
}

class FollowNumbering : public ::testing::TestWithParam<Numbering> {};

// A CT writes a series in bursts, each burst's files in any order (as a C-STORE receiver
// stores them), under names that say nothing about position. However the InstanceNumbers
// run, or whether there are any, the followed series gives the finished series' mesh, and
// its first slice goes while most files are still to come (the numbers are a hint: where
// they contradict the positions, one note says so).
TEST_P(FollowNumbering, GivesTheFinishedMeshAndTheFirstSliceEarly) {
  const Volume v = Link(38);  // 32 slices
  VolumeInfo placed = v.info;
  placed.origin = {-40, 12, 300};
  auto writer = io::DicomSliceWriter::Create(placed, DicomFor(v));
  ASSERT_TRUE(writer.ok()) << writer.status();
  Scanner scanner{v, *writer, testing::MakeTempDir() + "/ct", Numbers(GetParam(), v.info.nz),
                  /*ms=*/50};
  const Followed live = FollowScanner(scanner);
  ASSERT_NE(live.source, nullptr);
  EXPECT_GE(live.written_at_first_read, 3);
  EXPECT_LE(live.written_at_first_read, v.info.nz / 2) << "the first slice waited for most files";
  EXPECT_EQ(live.source->next_slice(), v.info.nz);
  auto finished = io::OpenVolume(scanner.dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  EXPECT_EQ(live.source->info().spacing, (*finished)->info().spacing);
  EXPECT_EQ(live.source->info().origin, (*finished)->info().origin);
  ExpectSameMesh(MeshOf(**finished), live.mesh);
  const Numbering n = GetParam();
  const bool contradict =
      n == Numbering::kRandom || n == Numbering::kRestarted || n == Numbering::kEqual;
  EXPECT_EQ(CountContaining(live.notes, "InstanceNumbers do not follow the slice positions"),
            contradict ? 1 : 0)
      << Joined(live.notes);
  EXPECT_EQ(live.notes.size(), contradict ? 1u : 0u) << Joined(live.notes);
}

std::string NumberingName(const ::testing::TestParamInfo<Numbering>& p) {
  static const char* kNames[] = {"Ordered", "Random", "Restarted", "Reversed", "Equal", "Absent"};
  return kNames[static_cast<int>(p.param)];
}

INSTANTIATE_TEST_SUITE_P(Dicom, FollowNumbering,
                         ::testing::Values(Numbering::kOrdered, Numbering::kRandom,
                                           Numbering::kRestarted, Numbering::kReversed,
                                           Numbering::kEqual, Numbering::kAbsent),
                         NumberingName);

// Twice the signed volume a closed mesh encloses (the sign: which way its normals point).
double SignedVolume(const IndexedMesh& m) {
  double v = 0;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    v += Dot(m.positions[m.indices[3 * t]],
             Cross(m.positions[m.indices[3 * t + 1]], m.positions[m.indices[3 * t + 2]]));
  }
  return v;
}

// The farthest a vertex of `b` lies from the nearest vertex of `a` (one-sided; both ways: the
// same vertex sets up to that distance).
double FarthestVertex(const IndexedMesh& a, const IndexedMesh& b) {
  constexpr double kCell = 1e-2;  // larger than any rounding, smaller than any spacing
  std::map<std::array<int64_t, 3>, std::vector<Vec3>> cells;
  auto cell = [](const Vec3& p, int dx, int dy, int dz) {
    return std::array<int64_t, 3>{std::llround(std::floor(p.x / kCell)) + dx,
                                  std::llround(std::floor(p.y / kCell)) + dy,
                                  std::llround(std::floor(p.z / kCell)) + dz};
  };
  for (const Vec3& p : a.positions) cells[cell(p, 0, 0, 0)].push_back(p);
  double worst = 0;
  for (const Vec3& p : b.positions) {
    double best = std::numeric_limits<double>::infinity();
    for (int dx = -1; dx <= 1; ++dx) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dz = -1; dz <= 1; ++dz) {
          auto it = cells.find(cell(p, dx, dy, dz));
          if (it == cells.end()) continue;
          for (const Vec3& q : it->second) best = std::min(best, Norm(p - q));
        }
      }
    }
    worst = std::max(worst, best);
  }
  return worst;
}

class FollowDescending : public ::testing::TestWithParam<Numbering> {};

// Many CT protocols acquire head to feet: positions decreasing along the slice normal. The
// followed series grows that way (its grid's z axis against the normal, its origin at the
// first slice acquired), its first slice goes while most files are still to come, and its
// mesh is the finished folder's surface (read from the lowest slice up): at full resolution
// the same vertices (up to float rounding), as many triangles, normals out the same way
// (marching cubes splits some cubes' quads along the other diagonal when the grid runs the
// other way); simplified, the same surface swept the other way, as close to the full
// resolution as the finished folder's mesh is.
TEST_P(FollowDescending, GrowsHeadToFeetWithTheFinishedFoldersSurface) {
  const Volume v = Link(38);  // 32 slices
  VolumeInfo placed = v.info;
  placed.origin = {-40, 12, 300};
  auto writer = io::DicomSliceWriter::Create(placed, DicomFor(v));
  ASSERT_TRUE(writer.ok()) << writer.status();
  Scanner scanner{v, *writer, testing::MakeTempDir() + "/ct", Numbers(GetParam(), v.info.nz),
                  /*ms=*/50};
  scanner.descending = true;
  std::atomic<int64_t> first{-1};
  std::thread thread([&] { scanner.Run(); });
  io::FollowOptions f = Fast();
  f.done_file = "DONE";
  f.progress = [&](int64_t, int64_t read) {
    if (read == 1) first = scanner.written.load();
  };
  auto followed = io::FollowVolume(scanner.dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  SessionOptions full = Options();
  full.schedule = Schedule::kNone;
  auto live = io::RunSessions(**followed, {full, Options()});
  thread.join();
  ASSERT_TRUE(live.ok()) << live.status();
  EXPECT_GE(first.load(), 3);
  EXPECT_LE(first.load(), v.info.nz / 2) << "the first slice waited for most files";
  const VolumeInfo& grid = (*followed)->info();
  EXPECT_EQ((*followed)->next_slice(), v.info.nz);
  const double top = 300 + (v.info.nz - 1) * v.info.spacing[2];
  EXPECT_NEAR(grid.origin[2], top, 1e-9) << "the origin is the first slice acquired";
  EXPECT_EQ(grid.directions[2], (std::array<double, 3>{0, 0, -1}));
  EXPECT_EQ(grid.spacing, v.info.spacing);

  auto finished = io::OpenVolume(scanner.dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  EXPECT_EQ((*finished)->info().directions[2], (std::array<double, 3>{0, 0, 1}));
  auto read = io::RunSessions(**finished, {full, Options()});
  ASSERT_TRUE(read.ok()) << read.status();
  const IndexedMesh a = (*read)[0]->Snapshot(), b = (*live)[0]->Snapshot();
  ASSERT_GT(a.num_triangles(), 1000u);
  EXPECT_EQ(a.num_triangles(), b.num_triangles());
  EXPECT_EQ(a.num_vertices(), b.num_vertices());
  // (The engine's float32 vertices, placed from the other end of each z edge.)
  EXPECT_LT(FarthestVertex(a, b), 1e-3 * v.info.spacing[0]);
  EXPECT_LT(FarthestVertex(b, a), 1e-3 * v.info.spacing[0]);
  EXPECT_NEAR(SignedVolume(b) / SignedVolume(a), 1.0, 1e-3) << "normals point the same way";
  auto same_topology = [](const IndexedMesh& x, const IndexedMesh& y) {
    const eval::TopologyReport tx = eval::AnalyzeTopology(x), ty = eval::AnalyzeTopology(y);
    EXPECT_TRUE(ty.IsManifold());
    EXPECT_EQ(tx.euler, ty.euler);
    EXPECT_EQ(tx.components, ty.components);
    EXPECT_EQ(tx.boundary_edges > 0, ty.boundary_edges > 0);
  };
  same_topology(a, b);
  const eval::Distances apart = eval::MeasureDistances(a, b);
  EXPECT_LT(apart.linf_max, 0.25 * v.info.spacing[0]);  // the other diagonal of some quads
  // Simplified: the other sweep's simplification of the same surface, as good.
  const IndexedMesh sa = (*read)[1]->Snapshot(), sb = (*live)[1]->Snapshot();
  same_topology(sa, sb);
  EXPECT_NEAR(static_cast<double>(sb.num_triangles()) / static_cast<double>(sa.num_triangles()),
              1.0, 0.15);
  const double finished_off = eval::MeasureDistances(a, sa).linf_max;
  const double followed_off = eval::MeasureDistances(a, sb).linf_max;
  EXPECT_LT(followed_off, 1.5 * finished_off + 0.1 * Options().error);
  EXPECT_NEAR(SignedVolume(sb) / SignedVolume(sa), 1.0, 0.02);
}

INSTANTIATE_TEST_SUITE_P(Dicom, FollowDescending,
                         ::testing::Values(Numbering::kOrdered, Numbering::kRandom,
                                           Numbering::kAbsent),
                         NumberingName);

// A scan of 18 slices and its DICOM writer, for what real scanners write.
class FollowDicom : public ::testing::Test {
 protected:
  void SetUp() override {
    absl::StatusOr<io::DicomSliceWriter> w = io::DicomSliceWriter::Create(v.info, DicomFor(v));
    ASSERT_TRUE(w.ok()) << w.status();
    writer.emplace(*std::move(w));
  }
  // Slice z as the file `path`, with InstanceNumber `number`.
  void Put(const std::string& path, int64_t z, int64_t number) {
    absl::Status st = writer->Write(path, z, v.slices[static_cast<size_t>(z)], number);
    EXPECT_TRUE(st.ok()) << st;
  }
  // A scanner writing the scan into a fresh folder.
  // Slower under the sanitizers, whose reader is: the first slice must still go before the
  // last file is written on a loaded machine.
  Scanner Scan(Numbering numbering, int ms = testing::kSanitized ? 100 : 40,
               std::string temp = "") {
    return Scanner{v, *writer, testing::MakeTempDir() + "/ct", Numbers(numbering, v.info.nz), ms,
                   std::move(temp)};
  }
  const Volume v = Link(24);
  std::optional<io::DicomSliceWriter> writer;
};

// A burst that ends with nothing new in the folder for a second lets its lowest slice go,
// the numbers (shuffled) saying nothing: the first slices do not wait for the next burst.
TEST_F(FollowDicom, BurstFollowedByAPauseGoesWithinASecondOrSo) {
  const std::string dir = testing::MakeTempDir();
  const std::vector<int64_t> numbers = Numbers(Numbering::kRandom, v.info.nz);
  auto write = [&](int64_t z) {
    Put(absl::StrCat(dir, "/im", (z * 7919) % 10007), z, numbers[static_cast<size_t>(z)]);
  };
  for (int64_t z : {3, 0, 4, 1, 2}) write(z);
  const auto start = std::chrono::steady_clock::now();
  std::atomic<double> fifth_read_s{-1};
  std::thread scanner([&] {  // the next burst comes once the first is meshed (or 5 s)
    while (fifth_read_s < 0 && std::chrono::steady_clock::now() - start < std::chrono::seconds(5)) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    for (int64_t z = 5; z < v.info.nz; ++z) write(z);
    std::ofstream(dir + "/DONE") << "";
  });
  io::FollowOptions f = Fast();
  f.done_file = "DONE";
  f.progress = [&](int64_t, int64_t read) {
    if (read == 5) {
      fifth_read_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
  };
  auto followed = io::FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  const IndexedMesh live = MeshOf(**followed);
  scanner.join();
  EXPECT_GT(fifth_read_s.load(), 0) << "the burst waited for the next one";
  EXPECT_LT(fifth_read_s.load(), 2.5);
  EXPECT_EQ((*followed)->next_slice(), v.info.nz);
  auto finished = io::OpenVolume(dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live);
}

// A writer slower than a file a second, out of position order: a second without news is
// no end of a burst for it (its usual interval is), so slice 2 does not go before 1 and 0.
TEST_F(FollowDicom, SlowWriterOutOfOrderIsWaitedFor) {
  const std::string dir = testing::MakeTempDir();
  const std::vector<int64_t> numbers = Numbers(Numbering::kRandom, v.info.nz);
  std::thread scanner([&] {
    auto write = [&](int64_t z) {
      Put(absl::StrCat(dir, "/im", z), z, numbers[static_cast<size_t>(z)]);
    };
    int64_t k = 0;
    for (int64_t z : {2, 3, 4, 1, 0}) {
      if (k++ > 0) std::this_thread::sleep_for(std::chrono::milliseconds(1100));
      write(z);
    }
    for (int64_t z = 5; z < v.info.nz; ++z) write(z);
    std::ofstream(dir + "/DONE") << "";
  });
  io::FollowOptions f = Fast();
  f.done_file = "DONE";
  auto followed = io::FollowVolume(dir, f);
  absl::Status st = followed.status();
  IndexedMesh live;
  if (followed.ok()) {
    auto run = io::RunSession(**followed, Options());
    st = run.status();
    if (run.ok()) live = (*run)->Snapshot();
  }
  scanner.join();
  ASSERT_TRUE(st.ok()) << st;
  auto finished = io::OpenVolume(dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live);
}

// A CT writes its localizer first (a front and a side projection, ImageType LOCALIZER);
// a scout without that flag (two images that are not parallel) can be there too. Each is
// set aside with one note naming it, and the stack that grows is followed.
TEST_F(FollowDicom, ScoutsInTheFolderAreSetAsideAndTheStackFollowed) {
  Scanner scanner = Scan(Numbering::kRandom);
  fs::create_directories(scanner.dir);
  const std::string flagged = testing::WriteLocalizer(scanner.dir, v.info, true);
  const std::string unflagged = testing::WriteLocalizer(scanner.dir, v.info, false);
  const Followed live = FollowScanner(scanner);
  ASSERT_NE(live.source, nullptr);
  EXPECT_EQ(live.source->next_slice(), v.info.nz);
  EXPECT_LT(live.written_at_first_read, v.info.nz);
  std::vector<std::string> notes;
  auto finished = io::OpenVolume(scanner.dir, io::OpenOptions{.note = [&](const std::string& line) {
                                   notes.push_back(line);
                                 }});
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live.mesh);
  for (const std::vector<std::string>* lines : {&live.notes, &std::as_const(notes)}) {
    EXPECT_EQ(CountContaining(*lines, flagged + " 'Scout'"), 1) << Joined(*lines);
    EXPECT_EQ(CountContaining(*lines, "a localizer (ImageType LOCALIZER)"), 1) << Joined(*lines);
    EXPECT_EQ(CountContaining(*lines, unflagged + " 'Scout'"), 1) << Joined(*lines);
    EXPECT_EQ(CountContaining(*lines, "not parallel"), 1) << Joined(*lines);
  }
}

// Two reconstructions of one scan in one folder: following needs --series to pick one
// (without it, an error lists both); with it the other is set aside with a note.
TEST(Follow, DicomTwoStacksNeedSeriesToPickOne) {
  const Volume v = Link(24);
  const std::string dir = testing::MakeTempDir();
  io::DicomWriteOptions soft = DicomFor(v), bone = DicomFor(v);
  soft.series_uid = "1.2.826.0.1.3680043.2.1125.5.1";
  soft.series_description = "soft tissue";
  bone.series_uid = "1.2.826.0.1.3680043.2.1125.5.2";
  bone.series_description = "bone";
  VolumeInfo shifted = v.info;
  shifted.origin = {0, 0, 10};
  for (const auto& [opts, info] : {std::pair{soft, v.info}, std::pair{bone, shifted}}) {
    auto writer = io::DicomSliceWriter::Create(info, opts);
    ASSERT_TRUE(writer.ok()) << writer.status();
    for (int64_t z = 0; z < v.info.nz; ++z) {
      ASSERT_TRUE(writer
                      ->Write(absl::StrCat(dir, "/", opts.series_description, z), z,
                              v.slices[static_cast<size_t>(z)])
                      .ok());
    }
  }
  io::FollowOptions f = Fast();
  f.settle_s = 0.5;
  auto both = io::FollowVolume(dir, f);
  ASSERT_FALSE(both.ok());
  const std::string msg(both.status().message());
  const std::string count = absl::StrCat(" (", v.info.nz, " images");
  for (const std::string& what : {soft.series_uid + " 'soft tissue'" + count,
                                  bone.series_uid + " 'bone'" + count, std::string("--series")}) {
    EXPECT_TRUE(absl::StrContains(msg, what)) << what << " in " << msg;
  }
  std::vector<std::string> notes;
  f.dicom_series = bone.series_uid;
  f.note = [&](const std::string& line) { notes.push_back(line); };
  auto picked = io::FollowVolume(dir, f);
  ASSERT_TRUE(picked.ok()) << picked.status();
  const IndexedMesh live = MeshOf(**picked);
  EXPECT_EQ((*picked)->info().origin, shifted.origin);
  auto finished = io::OpenVolume(dir, io::OpenOptions{.dicom_series = bone.series_uid});
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live);
  EXPECT_EQ(notes.size(), 1u) << Joined(notes);
  EXPECT_EQ(
      CountContaining(notes, soft.series_uid + " 'soft tissue': not the series --series picks"), 1)
      << Joined(notes);
}

// Transfer tools write a file under a temporary name (NAME.part, .NAME.tmp) and rename it
// into place: the half-written temporary files are neither read nor reported.
TEST_F(FollowDicom, FilesRenamedIntoPlaceAreOnlyTakenWhole) {
  for (const char* temp : {"suffix", "hidden"}) {
    SCOPED_TRACE(temp);
    Scanner scanner = Scan(Numbering::kOrdered, /*ms=*/10, temp);
    const Followed live = FollowScanner(scanner);
    ASSERT_NE(live.source, nullptr);
    EXPECT_EQ(live.source->next_slice(), v.info.nz);
    EXPECT_TRUE(live.notes.empty()) << Joined(live.notes);
    auto finished = io::OpenVolume(scanner.dir);
    ASSERT_TRUE(finished.ok()) << finished.status();
    ExpectSameMesh(MeshOf(**finished), live.mesh);
  }
}

// Files that are no slice of the series: a note each for a text file, random bytes and a
// dose report (a DICOM object without an image), and the mesh is the series'.
TEST_F(FollowDicom, FilesThatAreNoSlicesAreSkippedWithANote) {
  Scanner scanner = Scan(Numbering::kOrdered);
  fs::create_directories(scanner.dir);
  std::ofstream(scanner.dir + "/notes.txt") << "patient moved at slice 12\n";
  std::ofstream(scanner.dir + "/noise.bin", std::ios::binary) << std::string("\x7f\x13\x00\xee", 4);
  testing::WriteDoseReport(scanner.dir + "/dose.dcm", "1.2.826.0.1.3680043.2.1125.5.9");
  const Followed live = FollowScanner(scanner);
  ASSERT_NE(live.source, nullptr);
  EXPECT_EQ(live.source->next_slice(), v.info.nz);
  auto finished = io::OpenVolume(scanner.dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live.mesh);
  EXPECT_EQ(live.notes.size(), 3u) << Joined(live.notes);
  EXPECT_EQ(CountContaining(live.notes, "notes.txt: not a DICOM file"), 1) << Joined(live.notes);
  EXPECT_EQ(CountContaining(live.notes, "noise.bin: not a DICOM file"), 1) << Joined(live.notes);
  EXPECT_EQ(CountContaining(live.notes, "dose.dcm: DICOM file without an image"), 1)
      << Joined(live.notes);
}

// Bad folders end with an error naming the culprit, never a hang past --settle: slices at
// one position (at once), a localizer and nothing else, a slice file that never becomes
// whole and a DICOM file that does not parse (when the scan ends).
TEST_F(FollowDicom, BadInputsAreClearErrorsNamingTheCulprit) {
  auto write = [&](const std::string& dir, int64_t z, const std::string& name = "") {
    const std::string path = dir + "/" + (name.empty() ? absl::StrCat("s", z) : name);
    EXPECT_TRUE(writer->Write(path, z, v.slices[static_cast<size_t>(z)]).ok());
    return path;
  };
  auto seconds_since = [](std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
  io::FollowOptions f = Fast();
  f.settle_s = 0.5;

  const std::string dup = testing::MakeTempDir();
  for (int64_t z = 0; z < 6; ++z) write(dup, z);
  write(dup, 3, "again");
  f.settle_s = 5;  // the error comes as soon as both are seen
  auto start = std::chrono::steady_clock::now();
  absl::StatusOr<std::unique_ptr<SliceSource>> twice = io::FollowVolume(dup, f);
  absl::Status st = twice.status();
  if (twice.ok()) st = io::RunSession(**twice, Options()).status();
  EXPECT_TRUE(absl::StrContains(st.message(), "are at the same position")) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), "s3") && absl::StrContains(st.message(), "again"))
      << st;
  EXPECT_LT(seconds_since(start), 2.0);
  f.settle_s = 0.5;

  const std::string scout = testing::MakeTempDir();
  const std::string uid = testing::WriteLocalizer(scout, v.info);
  auto only = io::FollowVolume(scout, f);
  ASSERT_FALSE(only.ok());
  EXPECT_TRUE(absl::StrContains(only.status().message(), "no slice stack to follow"))
      << only.status();
  EXPECT_TRUE(absl::StrContains(only.status().message(), uid + " 'Scout' (2 images): a localizer"))
      << only.status();

  for (const bool garbage : {false, true}) {
    const std::string dir = testing::MakeTempDir();
    for (int64_t z = 0; z < 6; ++z) write(dir, z);
    const std::string bad = write(dir, 6, "bad.dcm");
    if (garbage) {  // a DICOM preamble and nothing a parser can read
      std::ofstream(bad, std::ios::binary)
          << std::string(128, '\0') << "DICM" << std::string(300, '\xff');
    } else {  // cut in its pixel data, and never finished
      fs::resize_file(bad, fs::file_size(bad) / 2);
    }
    start = std::chrono::steady_clock::now();
    auto followed = io::FollowVolume(dir, f);
    ASSERT_TRUE(followed.ok()) << followed.status();
    auto run = io::RunSession(**followed, Options());
    ASSERT_FALSE(run.ok());
    EXPECT_TRUE(absl::StrContains(run.status().message(), bad)) << run.status();
    EXPECT_TRUE(absl::StrContains(run.status().message(), "still not whole")) << run.status();
    EXPECT_LT(seconds_since(start), 4.0);
  }
}

TEST(Follow, NothingArrivingIsAClearError) {
  io::FollowOptions f = Fast();
  f.settle_s = 0.2;
  auto none = io::FollowVolume(testing::MakeTempDir() + "/never", f);
  ASSERT_FALSE(none.ok());
  EXPECT_TRUE(absl::StrContains(none.status().message(), "no complete slice appeared"))
      << none.status();
}

}  // namespace
}  // namespace tandem
