// End to end: the real tandem-server (child process, 127.0.0.1, ephemeral port) and the
// real tandem-client binary. Every wait is bounded.
#include <gtest/gtest.h>
#include <signal.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <numbers>
#include <set>
#include <sstream>
#include <string_view>
#include <thread>
#include <tuple>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "absl/strings/str_split.h"
#include "service/service_testutil.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/eval/report.h"
#include "tandem/eval/synthetic.h"
#include "tandem/eval/topology.h"
#include "tandem/io/mesh_io.h"
#include "tandem/io/series.h"
#include "tandem/io/volume_writers.h"
#include "tandem/mesh.h"
#include "testutil/embedded.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

constexpr char kHead[] = "ct_head_headsq_64x64x93_int16.json";

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

RunResult Client(std::vector<std::string> args, double timeout_s = 120,
                 const std::vector<std::string>& env = {}) {
  args.insert(args.begin(), BinPath("tandem-client"));
  return RunProcess(args, timeout_s, env);
}

std::vector<std::string> HeadArgs(const std::string& server, const std::string& input) {
  return {"stream", "--server", server, "--input", input, "--iso", "500", "--error", "0.75"};
}

// The generated volume of the load, kill and concurrency tests (service_testutil.h).
std::vector<std::string> LoadArgs(const std::string& server, const std::string& input) {
  return {"stream", "--server", server, "--input", input, "--iso", kLoadIso, "--error", kLoadError};
}

SessionOptions HeadOptions() {
  SessionOptions o;
  o.iso = 500;
  o.error = 0.75;
  return o;
}

std::vector<std::string> Concat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

// "preview slice=S triangles=T ... sent=N" lines of --verbose, in arrival order.
struct PreviewLine {
  int64_t slice = 0, triangles = 0, sent = 0;
};
std::vector<PreviewLine> PreviewLines(const std::string& err) {
  std::vector<PreviewLine> out;
  for (absl::string_view line : absl::StrSplit(err, '\n')) {
    if (!absl::StartsWith(line, "preview ")) continue;
    PreviewLine p;
    for (absl::string_view field : absl::StrSplit(line, ' ')) {
      std::pair<std::string, std::string> kv = absl::StrSplit(field, absl::MaxSplits('=', 1));
      int64_t v = 0;
      if (!absl::SimpleAtoi(kv.second, &v)) continue;
      if (kv.first == "slice") p.slice = v;
      if (kv.first == "triangles") p.triangles = v;
      if (kv.first == "sent") p.sent = v;
    }
    out.push_back(p);
  }
  return out;
}

std::set<std::string> Keys(const std::string& json) {
  std::set<std::string> keys;
  const nlohmann::json parsed = nlohmann::json::parse(json);
  for (const auto& [k, v] : parsed.items()) keys.insert(k);
  return keys;
}

class ServiceE2eTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto server = TestServer::Start();
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    dir_ = MakeTempDir();
  }
  std::unique_ptr<TestServer> server_;
  std::string dir_;
};

TEST_F(ServiceE2eTest, HealthAndInfo) {
  EXPECT_EQ(server_->Health(), "SERVING");
  RunResult health = Client({"health", "--server", server_->address()});
  EXPECT_EQ(health.exit_code, 0) << health.err;
  EXPECT_EQ(health.out, "SERVING\n");
  RunResult info = Client({"info", "--server", server_->address()});
  EXPECT_EQ(info.exit_code, 0) << info.err;
  EXPECT_NE(info.out.find("dtypes                 uint8, int8, uint16, int16, uint32, int32, "
                          "uint64, int64, float32"),
            std::string::npos)
      << info.out;
  EXPECT_NE(info.out.find("max sessions           8"), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("active sessions        0"), std::string::npos) << info.out;
}

// The service's final mesh and metrics are exactly a local TandemSession's.
TEST_F(ServiceE2eTest, SharedVolumeMatchesLocalSession) {
  TANDEM_SHARED_OR_SKIP(input, kHead);
  const std::string drc = dir_ + "/head.drc", metrics = dir_ + "/head.json";
  RunResult r = Client(Concat(HeadArgs(server_->address(), input),
                              {"--compression-level", "0", "--out", drc, "--metrics", metrics}));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("triangles final"), std::string::npos) << "summary table on stdout";

  auto local = RunLocal(input, HeadOptions());
  ASSERT_TRUE(local.ok()) << local.status();
  const IndexedMesh expected = (*local)->Snapshot();
  const eval::MetricsReport want = eval::MakeReport(**local, expected);

  auto mesh = codec::DecodeDraco(ReadFile(drc));
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  ASSERT_EQ(mesh->num_triangles(), expected.num_triangles());
  ASSERT_EQ(mesh->num_vertices(), expected.num_vertices());
  EXPECT_EQ(mesh->indices, expected.indices) << "level 0 keeps the snapshot's order";
  const double tol = codec::PositionTolerance(expected, 16);
  double worst = 0;
  for (size_t i = 0; i < expected.num_vertices(); ++i) {
    for (int c = 0; c < 3; ++c) {
      worst = std::max(worst, std::abs(mesh->positions[i][c] - expected.positions[i][c]));
    }
  }
  EXPECT_LE(worst, tol);

  const std::string json = ReadFile(metrics);
  auto got = eval::ReportFromJson(json);
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(got->input, input);
  EXPECT_EQ(got->stats.triangles_extracted, want.stats.triangles_extracted);
  EXPECT_EQ(got->triangles_final, want.triangles_final);
  EXPECT_EQ(got->vertices_final, want.vertices_final);
  EXPECT_EQ(got->stats.peak_triangles, want.stats.peak_triangles);
  EXPECT_DOUBLE_EQ(got->error_max, want.error_max);
  EXPECT_EQ(got->stats.trace, want.stats.trace);
  EXPECT_EQ(got->stats.contractions, want.stats.contractions);
  EXPECT_EQ(got->stats.evaluations, want.stats.evaluations);
  EXPECT_EQ(got->stats.q_pushes, want.stats.q_pushes);
  EXPECT_EQ(got->stats.w_pushes, want.stats.w_pushes);
  EXPECT_GT(got->stats.w_pushes, 0);
  // The final mesh is corrected as locally.
  EXPECT_EQ(got->stats.sag_corrected, want.stats.sag_corrected);
  EXPECT_EQ(got->stats.refusals.link, want.stats.refusals.link);
  EXPECT_EQ(got->stats.refusals.flip, want.stats.refusals.flip);
  EXPECT_DOUBLE_EQ(got->anisotropy, want.anisotropy);
  EXPECT_EQ(got->nx, 64);
  EXPECT_EQ(got->nz, 93);
  EXPECT_GT(got->bytes_received, 64 * 64 * 93 * 2);
  EXPECT_GT(got->bytes_sent, 0);
  // The keys of `tandem extract --metrics` (ReportToJson of a local run), plus the
  // service-only byte counts and the session's memory peak.
  std::set<std::string> want_keys = Keys(eval::ReportToJson(want));
  want_keys.insert({"bytes_received", "bytes_sent", "peak_session_bytes"});
  EXPECT_EQ(Keys(json), want_keys);
}

// Default level (Edgebreaker, vertices reordered) into a PLY: same mesh up to renaming.
TEST_F(ServiceE2eTest, DefaultLevelSavesTheSameMeshAsPly) {
  TANDEM_SHARED_OR_SKIP(input, kHead);
  const std::string ply = dir_ + "/head.ply";
  RunResult r = Client(Concat(HeadArgs(server_->address(), input), {"--out", ply}));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto local = RunLocal(input, HeadOptions());
  ASSERT_TRUE(local.ok());
  const IndexedMesh expected = (*local)->Snapshot();
  auto mesh = io::ReadMesh(ply);
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  ASSERT_EQ(mesh->num_triangles(), expected.num_triangles());
  ASSERT_EQ(mesh->num_vertices(), expected.num_vertices());
  auto map = MatchVertices(expected, *mesh, codec::PositionTolerance(expected, 16));
  ASSERT_TRUE(map.ok()) << map.status();
  EXPECT_TRUE(SameTriangles(expected, *mesh, *map));
}

TEST_F(ServiceE2eTest, PreviewsArriveInOrderDecodeAndFollowTheTrace) {
  TANDEM_SHARED_OR_SKIP(input, kHead);
  const std::string partials = dir_ + "/partials";
  // Paced (0.93 s for the 93 slices): unpaced, a fast machine streams them in 60 ms and the
  // server's 250 ms spacing lets one preview through, so the order would go unchecked.
  RunResult r = Client(Concat(HeadArgs(server_->address(), input),
                              {"--rate", "100", "--preview-every", "10", "--partials", partials,
                               "--verbose", "--out", dir_ + "/head.drc"}));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto local = RunLocal(input, HeadOptions());
  ASSERT_TRUE(local.ok());
  const std::vector<int64_t>& trace = (*local)->stats().trace;

  const std::vector<PreviewLine> lines = PreviewLines(r.err);
  ASSERT_GE(lines.size(), 2u) << r.err;
  for (size_t i = 1; i < lines.size(); ++i) EXPECT_GT(lines[i].slice, lines[i - 1].slice);
  size_t files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(partials)) {
    const std::string name = entry.path().filename().string();
    int64_t slice = -1;
    ASSERT_TRUE(absl::StartsWith(name, "preview_") && absl::EndsWith(name, ".drc")) << name;
    ASSERT_TRUE(absl::SimpleAtoi(name.substr(8, name.size() - 12), &slice)) << name;
    EXPECT_EQ((slice + 1) % 10, 0) << "every 10 slices: " << name;
    auto mesh = codec::DecodeDraco(ReadFile(entry.path().string()));
    ASSERT_TRUE(mesh.ok()) << name << ": " << mesh.status();
    // tandem-lag records two trace entries per slice (after EXTRACT and after SIMPLIFY);
    // the preview after slice k shows one of slice k's (core may defer that SIMPLIFY).
    ASSERT_LT(static_cast<size_t>(2 * slice + 1), trace.size());
    const int64_t got = static_cast<int64_t>(mesh->num_triangles());
    EXPECT_TRUE(got == trace[2 * slice] || got == trace[2 * slice + 1])
        << name << ": " << got << " triangles; trace has " << trace[2 * slice] << ", "
        << trace[2 * slice + 1];
    ++files;
  }
  EXPECT_EQ(files, lines.size());
}

TEST_F(ServiceE2eTest, PacedStreamGetsAPreviewBeforeTheLastSlice) {
  TANDEM_SHARED_OR_SKIP(input, kHead);
  RunResult r = Client(Concat(HeadArgs(server_->address(), input),
                              {"--rate", "40", "--preview-every", "5", "--verbose", "--out",
                               dir_ + "/head.drc"}));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<PreviewLine> lines = PreviewLines(r.err);
  ASSERT_GE(lines.size(), 5u) << r.err;
  EXPECT_LT(lines.front().sent, 93) << "the first preview came before the scan ended";
  EXPECT_LT(lines.front().slice, 20);
}

// A 1100 x 1100 float32 slice is 4.84 MB, over gRPC's 4 MiB default message size. (Six
// slices: the sphere is a small blob in the middle, so the time goes to moving slices.)
TEST_F(ServiceE2eTest, SlicesLargerThanFourMiBInChunksAndWhole) {
  auto path = WriteSyntheticVolume(dir_, "big_sphere",
                                   eval::MakeSyntheticSource(eval::Shape::kSphere, 1100, 1100, 6));
  ASSERT_TRUE(path.ok()) << path.status();
  SessionOptions options;
  options.error = 0.1;
  auto local = RunLocal(*path, options);
  ASSERT_TRUE(local.ok()) << local.status();
  const IndexedMesh expected = (*local)->Snapshot();
  ASSERT_GT(expected.num_triangles(), 20u);
  for (const char* chunk : {"1048576", "8000000"}) {
    const std::string out = dir_ + "/big_" + chunk + ".drc";
    RunResult r = Client({"stream", "--server", server_->address(), "--input", *path, "--iso",
                          "0", "--error", "0.1", "--chunk-bytes", chunk, "--out", out});
    ASSERT_EQ(r.exit_code, 0) << chunk << ": " << r.err;
    auto mesh = codec::DecodeDraco(ReadFile(out));
    ASSERT_TRUE(mesh.ok());
    EXPECT_EQ(mesh->num_triangles(), expected.num_triangles()) << chunk;
    EXPECT_EQ(mesh->num_vertices(), expected.num_vertices()) << chunk;
  }
}

// The client sends a mapped file's slices in place and reads the others (gzip NRRD here):
// the server must see the same voxels either way.
TEST_F(ServiceE2eTest, MappedAndReadVolumesStreamTheSameMesh) {
  auto source = eval::MakeSyntheticSource(eval::Shape::kLink, 40, 36, 30);
  const VolumeInfo info = source->info();
  std::vector<std::vector<uint8_t>> slices(static_cast<size_t>(info.nz));
  for (auto& slice : slices) ASSERT_TRUE(source->ReadSlice(&slice).ok());
  auto slice_fn = [&slices](int64_t z, std::vector<uint8_t>* bytes) {
    *bytes = slices[static_cast<size_t>(z)];
    return absl::OkStatus();
  };
  const std::string raw = dir_ + "/link.json", gz = dir_ + "/link.nrrd";
  ASSERT_TRUE(io::WriteVolume(raw, info, slice_fn).ok());
  io::VolumeWriteOptions gzip;
  gzip.gzip = true;
  ASSERT_TRUE(io::WriteVolume(gz, info, slice_fn, gzip).ok());
  std::string meshes[2];
  for (int i = 0; i < 2; ++i) {
    const std::string out = dir_ + "/link" + std::to_string(i) + ".ply";
    RunResult r = Client({"stream", "--server", server_->address(), "--input", i == 0 ? raw : gz,
                          "--iso", "0", "--error", "0.05", "--chunk-bytes", "1000", "--out", out});
    ASSERT_EQ(r.exit_code, 0) << r.err;
    meshes[i] = ReadFile(out);
  }
  ASSERT_GT(meshes[0].size(), 1000u);
  EXPECT_EQ(meshes[0], meshes[1]);
}

