// `tandem extract --labels` run as a user would: the refusals of what cannot work (a float
// volume, bad label ids, flags without --labels, outputs that cannot hold one mesh per
// label, a bad names table), each naming the culprit; a map of many scattered uint64 ids.
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "tandem/eval/topology.h"
#include "tandem/io/mesh_io.h"
#include "tandem/io/volume_writers.h"
#include "tandem/volume.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

class CliLabels : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir(); }
  std::string Path(const std::string& name) const { return dir_ + "/" + name; }
  testing::CommandOutput Tandem(const std::string& args) const {
    return testing::RunCommand(testing::BinPath("tandem") + " extract " + args);
  }
  // A 6^3 label map of type t: label 3 in one corner block, label 7 beside it.
  std::string LabelVolume(const std::string& name, DType t) const {
    VolumeInfo info;
    info.nx = info.ny = info.nz = 6;
    info.dtype = t;
    const std::string path = Path(name);
    EXPECT_TRUE(io::WriteVolume(path, info, [t](int64_t z, std::vector<uint8_t>* bytes) {
                  bytes->assign(36 * DTypeSize(t), 0);
                  for (int64_t j = 1; j < 4; ++j) {
                    for (int64_t i = 1; i < 5; ++i) {
                      const double id = z < 1 || z > 3 ? 0 : i < 3 ? 3 : 7;
                      testing::StoreValue(t, id, bytes->data() + (j * 6 + i) * DTypeSize(t));
                    }
                  }
                  return absl::OkStatus();
                }).ok());
    return path;
  }
  // A one-voxel label at every voxel of an nx x ny x nz uint64 map (.json + .raw): distinct
  // ids scattered over the whole range, with 2^53 and 2^53 + 1 (one double apart from
  // nothing) and 2^64 - 1 among them. Returns the ids in voxel order.
  std::vector<uint64_t> ManyIdVolume(const std::string& path, int64_t nx, int64_t ny,
                                     int64_t nz) const {
    std::vector<uint64_t> ids = {uint64_t{1} << 53, (uint64_t{1} << 53) + 1, UINT64_MAX};
    std::set<uint64_t> seen(ids.begin(), ids.end());
    std::mt19937_64 rng(64);
    while (static_cast<int64_t>(ids.size()) < nx * ny * nz) {
      const uint64_t id = rng();
      if (id != 0 && seen.insert(id).second) ids.push_back(id);
    }
    std::shuffle(ids.begin(), ids.end(), rng);
    VolumeInfo info;
    info.nx = nx, info.ny = ny, info.nz = nz;
    info.dtype = DType::kUInt64;
    EXPECT_TRUE(io::WriteVolume(path, info, [&](int64_t z, std::vector<uint8_t>* bytes) {
                  bytes->resize(nx * ny * 8);
                  std::memcpy(bytes->data(), ids.data() + z * nx * ny, bytes->size());
                  return absl::OkStatus();
                }).ok());
    return ids;
  }
  // Runs the CLI with `args` (no shell) and returns its peak resident set in bytes, or -1
  // when it did not exit with 0.
  static int64_t PeakRssOf(const std::vector<std::string>& args) {
    std::vector<char*> argv;
    const std::string bin = testing::BinPath("tandem");
    argv.push_back(const_cast<char*>(bin.c_str()));
    for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const pid_t pid = fork();
    if (pid == 0) {
      std::freopen("/dev/null", "w", stderr);
      execv(bin.c_str(), argv.data());
      _exit(127);
    }
    int status = 0;
    struct rusage ru {};
    if (pid < 0 || wait4(pid, &status, 0, &ru) != pid) return -1;
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) return -1;
    return static_cast<int64_t>(ru.ru_maxrss) * 1024;
  }
  // What a label costs in memory: simplified to a handful of triangles each, 4x the labels
  // grow the peak resident set by what those need in the sweep and the outputs, not by
  // kilobytes of bookkeeping per label (a million ids: gigabytes). `out(k)` gives run k's
  // output flags; the result is in bytes per added label (-1: a run failed).
  double PeakRssPerLabel(const std::function<std::vector<std::string>(int)>& out) const {
    int64_t rss[2] = {0, 0};
    const int64_t nz[2] = {4, 16}, n = 32 * 32;
    for (int k = 0; k < 2; ++k) {
      const std::string in = Path(absl::StrCat("many", k, ".json"));
      ManyIdVolume(in, 32, 32, nz[k]);
      std::vector<std::string> args = {
          "extract",  "--input",   in,
          "--labels", "--error",   "4",
          "--quiet",  "--metrics", Path(absl::StrCat("many", k, "m.json"))};
      for (std::string& a : out(k)) args.push_back(std::move(a));
      rss[k] = PeakRssOf(args);
      if (rss[k] <= 0) return -1;
    }
    return static_cast<double>(rss[1] - rss[0]) / static_cast<double>((nz[1] - nz[0]) * n);
  }
  // Each file in `dir` a closed manifold sphere: one component, Euler characteristic 2.
  static void ExpectSpheres(const std::string& dir, std::initializer_list<const char*> files) {
    for (const char* file : files) {
      SCOPED_TRACE(file);
      auto mesh = io::ReadMesh(dir + file);
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      const eval::TopologyReport t = eval::AnalyzeTopology(*mesh);
      EXPECT_TRUE(t.IsClosedManifold());
      EXPECT_EQ(t.euler, 2);
      EXPECT_EQ(t.components, 1u);
    }
  }
  std::string dir_;
};

