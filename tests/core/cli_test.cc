// The `tandem` executable, run as a user would: exit codes, files written, messages.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "tandem/geometry.h"
#include "tandem/io/mesh_io.h"
#include "tandem/eval/metrics.h"
#include "tandem/io/series.h"
#include "tandem/eval/topology.h"
#include "tandem/io/volume_writers.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

using Output = testing::CommandOutput;
using testing::RunCommand;

Output RunTandem(const std::string& args) {
  return RunCommand(testing::BinPath("tandem") + " " + args);
}

nlohmann::json ReadJson(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return nlohmann::json::parse(ss.str());
}

// A program run with the dynamic loader naming every library it loads and initialises
// (LD_DEBUG=files), on stderr with the program's own output.
Output RunLoading(const std::string& program, const std::string& args) {
  return RunCommand("LD_DEBUG=files " + program + " " + args);
}

class Cli : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir(); }
  std::string Path(const std::string& name) const { return dir_ + "/" + name; }
  // A copy of the CLI installed alone: PREFIX/bin/tandem, and PREFIX/lib/tandem/ (where the
  // modules go, core/module/include/tandem/module/module_loader.h) empty. Its path.
  std::string InstallAlone(const std::string& prefix) const {
    namespace fs = std::filesystem;
    fs::create_directories(Path(prefix + "/bin"));
    fs::create_directories(Path(prefix + "/lib/tandem"));
    fs::copy_file(testing::BinPath("tandem"), Path(prefix + "/bin/tandem"));
    return Path(prefix + "/bin/tandem");
  }
  std::string dir_;
};

TEST_F(Cli, HelpTellsTheSubcommandsAndOptions) {
  Output o = RunTandem("--help");
  EXPECT_EQ(o.code, 0);
  for (const char* word : {"extract", "generate", "measure"}) {
    EXPECT_NE(o.text.find(word), std::string::npos) << word;
  }
  o = RunTandem("extract --help");
  EXPECT_EQ(o.code, 0);
  for (const char* opt : {"--input", "--iso", "--error", "--alpha", "--schedule",
                          "--target-triangles", "--no-simplify", "--metrics", "--reference"}) {
    EXPECT_NE(o.text.find(opt), std::string::npos) << opt;
  }
  EXPECT_EQ(RunTandem("generate --help").code, 0);
  EXPECT_EQ(RunTandem("measure --help").code, 0);
  EXPECT_NE(RunTandem("").code, 0);
  EXPECT_NE(RunTandem("frobnicate").code, 0);
}

// Mistakes on the command line get a message that says what was wrong: a repeated
// option (it used to keep the last value silently), a malformed number or a list given
// to --iso (both used to be reported as "no iso-value suggested"), a misspelt option
// (with the closest real one), and --version answers.
TEST_F(Cli, CommandLineMistakesAreNamed) {
  ASSERT_EQ(RunTandem("generate sphere --size 16 --out " + Path("s.json")).code, 0);
  const std::string extract = "extract --input " + Path("s.json") + " --out " + Path("m.ply");
  Output o = RunTandem(extract + " --iso 1 --iso 2");
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("--iso given twice ('1' and '2'): give it once"), std::string::npos)
      << o.text;
  o = RunTandem(extract + " --iso 1x");
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("--iso: '1x' is not a number"), std::string::npos) << o.text;
  // Several iso-values need an output pattern: two surfaces must not write one file.
  o = RunTandem(extract + " --iso 60,120");
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("with 2 iso-values, name the outputs with a pattern holding {iso}"),
            std::string::npos) << o.text;
  o = RunTandem(extract + " --iso 60,60");
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("60 is given twice"), std::string::npos) << o.text;
  o = RunTandem(extract + " --iso 60,,120");
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("--iso: '' is not a number"), std::string::npos) << o.text;
  o = RunTandem(extract + " --erorr 0.5");
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("unknown option --erorr (did you mean --error?)"), std::string::npos)
      << o.text;
  o = RunTandem("--version");
  EXPECT_EQ(o.code, 0);
  EXPECT_EQ(o.text.rfind("tandem 0.", 0), 0u) << o.text;
  EXPECT_NE(o.text.find("(git "), std::string::npos) << o.text;
}