// Streaming must not cost the client fresh memory per message: glibc used to give each freed
// ~1 MiB message buffer back to the kernel, so every message was page-faulted in and zeroed
// again (42,000 faults for 64 MiB, two thirds of the client's CPU time). Now its buffers are
// kept and a mapped volume is sent from the page cache: ~2,400 faults, most of them the
// process starting up.
TEST_F(ServiceE2eTest, StreamingDoesNotPageFaultEveryMessageAnew) {
  if (kSanitized) GTEST_SKIP() << "page faults are the sanitizer's own under ASan and TSan";
  constexpr int64_t kN = 256;  // 64 MiB of float32 in 256 slices of 256 KiB
  auto path = WriteSyntheticVolume(dir_, "sphere256",
                                   eval::MakeSyntheticSource(eval::Shape::kSphere, kN, kN, kN));
  ASSERT_TRUE(path.ok()) << path.status();
  RunResult r = Client({"stream", "--server", server_->address(), "--input", *path, "--iso", "0",
                        "--error", "0.5", "--out", dir_ + "/sphere256.ply"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const int64_t volume_pages = kN * kN * kN * 4 / 4096;
  ASSERT_GT(r.minor_faults, 0);
  EXPECT_LT(r.minor_faults, 1500 + volume_pages / 4)
      << "the client faulted in fresh pages for a large part of the " << volume_pages
      << " pages it streamed";
}

TEST_F(ServiceE2eTest, EightConcurrentStreamsMatchOneAtATime) {
  auto load = WriteLoadVolume(dir_);
  ASSERT_TRUE(load.ok()) << load.status();
  const std::string& input = *load;
  RunResult single = Client(Concat(LoadArgs(server_->address(), input),
                                   {"--out", dir_ + "/single.drc", "--metrics",
                                    dir_ + "/single.json"}));
  ASSERT_EQ(single.exit_code, 0) << single.err;
  std::vector<std::unique_ptr<ChildProcess>> clients;
  for (int i = 0; i < 8; ++i) {
    std::vector<std::string> argv = Concat(
        LoadArgs(server_->address(), input),
        {"--out", dir_ + "/c" + std::to_string(i) + ".drc", "--metrics",
         dir_ + "/c" + std::to_string(i) + ".json"});
    argv.insert(argv.begin(), BinPath("tandem-client"));
    auto child = ChildProcess::Spawn(argv, dir_);
    ASSERT_TRUE(child.ok());
    clients.push_back(*std::move(child));
  }
  auto want = eval::ReportFromJson(ReadFile(dir_ + "/single.json"));
  ASSERT_TRUE(want.ok());
  const std::string want_mesh = ReadFile(dir_ + "/single.drc");
  for (int i = 0; i < 8; ++i) {
    std::optional<int> code = clients[i]->Wait(120);
    ASSERT_TRUE(code.has_value()) << "client " << i << " still running";
    ASSERT_EQ(*code, 0) << clients[i]->Stderr();
    auto got = eval::ReportFromJson(ReadFile(dir_ + "/c" + std::to_string(i) + ".json"));
    ASSERT_TRUE(got.ok());
    EXPECT_EQ(got->stats.trace, want->stats.trace) << i;
    EXPECT_EQ(got->triangles_final, want->triangles_final) << i;
    EXPECT_DOUBLE_EQ(got->error_max, want->error_max) << i;
    EXPECT_EQ(ReadFile(dir_ + "/c" + std::to_string(i) + ".drc"), want_mesh)
        << "client " << i << ": the Draco bytes are deterministic";
  }
  v1::Counters counters;
  EXPECT_TRUE(server_->WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_EQ(counters.sessions_started(), 9);
}

// A client killed mid-stream leaves no session, thread or session memory behind.
// With --resume-window-seconds 0 a killed client's session ends at once (with the default
// window it waits for a resume: AKilledClientRestartedWithResume..., ServiceResume).
TEST_F(ServiceE2eTest, KilledClientLeavesNothingBehind) {
  auto load = WriteLoadVolume(dir_);
  ASSERT_TRUE(load.ok()) << load.status();
  const std::string& input = *load;
  auto no_resume = TestServer::Start({"--resume-window-seconds", "0"});
  ASSERT_TRUE(no_resume.ok()) << no_resume.status();
  server_ = *std::move(no_resume);
  std::vector<std::string> argv = Concat(LoadArgs(server_->address(), input),
                                         {"--rate", "25", "--out", dir_ + "/never.drc"});
  argv.insert(argv.begin(), BinPath("tandem-client"));
  auto client = ChildProcess::Spawn(argv, dir_);
  ASSERT_TRUE(client.ok());
  bool active = false;
  for (int i = 0; i < 200 && !active; ++i) {  // up to 10 s
    auto info = server_->Info();
    active = info.ok() && info->counters().active_sessions() == 1 &&
             info->counters().worker_threads() == 1 && info->counters().session_bytes() > 0;
    if (!active) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_TRUE(active) << "the stream never showed up in the server's counters";
  (*client)->Signal(SIGKILL);
  EXPECT_EQ((*client)->Wait(10), 128 + SIGKILL);
  v1::Counters counters;
  EXPECT_TRUE(server_->WaitIdle(15, &counters)) << counters.ShortDebugString();
  EXPECT_FALSE(std::filesystem::exists(dir_ + "/never.drc"));
  EXPECT_EQ(server_->Health(), "SERVING");
  RunResult after = Client(Concat(LoadArgs(server_->address(), input), {"--out", dir_ + "/ok.drc"}));
  EXPECT_EQ(after.exit_code, 0) << after.err;
}

TEST_F(ServiceE2eTest, ClientReportsErrorsClearly) {
  TANDEM_SHARED_OR_SKIP(input, kHead);
  RunResult bad_ext = Client(Concat(HeadArgs(server_->address(), input), {"--out", dir_ + "/m.off"}));
  EXPECT_EQ(bad_ext.exit_code, 2);
  EXPECT_NE(bad_ext.err.find(".drc, .ply, .obj, .stl or .glb"), std::string::npos) << bad_ext.err;
  RunResult no_folder =
      Client(Concat(HeadArgs(server_->address(), input), {"--out", dir_ + "/absent/m.drc"}));
  EXPECT_EQ(no_folder.exit_code, 1);  // the file system's state, not the command line
  EXPECT_NE(no_folder.err.find("does not exist"), std::string::npos) << no_folder.err;
  RunResult missing = Client(Concat(HeadArgs(server_->address(), dir_ + "/absent.json"),
                                    {"--out", dir_ + "/m.drc"}));
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.err.find("absent.json"), std::string::npos) << missing.err;
  // No server was involved: no gRPC code in the message.
  EXPECT_EQ(missing.err.find("NOT_FOUND"), std::string::npos) << missing.err;
  // Options are checked as `tandem extract` checks them, before anything is sent.
  RunResult rejected = Client({"stream", "--server", server_->address(), "--input", input,
                               "--iso", "500", "--error", "0", "--out", dir_ + "/m.drc"});
  EXPECT_EQ(rejected.exit_code, 2);
  EXPECT_NE(rejected.err.find("error threshold E0 must be a finite number > 0"), std::string::npos)
      << rejected.err;
  RunResult no_server = Client(Concat(HeadArgs("127.0.0.1:1", input),
                                      {"--out", dir_ + "/m.drc", "--timeout", "10"}));
  EXPECT_EQ(no_server.exit_code, 1);
  EXPECT_NE(no_server.err.find("UNAVAILABLE"), std::string::npos) << no_server.err;
  RunResult missing_flag = Client({"stream", "--input", input});
  EXPECT_EQ(missing_flag.exit_code, 2);
  EXPECT_NE(missing_flag.err.find("missing --out"), std::string::npos) << missing_flag.err;
  RunResult help = Client({"stream", "--help"});
  EXPECT_EQ(help.exit_code, 0);
  for (const char* flag : {"--server", "--input", "--iso", "--error", "--alpha", "--schedule",
                           "--target-triangles", "--rate", "--chunk-bytes", "--quantization-bits",
                           "--preview-every", "--out", "--partials", "--metrics", "--reference"}) {
    EXPECT_NE(help.out.find(flag), std::string::npos) << flag;
  }
}

// tandem-client stream --spacing gives a TIFF stack without resolution tags its extent, as
// tandem extract does (the flags are shared): the mesh scales axis by axis.
TEST_F(ServiceE2eTest, SpacingFlagGivesATiffStackWithoutResolutionItsExtent) {
  testing::WriteBareTiffStack(dir_ + "/bare.tif", 24, 20, 16);
  auto run = [&](const std::string& out, std::vector<std::string> extra) {
    std::vector<std::string> args = {
        "stream", "--server", server_->address(), "--input", dir_ + "/bare.tif",
        "--iso",  "100",      "--no-simplify",    "--out",   out};
    args.insert(args.end(), extra.begin(), extra.end());
    RunResult r = Client(args);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    auto mesh = io::ReadMesh(out);
    EXPECT_TRUE(mesh.ok()) << mesh.status();
    std::array<double, 3> hi{-1e30, -1e30, -1e30};
    for (const Vec3& p : mesh.ok() ? mesh->positions : std::vector<Vec3>{}) {
      for (int a = 0; a < 3; ++a) hi[a] = std::max<double>(hi[a], p[a]);
    }
    return hi;
  };
  const std::array<double, 3> grid = run(dir_ + "/grid.ply", {});
  const std::array<double, 3> mm = run(dir_ + "/mm.ply", {"--spacing", "0.5,0.25,2"});
  const double s[3] = {0.5, 0.25, 2};
  for (int a = 0; a < 3; ++a) {
    EXPECT_GT(grid[a], 5) << a;
    EXPECT_NEAR(mm[a], grid[a] * s[a], 1e-3) << a;
  }
}

// The final metrics carry the session's own memory peak (as its budget counts it), next to
// the server process's peak RSS, which every session shares: --reference (a second,
// full-resolution session) raises the first, and both are labelled in the summary.
TEST_F(ServiceE2eTest, MetricsCarryTheSessionsOwnPeakMemory) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 64));
  ASSERT_TRUE(path.ok()) << path.status();
  auto stream = [&](const std::string& name, std::vector<std::string> extra) {
    RunResult r = Client(Concat({"stream", "--server", server_->address(), "--input", *path,
                                 "--iso", "0", "--error", "0.05", "--out", dir_ + "/m.ply",
                                 "--metrics", dir_ + "/" + name},
                                extra));
    EXPECT_EQ(r.exit_code, 0) << r.err;
    return std::make_pair(r, nlohmann::json::parse(ReadFile(dir_ + "/" + name)));
  };
  auto [plain_run, plain] = stream("plain.json", {});
  auto [ref_run, ref] = stream("ref.json", {"--reference"});
  const int64_t session = plain["peak_session_bytes"].get<int64_t>();
  // At least the slice buffer and a mesh of this many triangles (12 bytes a triangle).
  EXPECT_GT(session, 64 * 64 * 4 + 12 * plain["triangles_final"].get<int64_t>());
  EXPECT_LT(session, plain["peak_rss_bytes"].get<int64_t>());
  EXPECT_GT(ref["peak_session_bytes"].get<int64_t>(), session + 12 * plain["triangles_extracted"].get<int64_t>());
  EXPECT_NE(plain_run.out.find("peak session memory"), std::string::npos) << plain_run.out;
  EXPECT_NE(plain_run.out.find("server peak RSS"), std::string::npos) << plain_run.out;
}

TEST_F(ServiceE2eTest, ReferenceAddsDistances) {
  TANDEM_SHARED_OR_SKIP(input, kHead);
  const std::string metrics = dir_ + "/m.json";
  RunResult r = Client(Concat(HeadArgs(server_->address(), input),
                              {"--reference", "--out", dir_ + "/m.drc", "--metrics", metrics}));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto got = eval::ReportFromJson(ReadFile(metrics));
  ASSERT_TRUE(got.ok());
  ASSERT_TRUE(got->distance.has_value());
  EXPECT_GT(got->distance->linf_max, 0);
  EXPECT_LT(got->distance->l1_max, 0.75) << "mean distance below E0";
}

// The names of the files in `dir` that start with `prefix`, sorted (chunk files are
// zero-padded: in chunk order).
std::vector<std::string> SortedFileNames(const std::string& dir, absl::string_view prefix = "") {
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (absl::StartsWith(name, prefix)) files.push_back(name);
  }
  std::sort(files.begin(), files.end());
  return files;
}

// A value a streaming client prints as NAME=VALUE, up to the next space ("" until it has).
// Secrets go in variables, not flags, whose values every user could read on a command line.
std::string PrintedVariable(const std::string& err, absl::string_view name) {
  const std::string tag = absl::StrCat(name, "=");
  const size_t at = err.find(tag);
  if (at == std::string::npos) return "";
  const size_t begin = at + tag.size();
  const size_t end = err.find(' ', begin);
  if (end == std::string::npos) return "";
  return err.substr(begin, end - begin);
}

// A chunk file saved by `tandem-client stream --chunks`, decoded with its vertex ids.
absl::StatusOr<SealedChunk> ReadChunkFile(const std::string& path) {
  SealedChunk c;
  absl::StatusOr<IndexedMesh> mesh = codec::DecodeDraco(ReadFile(path), &c.ids);
  if (!mesh.ok()) return mesh.status();
  c.positions = std::move(mesh->positions);
  c.indices = std::move(mesh->indices);
  return c;
}

// Sealed chunks: every chunk saved, decoded with its vertex ids; the chunks weld into the
// final mesh (closed, manifold, the plain stream's topology), a vertex two chunks share
// decodes to bit-identical coordinates in both, and the bytes stay close to the plain
// stream's.
TEST_F(ServiceE2eTest, SealedChunksWeldIntoTheFinalMesh) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 96, 96, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  auto stream = [&](const std::string& name, std::vector<std::string> extra) {
    return Client(Concat({"stream", "--server", server_->address(), "--input", *path, "--iso",
                          "0", "--error", "0.05", "--out", dir_ + "/" + name + ".ply",
                          "--metrics", dir_ + "/" + name + ".json", "--verbose"},
                         extra));
  };
  RunResult plain = stream("plain", {});
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  // Paced: a chunk goes out every second (else 32768 triangles would make one).
  RunResult sealed =
      stream("sealed", {"--chunks", dir_ + "/chunks", "--rate", "40", "--reference"});
  ASSERT_EQ(sealed.exit_code, 0) << sealed.err;
  auto plain_report = eval::ReportFromJson(ReadFile(dir_ + "/plain.json"));
  auto sealed_report = eval::ReportFromJson(ReadFile(dir_ + "/sealed.json"));
  ASSERT_TRUE(plain_report.ok() && sealed_report.ok());
  // --verbose says when the mesh has arrived, after the last chunk and before it is written
  // (tests/bench/keep_pace.py times the arrival from it).
  for (const auto& [run, report] : {std::pair{&plain, &*plain_report}, {&sealed, &*sealed_report}}) {
    const std::string want = absl::StrCat("received surfaces=1 triangles=", report->triangles_final,
                                          " seconds=");
    const size_t at = run->err.find(want);
    ASSERT_NE(at, std::string::npos) << run->err;
    EXPECT_EQ(run->err.find("\nchunk ", at), std::string::npos) << run->err;
  }

  // The chunk files, zero-padded and in order, decoded with their ids.
  const std::vector<std::string> files = SortedFileNames(dir_ + "/chunks", "chunk_");
  ASSERT_GE(files.size(), 2u) << "a chunk a second over 2.4 s";
  std::vector<SealedChunk> chunks;
  std::map<uint32_t, Vec3> at;
  size_t shared = 0;
  for (size_t i = 0; i < files.size(); ++i) {
    char expected[32];
    std::snprintf(expected, sizeof(expected), "chunk_%06zu.drc", i);
    EXPECT_EQ(files[i], expected);
    absl::StatusOr<SealedChunk> read = ReadChunkFile(dir_ + "/chunks/" + files[i]);
    ASSERT_TRUE(read.ok()) << read.status();
    SealedChunk c = *std::move(read);
    for (size_t v = 0; v < c.ids.size(); ++v) {
      auto [it, fresh] = at.emplace(c.ids[v], c.positions[v]);
      if (!fresh) {
        ++shared;
        EXPECT_EQ(std::memcmp(&it->second, &c.positions[v], sizeof(Vec3)), 0) << "id " << c.ids[v];
      }
    }
    chunks.push_back(std::move(c));
  }
  EXPECT_GT(shared, 0u);
  const IndexedMesh welded = WeldChunks(chunks);
  EXPECT_EQ(static_cast<int64_t>(welded.num_triangles()), sealed_report->triangles_final);
  EXPECT_EQ(static_cast<int64_t>(welded.num_vertices()), sealed_report->vertices_final);
  const eval::TopologyReport t = eval::AnalyzeTopology(welded);
  EXPECT_TRUE(t.IsClosedManifold());
  auto plain_mesh = io::ReadMesh(dir_ + "/plain.ply");
  ASSERT_TRUE(plain_mesh.ok()) << plain_mesh.status();
  EXPECT_EQ(t.euler, eval::AnalyzeTopology(*plain_mesh).euler);
  // --out holds the same welded mesh.
  auto out_mesh = io::ReadMesh(dir_ + "/sealed.ply");
  ASSERT_TRUE(out_mesh.ok()) << out_mesh.status();
  EXPECT_EQ(out_mesh->num_triangles(), welded.num_triangles());
  // Within 5% of the plain stream's count, at the same error bound.
  EXPECT_NEAR(static_cast<double>(sealed_report->triangles_final),
              static_cast<double>(plain_report->triangles_final),
              0.05 * static_cast<double>(plain_report->triangles_final));
  EXPECT_LE(sealed_report->error_max, 0.05 * (1 + 1e-9));
  // --reference measures the welded chunks against the whole full-resolution surface (the
  // reference session must not seal: it measured an empty mesh, NaN, before).
  ASSERT_TRUE(sealed_report->distance.has_value()) << sealed.out;
  EXPECT_TRUE(std::isfinite(sealed_report->distance->l2_max)) << sealed.out;
  EXPECT_GT(sealed_report->distance->linf_max, 0);
  EXPECT_LT(sealed_report->distance->linf_max, 0.5);
  // Every chunk once: the verbose lines count them.
  size_t lines = 0;
  for (absl::string_view line : absl::StrSplit(sealed.err, '\n')) lines += absl::StartsWith(line, "chunk ");
  EXPECT_EQ(lines, files.size());
  // The chunks, however many, weigh under 2x the plain stream's final mesh (its bytes_sent).
  int64_t chunk_bytes = 0;
  for (const std::string& f : files) {
    chunk_bytes += static_cast<int64_t>(std::filesystem::file_size(dir_ + "/chunks/" + f));
  }
  EXPECT_LT(chunk_bytes, 2 * plain_report->bytes_sent);
}