TEST_F(CliLabels, AFloatVolumeIsRefused) {
  const std::string in = LabelVolume("f.json", DType::kFloat32);
  const auto r = Tandem("--input " + in + " --labels --out " + Path("out/"));
  EXPECT_EQ(r.code, 2) << r.text;
  EXPECT_NE(r.text.find("--labels needs integer voxels; " + in + " holds float32"),
            std::string::npos)
      << r.text;
}

TEST_F(CliLabels, BadLabelIdsAndFlagsWithoutLabelsAreNamed) {
  const std::string in = LabelVolume("u.nrrd", DType::kUInt32);
  const std::string out = " --out " + Path("out/");
  const struct {
    std::string args, message;
  } cases[] = {
      {"--labels --label-ids 3,x", "--label-ids 3,x: 'x' is not a label id"},
      {"--labels --label-ids 3,-7", "--label-ids 3,-7: '-7' is not a label id"},
      {"--labels --label-ids 3,,7", "--label-ids 3,,7: '' is not a label id"},
      {"--labels --label-ids 0,3", "--label-ids 0,3: 0 is the background (--background 0)"},
      {"--labels --background 7 --label-ids 7", "7 is the background (--background 7)"},
      {"--labels --background 18446744073709551616",
       "--background 18446744073709551616: '18446744073709551616' is not a label id"},
      {"--label-ids 3", "--label-ids goes with --labels"},
      {"--background 2", "--background goes with --labels"},
      {"--close", "--close goes with --labels"},
      {"--labels --iso 3", "--iso does not go with --labels"},
      {"--labels --format vtk", "--format vtk: expected ply, obj, stl or glb"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.args);
    const auto r = Tandem("--input " + in + out + " " + c.args);
    EXPECT_EQ(r.code, 2) << r.text;
    EXPECT_NE(r.text.find(c.message), std::string::npos) << r.text;
  }
  // One mesh per label needs a folder, or the one GLB.
  const auto file = Tandem("--input " + in + " --labels --out " + Path("seg.ply"));
  EXPECT_EQ(file.code, 2) << file.text;
  EXPECT_NE(file.text.find("must be a folder (end it with /) or one .glb"), std::string::npos)
      << file.text;
  const auto draco = Tandem("--input " + in + " --labels --glb-draco --out " + Path("seg.glb"));
  EXPECT_EQ(draco.code, 2) << draco.text;
  EXPECT_NE(draco.text.find("--glb-draco with --labels"), std::string::npos) << draco.text;
}

