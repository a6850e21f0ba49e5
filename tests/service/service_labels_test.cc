// Label volumes through the service (SessionConfig.labels): the real tandem-server on
// 127.0.0.1 and the real tandem-client write what `tandem extract --labels` writes (the same
// files, triangles and positions, up to Draco's quantization), touching labels keep sharing
// their interface triangles, every label's surface is a manifold, closed or open only at
// the box; previews carry every label; what a label session cannot do is refused naming
// the field, and the server stays healthy.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "service/service_testutil.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/common/wire.h"
#include "tandem/eval/topology.h"
#include "tandem/io/mesh_io.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/volume_writers.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"
#include "testutil/testutil.h"
#include "testutil/triangle_key.h"

namespace tandem::testing {
namespace {

constexpr int64_t kNx = 36, kNy = 28, kNz = 26;  // 36 wide: two parts fit (16 columns each)

// `cells` Voronoi cells of an nx x ny x nz grid, uint32 ids scattered past 2^16, filling the
// box (their surfaces are open where they meet it) except, with `ball`, a ball of background
// in the middle.
std::string WriteVoronoiVolume(const std::string& path, int64_t nx, int64_t ny, int64_t nz,
                               size_t cells, bool ball) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> pos(0, 1);
  std::uniform_int_distribution<uint32_t> id(1, 4000000000u);
  std::vector<std::array<double, 3>> seeds;
  std::vector<uint32_t> ids;
  while (seeds.size() < cells) {
    seeds.push_back({pos(rng) * nx, pos(rng) * ny, pos(rng) * nz});
    ids.push_back(id(rng));
  }
  VolumeInfo info;
  info.nx = nx;
  info.ny = ny;
  info.nz = nz;
  info.dtype = DType::kUInt32;
  const absl::Status st = io::WriteVolume(path, info, [&](int64_t z, std::vector<uint8_t>* bytes) {
    bytes->assign(static_cast<size_t>(nx * ny) * 4, 0);
    for (int64_t y = 0; y < ny; ++y) {
      for (int64_t x = 0; x < nx; ++x) {
        if (ball && std::hypot(x - 17.5, y - 13.5, z - 12.5) < 5) continue;  // background
        size_t best = 0;
        double d = 1e30;
        for (size_t s = 0; s < seeds.size(); ++s) {
          const double e = std::hypot(x - seeds[s][0], y - seeds[s][1], z - seeds[s][2]);
          if (e < d) {
            d = e;
            best = s;
          }
        }
        StoreValue(DType::kUInt32, ids[best], bytes->data() + (y * nx + x) * 4);
      }
    }
    return absl::OkStatus();
  });
  EXPECT_TRUE(st.ok()) << st;
  return path;
}

// About a dozen cells about a ball of background.
std::string WriteLabelVolume(const std::string& dir) {
  return WriteVoronoiVolume(dir + "/cells.nrrd", kNx, kNy, kNz, 12, true);
}

// A deep label map of `nz` slices, 32 x 32: blocks of about 7 voxels a side with wavy
// walls (curved interfaces, many triangles at a small E0), new ids all the way down.
std::string WriteDeepLabelVolume(const std::string& dir, int64_t nz) {
  VolumeInfo info;
  info.nx = 32;
  info.ny = 32;
  info.nz = nz;
  info.dtype = DType::kUInt32;
  const std::string path = dir + "/deep.nrrd";
  const absl::Status st = io::WriteVolume(path, info, [&](int64_t z, std::vector<uint8_t>* bytes) {
    bytes->assign(32 * 32 * 4, 0);
    for (int64_t y = 0; y < 32; ++y) {
      for (int64_t x = 0; x < 32; ++x) {
        const auto block = [](double u) { return static_cast<int64_t>(std::floor(u / 7)) + 1; };
        const int64_t bx = block(x + 2.5 * std::sin(0.45 * z + 0.3 * y));
        const int64_t by = block(y + 2.5 * std::sin(0.4 * x + 0.35 * z));
        const int64_t bz = block(z + 2.5 * std::sin(0.3 * x + 0.5 * y));
        StoreValue(DType::kUInt32, static_cast<double>(1 + bx + 16 * by + 256 * bz),
                   bytes->data() + (y * 32 + x) * 4);
      }
    }
    return absl::OkStatus();
  });
  EXPECT_TRUE(st.ok()) << st;
  return path;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The files of a label folder, by name.
std::set<std::string> LabelFiles(const std::string& dir) {
  std::set<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    names.insert(e.path().filename().string());
  }
  return names;
}

// For every two labels' files: how many triangles of the first are in the second reversed,
// at bit-identical positions (their shared interface).
std::map<std::pair<std::string, std::string>, size_t> SharedTriangles(
    const std::map<std::string, IndexedMesh>& meshes) {
  std::map<std::pair<std::string, std::string>, size_t> shared;
  for (const auto& [a, ma] : meshes) {
    std::set<TriangleKey> keys;
    for (size_t t = 0; t < ma.num_triangles(); ++t) keys.insert(KeyOfTriangle(ma, t, false));
    for (const auto& [b, mb] : meshes) {
      if (b <= a) continue;
      size_t n = 0;
      for (size_t t = 0; t < mb.num_triangles(); ++t) n += keys.count(KeyOfTriangle(mb, t, true));
      if (n > 0) shared[{a, b}] = n;
    }
  }
  return shared;
}

// Every boundary edge's two ends lie on the grid's box (spacing 1, origin 0), within `tol`.
void ExpectOpenOnlyAtTheBox(const IndexedMesh& m, double tol) {
  std::map<std::pair<uint32_t, uint32_t>, int> edges;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    for (int c = 0; c < 3; ++c) {
      uint32_t a = m.indices[3 * t + c], b = m.indices[3 * t + (c + 1) % 3];
      ++edges[{std::min(a, b), std::max(a, b)}];
    }
  }
  auto on_box = [&](const Vec3& p) {
    return std::abs(p.x) <= tol || std::abs(p.y) <= tol || std::abs(p.z) <= tol ||
           std::abs(p.x - (kNx - 1)) <= tol || std::abs(p.y - (kNy - 1)) <= tol ||
           std::abs(p.z - (kNz - 1)) <= tol;
  };
  for (const auto& [e, n] : edges) {
    if (n != 1) continue;
    EXPECT_TRUE(on_box(m.positions[e.first]) && on_box(m.positions[e.second]))
        << "a boundary edge inside the box at " << m.positions[e.first].x << ", "
        << m.positions[e.first].y << ", " << m.positions[e.first].z;
  }
}