// A sealed stream's memory is flat in its depth: through the real server and client, a
// volume eight times deeper (the same slices repeated) peaks within 1.2x of the shallow one
// in the server's own accounting (FinalMetrics.peak_session_bytes: the session, its slice
// buffers and the chunk being taken and encoded). The chunks are what a long stream could
// grow: however many triangles its pace leaves sealed, each goes out in parts of at most
// 16,384 (a deep stream's reached 33-45 k). With the default flags, the chunks the server
// keeps for late watchers and resumes are in a spill file, not in its memory.
TEST_F(ServiceE2eTest, SealedStreamMemoryIsFlatInDepth) {
  constexpr int64_t kSide = 160, kDepth = 64;
  auto server = TestServer::Start(
      {"--max-inflight-bytes", std::to_string(2 << 20), "--metrics-listen", "127.0.0.1:0"});
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string metrics = MetricsUrl(**server);
  ASSERT_FALSE(metrics.empty()) << (*server)->process().Stderr();
  int64_t peak[2] = {0, 0}, triangles[2] = {0, 0}, largest[2] = {0, 0};
  double kept_in_memory[2] = {0, 0}, kept_on_disk[2] = {0, 0};
  std::string deep_id, deep_key;
  for (int deep = 0; deep < 2; ++deep) {
    const int64_t nz = deep ? 8 * kDepth : kDepth;
    // A gyroid periodic in z (24 voxels), closed at the x/y borders.
    auto path = WriteSyntheticVolume(
        dir_, "gyroid" + std::to_string(nz),
        std::make_unique<FieldSource>(
            kSide, kSide, nz, [side = static_cast<double>(kSide)](double i, double j, double k) {
              const double w = 2 * std::numbers::pi / 24.0;
              if (std::min({i, j, side - 1 - i, side - 1 - j}) < 2) return 1.0;
              return std::sin(w * i) * std::cos(w * j) + std::sin(w * j) * std::cos(w * k) +
                     std::sin(w * k) * std::cos(w * i);
            }));
    ASSERT_TRUE(path.ok()) << path.status();
    const std::string name = dir_ + "/depth" + std::to_string(nz);
    RunResult r = Client({"stream", "--server", (*server)->address(), "--input", *path, "--iso",
                          "0", "--error", "0.2", "--seal", "--verbose", "--out", name + ".drc",
                          "--metrics", name + ".json", "--chunks", name},
                         300);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    // Both sessions' chunks are still kept (--watch-linger-seconds): the second's are the
    // difference.
    std::map<std::string, double> scraped = Scrape(metrics);
    kept_in_memory[deep] = scraped["tandem_watch_memory_bytes"];
    kept_on_disk[deep] = scraped["tandem_watch_spilled_bytes"];
    deep_id = PrintedVariable(r.err, "TANDEM_RESUME").substr(0, 32);
    deep_key = PrintedVariable(r.err, "TANDEM_WATCH_KEY");
    const nlohmann::json m = nlohmann::json::parse(ReadFile(name + ".json"));
    peak[deep] = m["peak_session_bytes"].get<int64_t>();
    triangles[deep] = m["triangles_final"].get<int64_t>();
    for (absl::string_view line : absl::StrSplit(r.err, '\n')) {
      if (!absl::StartsWith(line, "chunk ")) continue;  // chunk index=.. slices=.. triangles=T
      for (absl::string_view word : absl::StrSplit(line, ' ')) {
        int64_t t = 0;
        if (absl::ConsumePrefix(&word, "triangles=") && absl::SimpleAtoi(word, &t)) {
          largest[deep] = std::max(largest[deep], t);
        }
      }
    }
  }
  std::printf("peak_session_bytes %lld at %lld slices, %lld at %lld; largest chunk %lld\n",
              static_cast<long long>(peak[0]), static_cast<long long>(kDepth),
              static_cast<long long>(peak[1]), static_cast<long long>(8 * kDepth),
              static_cast<long long>(largest[1]));
  EXPECT_GT(triangles[1], 7 * triangles[0]);
  EXPECT_GT(largest[1], 0) << "no chunk line in --verbose";
  EXPECT_LE(largest[1], 16384);
  // How much is pending when a chunk is taken follows the server's pace, which a loaded machine
  // moves by a few percent; the chunk bound above is what keeps the peak flat.
  EXPECT_LE(peak[1], peak[0] * 5 / 4)
      << peak[0] << " bytes at " << kDepth << " slices, " << peak[1] << " at " << 8 * kDepth;
  // The chunks kept for late watchers and resumes (outside peak_session_bytes) take the
  // server's disk, not its memory: the bytes it holds of them in memory stay flat.
  std::printf("kept chunk bytes in memory %.0f, %.0f; on disk %.0f, %.0f\n", kept_in_memory[0],
              kept_in_memory[1] - kept_in_memory[0], kept_on_disk[0],
              kept_on_disk[1] - kept_on_disk[0]);
  EXPECT_GT(kept_on_disk[0], 0);
  EXPECT_GT(kept_on_disk[1] - kept_on_disk[0], 6 * kept_on_disk[0]);
  EXPECT_LE(kept_in_memory[1] - kept_in_memory[0], kept_in_memory[0] * 6 / 5);
  // A watcher that comes after the deep stream ended gets every chunk, read back from disk,
  // byte-identical to the streamer's.
  const std::string streamed = dir_ + "/depth" + std::to_string(8 * kDepth);
  RunResult late = Client({"watch", "--server", (*server)->address(), "--session", deep_id,
                           "--chunks", dir_ + "/late", "--out", dir_ + "/late.drc"},
                          300, {"TANDEM_WATCH_KEY=" + deep_key});
  ASSERT_EQ(late.exit_code, 0) << late.err;
  const std::vector<std::string> names = SortedFileNames(streamed, "chunk_");
  EXPECT_GT(names.size(), 8u);
  EXPECT_EQ(SortedFileNames(dir_ + "/late", "chunk_"), names);
  for (const std::string& name : names) {
    EXPECT_EQ(ReadFile(dir_ + "/late/" + name), ReadFile(streamed + "/" + name)) << name;
  }
}

// A spill directory the server cannot write is no reason to stop: it says so at start-up,
// keeps the chunks in memory as it would without one (logged once), and a late watcher gets
// each of them as the streamer did.
TEST_F(ServiceE2eTest, AnUnwritableSpillDirectoryKeepsTheWatchersChunksInMemory) {
  const std::string not_a_dir = dir_ + "/not_a_dir";
  std::ofstream(not_a_dir) << "a file\n";
  auto server =
      TestServer::Start({"--watch-spill-dir", not_a_dir, "--metrics-listen", "127.0.0.1:0"});
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string metrics = MetricsUrl(**server);
  ASSERT_FALSE(metrics.empty()) << (*server)->process().Stderr();
  EXPECT_NE((*server)->process().Stderr().find(
                "warning: cannot create a file in watch spill directory '" + not_a_dir +
                "': Not a directory; sealed chunks kept for watchers and resumes stay in memory"),
            std::string::npos)
      << (*server)->process().Stderr();
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  for (const char* name : {"a", "b"}) {
    RunResult r = Client({"stream", "--server", (*server)->address(), "--input", *path, "--iso",
                          "0", "--error", "0.05", "--seal", "--rate", "40", "--chunks",
                          dir_ + "/" + name, "--out", dir_ + "/" + name + ".ply"});
    ASSERT_EQ(r.exit_code, 0) << r.err;
    RunResult late =
        Client({"watch", "--server", (*server)->address(), "--session",
                PrintedVariable(r.err, "TANDEM_RESUME").substr(0, 32), "--chunks",
                dir_ + "/late_" + name, "--out", dir_ + "/late_" + name + ".ply"},
               120, {"TANDEM_WATCH_KEY=" + PrintedVariable(r.err, "TANDEM_WATCH_KEY")});
    ASSERT_EQ(late.exit_code, 0) << late.err;
    const std::vector<std::string> names = SortedFileNames(dir_ + "/" + name, "chunk_");
    EXPECT_GE(names.size(), 2u);
    EXPECT_EQ(SortedFileNames(dir_ + "/late_" + name, "chunk_"), names);
    for (const std::string& chunk : names) {
      EXPECT_EQ(ReadFile(dir_ + "/late_" + name + "/" + chunk),
                ReadFile(dir_ + "/" + name + "/" + chunk))
          << chunk;
    }
  }
  std::map<std::string, double> scraped = Scrape(metrics);
  EXPECT_GT(scraped["tandem_watch_memory_bytes"], 0);
  EXPECT_EQ(scraped["tandem_watch_spilled_bytes"], 0);
  const std::string log = (*server)->process().Stderr();
  const size_t failed = log.find("watch_spill_failed");
  ASSERT_NE(failed, std::string::npos) << log;
  EXPECT_EQ(log.find("watch_spill_failed", failed + 1), std::string::npos) << "logged once";
}

