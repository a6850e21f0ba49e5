// Following an acquisition: a writer thread plays the instrument (libtiff writing numbered
// slices in place, ZarrAppender growing an OME-Zarr array chunk row by chunk row) while
// FollowVolume + RunSession mesh it. The followed mesh must be exactly the mesh of the
// finished volume, and the first slice must be read before the last one is written. Ends:
// --expect-slices, a done-file, settling; errors: an acquisition that stops short, a slice
// file that arrives out of name order.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <cstring>
#include <fstream>
#include <random>
#include <thread>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "tandem/follow.h"
#include "tandem/series.h"
#include "tandem/synthetic.h"
#include "tandem/run_session.h"
#include "tandem/tandem.h"
#include "tandem/zarr.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

namespace fs = std::filesystem;

struct Volume {
  VolumeInfo info;
  std::vector<std::vector<uint8_t>> slices;
};

Volume Link(int64_t n = 36) {
  auto src = MakeSyntheticSource(Shape::kLink, n, n - 4, n - 6, {0.5, 0.5, 0.75});
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
  auto run = RunSession(src, Options());
  EXPECT_TRUE(run.ok()) << run.status();
  return run.ok() ? (*run)->Snapshot() : IndexedMesh{};
}

void ExpectSameMesh(const IndexedMesh& a, const IndexedMesh& b) {
  ASSERT_GT(a.num_triangles(), 100u);
  ASSERT_EQ(a.indices, b.indices);
  ASSERT_EQ(a.positions.size(), b.positions.size());
  for (size_t i = 0; i < a.positions.size(); ++i) ASSERT_EQ(a.positions[i], b.positions[i]) << i;
}

FollowOptions Fast() {
  FollowOptions f;
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
      EXPECT_TRUE(WriteTiffSlice(SliceName(dir, z), v.info, z, v.slices[z]).ok());
      written = z + 1;
      std::this_thread::sleep_for(std::chrono::milliseconds(15));
    }
    std::ofstream(dir + "/SCAN_DONE") << "";
  });
  FollowOptions f = Fast();
  f.done_file = "SCAN_DONE";
  f.progress = [&](int64_t, int64_t read) {
    if (read == 1) written_at_first_read = written.load();
  };
  auto followed = FollowVolume(dir, f);  // the folder does not exist yet: it waits
  ASSERT_TRUE(followed.ok()) << followed.status();
  EXPECT_EQ((*followed)->info().nz, 0) << "the count is not known while following";
  const IndexedMesh live = MeshOf(**followed);
  instrument.join();
  EXPECT_GE(written_at_first_read.load(), 1);
  EXPECT_LT(written_at_first_read.load(), v.info.nz) << "the first slice waited for the last";
  EXPECT_EQ((*followed)->next_slice(), v.info.nz);
  auto finished = OpenVolume(dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live);
}