// A variable the streaming client prints as NAME=VALUE (its session's id and watch key).
std::string PrintedVariable(const std::string& err, const std::string& name) {
  const std::string tag = name + "=";
  const size_t at = err.find(tag);
  if (at == std::string::npos) return "";
  const size_t begin = at + tag.size();
  const size_t end = err.find_first_of(" \n", begin);
  return end == std::string::npos ? "" : err.substr(begin, end - begin);
}

// The id and watch key a streaming client printed (bounded wait: up to 20 s).
struct Started {
  std::string id, watch_key;
  bool ok() const { return id.size() == 32 && watch_key.size() == 32; }
};
Started StartedOf(ChildProcess& streamer) {
  Started s;
  for (int i = 0; i < 800 && !s.ok(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
    const std::string err = streamer.Stderr();
    s.id = PrintedVariable(err, "TANDEM_RESUME").substr(0, 32);
    s.watch_key = PrintedVariable(err, "TANDEM_WATCH_KEY");
  }
  if (!s.ok()) ADD_FAILURE() << "no session printed: " << streamer.Stderr();
  return s;
}

class ServiceLabelsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    // Previews at every slice (each sealing what is due first), whatever their bytes.
    auto server = TestServer::Start({"--min-preview-interval-ms", "0", "--max-preview-share", "0",
                                     "--max-band-bytes-share", "0"});
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    dir_ = MakeTempDir();
    volume_ = WriteLabelVolume(dir_);
  }
  RunResult Run(const std::string& program, std::vector<std::string> args,
                const std::vector<std::string>& env = {}) {
    args.insert(args.begin(), BinPath(program));
    return RunProcess(args, 120, env);
  }
  // tandem-client watch of session `s` with its key, `args` after the session.
  RunResult Watch(const Started& s, std::vector<std::string> args) {
    args.insert(args.begin(), {"watch", "--server", server_->address(), "--session", s.id});
    return Run("tandem-client", args, {"TANDEM_WATCH_KEY=" + s.watch_key});
  }
  // The label config of a gRPC stream, on the volume's own grid.
  std::vector<v1::ExtractRequest> Requests(const v1::SessionConfig& config) {
    auto source = io::OpenVolume(volume_);
    EXPECT_TRUE(source.ok()) << source.status();
    return VolumeRequests(**source, config, 1 << 20);
  }
  static v1::SessionConfig LabelConfig() {
    v1::SessionConfig c;
    c.set_error(0.5);
    c.set_alpha(0.5);
    c.mutable_labels()->set_enabled(true);
    return c;
  }
  // The checks of the tests of the same names, with `parts` parts.
  void ExpectPreviewsAndFinalMessagesCarryTheLabels(int parts);
  void ExpectSealedChunksCarryTheirLabel(int parts);
  std::unique_ptr<TestServer> server_;
  std::string dir_, volume_;
};