TEST_F(CliLabels, ABadNamesTableNamesItsLine) {
  const std::string in = LabelVolume("u.nii.gz", DType::kUInt16);
  const std::string names = Path("names.csv");
  std::FILE* f = std::fopen(names.c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fputs("id,name\n3,Liver\nseven,Spleen\n", f);
  std::fclose(f);
  const auto r =
      Tandem("--input " + in + " --labels --label-names " + names + " --out " + Path("out/"));
  EXPECT_EQ(r.code, 1) << r.text;
  EXPECT_NE(r.text.find(names + ":3: 'seven' is not a label id"), std::string::npos) << r.text;
}

// The whole way: a uint16 label map written by the test, extracted with names and --close,
// one closed manifold file per label, the GLB with a node each and the figures per label.
TEST_F(CliLabels, ALabelMapToOneClosedFilePerLabel) {
  const std::string in = LabelVolume("seg.nrrd", DType::kUInt16);
  const std::string names = Path("names.ctbl");
  std::FILE* f = std::fopen(names.c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fputs("# Slicer\n0 Background 0 0 0 0\n3 Liver 221 130 101 255\n", f);
  std::fclose(f);
  const std::string out = Path("seg") + "/";
  const auto r = Tandem("--input " + in + " --labels --close --label-names " + names +
                        " --error 0.05 --out " + out + " --metrics " + Path("m.json"));
  if (r.text.find("has no label mode") != std::string::npos) {
    GTEST_SKIP() << "this build's engine has no label mode: " << r.text;
  }
  ASSERT_EQ(r.code, 0) << r.text;
  ExpectSpheres(out, {"Liver.ply", "7.ply"});
  std::ifstream in_json(Path("m.json"));
  const nlohmann::json m = nlohmann::json::parse(in_json);
  ASSERT_EQ(m["labels"].size(), 2u);
  EXPECT_EQ(m["labels"][0]["label"], 3);
  EXPECT_EQ(m["labels"][0]["name"], "Liver");
  EXPECT_EQ(m["labels"][0]["closed"], true);
  EXPECT_EQ(m["labels"][1]["label"], 7);
  EXPECT_GT(m["labels"][1]["volume"].get<double>(), 0.0);
  EXPECT_TRUE(std::filesystem::exists(out + "labels.glb"));
}

// --seal: the same outputs from the welded chunks: a file per label, each a closed manifold
// of the unsealed run's topology, the GLB and the figures per label.
TEST_F(CliLabels, SealedRunWritesTheSameOutputs) {
  VolumeInfo info;
  info.nx = info.ny = 10;
  info.nz = 40;
  info.dtype = DType::kUInt16;
  const std::string in = Path("stack.nrrd");
  // Boxes of labels 1..4 stacked along z, each 8 slices, with a tunnel through label 2 (a
  // torus) and label 3 wrapped around a voxel of label 9.
  ASSERT_TRUE(io::WriteVolume(in, info, [](int64_t z, std::vector<uint8_t>* bytes) {
                bytes->assign(100 * sizeof(uint16_t), 0);
                for (int64_t j = 1; j < 9; ++j) {
                  for (int64_t i = 1; i < 9; ++i) {
                    uint16_t id = z < 2 || z >= 34 ? 0 : static_cast<uint16_t>(1 + (z - 2) / 8);
                    if (id == 2 && i >= 4 && i < 6 && j >= 4 && j < 6) id = 0;
                    if (id == 3 && i == 5 && j == 5 && z == 21) id = 9;
                    testing::StoreValue(DType::kUInt16, id,
                                        bytes->data() + (j * 10 + i) * sizeof(uint16_t));
                  }
                }
                return absl::OkStatus();
              }).ok());
  std::map<std::string, eval::TopologyReport> runs[2];
  nlohmann::json metrics[2];
  for (int sealed = 0; sealed < 2; ++sealed) {
    const std::string out = Path(sealed ? "sealed" : "whole") + "/";
    const std::string json = Path(sealed ? "sealed.json" : "whole.json");
    const auto r = Tandem("--input " + in + " --labels --close --error 0.3 --out " + out +
                          " --metrics " + json + (sealed ? " --seal" : ""));
    ASSERT_EQ(r.code, 0) << r.text;
    for (const auto& entry : std::filesystem::directory_iterator(out)) {
      if (entry.path().extension() != ".ply") continue;
      auto mesh = io::ReadMesh(entry.path().string());
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      runs[sealed][entry.path().filename().string()] = eval::AnalyzeTopology(*mesh);
    }
    EXPECT_TRUE(std::filesystem::exists(out + "labels.glb"));
    std::ifstream in_json(json);
    metrics[sealed] = nlohmann::json::parse(in_json);
  }
  ASSERT_EQ(runs[1].size(), 5u);
  for (const auto& [file, whole] : runs[0]) {
    SCOPED_TRACE(file);
    ASSERT_TRUE(runs[1].count(file));
    const eval::TopologyReport& t = runs[1].at(file);
    EXPECT_TRUE(t.IsClosedManifold());
    EXPECT_EQ(t.euler, whole.euler);
    EXPECT_EQ(t.components, whole.components);
  }
  EXPECT_EQ(runs[1].at("2.ply").euler, 0);  // the tunnel: a torus
  EXPECT_EQ(runs[1].at("3.ply").euler, 4);  // a box around a cavity
  ASSERT_EQ(metrics[1]["labels"].size(), metrics[0]["labels"].size());
  for (size_t i = 0; i < metrics[1]["labels"].size(); ++i) {
    EXPECT_EQ(metrics[1]["labels"][i]["label"], metrics[0]["labels"][i]["label"]);
    EXPECT_EQ(metrics[1]["labels"][i]["closed"], true);
  }
  // Sealed, the session handed the mesh out as it went: it held less after every slice past
  // the first box's seal, and nothing at the end.
  const auto& whole = metrics[0]["trace"];
  const auto& sealed = metrics[1]["trace"];
  ASSERT_LE(sealed.size(), whole.size());  // the unsealed run adds its finishing pass
  EXPECT_EQ(sealed.back(), 0);
  int64_t less = 0;
  for (size_t i = 0; i < sealed.size(); ++i) {
    // Until a box is handed out the two runs differ only in the order of their contractions:
    // a triangle or two either way, 1 % at most.
    EXPECT_LE(sealed[i].get<int64_t>(), whole[i].get<int64_t>() * 101 / 100) << i;
    less += sealed[i].get<int64_t>() < whole[i].get<int64_t>();
  }
  EXPECT_GT(less, static_cast<int64_t>(sealed.size()) / 2);
}

// Split into slabs (--parts, and the automatic split of a grid 81 wide or more) a label map
// gives every label's closed manifold with one part's topology, sealed too. The split is
// part of the result (other files than one part's), and the automatic one is --parts 2's on
// this grid.
TEST_F(CliLabels, ASplitRunWritesEveryLabelWithOnePartsTopology) {
  VolumeInfo info;
  info.nx = 84;  // seams at column 41 (2 parts), 27 and 55 (3)
  info.ny = 12;
  info.nz = 24;
  info.dtype = DType::kUInt16;
  const std::string in = Path("wide.nrrd");
  // Label 1 a long box with a tunnel along y (a torus) around label 2 (a cavity: two spheres'
  // worth, χ 2 with the torus), which crosses the seams; label 3 one voxel on a seam column.
  ASSERT_TRUE(io::WriteVolume(in, info, [&info](int64_t z, std::vector<uint8_t>* bytes) {
                bytes->assign(static_cast<size_t>(info.nx * info.ny) * sizeof(uint16_t), 0);
                for (int64_t j = 0; j < info.ny; ++j) {
                  for (int64_t i = 0; i < info.nx; ++i) {
                    uint16_t id = 0;
                    if (i >= 2 && i < 82 && j >= 2 && j < 10 && z >= 2 && z < 22) id = 1;
                    if (i >= 62 && i < 66 && z >= 10 && z < 13) id = 0;
                    if (i >= 20 && i < 58 && j >= 4 && j < 8 && z >= 6 && z < 18) id = 2;
                    if (i == 41 && j == 3 && z == 12) id = 3;
                    testing::StoreValue(DType::kUInt16, id,
                                        bytes->data() + (j * info.nx + i) * sizeof(uint16_t));
                  }
                }
                return absl::OkStatus();
              }).ok());
  const struct {
    const char* name;
    std::string flags;
  } runs[] = {{"one", "--parts 1"},
              {"two", "--parts 2"},
              {"auto", ""},
              {"three", "--parts 3"},
              {"two-sealed", "--parts 2 --seal"}};
  std::map<std::string, std::map<std::string, eval::TopologyReport>> topology;
  std::map<std::string, std::map<std::string, std::string>> bytes;
  for (const auto& run : runs) {
    SCOPED_TRACE(run.name);
    const std::string out = Path(run.name) + "/";
    const auto r =
        Tandem("--input " + in + " --labels --close --error 0.3 --out " + out + " " + run.flags);
    ASSERT_EQ(r.code, 0) << r.text;
    for (const auto& entry : std::filesystem::directory_iterator(out)) {
      if (entry.path().extension() != ".ply") continue;
      const std::string file = entry.path().filename().string();
      auto mesh = io::ReadMesh(entry.path().string());
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      topology[run.name][file] = eval::AnalyzeTopology(*mesh);
      std::ifstream f(entry.path(), std::ios::binary);
      bytes[run.name][file].assign(std::istreambuf_iterator<char>(f), {});
    }
    EXPECT_TRUE(std::filesystem::exists(out + "labels.glb"));
  }
  const auto& one = topology["one"];
  ASSERT_EQ(one.size(), 3u);
  EXPECT_EQ(one.at("1.ply").euler, 2);  // the torus (0) and the cavity's sphere (2)
  EXPECT_EQ(one.at("1.ply").components, 2u);
  EXPECT_EQ(one.at("2.ply").euler, 2);
  EXPECT_EQ(one.at("3.ply").euler, 2);
  for (const auto& run : runs) {
    SCOPED_TRACE(run.name);
    ASSERT_EQ(topology[run.name].size(), one.size());
    for (const auto& [file, ref] : one) {
      SCOPED_TRACE(file);
      ASSERT_TRUE(topology[run.name].count(file));
      const eval::TopologyReport& t = topology[run.name].at(file);
      EXPECT_TRUE(t.IsClosedManifold());
      EXPECT_EQ(t.euler, ref.euler);
      EXPECT_EQ(t.components, ref.components);
    }
  }
  EXPECT_EQ(bytes["auto"], bytes["two"]);
  EXPECT_NE(bytes["two"].at("1.ply"), bytes["one"].at("1.ply"));
}

// The client checks a label volume as the CLI does, before it connects (the server is never
// asked: the address has none).
TEST_F(CliLabels, TheClientRefusesAFloatLabelVolumeBeforeSending) {
  const std::string client = testing::BinPath("tandem-client");
  if (!std::filesystem::exists(client)) GTEST_SKIP() << "built without the service";
  const std::string in = LabelVolume("f.mha", DType::kFloat32);
  const auto r = testing::RunCommand(client + " stream --server 127.0.0.1:1 --input " + in +
                                     " --labels --out " + Path("out/"));
  EXPECT_EQ(r.code, 2) << r.text;
  EXPECT_NE(r.text.find("--labels needs integer voxels; " + in + " holds float32"),
            std::string::npos)
      << r.text;
}

TEST_F(CliLabels, HelpListsTheLabelFlags) {
  const auto r = testing::RunCommand(testing::BinPath("tandem") + " extract --help");
  EXPECT_EQ(r.code, 0);
  for (const char* flag :
       {"--labels", "--background", "--label-ids", "--label-names", "--close", "--format"}) {
    EXPECT_NE(r.text.find(flag), std::string::npos) << flag;
  }
}

// Thousands of one-voxel labels with ids anywhere in uint64: every id its own closed
// surface and its own file, named by the exact id (2^53 and 2^53 + 1 are two files), and
// one node each in labels.glb and in the figures.
TEST_F(CliLabels, ManyScatteredUint64IdsEachGetTheirOwnSurface) {
  const std::string in = Path("many.json");
  const std::vector<uint64_t> ids = ManyIdVolume(in, 16, 16, 8);
  const std::string out = Path("many") + "/";
  const auto r = Tandem("--input " + in + " --labels --close --error 0.05 --quiet --out " + out +
                        " --metrics " + Path("m.json"));
  if (r.text.find("has no label mode") != std::string::npos) {
    GTEST_SKIP() << "this build's engine has no label mode: " << r.text;
  }
  ASSERT_EQ(r.code, 0) << r.text;
  std::set<std::string> expected;
  for (uint64_t id : ids) expected.insert(std::to_string(id) + ".ply");
  std::set<std::string> files;
  for (const auto& e : std::filesystem::directory_iterator(out)) {
    files.insert(e.path().filename().string());
  }
  ASSERT_EQ(files.size(), ids.size() + 1);  // and labels.glb
  EXPECT_TRUE(files.count("labels.glb"));
  files.erase("labels.glb");
  EXPECT_EQ(files, expected);
  ExpectSpheres(out, {"9007199254740992.ply", "9007199254740993.ply", "18446744073709551615.ply"});
  std::ifstream in_json(Path("m.json"));
  const nlohmann::json m = nlohmann::json::parse(in_json);
  ASSERT_EQ(m["labels"].size(), ids.size());
  size_t closed = 0;
  for (const auto& l : m["labels"]) closed += l["closed"].get<bool>() && l["euler"] == 2;
  EXPECT_EQ(closed, ids.size());
  // labels.glb: a node per label, its id exact in "extras".
  const std::string glb = testing::FileBytes(out + "labels.glb");
  ASSERT_GT(glb.size(), 20u);
  uint32_t json_bytes = 0;
  std::memcpy(&json_bytes, glb.data() + 12, 4);
  const nlohmann::json gltf = nlohmann::json::parse(glb.substr(20, json_bytes));
  ASSERT_EQ(gltf["nodes"].size(), ids.size());
  std::set<std::string> labels;
  for (const auto& node : gltf["nodes"]) labels.insert(node["extras"]["label"].get<std::string>());
  EXPECT_EQ(labels.size(), ids.size());
  EXPECT_TRUE(labels.count("18446744073709551615"));
  EXPECT_EQ(gltf["meshes"].size(), ids.size());
}

// What a label costs in memory: simplified to a handful of triangles each, 4x the labels
// grow the peak resident set by what those need in the sweep and the outputs (PeakRssPerLabel).
TEST_F(CliLabels, MemoryGrowsByTheSurfacesPerLabel) {
  if (testing::kSanitized) GTEST_SKIP() << "resident sizes say nothing under a sanitizer";
  const double per_label = PeakRssPerLabel([&](int k) {
    return std::vector<std::string>{"--out", Path(absl::StrCat("many", k, ".glb"))};
  });
  ASSERT_GT(per_label, -1) << "tandem extract failed";
  EXPECT_LT(per_label, 1152.0);
}

// One file per label (--out DIR/): the session goes before the complex is split and the
// complex before the files are written, so a label costs its surface, as with the GLB alone.
TEST_F(CliLabels, MemoryGrowsByTheSurfacesPerLabelInAFolder) {
  if (testing::kSanitized) GTEST_SKIP() << "resident sizes say nothing under a sanitizer";
  const double per_label = PeakRssPerLabel([&](int k) {
    return std::vector<std::string>{"--out", Path(absl::StrCat("dir", k)) + "/"};
  });
  ASSERT_GT(per_label, -1) << "tandem extract failed";
  EXPECT_LT(per_label, 1152.0);
}

// --neuroglancer: the coarser sweeps are kept as complexes, not sessions, and the segments are
// cut from them a shard at a time, not every level of every label at once.
TEST_F(CliLabels, MemoryGrowsByTheSurfacesPerLabelInANeuroglancerExport) {
  if (testing::kSanitized) GTEST_SKIP() << "resident sizes say nothing under a sanitizer";
  const auto probe = Tandem("--input " + Path("none.json") + " --labels --neuroglancer " +
                            Path("ng") + " --out " + Path("x.glb"));
  if (probe.text.find("without Draco") != std::string::npos) GTEST_SKIP() << probe.text;
  const double per_label = PeakRssPerLabel([&](int k) {
    return std::vector<std::string>{"--out", Path(absl::StrCat("ng", k, ".glb")), "--neuroglancer",
                                    Path(absl::StrCat("ng", k))};
  });
  ASSERT_GT(per_label, -1) << "tandem extract failed";
  EXPECT_LT(per_label, 2560.0);
}

}  // namespace
}  // namespace tandem