TEST(Follow, GrowingZarrArrayGivesTheFinishedVolumesMesh) {
  const Volume v = Link();
  const std::string store = testing::MakeTempDir() + "/acq.zarr";
  std::atomic<int64_t> written{0};
  std::atomic<int64_t> written_at_first_read{-1};
  std::thread instrument([&] {
    ZarrWriteOptions zo;
    zo.chunks = {4, 16, 16};  // planes become visible four at a time
    zo.version = 3;
    zo.compressor = ZarrCompressor::kZstd;
    auto w = ZarrAppender::Create(store, v.info, zo);
    ASSERT_TRUE(w.ok()) << w.status();
    for (int64_t z = 0; z < v.info.nz; ++z) {
      ASSERT_TRUE((*w)->Append(v.slices[z].data()).ok());
      written = z + 1;
      std::this_thread::sleep_for(std::chrono::milliseconds(15));
    }
    ASSERT_TRUE((*w)->Finish().ok());
  });
  FollowOptions f = Fast();
  f.expect_slices = v.info.nz;
  f.progress = [&](int64_t, int64_t read) {
    if (read == 1) written_at_first_read = written.load();
  };
  auto followed = FollowVolume(store, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  EXPECT_EQ((*followed)->info().nz, v.info.nz);
  const IndexedMesh live = MeshOf(**followed);
  instrument.join();
  EXPECT_LT(written_at_first_read.load(), v.info.nz);
  auto finished = OpenVolume(store);
  ASSERT_TRUE(finished.ok()) << finished.status();
  ExpectSameMesh(MeshOf(**finished), live);
}

TEST(Follow, AnAcquisitionThatStopsShortOfExpectSlicesFailsClearly) {
  const Volume v = Link(24);
  const std::string dir = testing::MakeTempDir();
  for (int64_t z = 0; z < 6; ++z) {
    ASSERT_TRUE(WriteTiffSlice(SliceName(dir, z), v.info, z, v.slices[z]).ok());
  }
  FollowOptions f = Fast();
  f.expect_slices = 10;
  f.settle_s = 0.4;
  auto followed = FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  auto run = RunSession(**followed, Options());
  ASSERT_FALSE(run.ok());
  EXPECT_TRUE(absl::StrContains(run.status().message(), "stopped after 6 of 10")) << run.status();

  // Without --expect-slices, settling ends the scan: the 6 slices are the volume.
  f.expect_slices = 0;
  auto settled = FollowVolume(dir, f);
  ASSERT_TRUE(settled.ok()) << settled.status();
  auto run2 = RunSession(**settled, Options());
  ASSERT_TRUE(run2.ok()) << run2.status();
  EXPECT_EQ((*settled)->next_slice(), 6);
}

TEST(Follow, ASliceFileArrivingOutOfOrderIsAnErrorNamingIt) {
  const Volume v = Link(24);
  const std::string dir = testing::MakeTempDir();
  for (int64_t z : {0, 1, 3}) {
    ASSERT_TRUE(WriteTiffSlice(SliceName(dir, z), v.info, z, v.slices[z]).ok());
  }
  FollowOptions f = Fast();
  f.settle_s = 5;  // the error comes when the file is seen; a short settle could end first
  auto followed = FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  std::vector<uint8_t> bytes;
  for (int i = 0; i < 3; ++i) ASSERT_TRUE((*followed)->ReadSlice(&bytes).ok()) << i;
  ASSERT_TRUE(WriteTiffSlice(SliceName(dir, 2), v.info, 2, v.slices[2]).ok());
  absl::Status st = (*followed)->ReadSlice(&bytes);
  ASSERT_FALSE(st.ok());
  EXPECT_TRUE(absl::StrContains(st.message(), "slice_00002.tif")) << st;
  EXPECT_TRUE(absl::StrContains(st.message(), "name order")) << st;
}

// Float range of a volume, for the DICOM writer's quantization.
DicomWriteOptions DicomFor(const Volume& v) {
  DicomWriteOptions o;
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

// A CT writes a series in bursts, each burst's files in any order (as a C-STORE receiver
// stores them), under names that say nothing about position.
TEST(Follow, DicomSeriesArrivingInShuffledBurstsGivesTheFinishedSeriesMesh) {
  const Volume v = Link();
  VolumeInfo placed = v.info;
  placed.origin = {-40, 12, 300};
  const std::string dir = testing::MakeTempDir() + "/ct";
  auto writer = DicomSliceWriter::Create(placed, DicomFor(v));
  ASSERT_TRUE(writer.ok()) << writer.status();
  std::atomic<int64_t> written{0};
  std::atomic<int64_t> written_at_first_read{-1};
  std::thread scanner([&] {
    fs::create_directories(dir);
    std::mt19937 rng(5);
    for (int64_t b = 0; b < v.info.nz; b += 4) {
      std::vector<int64_t> burst;
      for (int64_t z = b; z < std::min(b + 4, v.info.nz); ++z) burst.push_back(z);
      std::shuffle(burst.begin(), burst.end(), rng);
      for (int64_t z : burst) {
        const std::string name = absl::StrCat(dir, "/1.2.840.", (z * 7919) % 10007);
        EXPECT_TRUE(writer->Write(name, z, v.slices[z]).ok());
        ++written;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(40));
    }
    std::ofstream(dir + "/DONE") << "";
  });
  FollowOptions f = Fast();
  f.done_file = "DONE";
  f.progress = [&](int64_t, int64_t read) {
    if (read == 1) written_at_first_read = written.load();
  };
  auto followed = FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  const IndexedMesh live = MeshOf(**followed);
  scanner.join();
  EXPECT_LT(written_at_first_read.load(), v.info.nz) << "the first slice waited for the last";
  EXPECT_EQ((*followed)->next_slice(), v.info.nz);
  auto finished = OpenVolume(dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  EXPECT_EQ((*followed)->info().spacing, (*finished)->info().spacing);
  EXPECT_EQ((*followed)->info().origin, (*finished)->info().origin);
  ExpectSameMesh(MeshOf(**finished), live);
}

// The first files of a shuffled burst can be every other slice (0, 2, 4): their gaps look
// like a step of two. The InstanceNumbers say they are not neighbours, so the follower
// waits for 1 and 3 instead of meshing 0, 2, 4 and then failing on 1 "below" them (the
// demo's 100 slices/s DICOM scan hit this).
TEST(Follow, DicomBurstWhoseFirstFilesAreEveryOtherSliceWaitsForTheRest) {
  const Volume v = Link();
  const std::string dir = testing::MakeTempDir() + "/ct";
  fs::create_directories(dir);
  auto writer = DicomSliceWriter::Create(v.info, DicomFor(v));
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
  FollowOptions f = Fast();
  f.done_file = "DONE";
  f.settle_s = 5;
  auto followed = FollowVolume(dir, f);
  ASSERT_TRUE(followed.ok()) << followed.status();
  const IndexedMesh live = MeshOf(**followed);
  scanner.join();
  EXPECT_EQ((*followed)->next_slice(), v.info.nz);
  auto finished = OpenVolume(dir);
  ASSERT_TRUE(finished.ok()) << finished.status();
  EXPECT_EQ((*followed)->info().spacing, (*finished)->info().spacing);
  ExpectSameMesh(MeshOf(**finished), live);
}

TEST(Follow, DicomSliceBelowMeshedOnesOrAGapThatNeverClosesIsAnError) {
  const Volume v = Link(24);
  auto writer = DicomSliceWriter::Create(v.info, DicomFor(v));
  ASSERT_TRUE(writer.ok()) << writer.status();
  FollowOptions f = Fast();
  f.settle_s = 5;  // the error comes when the file is seen; a short settle could end first

  // Slices 2..6 arrive and are meshed; then slice 0 turns up below them.
  const std::string below = testing::MakeTempDir();
  for (int64_t z = 2; z < 7; ++z) {
    ASSERT_TRUE(writer->Write(absl::StrCat(below, "/s", z), z, v.slices[z]).ok());
  }
  auto followed = FollowVolume(below, f);
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
  auto held = FollowVolume(gap, f);
  ASSERT_TRUE(held.ok()) << held.status();
  auto run = RunSession(**held, Options());
  ASSERT_FALSE(run.ok());
  EXPECT_TRUE(absl::StrContains(run.status().message(), "gap between s2 and s4")) << run.status();
  EXPECT_EQ((*held)->next_slice(), 3);
}

TEST(Follow, NothingArrivingIsAClearError) {
  FollowOptions f = Fast();
  f.settle_s = 0.2;
  auto none = FollowVolume(testing::MakeTempDir() + "/never", f);
  ASSERT_FALSE(none.ok());
  EXPECT_TRUE(absl::StrContains(none.status().message(), "no complete slice appeared"))
      << none.status();
}

}  // namespace
}  // namespace tandem