// The client's folder holds tandem extract --labels' files, each the same mesh; interfaces
// shared; manifolds open only at the box, or closed with --close; the same figures.
// Sealed (--seal, both sides), the labels come as chunks per label, welded by the client into
// the same files (the figures measured before the grid, so the area within a hair). Split
// in two parts (--parts 2, which the server honours: the split is part of the result), too.
TEST_F(ServiceLabelsTest, StreamedLabelsAreTheLocalExtractsFiles) {
  std::map<std::pair<bool, bool>, nlohmann::json> one_part;  // by (close, seal)
  for (int run = 0; run < 6; ++run) {
    const bool close = run % 4 >= 2, seal = run % 2 == 1;
    const bool split = run >= 4;
    SCOPED_TRACE(close ? "--close" : "open at the box");
    SCOPED_TRACE(seal ? "--seal" : "whole at End");
    SCOPED_TRACE(split ? "--parts 2" : "one part");
    const std::string tag =
        std::string(close ? "closed" : "open") + (seal ? "_sealed" : "") + (split ? "_split" : "");
    std::vector<std::string> common = {"--input", volume_, "--labels", "--error", "0.5", "--quiet"};
    if (close) common.push_back("--close");
    if (seal) common.push_back("--seal");
    common.insert(common.end(), {"--parts", split ? "2" : "1"});
    const std::string local = dir_ + "/local_" + tag + "/", remote = dir_ + "/remote_" + tag + "/";
    RunResult cli = Run("tandem", [&] {
      std::vector<std::string> a = {"extract", "--out", local, "--metrics", dir_ + "/l.json"};
      a.insert(a.end(), common.begin(), common.end());
      return a;
    }());
    ASSERT_EQ(cli.exit_code, 0) << cli.err;
    RunResult client = Run("tandem-client", [&] {
      std::vector<std::string> a = {"stream", "--server",  server_->address(), "--out",
                                    remote,   "--metrics", dir_ + "/r.json"};
      a.insert(a.end(), common.begin(), common.end());
      return a;
    }());
    ASSERT_EQ(client.exit_code, 0) << client.err;

    const std::set<std::string> names = LabelFiles(local);
    ASSERT_GE(names.size(), 9u);  // a dozen cells, less the few the ball swallowed
    EXPECT_EQ(LabelFiles(remote), names);
    // The shared grid's step (the volume's box, padded by half its extent), two and a bit.
    const double tol = 3 * 1.5 * (kNx - 1) / 65535.0;
    std::map<std::string, IndexedMesh> local_meshes, remote_meshes;
    for (const std::string& name : names) {
      if (name == "labels.glb") continue;
      SCOPED_TRACE(name);
      auto a = io::ReadMesh(local + name);
      auto b = io::ReadMesh(remote + name);
      ASSERT_TRUE(a.ok() && b.ok()) << a.status() << b.status();
      ASSERT_EQ(a->num_triangles(), b->num_triangles());
      ASSERT_EQ(a->num_vertices(), b->num_vertices());
      auto map = MatchVertices(*a, *b, tol);
      ASSERT_TRUE(map.ok()) << map.status();
      EXPECT_TRUE(SameTriangles(*a, *b, *map));
      const eval::TopologyReport t = eval::AnalyzeTopology(*b);
      EXPECT_TRUE(t.IsManifold());
      if (close) {
        EXPECT_TRUE(t.IsClosedManifold());
      } else {
        ExpectOpenOnlyAtTheBox(*b, 1e-3);
      }
      local_meshes[name] = *std::move(a);
      remote_meshes[name] = *std::move(b);
    }
    // Touching labels share their interface triangles, exactly, in both outputs alike.
    const auto shared = SharedTriangles(local_meshes);
    EXPECT_GE(shared.size(), 10u);
    EXPECT_EQ(SharedTriangles(remote_meshes), shared);
    auto want = nlohmann::json::parse(ReadText(dir_ + "/l.json"));
    auto got = nlohmann::json::parse(ReadText(dir_ + "/r.json"));
    if (!split) {
      one_part[{close, seal}] = want;
    } else {  // really split: not one part's run
      EXPECT_NE(want["evaluations"], one_part.at({close, seal})["evaluations"]);
    }
    ASSERT_EQ(got["labels"].size(), want["labels"].size());
    EXPECT_EQ(got["labels"].size(), names.size() - 1);
    for (size_t i = 0; i < want["labels"].size(); ++i) {
      const auto& a = want["labels"][i];
      const auto& b = got["labels"][i];
      EXPECT_EQ(b["label"], a["label"]);
      EXPECT_EQ(b["triangles"], a["triangles"]);
      EXPECT_EQ(b["euler"], a["euler"]);
      EXPECT_EQ(b["closed"], a["closed"]);
      if (seal) {
        EXPECT_NEAR(b["area"].get<double>(), a["area"].get<double>(),
                    1e-3 * a["area"].get<double>());
      } else {
        EXPECT_DOUBLE_EQ(b["area"].get<double>(), a["area"].get<double>());
      }
    }
    EXPECT_EQ(got["triangles_final"], want["triangles_final"]);
    EXPECT_EQ(got["contractions"], want["contractions"]);
  }
}