// A uint8 scan at an integer iso-value (many grid values equal to it) through the real
// server and client, every Draco output decoded: the final mesh (full resolution,
// simplified, split, to a target count), the previews, the sealed chunks welded by id, and a
// Draco GLB. None has a zero-area triangle as written or two vertices at one position, and
// welded by position each is the mesh its ids make.
TEST_F(ServiceE2eTest, IntegerScanOutputsKeepTheirVerticesApartInDraco) {
  constexpr int64_t nx = 96, ny = 48, nz = 40;
  QuantisedSource phantom(DType::kUInt8, nx, ny, nz,
                          [](double i, double j, double k) { return Phantom(nx, ny, nz, i, j, k); },
                          {0.7, 0.7, 1.2}, {-130.5, 42.25, 300});
  const std::string volume = dir_ + "/phantom.json";
  ASSERT_TRUE(io::WriteVolume(volume, phantom.info(), [&](int64_t, std::vector<uint8_t>* bytes) {
                return phantom.ReadSlice(bytes);
              }).ok());
  auto stream = [&](const std::string& name, const std::vector<std::string>& extra) {
    return Client(Concat({"stream", "--server", server_->address(), "--input", volume, "--iso",
                          "120", "--quiet", "--out", dir_ + "/" + name},
                         extra));
  };
  auto decode = [&](const std::string& path) {
    absl::StatusOr<IndexedMesh> mesh = codec::DecodeDraco(ReadFile(path));
    EXPECT_TRUE(mesh.ok()) << path << ": " << mesh.status();
    return mesh.ok() ? *std::move(mesh) : IndexedMesh{};
  };
  for (const auto& [name, extra] : std::vector<std::pair<std::string, std::vector<std::string>>>{
           {"full", {"--no-simplify"}},
           {"plain", {}},
           {"parts", {"--parts", "2"}},
           {"target", {"--target-triangles", "1500", "--parts", "2"}},
           {"level0", {"--compression-level", "0"}},
           {"bits12", {"--quantization-bits", "12"}},
           {"full-bits14", {"--no-simplify", "--quantization-bits", "14"}}}) {
    const std::string previews = dir_ + "/previews_" + name;
    RunResult r =
        stream(name + ".drc",
               Concat(extra, {"--partials", previews, "--preview-every", "6", "--rate", "30"}));
    ASSERT_EQ(r.exit_code, 0) << name << ": " << r.err;
    const IndexedMesh mesh = decode(dir_ + "/" + name + ".drc");
    ASSERT_GT(mesh.num_triangles(), 200u) << name;
    const eval::TopologyReport t = eval::AnalyzeTopology(mesh);
    EXPECT_TRUE(t.IsManifold()) << name;
    ExpectEmbedded(mesh, t, name);
    const std::vector<std::string> files = SortedFileNames(previews);
    EXPECT_GE(files.size(), 2u) << name;
    for (const std::string& f : files) {
      const IndexedMesh preview = decode(previews + "/" + f);
      ExpectEmbedded(preview, eval::AnalyzeTopology(preview), name + " " + f);
    }
  }
  // Sealed, split: the chunks welded by id.
  for (const std::string parts : {"1", "2"}) {
    const std::string chunks_dir = dir_ + "/chunks" + parts;
    RunResult r = stream("sealed" + parts + ".ply", {"--chunks", chunks_dir, "--parts", parts});
    ASSERT_EQ(r.exit_code, 0) << r.err;
    std::vector<SealedChunk> chunks;
    for (const std::string& f : SortedFileNames(chunks_dir, "chunk_")) {
      absl::StatusOr<SealedChunk> c = ReadChunkFile(chunks_dir + "/" + f);
      ASSERT_TRUE(c.ok()) << c.status();
      chunks.push_back(*std::move(c));
    }
    const IndexedMesh welded = WeldChunks(chunks);
    const eval::TopologyReport t = eval::AnalyzeTopology(welded);
    EXPECT_TRUE(t.IsManifold());
    ExpectEmbedded(welded, t, "sealed chunks, parts " + parts);
  }
  // A Draco GLB, as the client writes it.
  RunResult r = stream("mesh.glb", {"--glb-draco"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string glb = ReadGlb(dir_ + "/mesh.glb").draco;
  absl::StatusOr<IndexedMesh> mesh = codec::DecodeDraco(glb);
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  ExpectEmbedded(*mesh, eval::AnalyzeTopology(*mesh), "Draco GLB");
}

// A sealed stream of a grid wide enough for four slabs (256 columns): each slab seals its own
// part, and every chunk the server sends holds what all of them sealed since the last, so the
// chunks along the way span several slabs' columns, not one slab's (before, the server
// took one slab's piece a slice and the others piled up until the end). The chunks weld into
// the plain stream's kind of mesh.
TEST_F(ServiceE2eTest, SealedChunksOfAWideGridComeFromEverySlab) {
  // Spacing 5 in y and z: a 256 x 240 x 240 box, whose ball-clipped gyroid spans x 26-230.
  auto path = WriteSyntheticVolume(
      dir_, "gyroid", eval::MakeSyntheticSource(eval::Shape::kGyroid, 256, 48, 48, {1, 5, 5}));
  ASSERT_TRUE(path.ok()) << path.status();
  auto stream = [&](const std::string& name, std::vector<std::string> extra) {
    return Client(Concat({"stream", "--server", server_->address(), "--input", *path, "--iso",
                          "0", "--error", "0.2", "--out", dir_ + "/" + name + ".ply",
                          "--metrics", dir_ + "/" + name + ".json"},
                         extra));
  };
  RunResult plain = stream("plain", {});
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  // Paced (a chunk a second): 48 slices in 2.4 s.
  RunResult sealed = stream("sealed", {"--chunks", dir_ + "/chunks", "--rate", "20"});
  ASSERT_EQ(sealed.exit_code, 0) << sealed.err;
  auto plain_report = eval::ReportFromJson(ReadFile(dir_ + "/plain.json"));
  auto sealed_report = eval::ReportFromJson(ReadFile(dir_ + "/sealed.json"));
  ASSERT_TRUE(plain_report.ok() && sealed_report.ok());
  const std::vector<std::string> files = SortedFileNames(dir_ + "/chunks", "chunk_");
  ASSERT_GE(files.size(), 2u);
  std::vector<SealedChunk> chunks;
  for (size_t i = 0; i < files.size(); ++i) {
    absl::StatusOr<SealedChunk> read = ReadChunkFile(dir_ + "/chunks/" + files[i]);
    ASSERT_TRUE(read.ok()) << read.status();
    SealedChunk c = *std::move(read);
    if (i + 1 < files.size()) {
      // Along the way: wider than a slab (64 columns), so from more than one. Where the
      // chunk starts and ends depends on when the server took it: under the sanitizers the
      // first chunk of one run held x 65-192+, the ball's lower cap before it reached the
      // first slab, so its ends are not checked against the outer slabs' columns.
      double lo = 1e9, hi = -1e9;
      for (const Vec3& p : c.positions) {
        lo = std::min(lo, p.x);
        hi = std::max(hi, p.x);
      }
      EXPECT_GT(hi - lo, 64.5) << files[i] << ": x " << lo << " to " << hi;
    }
    chunks.push_back(std::move(c));
  }
  const IndexedMesh welded = WeldChunks(chunks);
  EXPECT_EQ(static_cast<int64_t>(welded.num_triangles()), sealed_report->triangles_final);
  const eval::TopologyReport t = eval::AnalyzeTopology(welded);
  EXPECT_TRUE(t.IsClosedManifold());
  auto plain_mesh = io::ReadMesh(dir_ + "/plain.ply");
  ASSERT_TRUE(plain_mesh.ok()) << plain_mesh.status();
  EXPECT_EQ(t.euler, eval::AnalyzeTopology(*plain_mesh).euler);
  EXPECT_NEAR(static_cast<double>(sealed_report->triangles_final),
              static_cast<double>(plain_report->triangles_final),
              0.03 * static_cast<double>(plain_report->triangles_final));
  EXPECT_LE(sealed_report->error_max, 0.2 * (1 + 1e-9));
}

// Streams with the client's `args` and checks that the server's mesh (written to `ply`) is
// the local session's with options `o` over `path`; returns its triangle count (0 after a
// failure).
size_t StreamsAsLocally(const std::vector<std::string>& args, const std::string& path,
                        const std::string& ply, const SessionOptions& o) {
  RunResult r = Client(args);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  auto local = RunLocal(path, o);
  EXPECT_TRUE(local.ok()) << local.status();
  if (r.exit_code != 0 || !local.ok()) return 0;
  EXPECT_EQ((*local)->num_parts(), 1);  // merged at Finish
  const IndexedMesh expected = (*local)->Snapshot();
  auto mesh = io::ReadMesh(ply);
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  if (!mesh.ok()) return 0;
  EXPECT_EQ(mesh->num_triangles(), expected.num_triangles());
  if (mesh->num_triangles() != expected.num_triangles()) return 0;
  auto map = MatchVertices(expected, *mesh, codec::PositionTolerance(expected, 16));
  EXPECT_TRUE(map.ok()) << map.status();
  if (!map.ok()) return 0;
  EXPECT_TRUE(SameTriangles(expected, *mesh, *map));
  return expected.num_triangles();
}

// SessionConfig.parts (tandem-client --parts): the split the client asks for is the one the
// server's session runs, so each stream's mesh is the local session's with the same parts,
// and unset is the automatic split (2 on this 160-wide grid).
TEST_F(ServiceE2eTest, ThePartsAskedForAreTheSessionsSplit) {
  auto path = WriteSyntheticVolume(
      dir_, "gyroid", eval::MakeSyntheticSource(eval::Shape::kGyroid, 160, 40, 40, {1, 4, 4}));
  ASSERT_TRUE(path.ok()) << path.status();
  std::set<size_t> counts;
  for (int parts : {0, 1, 2, 5}) {
    SCOPED_TRACE(parts);
    const std::string ply = dir_ + "/p" + std::to_string(parts) + ".ply";
    std::vector<std::string> args = {"stream", "--server", server_->address(), "--input", *path,
                                     "--iso", "0", "--error", "0.3", "--out", ply};
    if (parts > 0) args = Concat(args, {"--parts", std::to_string(parts)});
    SessionOptions o;
    o.error = 0.3;
    o.parts = parts == 0 ? 2 : parts;
    counts.insert(StreamsAsLocally(args, *path, ply, o));
  }
  EXPECT_EQ(counts.size(), 3u);  // 1, 2 and 5 parts: three different meshes
  // Out of range: refused before any slice, naming the field.
  RunResult bad = Client({"stream", "--server", server_->address(), "--input", *path, "--iso",
                          "0", "--parts", "65", "--out", dir_ + "/bad.ply"});
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.err.find("--parts 65"), std::string::npos) << bad.err;
}

// SessionConfig.lockstep_error (tandem-client --lockstep-error): the finishing pass the
// client asks for, or turns off with 1, is the session's; unset is the core's default.
TEST_F(ServiceE2eTest, TheFinishingPassAskedForIsTheSessions) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 48, 48, 48));
  ASSERT_TRUE(path.ok()) << path.status();
  std::vector<size_t> counts;
  for (double lockstep : {0.0, 1.0, 0.3}) {  // 0: the flag not given
    SCOPED_TRACE(lockstep);
    const std::string ply = dir_ + "/f" + std::to_string(counts.size()) + ".ply";
    std::vector<std::string> args = {"stream", "--server", server_->address(), "--input", *path,
                                     "--iso", "0", "--error", "0.5", "--out", ply};
    SessionOptions o;
    o.error = 0.5;
    if (lockstep > 0) {
      args = Concat(args, {"--lockstep-error", absl::StrCat(lockstep)});
      o.lockstep_error = lockstep;
    }
    counts.push_back(StreamsAsLocally(args, *path, ply, o));
    EXPECT_GT(counts.back(), 0u);
  }
  // The pass by default (0.5) or at 0.3, and off: the count moves (on the 48³ Link at E0 0.5,
  // SIMPLIFY's passes give the default's and off's the same count, 212, and 0.3's 226).
  EXPECT_TRUE(counts[1] != counts[0] || counts[1] != counts[2]) << counts[0] << " " << counts[1];
  RunResult bad = Client({"stream", "--server", server_->address(), "--input", *path, "--iso",
                          "0", "--lockstep-error", "0", "--out", dir_ + "/bad.ply"});
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.err.find("--lockstep-error 0"), std::string::npos) << bad.err;
}

// The session a streaming client started, as it prints it: its id, its watch key (for
// TANDEM_WATCH_KEY) and ID:TOKEN (for TANDEM_RESUME).
struct Started {
  std::string id, watch_key, resume;
  bool ok() const { return id.size() == 32 && watch_key.size() == 32 && resume.size() == 65; }
};

// What `streamer` printed about its session (bounded wait: up to 10 s).
Started StartedOf(ChildProcess& streamer) {
  Started s;
  for (int i = 0; i < 400 && !s.ok(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
    const std::string err = streamer.Stderr();
    s.resume = PrintedVariable(err, "TANDEM_RESUME");
    s.watch_key = PrintedVariable(err, "TANDEM_WATCH_KEY");
    s.id = s.resume.substr(0, 32);
  }
  if (!s.ok()) ADD_FAILURE() << "no session printed: " << streamer.Stderr();
  return s;
}

std::vector<std::string> WatchKeyEnv(const Started& s) {
  return {"TANDEM_WATCH_KEY=" + s.watch_key};
}

// Watch: a second client attached by id and watch key while a sealed stream runs, and
// another after it ended, save byte-identical meshes to the streaming client's; unknown ids
// and sessions without sealed chunks are refused clearly. Without the key the session does
// not exist for a client: not in info, and its id gets the unknown id's NOT_FOUND.
TEST_F(ServiceE2eTest, WatchersGetTheStreamsMeshLiveAndLate) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  auto streamer = ChildProcess::Spawn(
      {BinPath("tandem-client"), "stream", "--server", server_->address(), "--input", *path,
       "--iso", "0", "--error", "0.05", "--seal", "--rate", "40", "--preview-every", "8",
       "--out", dir_ + "/s.ply"},
      dir_);
  ASSERT_TRUE(streamer.ok()) << streamer.status();
  const Started started = StartedOf(**streamer);
  ASSERT_TRUE(started.ok());
  const std::string& id = started.id;
  // Listed by info while it runs, to a client with the key (from a file), and to no other.
  std::ofstream(dir_ + "/key.txt") << started.watch_key << "\n";
  RunResult info = Client({"info", "--server", server_->address(), "--watch-key-file",
                           dir_ + "/key.txt"});
  EXPECT_NE(info.out.find(id), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("link.json"), std::string::npos) << info.out;
  RunResult stranger = Client({"info", "--server", server_->address()});
  EXPECT_EQ(stranger.exit_code, 0) << stranger.err;
  EXPECT_EQ(stranger.out.find(id), std::string::npos) << stranger.out;
  EXPECT_EQ(stranger.out.find("link.json"), std::string::npos) << stranger.out;
  EXPECT_NE(stranger.out.find("active sessions        1"), std::string::npos) << stranger.out;
  RunResult no_key = Client({"watch", "--server", server_->address(), "--session", id, "--out",
                             dir_ + "/no_key.ply"});
  EXPECT_EQ(no_key.exit_code, 1);
  EXPECT_NE(no_key.err.find("NOT_FOUND: no session '" + id + "' that this call may watch"),
            std::string::npos)
      << no_key.err;
  RunResult wrong_key = Client({"watch", "--server", server_->address(), "--session", id,
                                "--out", dir_ + "/no_key.ply"},
                               120, {"TANDEM_WATCH_KEY=" + std::string(32, 'f')});
  EXPECT_EQ(wrong_key.exit_code, 1);
  EXPECT_NE(wrong_key.err.find("NOT_FOUND"), std::string::npos) << wrong_key.err;
  EXPECT_FALSE(std::filesystem::exists(dir_ + "/no_key.ply"));
  RunResult live = Client({"watch", "--server", server_->address(), "--session", id, "--out",
                           dir_ + "/live.ply", "--chunks", dir_ + "/live", "--metrics",
                           dir_ + "/live.json", "--verbose"},
                          120, WatchKeyEnv(started));
  ASSERT_EQ(live.exit_code, 0) << live.err;
  EXPECT_EQ(live.err.find("warning"), std::string::npos) << live.err;
  ASSERT_EQ((*streamer)->Wait(60), std::optional<int>(0)) << (*streamer)->Stderr();
  EXPECT_NE(live.err.find("progress "), std::string::npos) << "it saw the session run";
  RunResult late = Client({"watch", "--server", server_->address(), "--session", id, "--out",
                           dir_ + "/late.ply", "--watch-key-file", dir_ + "/key.txt"});
  ASSERT_EQ(late.exit_code, 0) << late.err;
  const std::string mesh = ReadFile(dir_ + "/s.ply");
  ASSERT_FALSE(mesh.empty());
  EXPECT_EQ(ReadFile(dir_ + "/live.ply"), mesh);
  EXPECT_EQ(ReadFile(dir_ + "/late.ply"), mesh);
  EXPECT_TRUE(std::filesystem::exists(dir_ + "/live/chunk_000000.drc"));
  auto report = eval::ReportFromJson(ReadFile(dir_ + "/live.json"));
  ASSERT_TRUE(report.ok());
  EXPECT_EQ(report->stats.slices, 96);

  // An unknown id says the same as a known one without its key.
  RunResult unknown = Client({"watch", "--server", server_->address(), "--session",
                              "0123456789abcdef0123456789abcdef", "--out", dir_ + "/u.ply"},
                             120, WatchKeyEnv(started));
  EXPECT_EQ(unknown.exit_code, 1);
  const std::string unknown_text = absl::StrReplaceAll(
      unknown.err, {{"0123456789abcdef0123456789abcdef", id}});
  EXPECT_EQ(unknown_text, no_key.err);
  EXPECT_NE(unknown.err.find("0123456789abcdef0123456789abcdef"), std::string::npos) << unknown.err;
  // A plain (unsealed) stream has an id and a key too, but cannot be watched.
  RunResult plain = Client({"stream", "--server", server_->address(), "--input", *path, "--iso",
                            "0", "--error", "0.5", "--out", dir_ + "/p.ply"});
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  const std::string plain_id = PrintedVariable(plain.err, "TANDEM_RESUME").substr(0, 32);
  ASSERT_EQ(plain_id.size(), 32u) << plain.err;
  const std::string plain_key = PrintedVariable(plain.err, "TANDEM_WATCH_KEY");
  RunResult refused = Client({"watch", "--server", server_->address(), "--session", plain_id,
                              "--out", dir_ + "/r.ply"},
                             120, {"TANDEM_WATCH_KEY=" + plain_key});
  EXPECT_EQ(refused.exit_code, 1);
  EXPECT_NE(refused.err.find("FAILED_PRECONDITION"), std::string::npos) << refused.err;
}

// A watcher that reads nothing holds the stream back in no way, and misses no chunk: the
// watcher's channel has a 1 KiB flow-control window (no BDP probing), so the server cannot
// write it a single chunk while it does not read; the stream still runs to its end. Then the
// watcher reads: every chunk in index order without a gap, as many triangles as the stream's
// final mesh, and its final metrics; of the previews and progress messages sent while it was
// stalled it gets only the latest ones (latest wins), not the backlog.
TEST_F(ServiceE2eTest, AWatcherThatDoesNotReadNeitherSlowsTheStreamNorMissesAChunk) {
  auto path = WriteSyntheticVolume(dir_, "gyroid",
                                   eval::MakeSyntheticSource(eval::Shape::kGyroid, 96, 96, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  auto streamer = ChildProcess::Spawn(
      {BinPath("tandem-client"), "stream", "--server", server_->address(), "--input", *path,
       "--iso", "0", "--error", "0.02", "--seal", "--rate", "40", "--preview-every", "1",
       "--chunks", dir_ + "/chunks", "--out", dir_ + "/s.ply", "--metrics", dir_ + "/s.json"},
      dir_);
  ASSERT_TRUE(streamer.ok()) << streamer.status();
  const Started started = StartedOf(**streamer);
  ASSERT_TRUE(started.ok());

  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 1024);
  auto stub = v1::Tandem::NewStub(
      grpc::CreateCustomChannel(server_->address(), server_->Credentials(), args));
  grpc::ClientContext context;
  server_->AddToken(&context);
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(180));
  v1::WatchRequest request;
  request.set_session_id(started.id);
  request.set_watch_key(started.watch_key);
  auto watch = stub->Watch(&context, request);
  v1::ExtractResponse first;  // attached: the first message is read, then nothing
  ASSERT_TRUE(watch->Read(&first));

  ASSERT_EQ((*streamer)->Wait(120), std::optional<int>(0)) << (*streamer)->Stderr();
  auto report = eval::ReportFromJson(ReadFile(dir_ + "/s.json"));
  ASSERT_TRUE(report.ok()) << report.status();
  size_t chunk_files = 0;
  int64_t chunk_bytes = 0;
  for (const std::string& f : SortedFileNames(dir_ + "/chunks", "chunk_")) {
    ++chunk_files;
    chunk_bytes += static_cast<int64_t>(std::filesystem::file_size(dir_ + "/chunks/" + f));
  }
  ASSERT_GE(chunk_files, 2u);
  ASSERT_GT(chunk_bytes, 64 * 1024) << "the chunks must outgrow the watcher's window many times";

  std::vector<v1::ExtractResponse> got{first};
  for (v1::ExtractResponse m; watch->Read(&m);) got.push_back(m);
  ASSERT_TRUE(watch->Finish().ok());
  // Progress and previews sent once the first chunk was waiting for the window: 96 slices'
  // worth went by, and the watcher gets no backlog of them, only the latest.
  int64_t next_index = 0, triangles = 0, late_updates = 0, finals = 0;
  for (const v1::ExtractResponse& m : got) {
    if (m.has_sealed_chunk()) {
      EXPECT_EQ(m.sealed_chunk().index(), next_index++);
      triangles += m.sealed_chunk().triangles();
    }
    if (next_index > 0) late_updates += m.has_progress() + m.has_preview();
    finals += m.has_final_metrics();
  }
  EXPECT_EQ(next_index, static_cast<int64_t>(chunk_files));
  EXPECT_EQ(triangles, report->triangles_final);
  EXPECT_EQ(finals, 1);
  EXPECT_LE(late_updates, 2 * next_index + 2);
}