// Skin and bone in one pass: --iso A,B gives one surface per value from one read of the
// slices, each identical to its own single-iso run (plain and sealed), with one summary
// per surface and the --metrics as a JSON array in --iso order.
TEST_F(Cli, SeveralIsoValuesInOnePassEqualTheirSingleRuns) {
  ASSERT_EQ(RunTandem("generate link --size 40 --out " + Path("l.json")).code, 0);
  const std::string in = "extract --input " + Path("l.json") + " --error 0.01";
  for (const std::string extra : {"", " --seal"}) {
    SCOPED_TRACE(extra);
    Output o = RunTandem(in + extra + " --iso 0,0.05 --out " + Path("both_{iso}.ply") +
                         " --metrics " + Path("both.json"));
    ASSERT_EQ(o.code, 0) << o.text;
    nlohmann::json reports = ReadJson(Path("both.json"));
    ASSERT_TRUE(reports.is_array());
    ASSERT_EQ(reports.size(), 2u);
    for (const std::string iso : {"0", "0.05"}) {
      SCOPED_TRACE(iso);
      Output one = RunTandem(in + extra + " --iso " + iso + " --out " + Path("one.ply") +
                             " --quiet");
      ASSERT_EQ(one.code, 0) << one.text;
      auto a = io::ReadMesh(Path("both_" + iso + ".ply"));
      auto b = io::ReadMesh(Path("one.ply"));
      ASSERT_TRUE(a.ok()) << a.status();
      ASSERT_TRUE(b.ok()) << b.status();
      EXPECT_GT(a->indices.size(), 300u);
      EXPECT_EQ(a->positions, b->positions);
      EXPECT_EQ(a->indices, b->indices);
      const nlohmann::json& r = reports[iso == "0" ? 0 : 1];
      EXPECT_EQ(r["iso"].get<double>(), std::stod(iso));
      EXPECT_EQ(r["triangles_final"].get<int64_t>(), static_cast<int64_t>(a->indices.size() / 3));
    }
  }
  // The two surfaces differ, and without --metrics each gets its own summary.
  EXPECT_NE(io::ReadMesh(Path("both_0.ply"))->positions,
            io::ReadMesh(Path("both_0.05.ply"))->positions);
  Output o = RunTandem(in + " --iso 0,0.05 --out " + Path("s_{iso}.obj"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("-> " + Path("s_0.obj")), std::string::npos) << o.text;
  EXPECT_NE(o.text.find("-> " + Path("s_0.05.obj")), std::string::npos) << o.text;
}

TEST_F(Cli, GenerateThenExtractFullResolution) {
  Output g = RunTandem("generate sphere --size 32 --out " + Path("s.json"));
  ASSERT_EQ(g.code, 0) << g.text;
  ASSERT_TRUE(std::filesystem::exists(Path("s.raw")));
  EXPECT_EQ(std::filesystem::file_size(Path("s.raw")), 32u * 32 * 32 * 4);
  nlohmann::json side = ReadJson(Path("s.json"));
  ASSERT_TRUE(side.contains("suggested_isovalues"));
  EXPECT_EQ(side["suggested_isovalues"][0].get<double>(), 0.0);
  Output e = RunTandem("extract --input " + Path("s.json") + " --iso 0 --no-simplify --out " +
                       Path("s.ply") + " --quiet");
  ASSERT_EQ(e.code, 0) << e.text;
  auto mesh = io::ReadMesh(Path("s.ply"));
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  eval::TopologyReport r = eval::AnalyzeTopology(*mesh);
  EXPECT_TRUE(r.IsClosedManifold());
  EXPECT_EQ(r.euler, 2);
  EXPECT_GT(r.triangles, 2000u);
}

TEST_F(Cli, ExtractWritesMeshAndMetricsWithEveryKey) {
  ASSERT_EQ(RunTandem("generate link --size 48 --out " + Path("l.json")).code, 0);
  Output e = RunTandem("extract --input " + Path("l.json") + " --error 0.2 --alpha 0.2 --out " +
                       Path("l.obj") + " --metrics " + Path("m.json") + " --reference");
  ASSERT_EQ(e.code, 0) << e.text;
  nlohmann::json m = ReadJson(Path("m.json"));
  for (const char* key : {"triangles_extracted", "triangles_final", "vertices_final", "error_max",
                          "anisotropy", "directional_bias", "peak_triangles", "time_s",
                          "peak_rss_bytes", "trace", "refusals", "distance"}) {
    EXPECT_TRUE(m.contains(key)) << key;
  }
  for (const char* key : {"extract", "simplify", "total"}) EXPECT_TRUE(m["time_s"].contains(key));
  for (const char* d : {"L1", "L2", "Linf"}) {
    for (const char* k : {"forward", "backward", "max"}) EXPECT_TRUE(m["distance"][d].contains(k));
  }
  EXPECT_EQ(m["schedule"], "tandem-lag");  // the default
  EXPECT_LE(m["error_max"].get<double>(), 0.2);
  EXPECT_LT(m["distance"]["L2"]["max"].get<double>(), 0.2);
  auto mesh = io::ReadMesh(Path("l.obj"));
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_EQ(m["triangles_final"].get<size_t>(), mesh->num_triangles());
  EXPECT_EQ(m["vertices_final"].get<size_t>(), mesh->num_vertices());
  EXPECT_LT(mesh->num_triangles(), m["triangles_extracted"].get<size_t>() / 4);
  EXPECT_EQ(m["trace"].size(), 2u * 48 + 1);
  EXPECT_EQ(m["lockstep_error"].get<double>(), 0.5);
  eval::TopologyReport r = eval::AnalyzeTopology(*mesh);
  EXPECT_EQ(r.components, 2u);
  EXPECT_TRUE(r.IsClosedManifold());
  // Without --metrics a summary goes to stderr.
  Output s = RunTandem("extract --input " + Path("l.json") + " --error 0.2 --out " + Path("l.ply"));
  ASSERT_EQ(s.code, 0);
  EXPECT_NE(s.text.find("triangles final"), std::string::npos) << s.text;
}

// --seal: written as the chunks come (.ply, .obj) or welded at the end (--reference, .stl);
// either way the metrics count the file's mesh, and the anisotropy is that of the mesh.
TEST_F(Cli, SealedExtractWritesTheWholeMeshAndCountsIt) {
  ASSERT_EQ(RunTandem("generate link --size 48 --out " + Path("l.json")).code, 0);
  double anisotropy[2] = {0, 0};
  int run = 0;
  for (const char* extra : {" --out " , " --reference --out "}) {
    const std::string out = Path(run == 0 ? "s.ply" : "r.obj");
    Output e = RunTandem("extract --input " + Path("l.json") + " --error 0.2 --seal --metrics " +
                         Path("m.json") + extra + out);
    ASSERT_EQ(e.code, 0) << e.text;
    nlohmann::json m = ReadJson(Path("m.json"));
    auto mesh = io::ReadMesh(out);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    EXPECT_EQ(m["triangles_final"].get<size_t>(), mesh->num_triangles()) << out;
    EXPECT_EQ(m["vertices_final"].get<size_t>(), mesh->num_vertices()) << out;
    EXPECT_LE(m["error_max"].get<double>(), 0.2);
    EXPECT_NEAR(m["anisotropy"].get<double>(), eval::Anisotropy(*mesh), 1e-4)
        << out;  // float32 file
    anisotropy[run++] = m["anisotropy"].get<double>();
    const eval::TopologyReport r = eval::AnalyzeTopology(*mesh);
    EXPECT_EQ(r.components, 2u);
    EXPECT_TRUE(r.IsClosedManifold());
  }
  EXPECT_NEAR(anisotropy[0], anisotropy[1], 1e-9);  // the same sealed mesh both ways
  Output bad = RunTandem("extract --input " + Path("l.json") + " --seal --target-triangles 100 --out " +
                         Path("t.ply"));
  EXPECT_EQ(bad.code, 2) << bad.text;
  EXPECT_NE(bad.text.find("target triangle count"), std::string::npos) << bad.text;
}

TEST_F(Cli, MeasurePrintsDistancesBothWays) {
  ASSERT_EQ(RunTandem("generate sphere --size 32 --out " + Path("s.json")).code, 0);
  ASSERT_EQ(RunTandem("extract --input " + Path("s.json") + " --no-simplify --quiet --out " + Path("a.ply")).code, 0);
  ASSERT_EQ(RunTandem("extract --input " + Path("s.json") + " --error 0.3 --quiet --out " + Path("b.ply")).code, 0);
  Output o = RunTandem("measure " + Path("a.ply") + " " + Path("b.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  for (const char* w : {"L1", "L2", "Linf", "forward", "backward"}) {
    EXPECT_NE(o.text.find(w), std::string::npos) << w;
  }
  // --json: the distances alone, not the extract report's schema filled with zeros.
  o = RunTandem("measure --json " + Path("a.ply") + " " + Path("b.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  const nlohmann::json j = nlohmann::json::parse(o.text);
  EXPECT_EQ(j.size(), 1u) << o.text;
  EXPECT_GT(j["distance"]["L2"]["max"].get<double>(), 0.0);
  EXPECT_LT(j["distance"]["L2"]["max"].get<double>(), 0.3);
}

// The summary labels CPU and wall-clock figures as such, and the peak RSS is the process's
// (with --reference, the full-resolution run is part of it, as /usr/bin/time would say).
TEST_F(Cli, SummaryFiguresSayWhatTheyMeasure) {
  ASSERT_EQ(RunTandem("generate gyroid --size 64 --out " + Path("g.json")).code, 0);
  Output o = RunTandem("extract --input " + Path("g.json") + " --out " + Path("g.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("wall time in session"), std::string::npos) << o.text;
  EXPECT_NE(o.text.find("CPU extract/simplify"), std::string::npos) << o.text;
  ASSERT_EQ(RunTandem("extract --input " + Path("g.json") + " --metrics " + Path("plain.json") +
                      " --out " + Path("g.ply")).code, 0);
  ASSERT_EQ(RunTandem("extract --input " + Path("g.json") + " --reference --metrics " +
                      Path("ref.json") + " --out " + Path("g.ply")).code, 0);
  // The reference surface and its BVH hold about 13 MiB more here (23 vs 10 MiB measured).
  EXPECT_GT(ReadJson(Path("ref.json"))["peak_rss_bytes"].get<int64_t>(),
            ReadJson(Path("plain.json"))["peak_rss_bytes"].get<int64_t>() + (4 << 20));
}

TEST_F(Cli, BadInputGivesAClearErrorAndNonZeroExit) {
  Output o = RunTandem("extract --input " + Path("missing.json") + " --iso 1 --out " + Path("x.ply"));
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find("missing.json"), std::string::npos) << o.text;
  ASSERT_EQ(RunTandem("generate sphere --size 16 --out " + Path("s.json")).code, 0);
  o = RunTandem("extract --input " + Path("s.json") + " --out " + Path("x.off"));
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find(".ply, .obj, .stl or .glb"), std::string::npos) << o.text;
  // Each bad flag: a non-zero exit and a message that names the problem.
  for (const auto& [flags, names] : std::vector<std::pair<std::string, std::string>>{
           {"--alpha 2", "alpha"},
           {"--error -1", "E0"},
           {"--schedule fast", "fast"},
           {"--distance-guard -2", "distance guard"},
           {"--sag-correction 1.5", "sag correction"},
           {"--parts 99", "--parts 99"},
           {"--bogus 1", "--bogus"},
       }) {
    o = RunTandem("extract --input " + Path("s.json") + " " + flags + " --out " + Path("x.ply"));
    EXPECT_NE(o.code, 0) << flags;
    EXPECT_NE(o.text.find(names), std::string::npos) << flags << ": " << o.text;
  }
  // A truncated raw file: the reader names the file and the problem.
  std::filesystem::resize_file(Path("s.raw"), 1000);
  o = RunTandem("extract --input " + Path("s.json") + " --out " + Path("x.ply"));
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find("s."), std::string::npos) << o.text;
  EXPECT_FALSE(std::filesystem::exists(Path("x.ply")));
}

TEST_F(Cli, ZarrInputGivesTheSameMeshAsRawJson) {
  // The same volume as raw + JSON and as OME-Zarr (v2 and v3, chunks 7 planes deep with
  // edge chunks): extract gives the same mesh and the same metrics.
  ASSERT_EQ(RunTandem("generate link --dims 44,40,36 --spacing 0.5,0.75,1 --out " + Path("l.json")).code, 0);
  Output g = RunTandem("generate link --dims 44,40,36 --spacing 0.5,0.75,1 --zarr-chunks 7,16,16 --out " +
                       Path("l2.zarr"));
  ASSERT_EQ(g.code, 0) << g.text;
  g = RunTandem("generate link --dims 44,40,36 --spacing 0.5,0.75,1 --zarr-version 3 --zarr-codec zstd "
                "--zarr-chunks 5,0,32 --out " + Path("l3.zarr"));
  ASSERT_EQ(g.code, 0) << g.text;
  Output info = RunTandem("info --input " + Path("l3.zarr"));
  ASSERT_EQ(info.code, 0) << info.text;
  EXPECT_NE(info.text.find("44 x 40 x 36"), std::string::npos) << info.text;
  EXPECT_NE(info.text.find("spacing  0.5 0.75 1"), std::string::npos) << info.text;
  EXPECT_NE(info.text.find("OME-Zarr"), std::string::npos) << info.text;
  nlohmann::json want;
  for (const char* name : {"l.json", "l2.zarr", "l3.zarr"}) {
    // No --iso: the Zarr writer keeps the suggested iso-value like the sidecar does.
    Output e = RunTandem("extract --input " + Path(name) + " --error 0.1 --out " + Path(name) +
                         ".ply --metrics " + Path(name) + ".m.json");
    ASSERT_EQ(e.code, 0) << name << ": " << e.text;
    nlohmann::json m = ReadJson(Path(name) + ".m.json");
    for (const char* volatile_key : {"time_s", "peak_rss_bytes", "input"}) m.erase(volatile_key);
    if (want.is_null()) {
      want = m;
      EXPECT_GT(m["triangles_final"].get<int>(), 100);
    } else {
      EXPECT_EQ(m, want) << name;
    }
  }
  // --zarr-array picks a level; a level that does not exist is a clear error.
  Output bad = RunTandem("info --input " + Path("l2.zarr") + " --zarr-array 1");
  EXPECT_NE(bad.code, 0);
  EXPECT_NE(bad.text.find("level 1 does not exist"), std::string::npos) << bad.text;
  EXPECT_EQ(RunTandem("info --input " + Path("l2.zarr") + " --zarr-array 0").code, 0);
}

TEST_F(Cli, ExtractsTheSharedEngineCtToAPly) {
  TANDEM_SHARED_OR_SKIP(path, "ct_engine_256x256x128_uint8.json");
  Output o = RunTandem("extract --input " + path + " --iso 120 --no-simplify --quiet --out " + Path("engine.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  std::ifstream in(Path("engine.ply"), std::ios::binary);
  std::string header(200, '\0');
  in.read(header.data(), 200);
  EXPECT_EQ(header.rfind("ply\nformat binary_little_endian 1.0\n", 0), 0u);
  auto mesh = io::ReadMesh(Path("engine.ply"));
  ASSERT_TRUE(mesh.ok());
  EXPECT_GT(mesh->num_triangles(), 500000u);
  EXPECT_TRUE(eval::AnalyzeTopology(*mesh).IsManifold());
}

// Geometry that once aborted the CLI (exit 134: std::length_error from a queue sized by
// the reach in slice units) or gave a wrong mesh is refused with the field named.
TEST_F(Cli, ExtremeSidecarGeometryIsRefusedNotAborted) {
  ASSERT_EQ(RunTandem("generate sphere --size 12 --out " + Path("s.json")).code, 0);
  const nlohmann::json sidecar = ReadJson(Path("s.json"));
  struct Case {
    nlohmann::json spacing, origin;
    const char* text;
  };
  for (const Case& c : {Case{{1e160, 1e160, 1.0}, {0, 0, 0}, "invalid spacing 1e+160 on axis 0"},
                        Case{{1.0, 1.0, 1.0}, {1e30, 0, 0}, "invalid origin 1e+30 on axis 0"},
                        Case{{1e-300, 1e-300, 1e-300}, {0, 0, 0}, "invalid spacing 1e-300"}}) {
    nlohmann::json edited = sidecar;
    edited["spacing"] = c.spacing;
    edited["origin"] = c.origin;
    edited["raw_file"] = Path("s.raw");
    std::ofstream(Path("e.json")) << edited.dump();
    const Output o = RunTandem("extract --input " + Path("e.json") + " --out " + Path("e.ply"));
    EXPECT_EQ(o.code, 1) << o.text;  // the input's fault, not the command line's
    EXPECT_NE(o.text.find(c.text), std::string::npos) << o.text;
  }
}

// tandem generate writes every format the readers read, and each gives the same surface.
TEST_F(Cli, GenerateWritesEveryReadableFormat) {
  ASSERT_EQ(RunTandem("generate link --size 24 --out " + Path("l.json")).code, 0);
  ASSERT_EQ(RunTandem("extract --input " + Path("l.json") + " --metrics " + Path("l.m.json") +
                      " --out " + Path("l.ply")).code, 0);
  const int64_t want = ReadJson(Path("l.m.json"))["triangles_final"].get<int64_t>();
  ASSERT_GT(want, 50);
  for (const char* ext : {"nrrd", "nhdr", "nii", "nii.gz", "tif"}) {
    const std::string vol = Path(std::string("v.") + ext);
    Output o = RunTandem("generate link --size 24 --out " + vol);
    ASSERT_EQ(o.code, 0) << ext << ": " << o.text;
    o = RunTandem("extract --input " + vol + " --iso 0 --metrics " + Path("m.json") + " --out " +
                  Path("v.ply"));
    ASSERT_EQ(o.code, 0) << ext << ": " << o.text;
    EXPECT_EQ(ReadJson(Path("m.json"))["triangles_final"].get<int64_t>(), want) << ext;
  }
  Output bad = RunTandem("generate link --size 24 --out " + Path("v.xyz"));
  EXPECT_EQ(bad.code, 2) << bad.text;
  EXPECT_NE(bad.text.find("v.xyz"), std::string::npos) << bad.text;
}

TEST_F(Cli, FoldersOfSlicesAreVolumesAndInfoShowsTheValues) {
  // A TIFF sequence holds the float voxels exactly: the same mesh as the raw volume.
  ASSERT_EQ(RunTandem("generate link --size 24 --out " + Path("l.json")).code, 0);
  ASSERT_EQ(RunTandem("extract --input " + Path("l.json") + " --metrics " + Path("l.m.json") +
                      " --out " + Path("l.ply")).code, 0);
  Output o = RunTandem("generate link --size 24 --series tiff --out " + Path("tiffs"));
  ASSERT_EQ(o.code, 0) << o.text;
  o = RunTandem("extract --input " + Path("tiffs") + " --iso 0 --metrics " + Path("t.json") +
                " --out " + Path("t.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_EQ(ReadJson(Path("t.json"))["triangles_final"], ReadJson(Path("l.m.json"))["triangles_final"]);
  // A JPEG 2000 DICOM series in a rotated frame: info names the axes and the value range.
  o = RunTandem("generate link --size 24 --series dicom --dicom-syntax jpeg2000 --origin 5,6,7 "
                "--directions 0,1,0,-1,0,0,0,0,1 --out " + Path("dcm"));
  ASSERT_EQ(o.code, 0) << o.text;
  Output info = RunTandem("info --input " + Path("dcm"));
  ASSERT_EQ(info.code, 0) << info.text;
  EXPECT_NE(info.text.find("24 x 24 x 24"), std::string::npos) << info.text;
  EXPECT_NE(info.text.find("axes     x (0 1 0)  y (-1 0 0)  z (0 0 1)"), std::string::npos)
      << info.text;
  EXPECT_NE(info.text.find("DICOM CT series"), std::string::npos) << info.text;
  EXPECT_NE(info.text.find("values   "), std::string::npos) << info.text;
  EXPECT_NE(info.text.find(" .. "), std::string::npos) << "histogram rows: " << info.text;
  o = RunTandem("extract --input " + Path("dcm") + " --iso 0 --out " + Path("d.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  // A format that cannot store the rotation refuses it rather than dropping it.
  o = RunTandem("generate link --size 24 --directions 0,1,0,-1,0,0,0,0,1 --out " + Path("r.tif"));
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find("directions"), std::string::npos) << o.text;
}

// Six times the signed volume a closed mesh encloses: positive when its triangles wind
// counter-clockwise seen from outside (normals pointing out).
double SignedVolume(const IndexedMesh& m) {
  double v = 0;
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    const Vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
               c = m.positions[m.indices[3 * t + 2]];
    v += Dot(a, Cross(b, c));
  }
  return v;
}

// The largest distance between the vertices of two meshes of one vertex order (-1 when the
// counts differ).
double MaxVertexDistance(const IndexedMesh& a, const IndexedMesh& b) {
  if (a.num_vertices() != b.num_vertices() || a.indices != b.indices) return -1;
  double d = 0;
  for (size_t v = 0; v < a.num_vertices(); ++v) d = std::max(d, Norm(a.positions[v] - b.positions[v]));
  return d;
}

// --frame: a patient's NIfTI (RAS) and DICOM series (LPS) of one volume, written by the
// project's writers with the same geometry in the patient, give one mesh when both are
// asked for the same frame, and the files say which (SPACE=, as 3D Slicer reads it). In
// voxel frame the vertices are the grid coordinates of the world mesh's. Normals point out
// in every frame.
TEST_F(Cli, FrameFlagPutsNiftiAndDicomMeshesInOneFrame) {
  VolumeInfo info;
  info.nx = 28;
  info.ny = 24;
  info.nz = 20;
  info.dtype = DType::kInt16;
  info.spacing = {0.75, 0.5, 2.0};
  info.origin = {-120.5, 80.25, 30.0};
  const double c = std::cos(0.5), s = std::sin(0.5);  // rotated in the slice plane
  info.directions = {{{c, s, 0}, {-s, c, 0}, {0, 0, 1}}};
  info.space = Space::kLPS;
  // An off-centre ellipsoid (values 0..1000, iso 500): a flip or a shift shows.
  const io::SliceFn slices = [&](int64_t k, std::vector<uint8_t>* bytes) {
    bytes->resize(info.slice_bytes());
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        const double x = (i - 11.0) / 7.0, y = (j - 13.0) / 6.0, z = (k - 9.0) / 5.0;
        const auto v = static_cast<int16_t>(std::clamp(1000.0 - 500.0 * (x * x + y * y + z * z), 0.0, 1000.0));
        std::memcpy(bytes->data() + 2 * (j * info.nx + i), &v, 2);
      }
    }
    return absl::OkStatus();
  };
  ASSERT_TRUE(io::WriteDicomSeries(Path("dcm"), info, slices).ok());
  ASSERT_TRUE(io::WriteVolume(Path("v.nii"), info, slices).ok());  // turned into RAS
  const std::string flags = " --iso 500 --error 0.1 --out ";
  auto extract = [&](const std::string& input, const std::string& frame, const std::string& out) {
    const Output o = RunTandem("extract --input " + Path(input) + flags + Path(out) +
                               (frame.empty() ? "" : " --frame " + frame) + " --metrics " +
                               Path(out + ".json"));
    EXPECT_EQ(o.code, 0) << o.text;
    absl::StatusOr<IndexedMesh> m = io::ReadMesh(Path(out));
    EXPECT_TRUE(m.ok()) << m.status();
    EXPECT_GT(m->num_triangles(), 100u);
    EXPECT_GT(SignedVolume(*m), 0) << out << ": normals point in";
    return *m;
  };
  // Their own frames: the NIfTI's vertices are the DICOM's with x and y negated.
  const IndexedMesh dcm = extract("dcm", "", "dcm.ply");
  const IndexedMesh nii = extract("v.nii", "", "nii.ply");
  ASSERT_EQ(dcm.num_vertices(), nii.num_vertices());
  double flipped = 0;
  for (size_t v = 0; v < dcm.num_vertices(); ++v) {
    const Vec3 a = dcm.positions[v], b = nii.positions[v];
    flipped = std::max(flipped, Norm(Vec3{a.x + b.x, a.y + b.y, a.z - b.z}));
  }
  EXPECT_LT(flipped, 1e-3);
  EXPECT_EQ(ReadJson(Path("dcm.ply.json"))["frame"], "LPS");
  EXPECT_EQ(ReadJson(Path("nii.ply.json"))["frame"], "RAS");
  EXPECT_EQ(ReadJson(Path("dcm.ply.json"))["frame_text"], "DICOM patient LPS (mm)");
  // One frame asked of both: one mesh (float rounding: the NIfTI header holds float32).
  for (const char* frame : {"lps", "ras"}) {
    SCOPED_TRACE(frame);
    const IndexedMesh a = extract("dcm", frame, std::string("dcm_") + frame + ".ply");
    const IndexedMesh b = extract("v.nii", frame, std::string("nii_") + frame + ".ply");
    const double d = MaxVertexDistance(a, b);
    EXPECT_GE(d, 0) << "the meshes differ in their triangles";
    EXPECT_LT(d, 1e-3);
  }
  EXPECT_LT(MaxVertexDistance(extract("v.nii", "lps", "n.ply"), dcm), 1e-3);
  // Where 3D Slicer reads the frame: a PLY comment, the OBJ's first comment, the STL header.
  extract("v.nii", "lps", "n.obj");
  extract("dcm", "ras", "d.stl");
  EXPECT_NE(testing::FileBytes(Path("n.ply")).find("\ncomment SPACE=LPS\n"), std::string::npos);
  const std::string obj = testing::FileBytes(Path("n.obj"));
  EXPECT_EQ(obj.find("# SPACE=LPS\n"), obj.find('\n') + 1) << obj.substr(0, 200);
  EXPECT_NE(testing::FileBytes(Path("d.stl")).substr(0, 80).find("SPACE=RAS"), std::string::npos);
  EXPECT_NE(testing::FileBytes(Path("dcm.ply")).find("comment SPACE=LPS"), std::string::npos);
  EXPECT_NE(testing::FileBytes(Path("nii.ply")).find("comment SPACE=RAS"), std::string::npos);
  // A GLB names it in asset.extras (glTF's own frame is another); a sealed .ply, written as
  // its chunks come, says it as the welded one does.
  ASSERT_EQ(RunTandem("extract --input " + Path("dcm") + flags + Path("d.glb") + " --frame ras").code, 0);
  EXPECT_NE(testing::FileBytes(Path("d.glb")).find(R"("extras":{"frame":"RAS"})"), std::string::npos);
  Output sealed = RunTandem("extract --input " + Path("v.nii") + flags + Path("sealed.ply") +
                            " --seal --frame lps");
  ASSERT_EQ(sealed.code, 0) << sealed.text;
  EXPECT_NE(testing::FileBytes(Path("sealed.ply")).find("\ncomment SPACE=LPS\n"), std::string::npos);
  // Voxel frame: the grid coordinates of the world mesh's vertices, no SPACE= (not a
  // patient frame); E0 in voxels (0.1 of a step, not 0.1 mm).
  extract("dcm", "voxel", "vox.ply");
  EXPECT_EQ(testing::FileBytes(Path("vox.ply")).find("SPACE="), std::string::npos);
  EXPECT_EQ(ReadJson(Path("vox.ply.json"))["frame"], "voxel");
  EXPECT_EQ(ReadJson(Path("vox.ply.json"))["error_threshold"], 0.1);
  Output o = RunTandem("extract --input " + Path("dcm") + " --iso 500 --no-simplify --out " +
                       Path("full_vox.ply") + " --frame voxel");
  ASSERT_EQ(o.code, 0) << o.text;
  o = RunTandem("extract --input " + Path("dcm") + " --iso 500 --no-simplify --out " +
                Path("full_lps.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  const IndexedMesh fv = *io::ReadMesh(Path("full_vox.ply")),
                    fl = *io::ReadMesh(Path("full_lps.ply"));
  ASSERT_EQ(fv.num_vertices(), fl.num_vertices());
  EXPECT_EQ(fv.indices, fl.indices);
  double off_grid = 0;
  for (size_t v = 0; v < fv.num_vertices(); ++v) {
    const Vec3 w = fl.positions[v] - Vec3{info.origin[0], info.origin[1], info.origin[2]};
    for (int a = 0; a < 3; ++a) {
      const Vec3 d{info.directions[a][0], info.directions[a][1], info.directions[a][2]};
      off_grid = std::max(off_grid, std::abs(Dot(w, d) / info.spacing[a] - fv.positions[v][a]));
    }
  }
  EXPECT_LT(off_grid, 1e-3);
  EXPECT_GT(SignedVolume(fv), 0);
  // A frame the input cannot give: a usage error naming the flag.
  ASSERT_EQ(RunTandem("generate sphere --size 12 --out " + Path("s.json")).code, 0);
  o = RunTandem("extract --input " + Path("s.json") + " --frame ras --out " + Path("s.ply"));
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("--frame ras: the input's vertices are in grid"), std::string::npos)
      << o.text;
}

// `tandem simulate --as dicom` plays what scanners, reconstructions and transfer tools do:
// renumbered slices, a localizer series written first, files renamed into place. The
// folder holds the same stack as a plain run (the same mesh; the localizer set aside with a
// note, no temporary file left); following it notes the numbers that contradict the
// positions; two stacks in one folder need --series, which extract and info take.
TEST_F(Cli, SimulatedDicomVariantsHoldThePlainSeries) {
  namespace fs = std::filesystem;
  ASSERT_EQ(RunTandem("generate link --size 20 --out " + Path("l.json")).code, 0);
  const std::string simulate = "simulate --input " + Path("l.json") + " --as dicom --rate 0 ";
  Output o = RunTandem(simulate + "--out " + Path("plain"));
  ASSERT_EQ(o.code, 0) << o.text;
  o = RunTandem(simulate + "--numbering random --scout --temp-names suffix --out " + Path("real"));
  ASSERT_EQ(o.code, 0) << o.text;
  int files = 0;
  for (const auto& e : fs::directory_iterator(Path("real"))) {
    EXPECT_FALSE(e.path().string().ends_with(".part")) << e.path();
    ++files;
  }
  EXPECT_EQ(files, 20 + 2);
  const std::string extract = " --iso 0 --error 0.2 --out ";
  ASSERT_EQ(RunTandem("extract --input " + Path("plain") + extract + Path("plain.ply")).code, 0);
  o = RunTandem("extract --input " + Path("real") + extract + Path("real.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("tandem extract: ignoring DICOM series 1.2.826.0.1.3680043.2.1125.7.1 "
                        "'Scout' (2 images"),
            std::string::npos)
      << o.text;
  EXPECT_NE(o.text.find("a localizer (ImageType LOCALIZER)"), std::string::npos) << o.text;
  EXPECT_EQ(testing::FileBytes(Path("real.ply")), testing::FileBytes(Path("plain.ply")));
  o = RunTandem("extract --follow --settle 1 --input " + Path("real") + extract +
                Path("followed.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("InstanceNumbers do not follow the slice positions"), std::string::npos)
      << o.text;
  EXPECT_EQ(testing::FileBytes(Path("followed.ply")), testing::FileBytes(Path("plain.ply")));

  // Two stacks: refused, listing both; --series picks one.
  for (const auto& e : fs::directory_iterator(Path("plain"))) {
    fs::copy_file(e.path(), Path("real/plain_" + e.path().filename().string()));
  }
  o = RunTandem("info --no-values --input " + Path("real"));
  EXPECT_EQ(o.code, 1) << o.text;
  EXPECT_NE(o.text.find("holds 2 DICOM slice stacks"), std::string::npos) << o.text;
  const size_t at = o.text.find("1.2.826.0.1.3680043.2.1143.");  // a generated series UID
  ASSERT_NE(at, std::string::npos) << o.text;
  const std::string uid = o.text.substr(at, o.text.find(' ', at) - at);
  o = RunTandem("info --no-values --input " + Path("real") + " --series " + uid);
  EXPECT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("not the series --series picks"), std::string::npos) << o.text;
  o = RunTandem("extract --input " + Path("real") + " --series " + uid + extract + Path("picked.ply"));
  EXPECT_EQ(o.code, 0) << o.text;
  EXPECT_EQ(testing::FileBytes(Path("picked.ply")), testing::FileBytes(Path("plain.ply")));

  o = RunTandem(simulate + "--numbering sideways --out " + Path("x"));
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("--numbering 'sideways': expected ordered, random"), std::string::npos)
      << o.text;
  o = RunTandem("simulate --input " + Path("l.json") + " --as tiff --scout --out " + Path("y"));
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("go with --as dicom"), std::string::npos) << o.text;
}

// `tandem simulate --descending` plays a head-to-feet CT (the last slice of the volume first);
// `tandem extract --follow` meshes it as it comes, head to feet: the full-resolution surface
// of the finished folder (as many triangles and vertices), its grid's z axis turned round.
TEST_F(Cli, SimulatedDescendingAcquisitionIsFollowedHeadToFeet) {
  ASSERT_EQ(RunTandem("generate link --size 24 --out " + Path("l.json")).code, 0);
  const std::string dir = Path("desc");
  const Output o = RunCommand(
      testing::BinPath("tandem") + " simulate --input " + Path("l.json") + " --out " + dir +
      " --as dicom --rate 40 --descending --done-file DONE & " + testing::BinPath("tandem") +
      " extract --follow --done-file DONE --input " + dir + " --iso 0 --no-simplify --out " +
      Path("followed.ply") + " --metrics " + Path("followed.json") + " --frame voxel; wait");
  ASSERT_EQ(o.code, 0) << o.text;
  ASSERT_TRUE(std::filesystem::exists(Path("followed.ply"))) << o.text;
  const Output f = RunTandem("extract --input " + dir + " --iso 0 --no-simplify --out " +
                             Path("finished.ply") + " --metrics " + Path("finished.json") +
                             " --frame voxel");
  ASSERT_EQ(f.code, 0) << f.text;
  const nlohmann::json a = ReadJson(Path("followed.json")), b = ReadJson(Path("finished.json"));
  EXPECT_EQ(a["triangles_final"], b["triangles_final"]);
  EXPECT_EQ(a["vertices_final"], b["vertices_final"]);
  EXPECT_GT(a["triangles_final"].get<int64_t>(), 500);
  // In voxel frame the followed grid runs the other way: slice k is the finished one's 23 - k.
  const IndexedMesh fm = *io::ReadMesh(Path("followed.ply")),
                    gm = *io::ReadMesh(Path("finished.ply"));
  double lo = 1e9, hi = -1e9, glo = 1e9, ghi = -1e9;
  for (const Vec3& p : fm.positions) lo = std::min(lo, p.z), hi = std::max(hi, p.z);
  for (const Vec3& p : gm.positions) glo = std::min(glo, p.z), ghi = std::max(ghi, p.z);
  EXPECT_NEAR(lo, 23 - ghi, 1e-3);
  EXPECT_NEAR(hi, 23 - glo, 1e-3);
  EXPECT_GT(SignedVolume(fm) * SignedVolume(gm), 0) << "normals point the same way";
  const Output bad = RunTandem("simulate --input " + Path("l.json") + " --out " + Path("t") +
                               " --as tiff --descending");
  EXPECT_EQ(bad.code, 2) << bad.text;
  EXPECT_NE(bad.text.find("--descending go with --as dicom"), std::string::npos) << bad.text;
}

// GDCM lives in a module loaded only when a DICOM file is read or written
// (core/io/dicom_codec.h): its dictionaries cost about 12 ms at every start otherwise.
// GDCM is loaded only where DICOM is read or written: a DICOM series is read by the
// tandem-dicom-worker process (core/io/dicom_worker_client.h), never by the CLI itself, and
// the DICOM module is loaded by the CLI only to write one.
TEST_F(Cli, LoadsGdcmOnlyForDicomAndReadsItInTheWorker) {
  Output o = RunTandem("generate link --size 24 --out " + Path("v.json"));
  ASSERT_EQ(o.code, 0) << o.text;
  const std::string tandem = testing::BinPath("tandem");
  auto run = RunLoading;
  o = run(tandem, "generate link --size 24 --series dicom --out " + Path("dcm"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("libtandem_dicom.so"), std::string::npos) << o.text.substr(0, 2000);
  o = run(tandem, "extract --input " + Path("v.json") + " --iso 0 --out " + Path("v.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_EQ(o.text.find("libgdcm"), std::string::npos) << "GDCM loaded for a raw volume";
  EXPECT_EQ(o.text.find("tandem-dicom-worker"), std::string::npos);
  o = run(tandem, "extract --input " + Path("dcm") + " --iso 0 --out " + Path("d.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_EQ(o.text.find("libtandem_dicom.so"), std::string::npos) << o.text.substr(0, 2000);
  EXPECT_NE(
      o.text.find("libgdcmMSFF.so.3.0 [0];  needed by " + testing::BinPath("tandem-dicom-worker")),
      std::string::npos)
      << o.text.substr(0, 2000);

  // Installed: bin/tandem finds the worker in ../lib/tandem/. Without it, reading DICOM is a
  // clear error and every other format still works.
  const std::string lonely = InstallAlone("prefix");
  o = run(lonely, "extract --input " + Path("dcm") + " --iso 0 --out " + Path("m.ply"));
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find("DICOM support is not available"), std::string::npos) << o.text;
  EXPECT_NE(o.text.find(Path("prefix/lib/tandem/tandem-dicom-worker")), std::string::npos)
      << o.text;
  o = run(lonely, "extract --input " + Path("v.json") + " --iso 0 --out " + Path("m.ply"));
  EXPECT_EQ(o.code, 0) << o.text;
  std::filesystem::copy_file(testing::BinPath("tandem-dicom-worker"),
                             Path("prefix/lib/tandem/tandem-dicom-worker"));
  o = run(lonely, "extract --input " + Path("dcm") + " --iso 0 --out " + Path("m.ply"));
  EXPECT_EQ(o.code, 0) << o.text.substr(0, 2000);
  // Writing DICOM loads the module, also from ../lib/tandem/.
  o = run(lonely, "generate link --size 24 --series dicom --out " + Path("dcm2"));
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find(Path("prefix/lib/tandem/libtandem_dicom.so")), std::string::npos)
      << o.text.substr(0, 2000);
  std::filesystem::copy_file(testing::BinPath("libtandem_dicom.so"),
                             Path("prefix/lib/tandem/libtandem_dicom.so"));
  o = run(lonely, "generate link --size 24 --series dicom --out " + Path("dcm2"));
  EXPECT_EQ(o.code, 0) << o.text.substr(0, 2000);
}

// The corners of a mesh's bounding box.
std::pair<Vec3, Vec3> Bounds(const std::string& path) {
  auto mesh = io::ReadMesh(path);
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  Vec3 lo{1e30, 1e30, 1e30}, hi{-1e30, -1e30, -1e30};
  for (const Vec3& p : mesh.ok() ? mesh->positions : std::vector<Vec3>{}) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], p[a]);
      hi[a] = std::max(hi[a], p[a]);
    }
  }
  return {lo, hi};
}

// A TIFF stack without resolution tags gives no spacing: --spacing supplies it and the
// mesh's extent follows it exactly; a file's own spacing is replaced with a warning.
TEST_F(Cli, SpacingFlagGivesATiffStackWithoutResolutionItsExtent) {
  testing::WriteBareTiffStack(Path("bare.tif"), 24, 20, 16);
  const std::string common = " --iso 100 --no-simplify --quiet --input ";
  Output o = RunTandem("extract --out " + Path("grid.ply") + common + Path("bare.tif"));
  ASSERT_EQ(o.code, 0) << o.text;
  o = RunTandem("extract --spacing 0.5,0.25,2 --out " + Path("mm.ply") + common + Path("bare.tif"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_EQ(o.text.find("warning"), std::string::npos) << o.text;
  const auto [glo, ghi] = Bounds(Path("grid.ply"));
  const auto [mlo, mhi] = Bounds(Path("mm.ply"));
  const double s[3] = {0.5, 0.25, 2};
  for (int a = 0; a < 3; ++a) {
    EXPECT_GT(ghi[a] - glo[a], 5) << a;
    EXPECT_NEAR(mlo[a], glo[a] * s[a], 1e-4) << a;
    EXPECT_NEAR(mhi[a], ghi[a] * s[a], 1e-4) << a;
  }
  // ImageJ's description gives spacing 1: the flag replaces it, saying so.
  o = RunTandem("generate sphere --size 20 --out " + Path("ij.tif"));
  ASSERT_EQ(o.code, 0) << o.text;
  o = RunTandem("extract --spacing 2,2,2 --iso 0 --out " + Path("ij.ply") + " --input " +
                Path("ij.tif"));
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("warning: --spacing 2,2,2 replaces the spacing 1,1,1 that " +
                        Path("ij.tif") + " carries"),
            std::string::npos)
      << o.text;
  o = RunTandem("extract --spacing 1,0,1 --iso 100 --out " + Path("x.ply") + " --input " +
                Path("bare.tif"));
  EXPECT_EQ(o.code, 2) << o.text;
  EXPECT_NE(o.text.find("--spacing 1,0,1: expected three positive numbers"), std::string::npos)
      << o.text;
}

// The viewer's HTTP server is a module too (tandem/viewer/view_server.h): Debian's cpp-httplib
// links OpenSSL and Brotli, whose loading cost every start of the CLI ~5 ms and 3.8 MB resident
// (12.6 -> 7.7 ms for `tandem --version`, 19.7 -> 15.9 MB for the 128³ Link's extraction).
TEST_F(Cli, LoadsTheViewerModuleOnlyForTheViewer) {
  Output o = RunTandem("generate link --size 24 --out " + Path("v.json"));
  ASSERT_EQ(o.code, 0) << o.text;
  const std::string tandem = testing::BinPath("tandem");
  auto run = RunLoading;
  o = run(tandem, "extract --input " + Path("v.json") + " --iso 0 --out " + Path("v.ply"));
  ASSERT_EQ(o.code, 0) << o.text;
  for (const char* lib : {"libtandem_view", "libcpp-httplib", "libssl", "libcrypto"}) {
    EXPECT_EQ(o.text.find(lib), std::string::npos) << lib << " loaded for an extraction";
  }
  // The page is served when three.js is installed (deploy/install-web.sh); the module loads
  // either way, before the page's files are looked for.
  auto served = [](const Output& out) {
    EXPECT_TRUE(out.code == 0 || out.text.find("three.js is not installed") != std::string::npos)
        << out.text.substr(0, 3000);
    EXPECT_EQ(out.text.find("the browser viewer is not available"), std::string::npos);
  };
  const std::string view = "view " + Path("v.ply") + " --view 127.0.0.1:0 --linger 0";
  o = run(tandem, view);
  served(o);
  EXPECT_NE(o.text.find("libtandem_view.so"), std::string::npos) << o.text.substr(0, 2000);
  EXPECT_NE(o.text.find("libcpp-httplib"), std::string::npos);

  // Installed: bin/tandem finds it in ../lib/tandem/. Without it, the viewer is a clear
  // error naming where it was looked for, and extraction still works.
  const std::string lonely = InstallAlone("prefix");
  o = run(lonely, view);
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find("the browser viewer is not available"), std::string::npos) << o.text;
  EXPECT_NE(o.text.find(Path("prefix/lib/tandem/libtandem_view.so")), std::string::npos)
      << o.text;
  o = run(lonely, "extract --input " + Path("v.json") + " --iso 0 --out " + Path("m.ply"));
  EXPECT_EQ(o.code, 0) << o.text;
  std::filesystem::copy_file(testing::BinPath("libtandem_view.so"),
                             Path("prefix/lib/tandem/libtandem_view.so"));
  served(run(lonely, view));
}

// tandem view takes its token from a file or $TANDEM_VIEW_TOKEN, off the command line that
// every user of the machine can read; --view-token still works there, with a warning.
TEST_F(Cli, TheViewersTokenComesFromAFileOrTheEnvironment) {
  ASSERT_EQ(RunTandem("generate sphere --size 16 --out " + Path("s.json")).code, 0);
  ASSERT_EQ(RunTandem("extract --input " + Path("s.json") + " --iso 0 --out " + Path("s.ply")).code,
            0);
  {
    std::ofstream(Path("token.txt")) << "# for the viewer\ntok-from-file\n";
  }
  const std::string view = "view " + Path("s.ply") + " --view 127.0.0.1:0 --linger 0";
  Output o = RunTandem(view + " --view-token-file " + Path("token.txt"));
  if (o.text.find("three.js is not installed") != std::string::npos) {
    GTEST_SKIP() << "three.js is not installed (deploy/install-web.sh)";
  }
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("/?token=tok-from-file"), std::string::npos) << o.text;
  EXPECT_EQ(o.text.find("warning"), std::string::npos) << o.text;
  o = RunCommand("TANDEM_VIEW_TOKEN=tok-from-env " + testing::BinPath("tandem") + " " + view);
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("/?token=tok-from-env"), std::string::npos) << o.text;
  EXPECT_EQ(o.text.find("warning"), std::string::npos) << o.text;
  o = RunTandem(view + " --view-token on-argv");
  ASSERT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("/?token=on-argv"), std::string::npos) << o.text;
  EXPECT_NE(o.text.find("tandem: warning: --view-token on the command line can be read by every "
                        "user of this machine (ps); use --view-token-file FILE or "
                        "$TANDEM_VIEW_TOKEN instead"),
            std::string::npos)
      << o.text;
  o = RunTandem(view + " --view-token-file " + Path("missing.txt"));
  EXPECT_NE(o.code, 0);
  EXPECT_NE(o.text.find("--view-token-file " + Path("missing.txt") + ": cannot open"),
            std::string::npos)
      << o.text;
}

TEST_F(Cli, AnIsoOutsideTheDataIsAWarningAndExitThreeWithStrict) {
  ASSERT_EQ(RunTandem("generate sphere --size 20 --out " + Path("s.json")).code, 0);
  Output o = RunTandem("extract --input " + Path("s.json") + " --iso 1000 --quiet --out " +
                       Path("e.ply"));
  EXPECT_EQ(o.code, 0) << o.text;
  EXPECT_NE(o.text.find("iso 1000 is outside the data's value range ["), std::string::npos)
      << o.text;
  o = RunTandem("extract --input " + Path("s.json") + " --iso 1000 --quiet --strict --out " +
                Path("e2.ply"));
  EXPECT_EQ(o.code, 3) << o.text;
  EXPECT_TRUE(std::filesystem::exists(Path("e2.ply"))) << "the (empty) mesh is still written";
  o = RunTandem("extract --input " + Path("s.json") + " --iso 0 --quiet --strict --out " +
                Path("e3.ply"));
  EXPECT_EQ(o.code, 0) << o.text;
  EXPECT_EQ(o.text.find("warning"), std::string::npos) << o.text;
}

// The isotropy term grows as E0 x a length (the paper's normalisation), so a fine E0 with
// --alpha keeps nearly every triangle: that is said, not left for the user to find.
TEST_F(Cli, AnAlphaThatKeepsMostTrianglesAtThisErrorIsAWarning) {
  ASSERT_EQ(RunTandem("generate sphere --size 40 --out " + Path("s.json")).code, 0);
  const auto run = [&](const std::string& flags, const std::string& name) {
    Output o = RunTandem("extract --input " + Path("s.json") + " --quiet " + flags + " --out " +
                         Path(name + ".ply") + " --metrics " + Path(name + ".json"));
    EXPECT_EQ(o.code, 0) << o.text;
    const nlohmann::json m = ReadJson(Path(name + ".json"));
    return std::make_pair(o.text, m["triangles_final"].get<double>() /
                                      m["triangles_extracted"].get<double>());
  };
  // alpha 1 x spacing 1 / 5 = 0.2: E0 0.05 is below it.
  const auto [warned, kept_warned] = run("--alpha 1 --error 0.05", "a");
  EXPECT_NE(warned.find("warning: --alpha 1 at --error 0.05 keeps most triangles"),
            std::string::npos)
      << warned;
  EXPECT_GT(kept_warned, 0.5) << "the warning says what happens";
  const auto [plain, kept_plain] = run("--alpha 0 --error 0.05", "b");
  EXPECT_EQ(plain.find("warning"), std::string::npos) << plain;
  EXPECT_LT(kept_plain, 0.2);
  const auto [above, kept_above] = run("--alpha 0.2 --error 0.2", "c");
  EXPECT_EQ(above.find("warning"), std::string::npos) << above;
  EXPECT_LT(kept_above, 0.2);
  // Spacing 0.5 halves the limit: E0 0.05 at alpha 0.4 is not below 0.4 x 0.5 / 5 = 0.04.
  ASSERT_EQ(RunTandem("generate sphere --size 40 --spacing 0.5,0.5,0.5 --out " + Path("h.json"))
                .code,
            0);
  Output o = RunTandem("extract --input " + Path("h.json") +
                       " --quiet --alpha 0.4 --error 0.05 --out " + Path("h.ply"));
  EXPECT_EQ(o.code, 0) << o.text;
  EXPECT_EQ(o.text.find("warning"), std::string::npos) << o.text;
}

}  // namespace
}  // namespace tandem