// Previews of a label session hold every label's surface, each vertex tagged with its
// label (Preview.labels), while the scan is still arriving; the final messages carry each
// label's id, then the session's figures. In one part or two (the parts' meshes welded).
TEST_F(ServiceLabelsTest, PreviewsAndFinalMessagesCarryTheLabels) {
  for (int parts : {1, 2}) {
    SCOPED_TRACE(absl::StrCat(parts, " parts"));
    ExpectPreviewsAndFinalMessagesCarryTheLabels(parts);
  }
}

void ServiceLabelsTest::ExpectPreviewsAndFinalMessagesCarryTheLabels(int parts) {
  v1::SessionConfig config = LabelConfig();
  config.set_parts(parts);
  config.mutable_preview()->set_every_slices(1);
  auto stub = server_->NewStub();
  const StreamOutcome outcome = RunStream(*stub, Requests(config), server_.get());
  ASSERT_TRUE(outcome.status.ok()) << outcome.status.error_message();
  size_t previews_mid_scan = 0;
  std::set<uint64_t> final_labels;
  int64_t session_labels = -1;
  for (const v1::ExtractResponse& r : outcome.responses) {
    if (r.has_preview() && r.preview().slice() < kNz - 1 && r.preview().triangles() > 0) {
      const v1::Preview& p = r.preview();
      std::vector<uint32_t> group;
      auto mesh = codec::DecodeDraco(p.draco(), &group);
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      ASSERT_GE(p.labels_size(), 2);
      EXPECT_TRUE(std::is_sorted(p.labels().begin(), p.labels().end()));
      std::set<uint32_t> seen(group.begin(), group.end());
      EXPECT_GE(seen.size(), 2u);
      EXPECT_LT(*seen.rbegin(), static_cast<uint32_t>(p.labels_size()));
      ++previews_mid_scan;
    }
    if (r.has_final_mesh()) {
      ASSERT_TRUE(r.final_mesh().has_label());
      final_labels.insert(r.final_mesh().label());
    }
    if (r.has_final_metrics()) {
      const v1::FinalMetrics& m = r.final_metrics();
      if (m.has_label()) {
        EXPECT_TRUE(final_labels.count(m.label()));
        EXPECT_GT(m.label_figures().area(), 0);
        EXPECT_TRUE(m.label_figures().manifold());
      } else {
        session_labels = m.labels();
        EXPECT_GT(m.triangles_final(), 0);
      }
    }
  }
  EXPECT_GE(previews_mid_scan, 3u);
  EXPECT_GE(final_labels.size(), 9u);
  for (uint64_t id : final_labels) EXPECT_GT(id, 65535u) << "ids are kept as they are";
  EXPECT_EQ(session_labels, static_cast<int64_t>(final_labels.size()));
  EXPECT_TRUE(outcome.responses.back().has_final_metrics());
  EXPECT_FALSE(outcome.responses.back().final_metrics().has_label());
}

// A sealed label session sends each chunk as one SealedChunk per label it holds, while the
// slices arrive; each label's chunks weld into its surface as the unsealed session sends it,
// and touching labels share their interface triangles exactly.
TEST_F(ServiceLabelsTest, SealedChunksCarryTheirLabelBeforeEnd) {
  for (int parts : {1, 2}) {
    SCOPED_TRACE(absl::StrCat(parts, " parts"));
    ExpectSealedChunksCarryTheirLabel(parts);
  }
}