// Starts `tandem-client ARGS` in `dir` and waits (bounded) for the session it prints.
std::unique_ptr<ChildProcess> StartStreamer(std::vector<std::string> args, const std::string& dir,
                                            Started* started) {
  args.insert(args.begin(), BinPath("tandem-client"));
  auto child = ChildProcess::Spawn(args, dir);
  if (!child.ok()) {
    ADD_FAILURE() << child.status();
    return nullptr;
  }
  *started = StartedOf(**child);
  return *std::move(child);
}

// The session `id` as GetInfo lists it to a call with its watch key (nullopt while it is
// not listed).
std::optional<v1::SessionSummary> Summary(const TestServer& server, const std::string& id,
                                          const std::string& watch_key) {
  auto info = server.Info({watch_key});
  if (!info.ok()) return std::nullopt;
  for (const v1::SessionSummary& s : info->sessions()) {
    if (s.id() == id) return s;
  }
  return std::nullopt;
}

// Waits (bounded) until `pred` holds for session `id`'s summary.
bool WaitForSession(const TestServer& server, const std::string& id, const std::string& watch_key,
                    const std::function<bool(const v1::SessionSummary&)>& pred,
                    double timeout_s = 20) {
  for (int i = 0; i < timeout_s * 20; ++i) {
    if (auto s = Summary(server, id, watch_key); s && pred(*s)) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return false;
}

// Two mesh files hold the same mesh: the same vertices, bit for bit, and the same
// triangles (vertex order may differ: sealed chunks go out on a clock).
void ExpectSameMesh(const std::string& a_path, const std::string& b_path) {
  auto a = io::ReadMesh(a_path);
  auto b = io::ReadMesh(b_path);
  ASSERT_TRUE(a.ok() && b.ok()) << a.status() << " " << b.status();
  ASSERT_EQ(a->num_vertices(), b->num_vertices());
  ASSERT_EQ(a->num_triangles(), b->num_triangles());
  auto map = MatchVertices(*a, *b, 0.0);
  ASSERT_TRUE(map.ok()) << map.status();
  EXPECT_TRUE(SameTriangles(*a, *b, *map));
}

// Several surfaces in one stream (--iso A,B: SessionConfig.extra_isos): each saved surface
// is the one its own single-iso stream gives (the same bytes), plain; and sealed, live
// through a watcher too, each the same mesh as its single sealed stream.
TEST_F(ServiceE2eTest, SeveralIsoValuesInOneStreamEqualTheirSingleStreams) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 64));
  ASSERT_TRUE(path.ok()) << path.status();
  auto stream = [&](const std::string& iso, const std::string& out,
                    std::vector<std::string> extra) {
    return Client(Concat({"stream", "--server", server_->address(), "--input", *path, "--iso",
                          iso, "--error", "0.02", "--out", dir_ + "/" + out},
                         extra));
  };
  RunResult both = stream("0,0.05", "both_{iso}.ply", {"--metrics", dir_ + "/both.json"});
  ASSERT_EQ(both.exit_code, 0) << both.err;
  const nlohmann::json reports = nlohmann::json::parse(ReadFile(dir_ + "/both.json"));
  ASSERT_TRUE(reports.is_array());
  ASSERT_EQ(reports.size(), 2u);
  EXPECT_EQ(reports[0]["iso"].get<double>(), 0.0);
  EXPECT_EQ(reports[1]["iso"].get<double>(), 0.05);
  for (const std::string iso : {"0", "0.05"}) {
    SCOPED_TRACE(iso);
    RunResult one = stream(iso, "one_" + iso + ".ply", {});
    ASSERT_EQ(one.exit_code, 0) << one.err;
    const std::string mesh = ReadFile(dir_ + "/one_" + iso + ".ply");
    EXPECT_GT(mesh.size(), 10000u);
    EXPECT_EQ(ReadFile(dir_ + "/both_" + iso + ".ply"), mesh);
    // Sealed, one surface alone, for the comparison below.
    RunResult sealed = stream(iso, "sealed_one_" + iso + ".ply", {"--seal"});
    ASSERT_EQ(sealed.exit_code, 0) << sealed.err;
  }
  EXPECT_NE(ReadFile(dir_ + "/both_0.ply"), ReadFile(dir_ + "/both_0.05.ply"));

  // Sealed, watched while it runs: the watcher saves both surfaces too.
  auto streamer = ChildProcess::Spawn(
      {BinPath("tandem-client"), "stream", "--server", server_->address(), "--input", *path,
       "--iso", "0,0.05", "--error", "0.02", "--seal", "--rate", "40", "--chunks",
       dir_ + "/chunks", "--out", dir_ + "/sealed_{iso}.ply"},
      dir_);
  ASSERT_TRUE(streamer.ok()) << streamer.status();
  const Started started = StartedOf(**streamer);
  ASSERT_TRUE(started.ok());
  RunResult live = Client({"watch", "--server", server_->address(), "--session", started.id,
                           "--out", dir_ + "/watched_{iso}.ply"},
                          120, WatchKeyEnv(started));
  ASSERT_EQ(live.exit_code, 0) << live.err;
  ASSERT_EQ((*streamer)->Wait(60), std::optional<int>(0)) << (*streamer)->Stderr();
  for (const std::string iso : {"0", "0.05"}) {
    SCOPED_TRACE(iso);
    ExpectSameMesh(dir_ + "/sealed_" + iso + ".ply", dir_ + "/sealed_one_" + iso + ".ply");
    EXPECT_EQ(ReadFile(dir_ + "/watched_" + iso + ".ply"), ReadFile(dir_ + "/sealed_" + iso + ".ply"));
  }
  EXPECT_TRUE(std::filesystem::exists(dir_ + "/chunks/chunk_000001.drc"));
  // Without {iso}, two surfaces would write one file: refused before anything is sent.
  RunResult clash = stream("0,0.05", "clash.ply", {});
  EXPECT_EQ(clash.exit_code, 2);
  EXPECT_NE(clash.err.find("pattern holding {iso}"), std::string::npos) << clash.err;
}

// A client killed mid-scan and started again with --resume ID:TOKEN: the server kept the
// session (listed as waiting), the new client skips what it has, and the mesh is the one
// an uninterrupted stream gives; plain and sealed.
TEST_F(ServiceE2eTest, AKilledClientRestartedWithResumeGetsTheUninterruptedMesh) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  for (const bool seal : {false, true}) {
    SCOPED_TRACE(seal ? "sealed" : "plain");
    const std::string tag = seal ? "sealed" : "plain";
    std::vector<std::string> base = {"stream", "--server", server_->address(), "--input", *path,
                                     "--iso", "0", "--error", "0.05"};
    if (seal) base.push_back("--seal");
    RunResult whole = Client(Concat(base, {"--out", dir_ + "/whole_" + tag + ".ply"}));
    ASSERT_EQ(whole.exit_code, 0) << whole.err;

    Started started;
    auto first =
        StartStreamer(Concat(base, {"--rate", "40", "--out", dir_ + "/never_" + tag + ".ply"}),
                      dir_, &started);
    ASSERT_TRUE(first != nullptr && started.ok());
    const std::string& id = started.id;
    const std::string& key = started.resume;
    ASSERT_TRUE(WaitForSession(*server_, id, started.watch_key,
                               [](const v1::SessionSummary& s) { return s.slices_consumed() >= 12; }));
    first->Signal(SIGKILL);
    EXPECT_EQ(first->Wait(10), 128 + SIGKILL);
    EXPECT_TRUE(WaitForSession(*server_, id, started.watch_key,
                               [](const v1::SessionSummary& s) { return s.waiting_for_resume(); }));
    RunResult info =
        Client({"info", "--server", server_->address()}, 120, WatchKeyEnv(started));
    EXPECT_NE(info.out.find(id + "  waiting for its client to resume"), std::string::npos)
        << info.out;
    EXPECT_NE(info.out.find("waiting for a resume   1"), std::string::npos) << info.out;

    // The key from the variable (plain) or from a file (sealed), not on the command line.
    std::vector<std::string> args = Concat(base, {"--out", dir_ + "/resumed_" + tag + ".ply",
                                                  "--metrics", dir_ + "/resumed_" + tag + ".json"});
    std::vector<std::string> env;
    if (seal) {
      std::ofstream(dir_ + "/resume.txt") << key << "\n";
      args = Concat(args, {"--resume-file", dir_ + "/resume.txt"});
    } else {
      env.push_back("TANDEM_RESUME=" + key);
    }
    RunResult resumed = Client(args, 120, env);
    ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
    EXPECT_EQ(resumed.err.find("warning"), std::string::npos) << resumed.err;
    EXPECT_NE(resumed.err.find("tandem-client: session " + id + " resumed at slice"),
              std::string::npos)
        << resumed.err;
    ExpectSameMesh(dir_ + "/whole_" + tag + ".ply", dir_ + "/resumed_" + tag + ".ply");
    auto report = eval::ReportFromJson(ReadFile(dir_ + "/resumed_" + tag + ".json"));
    ASSERT_TRUE(report.ok()) << report.status();
    EXPECT_EQ(report->stats.slices, 96);
    EXPECT_FALSE(std::filesystem::exists(dir_ + "/never_" + tag + ".ply"));
  }
  RunResult bad = Client({"stream", "--server", server_->address(), "--input", *path, "--iso", "0",
                          "--error", "0.05", "--resume", "nocolon", "--out", dir_ + "/x.ply"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("ID:TOKEN"), std::string::npos) << bad.err;
}

// A TCP proxy in front of `server`, whose connections a test can cut.
absl::StatusOr<std::unique_ptr<TcpProxy>> ProxyTo(const TestServer& server) {
  const std::string& address = server.address();
  int port = 0;
  if (!absl::SimpleAtoi(address.substr(address.rfind(':') + 1), &port)) {
    return absl::InternalError(absl::StrCat("no port in ", address));
  }
  return TcpProxy::Start(port);
}

// The network path fails mid-scan (every connection through a proxy reset): the running
// client resumes by itself, its chunk files have no gap and no repeat, a watcher attached
// before the cut gets the whole mesh too, and it is the uninterrupted stream's mesh.
TEST_F(ServiceE2eTest, AConnectionCutMidScanIsResumedByTheClientItself) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  const std::string& address = server_->address();
  auto proxy = ProxyTo(*server_);
  ASSERT_TRUE(proxy.ok()) << proxy.status();
  auto args = [&](const std::string& server) {
    return std::vector<std::string>{"stream", "--server", server, "--input", *path, "--iso", "0",
                                    "--error", "0.05", "--seal"};
  };
  RunResult whole = Client(Concat(args(address), {"--out", dir_ + "/whole.ply"}));
  ASSERT_EQ(whole.exit_code, 0) << whole.err;

  Started started;
  auto client = StartStreamer(
      Concat(args((*proxy)->address()), {"--rate", "40", "--chunks", dir_ + "/chunks", "--out",
                                         dir_ + "/cut.ply", "--metrics", dir_ + "/cut.json"}),
      dir_, &started);
  ASSERT_TRUE(client != nullptr && started.ok());
  const std::string& id = started.id;
  auto watcher = ChildProcess::Spawn({BinPath("tandem-client"), "watch", "--server", address,
                                      "--session", id, "--out", dir_ + "/watched.ply"},
                                     dir_, WatchKeyEnv(started));
  ASSERT_TRUE(watcher.ok()) << watcher.status();
  ASSERT_TRUE(WaitForSession(*server_, id, started.watch_key,
                             [](const v1::SessionSummary& s) {
                               return s.slices_consumed() >= 24;
                             }));
  EXPECT_GE((*proxy)->CutAll(), 1);
  ASSERT_EQ(client->Wait(90), std::optional<int>(0)) << client->Stderr();
  const std::string err = client->Stderr();
  EXPECT_NE(err.find("the stream broke"), std::string::npos) << err;
  EXPECT_NE(err.find("resumed at slice"), std::string::npos) << err;
  ExpectSameMesh(dir_ + "/whole.ply", dir_ + "/cut.ply");
  auto report = eval::ReportFromJson(ReadFile(dir_ + "/cut.json"));
  ASSERT_TRUE(report.ok()) << report.status();
  // Every chunk once, named without a gap, and no temporary file left.
  const std::vector<std::string> files = SortedFileNames(dir_ + "/chunks", "chunk_");
  ASSERT_FALSE(files.empty());
  char last[32];
  std::snprintf(last, sizeof(last), "chunk_%06zu.drc", files.size() - 1);
  EXPECT_EQ(files.back(), last);
  ASSERT_EQ((*watcher)->Wait(60), std::optional<int>(0)) << (*watcher)->Stderr();
  EXPECT_EQ(ReadFile(dir_ + "/watched.ply"), ReadFile(dir_ + "/cut.ply"));
}

// The request stream of a synthetic n x n x nz shape, iso 0, E0 0.05, 1 MiB chunks.
std::vector<v1::ExtractRequest> ShapeRequests(eval::Shape shape, int64_t n, int64_t nz) {
  v1::SessionConfig config;
  config.set_iso(0);
  config.set_error(0.05);
  auto source = eval::MakeSyntheticSource(shape, n, n, nz);
  return VolumeRequests(*source, config, 1 << 20);
}

// Starts a stream, sends the config and slices 0..slices-1, waits until they are consumed,
// then vanishes (cancels). Sets the session's id, resume token and watch key.
void VanishMidScan(v1::Tandem::Stub& stub, const std::vector<v1::ExtractRequest>& requests,
                   int64_t slices, std::string* id, std::string* token,
                   std::string* watch_key) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  auto stream = stub.Extract(&context);
  for (const v1::ExtractRequest& r : requests) {
    if (r.has_end() || (r.has_chunk() && r.chunk().slice() >= slices)) break;
    if (!stream->Write(r)) break;
  }
  v1::ExtractResponse response;
  while (stream->Read(&response)) {
    if (response.has_progress() && !response.progress().session_id().empty()) {
      *id = response.progress().session_id();
      *token = response.progress().resume_token();
      *watch_key = response.progress().watch_key();
    }
    if (response.has_progress() && response.progress().slices_consumed() == slices) break;
  }
  context.TryCancel();
  stream->Finish();
}