void ServiceLabelsTest::ExpectSealedChunksCarryTheirLabel(int parts) {
  auto stub = server_->NewStub();
  v1::SessionConfig whole_config = LabelConfig();
  whole_config.set_parts(parts);
  whole_config.mutable_labels()->set_close(true);
  v1::SessionConfig sealed_config = whole_config;
  sealed_config.set_sealed_chunks(true);
  sealed_config.mutable_preview()->set_every_slices(1);  // each preview seals what is due
  const StreamOutcome whole = RunStream(*stub, Requests(whole_config), server_.get());
  ASSERT_TRUE(whole.status.ok()) << whole.status.error_message();
  const StreamOutcome sealed = RunStream(*stub, Requests(sealed_config), server_.get());
  ASSERT_TRUE(sealed.status.ok()) << sealed.status.error_message();

  std::map<uint64_t, std::vector<SealedChunk>> chunks;
  size_t before_last_slice = 0;
  int64_t index = 0;
  int64_t last_progress_slice = -1;
  for (const v1::ExtractResponse& r : sealed.responses) {
    if (r.has_progress()) last_progress_slice = r.progress().slices_consumed() - 1;
    ASSERT_FALSE(r.has_final_mesh()) << "a sealed session's surfaces are its chunks";
    if (!r.has_sealed_chunk()) continue;
    const v1::SealedChunk& c = r.sealed_chunk();
    ASSERT_TRUE(c.has_label_pairs());
    EXPECT_FALSE(c.has_label());
    EXPECT_EQ(c.surface(), 0);
    EXPECT_EQ(c.index(), index++);
    if (last_progress_slice >= 0 && last_progress_slice < kNz - 1) ++before_last_slice;
    SealedChunk chunk;
    auto mesh = codec::DecodeDraco(c.draco(), &chunk.ids);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    EXPECT_EQ(static_cast<int64_t>(mesh->num_triangles()), c.triangles());
    LabelId background = 1;
    const absl::Status pairs =
        common::LabelPairsFromProto(c.label_pairs(), mesh->num_triangles(), &chunk, &background);
    ASSERT_TRUE(pairs.ok()) << pairs;
    EXPECT_EQ(background, 0u);
    // Each triangle once: every one separates two labels, or a label and the background.
    for (const LabelPair& p : chunk.pairs) EXPECT_NE(p.inside, p.outside);
    chunk.positions = std::move(mesh->positions);
    chunk.indices = std::move(mesh->indices);
    for (auto& [label, part] : SplitLabeledChunk(chunk, background)) {
      chunks[label].push_back(std::move(part));
    }
  }
  EXPECT_GE(before_last_slice, 1u);
  std::map<uint64_t, IndexedMesh> want;  // label -> the unsealed session's surface
  for (size_t i = 0; i < whole.responses.size(); ++i) {
    const v1::ExtractResponse& r = whole.responses[i];
    if (!r.has_final_mesh() || r.final_mesh().chunk_index() != 0) continue;
    std::string bytes;
    for (size_t k = i; k < i + r.final_mesh().chunk_count(); ++k) {
      bytes += whole.responses[k].final_mesh().draco();
    }
    auto mesh = codec::DecodeDraco(bytes);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    want[r.final_mesh().label()] = *std::move(mesh);
  }
  ASSERT_GE(want.size(), 9u);
  ASSERT_EQ(chunks.size(), want.size());
  // Sealing keeps the topology, not every contraction (the front's margin): each label is a
  // closed manifold of the unsealed Euler characteristic, and touching labels share
  // triangles at bit-identical positions (triangle for triangle against tandem extract
  // --seal: StreamedLabelsAreTheLocalExtractsFiles).
  std::map<std::string, IndexedMesh> sealed_meshes, whole_meshes;
  for (const auto& [label, list] : chunks) {
    SCOPED_TRACE(absl::StrCat("label ", label));
    ASSERT_TRUE(want.count(label));
    const IndexedMesh got = WeldChunks(list);
    const eval::TopologyReport t = eval::AnalyzeTopology(got);
    EXPECT_TRUE(t.IsClosedManifold());
    EXPECT_EQ(t.euler, eval::AnalyzeTopology(want[label]).euler);
    sealed_meshes[absl::StrCat(label)] = got;
    whole_meshes[absl::StrCat(label)] = want[label];
  }
  EXPECT_GE(SharedTriangles(whole_meshes).size(), 10u);
  EXPECT_GE(SharedTriangles(sealed_meshes).size(), 10u);
  // The session's metrics count every label, each with its figures.
  ASSERT_TRUE(sealed.responses.back().has_final_metrics());
  EXPECT_EQ(sealed.responses.back().final_metrics().labels(), static_cast<int64_t>(want.size()));
}

// What a label session cannot do is refused with INVALID_ARGUMENT naming the field; the
// server then meshes a good label stream as ever.
TEST_F(ServiceLabelsTest, RefusalsNameTheFieldAndTheServerStaysHealthy) {
  auto stub = server_->NewStub();
  struct Case {
    std::string field;
    v1::SessionConfig config;
    bool float32 = false;
  };
  std::vector<Case> cases;
  auto add = [&](const std::string& field, auto edit, bool float32 = false) {
    Case c{field, LabelConfig(), float32};
    edit(c.config);
    cases.push_back(c);
  };
  add(
      "config.labels.enabled", [](v1::SessionConfig&) {}, /*float32=*/true);
  add("config.extra_isos", [](v1::SessionConfig& c) { c.add_extra_isos(3); });
  add("config.compute_distances", [](v1::SessionConfig& c) { c.set_compute_distances(true); });
  add("config.labels.only", [](v1::SessionConfig& c) {
    c.mutable_labels()->add_only(9);
    c.mutable_labels()->add_only(4);
  });
  add("config.labels.background", [](v1::SessionConfig& c) {
    c.mutable_labels()->set_background(4);
    c.mutable_labels()->add_only(4);
  });
  add("config.labels.background", [](v1::SessionConfig& c) {
    c.mutable_labels()->set_enabled(false);
    c.mutable_labels()->set_background(4);
  });
  for (const Case& c : cases) {
    SCOPED_TRACE(c.field);
    std::vector<v1::ExtractRequest> requests = Requests(c.config);
    if (c.float32) {  // the same bytes, declared float32 (ids read as floats)
      requests[0].mutable_config()->set_dtype(v1::DTYPE_FLOAT32);
    }
    const StreamOutcome outcome = RunStream(*stub, requests, server_.get());
    EXPECT_EQ(outcome.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT)
        << outcome.status.error_message();
    EXPECT_NE(outcome.status.error_message().find(c.field), std::string::npos)
        << outcome.status.error_message();
  }
  EXPECT_EQ(server_->Health(), "SERVING");
  const StreamOutcome good = RunStream(*stub, Requests(LabelConfig()), server_.get());
  EXPECT_TRUE(good.status.ok()) << good.status.error_message();
  EXPECT_TRUE(server_->WaitIdle(20));
}