// Resume by the protocol itself: wrong id, token or slice are refused clearly and leave
// the session waiting; the right resume gives the uninterrupted stream's final mesh, byte
// for byte; a session nobody resumes ends after the window and leaves nothing behind.
// Several surfaces in one stream survive a cut too: the client resumes the one session
// (its chunk indices count all surfaces) and each surface is the uninterrupted stream's.
TEST_F(ServiceE2eTest, ACutStreamOfSeveralSurfacesResumesEachOfThem) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  const std::string& address = server_->address();
  auto proxy = ProxyTo(*server_);
  ASSERT_TRUE(proxy.ok()) << proxy.status();
  auto args = [&](const std::string& server) {
    return std::vector<std::string>{"stream", "--server", server, "--input", *path, "--iso",
                                    "0,0.05", "--error", "0.05", "--seal"};
  };
  RunResult whole = Client(Concat(args(address), {"--out", dir_ + "/whole_{iso}.ply"}));
  ASSERT_EQ(whole.exit_code, 0) << whole.err;
  Started started;
  auto client = StartStreamer(
      Concat(args((*proxy)->address()), {"--rate", "40", "--out", dir_ + "/cut_{iso}.ply"}), dir_,
      &started);
  ASSERT_TRUE(client != nullptr && started.ok());
  ASSERT_TRUE(WaitForSession(*server_, started.id, started.watch_key,
                             [](const v1::SessionSummary& s) {
                               return s.slices_consumed() >= 24;
                             }));
  EXPECT_GE((*proxy)->CutAll(), 1);
  ASSERT_EQ(client->Wait(90), std::optional<int>(0)) << client->Stderr();
  EXPECT_NE(client->Stderr().find("resumed at slice"), std::string::npos) << client->Stderr();
  for (const std::string iso : {"0", "0.05"}) {
    SCOPED_TRACE(iso);
    ExpectSameMesh(dir_ + "/whole_" + iso + ".ply", dir_ + "/cut_" + iso + ".ply");
  }
}