// A sealed label session is watched like a sealed iso-surface session: a watcher attached
// while it runs and one after it ended get every label's chunks and figures and write the
// streaming client's files byte for byte (--out DIR/, or the one .glb); --out must then be
// a folder or a .glb. An unsealed label session is refused as an unsealed iso session is.
TEST_F(ServiceLabelsTest, WatchersOfALabelSessionWriteTheStreamersFiles) {
  const std::string streamed = dir_ + "/streamed/";
  auto streamer = ChildProcess::Spawn(
      {BinPath("tandem-client"), "stream", "--server", server_->address(), "--input", volume_,
       "--labels", "--seal", "--error", "0.5", "--rate", "10", "--preview-every", "2", "--out",
       streamed, "--metrics", dir_ + "/streamed.json"},
      dir_);
  ASSERT_TRUE(streamer.ok()) << streamer.status();
  const Started started = StartedOf(**streamer);
  ASSERT_TRUE(started.ok());
  RunResult live =
      Watch(started, {"--out", dir_ + "/live/", "--metrics", dir_ + "/live.json", "--verbose"});
  ASSERT_EQ(live.exit_code, 0) << live.err;
  ASSERT_EQ((*streamer)->Wait(60), std::optional<int>(0)) << (*streamer)->Stderr();
  EXPECT_NE(live.err.find("progress "), std::string::npos) << "it saw the session run";
  EXPECT_NE(live.err.find("preview "), std::string::npos) << live.err;
  RunResult late = Watch(started, {"--out", dir_ + "/late/", "--quiet"});
  ASSERT_EQ(late.exit_code, 0) << late.err;
  RunResult glb = Watch(started, {"--out", dir_ + "/late.glb", "--quiet"});
  ASSERT_EQ(glb.exit_code, 0) << glb.err;

  const std::set<std::string> names = LabelFiles(streamed);
  ASSERT_GE(names.size(), 10u);  // a file per label and labels.glb
  EXPECT_TRUE(names.count("labels.glb"));
  for (const char* watcher : {"live", "late"}) {
    SCOPED_TRACE(watcher);
    EXPECT_EQ(LabelFiles(dir_ + "/" + watcher), names);
    for (const std::string& name : names) {
      EXPECT_EQ(ReadText(dir_ + "/" + watcher + "/" + name), ReadText(streamed + name)) << name;
    }
  }
  EXPECT_EQ(ReadText(dir_ + "/late.glb"), ReadText(streamed + "labels.glb"));
  auto want = nlohmann::json::parse(ReadText(dir_ + "/streamed.json"));
  auto got = nlohmann::json::parse(ReadText(dir_ + "/live.json"));
  EXPECT_EQ(got["labels"], want["labels"]);
  EXPECT_EQ(got["labels"].size(), names.size() - 1);
  EXPECT_EQ(got["triangles_final"], want["triangles_final"]);
  EXPECT_EQ(got["slices"], kNz);

  // A label session's files need a folder or a .glb; a single mesh file is refused by name.
  RunResult ply = Watch(started, {"--out", dir_ + "/one.ply"});
  EXPECT_EQ(ply.exit_code, 2) << ply.err;
  EXPECT_NE(ply.err.find("is a label session: --out must be a folder (end it with /) or one "
                         ".glb"),
            std::string::npos)
      << ply.err;
  EXPECT_FALSE(std::filesystem::exists(dir_ + "/one.ply"));

  // A session of background only sends no label: its Progress tells the watcher what it is,
  // and the watcher writes what the streamer wrote (labels.glb alone).
  VolumeInfo empty;
  empty.nx = empty.ny = empty.nz = 8;
  empty.dtype = DType::kUInt16;
  ASSERT_TRUE(io::WriteVolume(dir_ + "/empty.nrrd", empty, [](int64_t, std::vector<uint8_t>* b) {
                b->assign(8 * 8 * 2, 0);
                return absl::OkStatus();
              }).ok());
  auto none = ChildProcess::Spawn(
      {BinPath("tandem-client"), "stream", "--server", server_->address(), "--input",
       dir_ + "/empty.nrrd", "--labels", "--seal", "--out", dir_ + "/none/"},
      dir_);
  ASSERT_TRUE(none.ok()) << none.status();
  const Started none_started = StartedOf(**none);
  ASSERT_EQ((*none)->Wait(60), std::optional<int>(0)) << (*none)->Stderr();
  RunResult none_watch = Watch(none_started, {"--out", dir_ + "/none_watched/"});
  ASSERT_EQ(none_watch.exit_code, 0) << none_watch.err;
  EXPECT_NE(none_watch.out.find("(0 labels)"), std::string::npos) << none_watch.out;
  EXPECT_EQ(LabelFiles(dir_ + "/none_watched"), std::set<std::string>{"labels.glb"});
  EXPECT_EQ(ReadText(dir_ + "/none_watched/labels.glb"), ReadText(dir_ + "/none/labels.glb"));

  // Unsealed, the labels come whole after End: not watchable, like an unsealed iso session.
  RunResult plain = Run("tandem-client", {"stream", "--server", server_->address(), "--input",
                                          volume_, "--labels", "--out", dir_ + "/plain/"});
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  Started plain_started;
  plain_started.id = PrintedVariable(plain.err, "TANDEM_RESUME").substr(0, 32);
  plain_started.watch_key = PrintedVariable(plain.err, "TANDEM_WATCH_KEY");
  ASSERT_TRUE(plain_started.ok()) << plain.err;
  RunResult refused = Watch(plain_started, {"--out", dir_ + "/refused/"});
  EXPECT_EQ(refused.exit_code, 1) << refused.err;
  EXPECT_NE(refused.err.find("does not send sealed chunks (SessionConfig.sealed_chunks): it "
                             "cannot be watched"),
            std::string::npos)
      << refused.err;
  EXPECT_EQ(server_->Health(), "SERVING");
}

// A sealed label session keeps each label's chunks to measure its figures at End: they
// count in the per-session budget, so a deep one over it ends with the budget's error
// naming them (its front alone stays under it), and the server goes on meshing.
TEST_F(ServiceLabelsTest, KeptLabelChunksCountInTheSessionBudget) {
  // At E0 0.1 the 80 slices seal about 250 k triangles, each label's chunks some 15 MiB
  // beyond the front's 15 MiB at its peak.
  const std::string deep = WriteDeepLabelVolume(dir_, 80);
  auto small = TestServer::Start({"--session-memory-mb", "20"});
  ASSERT_TRUE(small.ok()) << small.status();
  RunResult over =
      Run("tandem-client", {"stream", "--server", (*small)->address(), "--input", deep, "--labels",
                            "--seal", "--error", "0.1", "--out", dir_ + "/over/"});
  EXPECT_EQ(over.exit_code, 1) << over.err;
  EXPECT_NE(over.err.find("RESOURCE_EXHAUSTED: session memory budget exceeded"), std::string::npos)
      << over.err;
  EXPECT_NE(over.err.find("each label's sealed chunks, kept to measure its figures at End"),
            std::string::npos)
      << over.err;
  EXPECT_NE(over.err.find("per-session budget of 20.0 MiB"), std::string::npos) << over.err;
  EXPECT_EQ((*small)->Health(), "SERVING");
  EXPECT_TRUE((*small)->WaitIdle(20));
  RunResult good =
      Run("tandem-client", {"stream", "--server", (*small)->address(), "--input", volume_,
                            "--labels", "--seal", "--out", dir_ + "/good/", "--quiet"});
  EXPECT_EQ(good.exit_code, 0) << good.err;
  EXPECT_GE(LabelFiles(dir_ + "/good").size(), 10u);
}

// The CPU seconds process `pid` has used (/proc/PID/stat: utime + stime).
double CpuSeconds(pid_t pid) {
  std::istringstream in(ReadText(absl::StrCat("/proc/", pid, "/stat")));
  std::string field;
  double ticks = 0;
  for (int k = 1; k <= 15 && in >> field; ++k) {
    if (k >= 14) ticks += std::stod(field);  // the command (field 2) has no space here
  }
  return ticks / static_cast<double>(sysconf(_SC_CLK_TCK));
}

// A sealed label session sends each interface triangle once (the labels on its two sides
// beside it) and each piece encoded once: on a Voronoi volume of a hundred and fifty cells
// its bytes on the wire stay near those of the unsealed session, which sends each label's
// surface whole (interfaces in both labels). The margin is for a loaded machine, which cuts
// more chunks by time (one a second), each seam resending vertices. Both give the same labels.
TEST_F(ServiceLabelsTest, SealedLabelSessionsSendAboutTheUnsealedBytes) {
  const std::string cells = WriteVoronoiVolume(dir_ + "/many.nrrd", 64, 64, 48, 150, false);
  auto stub = server_->NewStub();
  struct Sent {
    int64_t bytes = 0, labels = 0;
    double cpu_s = 0, encode_s = 0;
  };
  auto run = [&](bool sealed) {
    v1::SessionConfig config = LabelConfig();
    config.set_sealed_chunks(sealed);
    auto source = io::OpenVolume(cells);
    EXPECT_TRUE(source.ok()) << source.status();
    const std::vector<v1::ExtractRequest> requests = VolumeRequests(**source, config, 1 << 20);
    const double cpu = CpuSeconds(server_->process().pid());
    const StreamOutcome got = RunStream(*stub, requests, server_.get());
    EXPECT_TRUE(got.status.ok()) << got.status.error_message();
    Sent sent;
    sent.cpu_s = CpuSeconds(server_->process().pid()) - cpu;
    for (const v1::ExtractResponse& r : got.responses) {
      sent.bytes += static_cast<int64_t>(r.ByteSizeLong());
      if (r.has_final_metrics() && !r.final_metrics().has_label()) {
        sent.labels = r.final_metrics().labels();
        sent.encode_s = r.final_metrics().time_encode_s();
      }
    }
    return sent;
  };
  const Sent whole = run(false), sealed = run(true);
  const double ratio = static_cast<double>(sealed.bytes) / static_cast<double>(whole.bytes);
  std::printf("%lld labels: unsealed %lld bytes, %.2f s server CPU (%.3f s encoding); sealed "
              "%lld bytes (%.3fx), %.2f s (%.3f s)\n",
              static_cast<long long>(whole.labels), static_cast<long long>(whole.bytes),
              whole.cpu_s, whole.encode_s, static_cast<long long>(sealed.bytes), ratio,
              sealed.cpu_s, sealed.encode_s);
  EXPECT_GE(whole.labels, 100);
  EXPECT_EQ(sealed.labels, whole.labels);
  EXPECT_LE(ratio, 1.3);
}

}  // namespace
}  // namespace tandem::testing