TEST(ServiceResume, BadResumesAreRefusedAndAnUnclaimedSessionEnds) {
  auto server = TestServer::Start({"--resume-window-seconds", "8"});
  ASSERT_TRUE(server.ok()) << server.status();
  auto stub = (*server)->NewStub();
  const std::vector<v1::ExtractRequest> requests = ShapeRequests(eval::Shape::kLink, 48, 40);
  StreamOutcome whole = RunStream(*stub, requests);
  ASSERT_TRUE(whole.status.ok()) << whole.status.error_message();

  std::string id, token, watch_key;
  VanishMidScan(*stub, requests, 10, &id, &token, &watch_key);
  ASSERT_EQ(id.size(), 32u);
  ASSERT_EQ(token.size(), 32u);
  ASSERT_EQ(watch_key.size(), 32u);
  EXPECT_NE(watch_key, token) << "watching is not resuming";
  ASSERT_TRUE(WaitForSession(**server, id, watch_key, [](const v1::SessionSummary& s) {
    return s.waiting_for_resume() && s.slices_consumed() == 10;
  }));

  // The rest of the stream, as a resume from `next`.
  auto resume = [&](const std::string& rid, const std::string& rtoken, int64_t next) {
    std::vector<v1::ExtractRequest> rest;
    v1::ExtractRequest head;
    head.mutable_config()->mutable_resume()->set_session_id(rid);
    head.mutable_config()->mutable_resume()->set_token(rtoken);
    head.mutable_config()->mutable_resume()->set_next_slice(next);
    rest.push_back(head);
    for (const v1::ExtractRequest& r : requests) {
      if (r.has_end() || (r.has_chunk() && r.chunk().slice() >= next)) rest.push_back(r);
    }
    return RunStream(*stub, rest);
  };
  StreamOutcome unknown = resume("0123456789abcdef0123456789abcdef", token, 10);
  EXPECT_EQ(unknown.status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_NE(unknown.status.error_message().find("0123456789abcdef0123456789abcdef"),
            std::string::npos);
  StreamOutcome stolen = resume(id, std::string(32, '0'), 10);
  EXPECT_EQ(stolen.status.error_code(), grpc::StatusCode::PERMISSION_DENIED)
      << stolen.status.error_message();
  EXPECT_NE(stolen.status.error_message().find("token"), std::string::npos);
  StreamOutcome early = resume(id, token, 3);
  EXPECT_EQ(early.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(early.status.error_message().find("expects slice 10"), std::string::npos)
      << early.status.error_message();
  EXPECT_EQ(early.trailers["tandem-expected-slice"], "10");
  StreamOutcome late = resume(id, token, 12);
  EXPECT_EQ(late.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);

  StreamOutcome good = resume(id, token, 10);
  ASSERT_TRUE(good.status.ok()) << good.status.error_message();
  ASSERT_FALSE(good.responses.empty());
  EXPECT_EQ(good.responses.front().progress().session_id(), id);
  EXPECT_TRUE(good.responses.front().progress().resume_token().empty()) << "creator only";
  EXPECT_EQ(good.responses.front().progress().watch_key(), watch_key);
  EXPECT_EQ(good.responses.front().progress().slices_consumed(), 10);
  auto final_mesh = [](const StreamOutcome& o) {
    std::string draco;
    for (const v1::ExtractResponse& r : o.responses) {
      if (r.has_final_mesh()) draco += r.final_mesh().draco();
    }
    return draco;
  };
  EXPECT_FALSE(final_mesh(good).empty());
  EXPECT_EQ(final_mesh(good), final_mesh(whole));
  EXPECT_EQ(good.responses.back().final_metrics().slices(), 40);
  // Resumed once, it is gone: a second resume finds nothing.
  EXPECT_EQ(resume(id, token, 10).status.error_code(), grpc::StatusCode::NOT_FOUND);

  // Nobody resumes the next one: after the 8 s window it ends, and nothing is left.
  std::string id2, token2, watch_key2;
  VanishMidScan(*stub, requests, 10, &id2, &token2, &watch_key2);
  ASSERT_TRUE(WaitForSession(**server, id2, watch_key2,
                             [](const v1::SessionSummary& s) { return s.waiting_for_resume(); }));
  v1::Counters counters;
  EXPECT_TRUE((*server)->WaitIdle(20, &counters)) << counters.ShortDebugString();
  EXPECT_TRUE(WaitForSession(**server, id2, watch_key2, [](const v1::SessionSummary& s) {
    return s.finished() && !s.waiting_for_resume();
  }));
  EXPECT_EQ(resume(id2, token2, 10).status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ((*server)->Health(), "SERVING");
}

// Two replicas behind client-side round robin: the resume of a killed client reaches
// the replica that holds the session by trying the next one after a NOT_FOUND.
TEST(ServiceResume, ARoundRobinClientFindsTheReplicaWithItsSession) {
  const std::string dir = MakeTempDir();
  auto a = TestServer::Start();
  auto b = TestServer::Start();
  ASSERT_TRUE(a.ok() && b.ok());
  const std::string target = absl::StrCat("ipv4:", (*a)->address(), ",", (*b)->address());
  auto path =
      WriteSyntheticVolume(dir, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 48, 48, 80));
  ASSERT_TRUE(path.ok()) << path.status();
  const std::vector<std::string> base = {"stream", "--server", target, "--lb", "round_robin",
                                         "--input", *path, "--iso", "0", "--error", "0.05"};
  RunResult whole = Client(Concat(base, {"--out", dir + "/whole.ply"}));
  ASSERT_EQ(whole.exit_code, 0) << whole.err;
  for (int round = 0; round < 2; ++round) {  // the session on either replica
    SCOPED_TRACE(round);
    Started started;
    auto first =
        StartStreamer(Concat(base, {"--rate", "25", "--out", dir + "/never.ply"}), dir, &started);
    ASSERT_TRUE(first != nullptr && started.ok());
    const std::string& id = started.id;
    const std::string& key = started.resume;
    TestServer& holder = Summary(**a, id, started.watch_key) ? **a : **b;
    ASSERT_TRUE(WaitForSession(holder, id, started.watch_key,
                               [](const v1::SessionSummary& s) { return s.slices_consumed() >= 10; }));
    first->Signal(SIGKILL);
    first->Wait(10);
    ASSERT_TRUE(WaitForSession(holder, id, started.watch_key,
                               [](const v1::SessionSummary& s) { return s.waiting_for_resume(); }));
    const std::string out = dir + "/resumed" + std::to_string(round) + ".ply";
    // --resume on the command line still works, with a warning that others can read it.
    RunResult resumed = Client(Concat(base, {"--resume", key, "--out", out}));
    ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
    EXPECT_NE(resumed.err.find("tandem-client: warning: --resume on the command line can be read "
                               "by every user of this machine (ps); use --resume-file FILE or "
                               "$TANDEM_RESUME instead"),
              std::string::npos)
        << resumed.err;
    ExpectSameMesh(dir + "/whole.ply", out);
  }
}

// A deep sealed scan, whose chunks outgrow the server's --watch-retain-mb (0 here: it keeps
// only the newest for watchers), resumed by a new client process after a SIGKILL: with the
// first run's --chunks DIR it asks only for the chunks not saved there, which the server kept
// because they were not acknowledged, and the mesh is the uninterrupted stream's; without
// them the resume is refused, naming --chunks DIR.
TEST(ServiceResume, AKilledClientResumesFromItsChunkFolderPastTheWatchRetention) {
  const std::string dir = MakeTempDir();
  auto server = TestServer::Start({"--watch-retain-mb", "0", "--resume-window-seconds", "8"});
  ASSERT_TRUE(server.ok()) << server.status();
  // A gyroid through every slice: a chunk about every second at --rate 30.
  auto path = WriteSyntheticVolume(
      dir, "gyroid", eval::MakeSyntheticSource(eval::Shape::kGyroid, 64, 64, 192, {1, 1, 1.0 / 3}));
  ASSERT_TRUE(path.ok()) << path.status();
  const std::vector<std::string> base = {"stream", "--server", (*server)->address(), "--input",
                                         *path, "--iso", "0", "--error", "0.05", "--seal"};
  RunResult whole = Client(Concat(base, {"--out", dir + "/whole.ply"}));
  ASSERT_EQ(whole.exit_code, 0) << whole.err;
  for (const bool keep : {true, false}) {
    SCOPED_TRACE(keep ? "with --chunks" : "without --chunks");
    const std::string tag = keep ? "kept" : "lost";
    const std::string chunks = dir + "/chunks_" + tag;
    std::vector<std::string> args = base;
    if (keep) args = Concat(args, {"--chunks", chunks});
    Started started;
    auto first = StartStreamer(Concat(args, {"--rate", "30", "--out", dir + "/never.ply"}), dir,
                               &started);
    ASSERT_TRUE(first != nullptr && started.ok());
    // Killed once several chunks came (saved, with --chunks) and the server's watch retention
    // dropped them: mid-scan.
    ASSERT_TRUE(WaitForSession(**server, started.id, started.watch_key,
                               [](const v1::SessionSummary& s) {
                                 return s.slices_consumed() >= 100;
                               }));
    const std::string fourth = chunks + "/chunk_000003.drc";
    for (int i = 0; i < 400 && keep && !std::filesystem::exists(fourth); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(25));
    }
    ASSERT_LT(Summary(**server, started.id, started.watch_key)->slices_consumed(), 192);
    first->Signal(SIGKILL);
    EXPECT_EQ(first->Wait(10), 128 + SIGKILL);
    ASSERT_TRUE(WaitForSession(**server, started.id, started.watch_key,
                               [](const v1::SessionSummary& s) { return s.waiting_for_resume(); }));
    if (keep) {
      ASSERT_TRUE(std::filesystem::exists(fourth)) << first->Stderr();
    }
    const std::string out = dir + "/resumed_" + tag + ".ply";
    RunResult resumed = Client(Concat(args, {"--out", out, "--verbose"}), 120,
                               {"TANDEM_RESUME=" + started.resume});
    if (!keep) {
      EXPECT_EQ(resumed.exit_code, 1) << resumed.err;
      EXPECT_NE(resumed.err.find("FAILED_PRECONDITION: session " + started.id +
                                 " cannot resend its sealed chunks from index 0"),
                std::string::npos)
          << resumed.err;
      EXPECT_NE(resumed.err.find("tandem-client stream --chunks DIR"), std::string::npos)
          << resumed.err;
      EXPECT_FALSE(std::filesystem::exists(out));
      continue;
    }
    ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
    int64_t kept = -1;
    const std::string note = " sealed chunks kept in " + chunks + "; the server sends the rest";
    const size_t note_at = resumed.err.find(note);
    ASSERT_NE(note_at, std::string::npos) << resumed.err;
    const size_t number_at = resumed.err.rfind(' ', note_at - 1) + 1;
    ASSERT_TRUE(absl::SimpleAtoi(resumed.err.substr(number_at, note_at - number_at), &kept))
        << resumed.err;
    EXPECT_GE(kept, 3) << resumed.err;
    // The folder's chunks, then the server's from where the folder stopped: each chunk once.
    const std::vector<std::string> files = SortedFileNames(chunks);
    ASSERT_GE(files.size(), static_cast<size_t>(kept) + 2);
    for (size_t i = 0; i + 1 < files.size(); ++i) {
      const std::string line = absl::StrFormat("chunk index=%d ", i);
      const size_t seen = resumed.err.find(line, note_at);
      EXPECT_NE(seen, std::string::npos) << line << resumed.err;
      EXPECT_EQ(resumed.err.find(line, seen + 1), std::string::npos) << line << resumed.err;
    }
    ExpectSameMesh(dir + "/whole.ply", out);
    // The folder holds every chunk once, listed in its manifest, no temporary file left.
    EXPECT_EQ(files.back(), "chunks.tsv");
    for (size_t i = 0; i + 1 < files.size(); ++i) {
      EXPECT_EQ(files[i], absl::StrFormat("chunk_%06d.drc", i));
    }
    const std::vector<std::string> lines =
        absl::StrSplit(ReadFile(chunks + "/chunks.tsv"), '\n', absl::SkipEmpty());
    EXPECT_EQ(lines.size(), files.size()) << "the session line and one a chunk";
    EXPECT_EQ(lines.front(), "session\t" + started.id);
  }
  v1::Counters counters;
  EXPECT_TRUE((*server)->WaitIdle(20, &counters)) << counters.ShortDebugString();
}

// Sessions live in the server's memory: a killed client resumed against the restarted
// server is told that its session is gone and to send the scan again, not a bare NOT_FOUND.
TEST(ServiceResume, AResumeAfterTheServerRestartedSaysTheSessionIsLost) {
  const std::string dir = MakeTempDir();
  auto path = WriteSyntheticVolume(dir, "sphere",
                                   eval::MakeSyntheticSource(eval::Shape::kSphere, 48, 48, 96));
  ASSERT_TRUE(path.ok()) << path.status();
  Started started;
  {
    auto server = TestServer::Start();
    ASSERT_TRUE(server.ok()) << server.status();
    auto first = StartStreamer({"stream", "--server", (*server)->address(), "--input", *path,
                                "--iso", "0", "--rate", "30", "--out", dir + "/never.ply"},
                               dir, &started);
    ASSERT_TRUE(first != nullptr && started.ok());
    ASSERT_TRUE(WaitForSession(**server, started.id, started.watch_key,
                               [](const v1::SessionSummary& s) {
                                 return s.slices_consumed() >= 10;
                               }));
    first->Signal(SIGKILL);
    EXPECT_EQ(first->Wait(10), 128 + SIGKILL);
    (*server)->process().Signal(SIGKILL);
  }
  auto restarted = TestServer::Start();
  ASSERT_TRUE(restarted.ok()) << restarted.status();
  RunResult resumed = Client({"stream", "--server", (*restarted)->address(), "--input", *path,
                              "--iso", "0", "--out", dir + "/resumed.ply"},
                             120, {"TANDEM_RESUME=" + started.resume});
  EXPECT_EQ(resumed.exit_code, 1) << resumed.err;
  EXPECT_NE(resumed.err.find("NOT_FOUND: the server no longer has session " + started.id +
                             " (it restarted or the session expired); send the scan again "
                             "without --resume"),
            std::string::npos)
      << resumed.err;
  EXPECT_FALSE(std::filesystem::exists(dir + "/resumed.ply"));
  // Sent again without the resume, the scan gives its mesh.
  RunResult again = Client({"stream", "--server", (*restarted)->address(), "--input", *path,
                            "--iso", "0", "--out", dir + "/again.ply"});
  EXPECT_EQ(again.exit_code, 0) << again.err;
}

// The server side of a resume from the client's folder: a session whose client asked for
// chunk_acks keeps every chunk the client has not acknowledged although --watch-retain-mb
// (0 here) dropped them for watchers, while it waits for the resume; a resume that holds
// none of them gets them all again, and the chunks make up the uninterrupted stream's mesh.
// Without chunk_acks the same resume is refused: the server no longer has chunk 0.
TEST(ServiceResume, UnacknowledgedChunksWaitWithTheParkedSession) {
  auto server = TestServer::Start({"--watch-retain-mb", "0", "--resume-window-seconds", "8"});
  ASSERT_TRUE(server.ok()) << server.status();
  auto stub = (*server)->NewStub();
  std::vector<v1::ExtractRequest> requests = ShapeRequests(eval::Shape::kGyroid, 40, 40);
  requests.front().mutable_config()->set_sealed_chunks(true);
  StreamOutcome whole = RunStream(*stub, requests);
  ASSERT_TRUE(whole.status.ok()) << whole.status.error_message();
  ASSERT_TRUE(whole.responses.back().has_final_metrics());
  const int64_t triangles = whole.responses.back().final_metrics().triangles_final();
  constexpr int64_t kVanishAt = 36;

  for (const bool acks : {true, false}) {
    SCOPED_TRACE(acks ? "chunk_acks" : "no chunk_acks");
    std::vector<v1::ExtractRequest> mine = requests;
    mine.front().mutable_config()->set_chunk_acks(acks);
    // Paced (a chunk comes about every second), never acknowledging, then gone.
    std::string id, token, watch_key;
    int64_t chunks_seen = 0;
    {
      grpc::ClientContext context;
      context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
      auto stream = stub->Extract(&context);
      std::thread writer([&] {
        for (const v1::ExtractRequest& r : mine) {
          if (r.has_end() || (r.has_chunk() && r.chunk().slice() >= kVanishAt)) break;
          if (r.has_chunk()) std::this_thread::sleep_for(std::chrono::milliseconds(70));
          if (!stream->Write(r)) break;
        }
      });
      v1::ExtractResponse response;
      while (stream->Read(&response)) {
        if (response.has_progress() && !response.progress().session_id().empty()) {
          id = response.progress().session_id();
          token = response.progress().resume_token();
          watch_key = response.progress().watch_key();
          EXPECT_EQ(response.progress().chunk_acks(), acks);
        }
        if (response.has_sealed_chunk()) ++chunks_seen;
        if (response.has_progress() && response.progress().slices_consumed() == kVanishAt) break;
      }
      writer.join();
      context.TryCancel();
      stream->Finish();
    }
    ASSERT_GE(chunks_seen, 2) << "the watch retention dropped some";
    ASSERT_TRUE(WaitForSession(**server, id, watch_key, [](const v1::SessionSummary& s) {
      return s.waiting_for_resume();
    }));
    std::vector<v1::ExtractRequest> rest;
    v1::ExtractRequest head;
    head.mutable_config()->mutable_resume()->set_session_id(id);
    head.mutable_config()->mutable_resume()->set_token(token);
    head.mutable_config()->mutable_resume()->set_next_slice(kVanishAt);
    head.mutable_config()->mutable_resume()->set_chunks_received(0);
    rest.push_back(head);
    for (const v1::ExtractRequest& r : mine) {
      if (r.has_end() || (r.has_chunk() && r.chunk().slice() >= kVanishAt)) rest.push_back(r);
    }
    StreamOutcome resumed = RunStream(*stub, rest);
    if (!acks) {
      EXPECT_EQ(resumed.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
      EXPECT_NE(resumed.status.error_message().find("cannot resend its sealed chunks from index 0"),
                std::string::npos)
          << resumed.status.error_message();
      continue;
    }
    ASSERT_TRUE(resumed.status.ok()) << resumed.status.error_message();
    int64_t next = 0, sum = 0;
    for (const v1::ExtractResponse& r : resumed.responses) {
      if (!r.has_sealed_chunk()) continue;
      EXPECT_EQ(r.sealed_chunk().index(), next);
      ++next;
      sum += r.sealed_chunk().triangles();
    }
    EXPECT_GT(next, chunks_seen);
    ASSERT_TRUE(resumed.responses.back().has_final_metrics());
    EXPECT_EQ(resumed.responses.back().final_metrics().triangles_final(), triangles);
    EXPECT_EQ(sum, triangles);
  }
}

// ChunksReceived is the client's word about what it saved: on a stream that did not ask for
// chunk_acks, or above the chunks sent, it ends the stream with INVALID_ARGUMENT naming why.
TEST(ServiceResume, ChunksReceivedOutOfTurnIsRefusedNamingTheRule) {
  auto server = TestServer::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  auto stub = (*server)->NewStub();
  std::vector<v1::ExtractRequest> requests = ShapeRequests(eval::Shape::kSphere, 32, 24);
  requests.front().mutable_config()->set_sealed_chunks(true);
  v1::ExtractRequest ack;
  ack.mutable_chunks_received()->set_count(5);

  StreamOutcome unasked = RunStream(*stub, {requests.front(), ack});
  EXPECT_EQ(unasked.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(unasked.status.error_message().find("SessionConfig.chunk_acks"), std::string::npos)
      << unasked.status.error_message();

  // Asked for, after the first Progress said so, but above the chunks sent (none yet).
  requests.front().mutable_config()->set_chunk_acks(true);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  auto stream = stub->Extract(&context);
  ASSERT_TRUE(stream->Write(requests.front()));
  v1::ExtractResponse first;
  ASSERT_TRUE(stream->Read(&first));
  ASSERT_TRUE(first.has_progress());
  EXPECT_TRUE(first.progress().chunk_acks());
  const std::string id = first.progress().session_id();
  stream->Write(ack);
  stream->WritesDone();
  v1::ExtractResponse rest;
  while (stream->Read(&rest)) {
  }
  const grpc::Status st = stream->Finish();
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st.error_message(),
            "ChunksReceived.count = 5, but session " + id + " has sent 0 sealed chunks");
  v1::Counters counters;
  EXPECT_TRUE((*server)->WaitIdle(20, &counters)) << counters.ShortDebugString();
}

// A session waiting for a resume holds a session slot, but gives it up to a new stream
// that would otherwise be refused as busy.
TEST(ServiceResume, AWaitingSessionGivesItsSlotToANewStream) {
  auto server = TestServer::Start({"--max-sessions", "1"});
  ASSERT_TRUE(server.ok()) << server.status();
  auto stub = (*server)->NewStub();
  const std::vector<v1::ExtractRequest> requests = ShapeRequests(eval::Shape::kSphere, 32, 24);
  std::string id, token, watch_key;
  VanishMidScan(*stub, requests, 8, &id, &token, &watch_key);
  ASSERT_TRUE(WaitForSession(**server, id, watch_key,
                             [](const v1::SessionSummary& s) { return s.waiting_for_resume(); }));
  // The parked session holds the vanished stream's slot from the moment it waits, whether or
  // not gRPC has finished with that stream (a new stream in between was refused as busy).
  StreamOutcome next = RunStream(*stub, requests);
  EXPECT_TRUE(next.status.ok()) << next.status.error_message();
  // The next stream's slot is free once gRPC has finished with it (bounded: 5 s).
  for (int i = 0; i < 200; ++i) {
    auto info = (*server)->Info();
    if (info.ok() && info->counters().active_sessions() == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  v1::ExtractRequest head;
  head.mutable_config()->mutable_resume()->set_session_id(id);
  head.mutable_config()->mutable_resume()->set_token(token);
  head.mutable_config()->mutable_resume()->set_next_slice(8);
  StreamOutcome resumed = RunStream(*stub, {head});
  EXPECT_EQ(resumed.status.error_code(), grpc::StatusCode::NOT_FOUND);
  v1::Counters counters;
  EXPECT_TRUE((*server)->WaitIdle(20, &counters)) << counters.ShortDebugString();
}

TEST_F(ServiceE2eTest, SealedChunksRefuseATargetTriangleCount) {
  auto path =
      WriteSyntheticVolume(dir_, "s", eval::MakeSyntheticSource(eval::Shape::kSphere, 16, 16, 16));
  ASSERT_TRUE(path.ok());
  RunResult r = Client({"stream", "--server", server_->address(), "--input", *path, "--iso", "0",
                        "--error", "0.1", "--out", dir_ + "/x.ply", "--seal",
                        "--target-triangles", "100"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--target-triangles"), std::string::npos) << r.err;
}

// ---------------------------------------------------------------------------------------
// Shutdown: one server per test, started here.

// Streams a sphere of nz slices at `rate` slices/s to the server with the real client,
// and returns once the server reports the session active (nullptr on failure).
std::unique_ptr<ChildProcess> StartPacedStream(TestServer& server, const std::string& dir,
                                               int64_t nxy, int64_t nz, int rate) {
  auto path = WriteSyntheticVolume(dir, "sphere",
                                   eval::MakeSyntheticSource(eval::Shape::kSphere, nxy, nxy, nz));
  EXPECT_TRUE(path.ok());
  if (!path.ok()) return nullptr;
  std::vector<std::string> argv = {BinPath("tandem-client"), "stream", "--server",
                                   server.address(), "--input", *path, "--iso", "0",
                                   "--error", "0.5", "--rate", std::to_string(rate),
                                   "--out", dir + "/s.drc"};
  auto client = ChildProcess::Spawn(argv, dir);
  EXPECT_TRUE(client.ok());
  if (!client.ok()) return nullptr;
  for (int i = 0; i < 200; ++i) {
    auto info = server.Info();
    if (info.ok() && info->counters().active_sessions() == 1) return *std::move(client);
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  ADD_FAILURE() << "the stream never became active";
  return nullptr;
}

TEST(ServiceShutdown, SigtermLetsARunningStreamFinishThenExitsZero) {
  const std::string dir = MakeTempDir();
  auto server = TestServer::Start({"--grace-seconds", "30"});
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = StartPacedStream(**server, dir, 40, 60, 40);
  ASSERT_TRUE(client);
  (*server)->process().Signal(SIGTERM);
  EXPECT_EQ(client->Wait(30), 0) << client->Stderr();
  EXPECT_TRUE(std::filesystem::exists(dir + "/s.drc"));
  EXPECT_EQ((*server)->process().Wait(30), 0) << (*server)->process().Stderr();
  const std::string log = (*server)->process().Stderr();
  EXPECT_NE(log.find("SIGTERM: draining"), std::string::npos) << log;
  EXPECT_NE(log.find("running ones (1)"), std::string::npos) << "it ran at the SIGTERM: " << log;
  EXPECT_NE(log.find("status=OK"), std::string::npos) << log;
  EXPECT_NE(log.find("stopped"), std::string::npos) << log;
}

TEST(ServiceShutdown, StreamsPastTheGracePeriodEndWithUnavailable) {
  const std::string dir = MakeTempDir();
  auto server = TestServer::Start({"--grace-seconds", "0.3"});
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = StartPacedStream(**server, dir, 24, 100, 10);
  ASSERT_TRUE(client);
  (*server)->process().Signal(SIGTERM);
  EXPECT_EQ((*server)->process().Wait(20), 0) << (*server)->process().Stderr();
  EXPECT_EQ(client->Wait(20), 1) << client->Stderr();
  const std::string err = client->Stderr();
  EXPECT_NE(err.find("UNAVAILABLE"), std::string::npos) << err;
  EXPECT_NE(err.find("did not finish within its --grace-seconds (0.3 s)"), std::string::npos)
      << err;
  const std::string log = (*server)->process().Stderr();
  EXPECT_NE(log.find("status=UNAVAILABLE"), std::string::npos) << log;
  EXPECT_NE(log.find("grace period over: 1 streams ended with UNAVAILABLE"), std::string::npos)
      << log;
}

// What a load balancer sees: from SIGTERM on, readiness ("") is NOT_SERVING while liveness
// stays SERVING and new streams are still accepted for --drain-delay-seconds; then the
// server exits, an idle client connection holding nothing up.
TEST(ServiceShutdown, DrainDelayKeepsServingWhileNotReady) {
  const std::string dir = MakeTempDir();
  auto volume =
      WriteSyntheticVolume(dir, "s", eval::MakeSyntheticSource(eval::Shape::kSphere, 20, 20, 20));
  ASSERT_TRUE(volume.ok()) << volume.status();
  auto server = TestServer::Start({"--drain-delay-seconds", "3", "--grace-seconds", "5"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  EXPECT_EQ(s.Health(), "SERVING");
  EXPECT_EQ(s.Health("liveness"), "SERVING");
  EXPECT_EQ(s.Health("tandem.v1.Tandem"), "SERVING");
  // An idle connection: connected, one call done, kept open until the end of the test.
  auto idle = s.NewStub();
  {
    grpc::ClientContext context;
    v1::InfoResponse info;
    ASSERT_TRUE(idle->GetInfo(&context, v1::InfoRequest(), &info).ok());
  }
  const auto signalled = std::chrono::steady_clock::now();
  s.process().Signal(SIGTERM);
  std::string health;
  for (int i = 0; i < 100 && health != "NOT_SERVING"; ++i) {
    health = s.Health();
    if (health != "NOT_SERVING") std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(health, "NOT_SERVING");
  EXPECT_EQ(s.Health("tandem.v1.Tandem"), "NOT_SERVING");
  EXPECT_EQ(s.Health("liveness"), "SERVING");
  RunResult r = RunProcess({BinPath("tandem-client"), "stream", "--server", s.address(),
                            "--input", *volume, "--iso", "0", "--error", "0.2", "--out",
                            dir + "/during_delay.ply"});
  EXPECT_EQ(r.exit_code, 0) << "a stream started during the delay is served\n" << r.err;
  EXPECT_LT(std::chrono::steady_clock::now() - signalled, std::chrono::milliseconds(2500))
      << "the stream must start within the delay for this test to mean anything";
  EXPECT_EQ(s.process().Wait(15), 0) << s.process().Stderr();
  const double exit_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - signalled).count();
  const std::string log = s.process().Stderr();
  EXPECT_GE(exit_s, 3.0) << "exited before the drain delay was over\n" << log;
  EXPECT_LT(exit_s, 6.0) << "nothing was running: the grace period must not be waited out\n"
                         << log;
  EXPECT_NE(log.find("SIGTERM: NOT_SERVING; still accepting streams for 3.0 s"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("stopped"), std::string::npos) << log;
}

// From SIGTERM to the exit, health checks get answers: "" and tandem.v1.Tandem NOT_SERVING,
// "liveness" SERVING, after the drain delay too, while a running stream finishes (gRPC has
// stopped listening then: a stand-in answers on the port); a new stream is refused with
// UNAVAILABLE; the running one ends OK and the server exits 0. gRPC closes its port before
// the stand-in can bind it, so the checks that fall in that moment are refused: one gap of a
// few checks at most (under the sanitizers it spans a check or two), never a second one.
TEST(ServiceShutdown, HealthAnswersNotServingUntilTheExit) {
  const std::string dir = MakeTempDir();
  auto server = TestServer::Start({"--drain-delay-seconds", "0.5", "--grace-seconds", "30"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  auto client = StartPacedStream(s, dir, 32, 80, 20);  // 4 s of scan
  ASSERT_TRUE(client);
  const auto signalled = std::chrono::steady_clock::now();
  s.process().Signal(SIGTERM);
  std::this_thread::sleep_for(std::chrono::milliseconds(1000));  // past the delay
  auto stub = s.NewStub();
  const StreamOutcome refused = RunStream(*stub, ShapeRequests(eval::Shape::kSphere, 16, 16));
  EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_NE(refused.status.error_message().find("shutting down"), std::string::npos)
      << refused.status.error_message();
  int answered = 0, unanswered = 0, gaps = 0;
  bool in_gap = false;
  auto check = [&](const std::string& got, const std::string& want) {
    if (got == "UNAVAILABLE") {
      ++unanswered;
      if (!in_gap) ++gaps;
      in_gap = true;
      return;
    }
    in_gap = false;
    ++answered;
    EXPECT_EQ(got, want);
  };
  while (!client->Wait(0).has_value() &&
         std::chrono::steady_clock::now() - signalled < std::chrono::seconds(20)) {
    check(s.Health(), "NOT_SERVING");
    check(s.Health("tandem.v1.Tandem"), "NOT_SERVING");
    check(s.Health("liveness"), "SERVING");
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  EXPECT_GE(answered, 9) << "the stream ended too soon for this test to mean anything";
  EXPECT_LE(gaps, 1) << unanswered << " checks refused";
  EXPECT_LE(unanswered, 6) << "the stand-in took more than a moment to answer";
  EXPECT_EQ(client->Wait(30), 0) << client->Stderr();
  EXPECT_EQ(s.process().Wait(30), 0) << s.process().Stderr();
  const std::string log = s.process().Stderr();
  EXPECT_NE(log.find("status=OK"), std::string::npos) << log;
  EXPECT_EQ(log.find("health checks go unanswered"), std::string::npos) << log;
}

// A second signal cuts the drain delay short.
TEST(ServiceShutdown, SecondSignalEndsTheDrainDelay) {
  auto server = TestServer::Start({"--drain-delay-seconds", "60"});
  ASSERT_TRUE(server.ok()) << server.status();
  (*server)->process().Signal(SIGTERM);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  (*server)->process().Signal(SIGINT);
  EXPECT_EQ((*server)->process().Wait(10), 0) << (*server)->process().Stderr();
  EXPECT_NE((*server)->process().Stderr().find("second signal"), std::string::npos)
      << (*server)->process().Stderr();
}

}  // namespace
// The client writes the server's mesh in every format the CLI writes: STL read back with
// the PLY's counts (the GLB is validated by tests/formats on the CLI's writer, shared).
TEST_F(ServiceE2eTest, ClientWritesStlAndGlb) {
  auto path =
      WriteSyntheticVolume(dir_, "link", eval::MakeSyntheticSource(eval::Shape::kLink, 40, 40, 40));
  ASSERT_TRUE(path.ok()) << path.status();
  std::vector<std::string> base = {"stream", "--server", server_->address(), "--input", *path,
                                   "--iso", "0", "--error", "0.3", "--compression-level", "0"};
  for (const char* ext : {"ply", "stl", "glb"}) {
    RunResult r = Client(Concat(base, {"--out", dir_ + "/m." + ext}));
    ASSERT_EQ(r.exit_code, 0) << ext << ": " << r.err;
  }
  auto ply = io::ReadMesh(dir_ + "/m.ply");
  auto stl = io::ReadMesh(dir_ + "/m.stl");
  ASSERT_TRUE(ply.ok() && stl.ok()) << ply.status() << stl.status();
  EXPECT_GT(ply->num_triangles(), 100u);
  EXPECT_EQ(stl->num_triangles(), ply->num_triangles());
  EXPECT_EQ(stl->num_vertices(), ply->num_vertices());
  EXPECT_GT(std::filesystem::file_size(dir_ + "/m.glb"), 24 * ply->num_vertices());
  // --glb-draco: the primitive is one Draco buffer (KHR_draco_mesh_compression) that decodes
  // to the same mesh, with the counts its accessors announce.
  RunResult draco = Client(Concat(base, {"--out", dir_ + "/d.glb", "--glb-draco"}));
  ASSERT_EQ(draco.exit_code, 0) << draco.err;
  const std::string glb = ReadFile(dir_ + "/d.glb");
  ASSERT_GT(glb.size(), 28u);
  uint32_t json_bytes = 0;
  std::memcpy(&json_bytes, glb.data() + 12, 4);
  const nlohmann::json gltf = nlohmann::json::parse(glb.substr(20, json_bytes));
  EXPECT_EQ(gltf["extensionsRequired"][0], "KHR_draco_mesh_compression");
  const nlohmann::json& ext = gltf["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"];
  const size_t bin = 20 + json_bytes + 8;
  const std::string buffer =
      glb.substr(bin, gltf["bufferViews"][ext["bufferView"].get<int>()]["byteLength"].get<size_t>());
  auto decoded = codec::DecodeDraco(buffer);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  EXPECT_EQ(decoded->num_triangles(), ply->num_triangles());
  EXPECT_EQ(decoded->num_vertices(), ply->num_vertices());
  EXPECT_EQ(gltf["accessors"][0]["count"].get<size_t>(), decoded->num_vertices());
  EXPECT_LT(glb.size(), std::filesystem::file_size(dir_ + "/m.glb") / 2);
  RunResult not_glb = Client(Concat(base, {"--out", dir_ + "/d.ply", "--glb-draco"}));
  EXPECT_EQ(not_glb.exit_code, 2);
  EXPECT_NE(not_glb.err.find("--glb-draco compresses a .glb output"), std::string::npos)
      << not_glb.err;
}

// A rotated DICOM series (written by GDCM, file names shuffled) streamed from its folder: the
// server gets the grid directions and sends back the local session's mesh, in the patient
// frame.
TEST_F(ServiceE2eTest, RotatedDicomFolderStreamsTheLocalMeshInThePatientFrame) {
  auto src = eval::MakeSyntheticSource(eval::Shape::kLink, 40, 36, 30, {0.7, 0.7, 1.2});
  VolumeInfo info = src->info();
  info.origin = {-120, 35, 410};
  const double c = std::sqrt(0.5);
  info.directions = {{{c, c, 0}, {-c, c, 0}, {0, 0, 1}}};
  const std::string dir = dir_ + "/series";
  std::vector<std::vector<uint8_t>> slices(info.nz);
  for (auto& b : slices) ASSERT_TRUE(src->ReadSlice(&b).ok());
  ASSERT_TRUE(io::WriteDicomSeries(dir, info, [&](int64_t z, std::vector<uint8_t>* b) {
                *b = slices[z];
                return absl::OkStatus();
              }).ok());
  // Reverse the names: file order says nothing about slice order.
  const int64_t nz = info.nz;
  for (int64_t z = 1; z <= nz; ++z) {
    char from[32], to[32];
    std::snprintf(from, sizeof(from), "IM%05lld.dcm", static_cast<long long>(z));
    std::snprintf(to, sizeof(to), "x%05lld", static_cast<long long>(nz + 1 - z));
    std::filesystem::rename(dir + "/" + from, dir + "/" + to);
  }
  const std::string drc = dir_ + "/series.drc";
  RunResult r = Client({"stream", "--server", server_->address(), "--input", dir, "--iso", "0",
                        "--error", "0.2", "--compression-level", "0", "--out", drc});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  SessionOptions o;
  o.iso = 0;
  o.error = 0.2;
  auto local = RunLocal(dir, o);
  ASSERT_TRUE(local.ok()) << local.status();
  const IndexedMesh expected = (*local)->Snapshot();
  auto mesh = codec::DecodeDraco(ReadFile(drc));
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  ASSERT_GT(expected.num_triangles(), 100u);
  ASSERT_EQ(mesh->num_triangles(), expected.num_triangles());
  ASSERT_EQ(mesh->indices, expected.indices);
  const double tol = codec::PositionTolerance(expected, 16);
  for (size_t i = 0; i < expected.num_vertices(); ++i) {
    for (int a = 0; a < 3; ++a) {
      ASSERT_NEAR(mesh->positions[i][a], expected.positions[i][a], tol) << i;
    }
  }
  // In the patient frame: the mesh's centre lies near the rotated grid's centre.
  Vec3 lo{1e30, 1e30, 1e30}, hi{-1e30, -1e30, -1e30};
  for (const Vec3& p : mesh->positions) {
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
  }
  const Vec3 grid_centre{19.5 * 0.7, 17.5 * 0.7, 14.5 * 1.2};
  Vec3 world{info.origin[0], info.origin[1], info.origin[2]};
  for (int a = 0; a < 3; ++a) {
    world = world + Vec3{info.directions[a][0], info.directions[a][1], info.directions[a][2]} *
                        grid_centre[a];
  }
  for (int a = 0; a < 3; ++a) EXPECT_NEAR((lo[a] + hi[a]) / 2, world[a], 2.0) << a;
}

// The README's live demo: `tandem simulate` plays a CT writing a series in shuffled bursts
// (also as other scanners do: a localizer series first, InstanceNumbers shuffled, files
// renamed into place) and a microscope growing an OME-Zarr array, while `tandem-client
// stream --follow` sends each slice to the real server as it becomes complete. The followed
// stream gives exactly the mesh of the finished acquisition, and its first preview is saved
// before the simulator has written the last slice.
TEST_F(ServiceE2eTest, FollowedSimulatedAcquisitionGivesTheFinishedMesh) {
  auto path = WriteSyntheticVolume(dir_, "pb",
                                   eval::MakeSyntheticSource(eval::Shape::kPillowBox, 48, 48, 48));
  ASSERT_TRUE(path.ok()) << path.status();
  const std::vector<std::string> real_ct = {"--scout", "--numbering", "random", "--temp-names",
                                            "hidden"};
  for (const auto& [name, as, extra] :
       {std::tuple<std::string, std::string, std::vector<std::string>>{"dicom", "dicom", {}},
        {"dicom_real", "dicom", real_ct},
        {"tiff", "tiff", {}},
        {"zarr", "zarr", {}}}) {
    SCOPED_TRACE(name);
    const std::string acq = dir_ + "/acq_" + name + (as == "zarr" ? ".zarr" : "");
    const std::string previews = dir_ + "/previews_" + name;
    RunResult sim;
    // Copies: clang 14 cannot capture structured bindings in a lambda.
    const std::string as_kind = as;
    const std::vector<std::string> sim_extra = extra;
    // Half the rate under the sanitizers, whose client and reader run slower, so that the
    // first preview still precedes the last slice (checked below) on a loaded machine.
    const std::string rate = kSanitized ? "10" : "20";
    std::thread instrument([&] {
      sim = RunProcess(Concat({BinPath("tandem"), "simulate", "--input", *path, "--out", acq,
                               "--as", as_kind, "--rate", rate, "--burst", "6", "--done-file",
                               "DONE"},
                              sim_extra));
    });
    std::vector<std::string> follow = {"stream", "--server", server_->address(), "--input", acq,
                                       "--follow", "--settle", "20", "--iso", "0", "--error",
                                       "0.2", "--compression-level", "0", "--preview-every",
                                       "6", "--partials", previews, "--out",
                                       dir_ + "/followed.drc"};
    if (as == "zarr") {
      follow.insert(follow.end(), {"--expect-slices", "48"});
    } else {
      follow.insert(follow.end(), {"--done-file", "DONE"});
    }
    follow.insert(follow.end(), {"--metrics", dir_ + "/followed.json"});
    RunResult r = Client(follow);
    instrument.join();
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
    ASSERT_EQ(r.exit_code, 0) << r.err;
    if (!extra.empty()) {
      EXPECT_NE(r.err.find("tandem-client: ignoring DICOM series 1.2.826.0.1.3680043.2.1125.7.1 "
                           "'Scout': a localizer (ImageType LOCALIZER)"),
                std::string::npos)
          << r.err;
      EXPECT_NE(r.err.find("InstanceNumbers do not follow the slice positions"), std::string::npos)
          << r.err;
    }
    RunResult whole = Client({"stream", "--server", server_->address(), "--input", acq, "--iso",
                              "0", "--error", "0.2", "--compression-level", "0", "--out",
                              dir_ + "/whole.drc", "--metrics", dir_ + "/whole.json"});
    ASSERT_EQ(whole.exit_code, 0) << whole.err;
    // Same metrics, but for timing, memory, byte counts (a followed stream's depth is not
    // known up front) and the preview count.
    nlohmann::json mf = nlohmann::json::parse(ReadFile(dir_ + "/followed.json"));
    nlohmann::json mw = nlohmann::json::parse(ReadFile(dir_ + "/whole.json"));
    for (const char* k : {"time_s", "peak_rss_bytes", "peak_session_bytes", "bytes_received",
                          "bytes_sent", "previews_sent", "nz"}) {
      mf.erase(k);
      mw.erase(k);
    }
    EXPECT_EQ(mf, mw);
    auto followed = codec::DecodeDraco(ReadFile(dir_ + "/followed.drc"));
    auto finished = codec::DecodeDraco(ReadFile(dir_ + "/whole.drc"));
    ASSERT_TRUE(followed.ok() && finished.ok());
    ASSERT_GT(finished->num_triangles(), 100u);
    EXPECT_EQ(followed->indices, finished->indices);
    EXPECT_EQ(followed->positions, finished->positions);
    // The first preview was on disk before the last slice was.
    std::filesystem::path first;
    for (const auto& e : std::filesystem::directory_iterator(previews)) {
      if (first.empty() || e.path() < first) first = e.path();
    }
    ASSERT_FALSE(first.empty()) << "no preview saved";
    EXPECT_LT(std::filesystem::last_write_time(first),
              std::filesystem::last_write_time(acq + "/DONE"));
  }
}

TEST_F(ServiceE2eTest, AnIsoOutsideTheDataIsAWarningAndExitThreeWithStrict) {
  auto path =
      WriteSyntheticVolume(dir_, "s", eval::MakeSyntheticSource(eval::Shape::kSphere, 20, 20, 20));
  ASSERT_TRUE(path.ok()) << path.status();
  std::vector<std::string> args = {"stream", "--server", server_->address(), "--input", *path,
                                   "--iso", "1000", "--error", "0.3", "--out", dir_ + "/e.ply"};
  RunResult r = Client(args);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("iso 1000 is outside the data's value range"), std::string::npos) << r.err;
  r = Client(Concat(args, {"--strict"}));
  EXPECT_EQ(r.exit_code, 3) << r.err;
}

// A followed acquisition that goes wrong (a slice missing for good, the scan shorter than
// --expect-slices) fails the stream with a message naming the files; the server keeps
// serving and has no session left behind.
TEST_F(ServiceE2eTest, AFollowedScanThatGoesWrongFailsCleanly) {
  auto src = eval::MakeSyntheticSource(eval::Shape::kSphere, 24, 24, 24);
  VolumeInfo info = src->info();
  std::vector<std::vector<uint8_t>> slices(info.nz);
  for (auto& b : slices) ASSERT_TRUE(src->ReadSlice(&b).ok());
  const std::string dir = dir_ + "/broken";
  io::DicomWriteOptions o;
  o.float_min = -20;
  o.float_max = 20;
  auto writer = io::DicomSliceWriter::Create(info, o);
  ASSERT_TRUE(writer.ok()) << writer.status();
  std::filesystem::create_directories(dir);
  for (int64_t z = 0; z < info.nz; ++z) {
    if (z == 12) continue;  // lost on the way from the scanner
    ASSERT_TRUE(writer->Write(dir + "/f" + std::to_string(z * 37 % 101), z, slices[z]).ok());
  }
  RunResult r = Client({"stream", "--server", server_->address(), "--input", dir, "--follow",
                        "--settle", "1", "--expect-slices", "24", "--iso", "0", "--error",
                        "0.3", "--out", dir_ + "/broken.ply"});
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("gap between f"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(dir_ + "/broken.ply"));
  EXPECT_EQ(server_->Health(), "SERVING");
  // The server notices the cancelled stream on its own schedule: a bounded wait.
  RunResult info_out;
  for (int i = 0; i < 50; ++i) {
    info_out = Client({"info", "--server", server_->address()});
    if (info_out.out.find("active sessions        0") != std::string::npos) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_NE(info_out.out.find("active sessions        0"), std::string::npos) << info_out.out;
}

}  // namespace tandem::testing
