// Label volumes' files: the label-name tables (CSV, 3D Slicer), the per-label meshes and the
// GLB with a node per label, and the per-label figures.
#include "tandem/io/labels_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "tandem/eval/label_metrics.h"
#include "tandem/eval/topology.h"
#include "tandem/io/mesh_io.h"
#include "testutil/testutil.h"

namespace tandem {
namespace {

namespace fs = std::filesystem;
using eval::AnalyzeTopology;
using eval::LabelMetrics;
using eval::LabelMetricsSummary;
using eval::LabelMetricsToJson;
using eval::MeasureLabel;
using eval::TopologyReport;

// The unit cube at (x0, 0, 0), 12 triangles counter-clockwise seen from outside, each face
// split along the same diagonal as the neighbour's (the shared face x = 1 is the same two
// triangles, reversed, in both cubes).
IndexedMesh Cube(double x0) {
  IndexedMesh m;
  for (int k = 0; k < 8; ++k) {
    m.positions.push_back(
        Vec3{x0 + (k & 1), static_cast<double>((k >> 1) & 1), static_cast<double>((k >> 2) & 1)});
  }
  // Vertex k = x + 2y + 4z; each face as a quad (a, b, c, d) counter-clockwise from outside.
  const uint32_t quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4},
                                {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
  for (const auto& q : quads) {
    m.indices.insert(m.indices.end(), {q[0], q[1], q[2], q[0], q[2], q[3]});
  }
  return m;
}

// Two unit cubes sharing the face x = 1, as SplitByLabel cuts a two-label complex.
std::vector<std::pair<LabelId, IndexedMesh>> TwoCubes(LabelId a = 1, LabelId b = 2) {
  return {{a, Cube(0)}, {b, Cube(1)}};
}

std::string Slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteFile(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

// The JSON chunk of a GLB, checked against the header's lengths.
nlohmann::json GlbJson(const std::string& path, uint32_t* bin_length = nullptr) {
  const std::string b = Slurp(path);
  auto le32 = [&](size_t at) {
    uint32_t v;
    std::memcpy(&v, b.data() + at, 4);
    return v;
  };
  EXPECT_GE(b.size(), 20u);
  EXPECT_EQ(le32(0), 0x46546C67u);
  EXPECT_EQ(le32(8), b.size());
  const uint32_t json_len = le32(12);
  EXPECT_EQ(le32(16), 0x4E4F534Au);
  if (bin_length != nullptr) {
    *bin_length = b.size() > 20 + json_len ? le32(20 + json_len) : 0;
  }
  return nlohmann::json::parse(b.substr(20, json_len));
}

// Positions of a mesh's vertices on the plane x = 1, as float32 read back.
std::set<std::array<float, 3>> OnPlaneX1(const IndexedMesh& m) {
  std::set<std::array<float, 3>> out;
  for (const Vec3& p : m.positions) {
    if (p.x == 1.0) {
      out.insert({static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)});
    }
  }
  return out;
}

TEST(LabelMeshes, OneClosedFilePerLabelAndTheSharedFaceIdentical) {
  const std::string dir = testing::MakeTempDir() + "/out/";
  for (const char* ext : {".ply", ".obj", ".stl"}) {
    SCOPED_TRACE(ext);
    auto files = io::WriteLabelMeshes(dir, ext, TwoCubes(), nullptr);
    ASSERT_TRUE(files.ok()) << files.status();
    ASSERT_EQ(files->size(), 2u);
    EXPECT_EQ((*files)[0].path, dir + "1" + ext);
    EXPECT_EQ((*files)[1].path, dir + "2" + ext);
    std::vector<IndexedMesh> read;
    for (const io::LabelFile& f : *files) {
      auto m = io::ReadMesh(f.path);
      ASSERT_TRUE(m.ok()) << m.status();
      EXPECT_EQ(m->num_triangles(), 12u);
      const eval::TopologyReport t = eval::AnalyzeTopology(*m);
      EXPECT_TRUE(t.IsClosedManifold()) << f.path;
      EXPECT_EQ(t.euler, 2);
      EXPECT_EQ(MeasureLabel(f.id, *m).volume, 1.0);  // outward: counter-clockwise kept
      read.push_back(*std::move(m));
    }
    EXPECT_EQ(OnPlaneX1(read[0]).size(), 4u);
    EXPECT_EQ(OnPlaneX1(read[0]), OnPlaneX1(read[1]));
    EXPECT_TRUE(fs::exists(dir + "labels.glb"));
  }
}

TEST(LabelMeshes, TheGlbHasANodeMeshAndMaterialPerLabelNamedAndColoured) {
  const std::string dir = testing::MakeTempDir();
  io::LabelNames names;
  names[1] = {"Liver", true, {255, 0, 0, 255}};
  names[2] = {"left kidney", false, {}};
  auto files = io::WriteLabelMeshes(dir + "/seg", ".ply", TwoCubes(), &names);
  ASSERT_TRUE(files.ok()) << files.status();
  EXPECT_EQ((*files)[0].path, dir + "/seg/Liver.ply");
  EXPECT_EQ((*files)[1].path, dir + "/seg/left_kidney.ply");
  EXPECT_EQ((*files)[1].name, "left kidney");
  uint32_t bin = 0;
  const nlohmann::json j = GlbJson(dir + "/seg/labels.glb", &bin);
  ASSERT_EQ(j["nodes"].size(), 2u);
  ASSERT_EQ(j["meshes"].size(), 2u);
  ASSERT_EQ(j["materials"].size(), 2u);
  EXPECT_EQ(j["scenes"][0]["nodes"], nlohmann::json::array({0, 1}));
  EXPECT_EQ(j["nodes"][0]["name"], "Liver");
  EXPECT_EQ(j["nodes"][1]["name"], "left kidney");
  EXPECT_EQ(j["nodes"][0]["extras"]["label"], "1");
  EXPECT_EQ(j["nodes"][1]["mesh"], 1);
  // The table's sRGB red is linear red; the unnamed colour is one of its own.
  EXPECT_EQ(j["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"],
            nlohmann::json::array({1.0, 0.0, 0.0, 1.0}));
  EXPECT_NE(j["materials"][1]["pbrMetallicRoughness"]["baseColorFactor"],
            j["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"]);
  for (int m = 0; m < 2; ++m) {
    const auto& prim = j["meshes"][m]["primitives"][0];
    EXPECT_EQ(prim["material"], m);
    EXPECT_EQ(j["accessors"][prim["attributes"]["POSITION"].get<int>()]["count"], 8);
    EXPECT_EQ(j["accessors"][prim["indices"].get<int>()]["count"], 36);
  }
  // 2 x (8 positions + 8 normals) x 12 bytes + 2 x 36 indices x 4 bytes.
  EXPECT_EQ(bin, 2u * (8 * 12 * 2 + 36 * 4));
  EXPECT_EQ(j["buffers"][0]["byteLength"], bin);
}

// The Khronos glTF validator (npm gltf-validator, deploy/install-web.sh) finds no error and
// no warning in labels.glb, and counts every label's vertices and triangles.
TEST(LabelMeshes, TheKhronosValidatorAcceptsTheGlb) {
  const std::string source = TANDEM_SOURCE_DIR;
  if (!fs::is_directory(source + "/node_modules/gltf-validator") ||
      testing::RunCommand("node --version").code != 0) {
    GTEST_SKIP() << "needs node and gltf-validator (bash deploy/install-web.sh)";
  }
  const std::string dir = testing::MakeTempDir();
  io::LabelNames names;
  names[2] = {"Spleen", true, {157, 108, 162, 128}};  // a translucent colour: blended
  ASSERT_TRUE(io::WriteLabelMeshes(dir, ".ply", TwoCubes(), &names).ok());
  const auto r = testing::RunCommand("node " + source + "/tests/formats/validate_gltf.mjs " +
                                     dir + "/labels.glb 16 24");
  EXPECT_EQ(r.code, 0) << r.text;
}

TEST(LabelMeshes, DistinctColoursWithoutATable) {
  std::set<std::array<uint8_t, 4>> seen;
  for (size_t order = 0; order < 12; ++order)
    seen.insert(io::LabelColor(order + 1, order, nullptr));
  EXPECT_EQ(seen.size(), 12u);
}

TEST(LabelMeshes, FileNamesAreSanitisedAndCollisionsResolved) {
  const std::string dir = testing::MakeTempDir();
  io::LabelNames names;
  names[3] = {"a/b", false, {}};
  names[4] = {"a b", false, {}};     // the same stem as 3's
  names[5] = {"labels", false, {}};  // labels.glb's
  names[6] = {"../..", false, {}};   // no letter or digit: the id
  names[7] = {"A_B", false, {}};     // 3's, in another case
  std::vector<std::pair<LabelId, IndexedMesh>> s;
  for (LabelId id = 3; id <= 8; ++id) s.emplace_back(id, Cube(static_cast<double>(id)));
  auto files = io::WriteLabelMeshes(dir, ".glb", s, &names);
  ASSERT_TRUE(files.ok()) << files.status();
  std::vector<std::string> got;
  for (const io::LabelFile& f : *files) got.push_back(fs::path(f.path).filename().string());
  EXPECT_EQ(got, (std::vector<std::string>{"a_b.glb", "a_b_4.glb", "labels_5.glb", "6.glb",
                                           "A_B_7.glb", "8.glb"}));
  for (const io::LabelFile& f : *files) EXPECT_EQ(fs::path(f.path).parent_path(), fs::path(dir));
  EXPECT_EQ(GlbJson(dir + "/labels.glb")["nodes"].size(), 6u);
}

TEST(LabelMeshes, OneGlbAloneAndAnEmptySet) {
  const std::string dir = testing::MakeTempDir();
  ASSERT_TRUE(
      io::WriteLabelsGlb(dir + "/all.glb", TwoCubes(7, (LabelId{1} << 60) + 1), nullptr).ok());
  const nlohmann::json j = GlbJson(dir + "/all.glb");
  EXPECT_EQ(j["nodes"][1]["name"], "1152921504606846977");  // 2^60 + 1, exactly
  ASSERT_TRUE(io::WriteLabelsGlb(dir + "/none.glb", {}, nullptr).ok());
  const nlohmann::json e = GlbJson(dir + "/none.glb");
  EXPECT_TRUE(e["nodes"].empty());
  EXPECT_FALSE(e.contains("buffers"));
}

// ---- Label-name tables ----

class LabelNamesTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir(); }
  std::string Write(const std::string& name, const std::string& text) {
    WriteFile(dir_ + "/" + name, text);
    return dir_ + "/" + name;
  }
  std::string dir_;
};

TEST_F(LabelNamesTest, CsvWithHeaderQuotesAndWithout) {
  auto n = io::ReadLabelNames(Write("a.csv",
                                "id,name\n1,Liver\n2,\"kidney, left\"\n\n"
                                "18446744073709551615,last\r\n"));
  ASSERT_TRUE(n.ok()) << n.status();
  ASSERT_EQ(n->size(), 3u);
  EXPECT_EQ(n->at(1).name, "Liver");
  EXPECT_EQ(n->at(2).name, "kidney, left");
  EXPECT_EQ(n->at(18446744073709551615u).name, "last");
  EXPECT_FALSE(n->at(1).has_color);
  auto plain = io::ReadLabelNames(Write("b.names", "3,bone\n4,skin,10,20,30\n"));
  ASSERT_TRUE(plain.ok()) << plain.status();
  EXPECT_EQ(plain->at(3).name, "bone");
  EXPECT_TRUE(plain->at(4).has_color);
  EXPECT_EQ(plain->at(4).rgba, (std::array<uint8_t, 4>{10, 20, 30, 255}));
}

TEST_F(LabelNamesTest, SlicerCsvColourTable) {
  // 3D Slicer 5's CSV colour tables.
  auto n =
      io::ReadLabelNames(Write("GenericAnatomyColors.csv",
                           "LabelValue,Name,Color_R,Color_G,Color_B,Color_A\n0,background,0,0,0,0\n"
                           "1,tissue,128,174,128,255\n"));
  ASSERT_TRUE(n.ok()) << n.status();
  EXPECT_EQ(n->at(1).name, "tissue");
  EXPECT_EQ(n->at(1).rgba, (std::array<uint8_t, 4>{128, 174, 128, 255}));
}

TEST_F(LabelNamesTest, SlicerColorTable) {
  for (const char* name : {"t.ctbl", "t.txt", "t"}) {
    SCOPED_TRACE(name);
    auto n = io::ReadLabelNames(Write(name,
                                  "# Color table file /tmp/t.ctbl\n# 3 values\n"
                                  "0 Background 0 0 0 0\n1 Liver\t221 130 101 255\n"
                                  "  2 Right_kidney 185 102 83 255\n"));
    ASSERT_TRUE(n.ok()) << n.status();
    ASSERT_EQ(n->size(), 3u);
    EXPECT_EQ(n->at(1).name, "Liver");
    EXPECT_EQ(n->at(2).name, "Right_kidney");
    EXPECT_EQ(n->at(1).rgba, (std::array<uint8_t, 4>{221, 130, 101, 255}));
    EXPECT_EQ(n->at(0).rgba[3], 0);
  }
}

TEST_F(LabelNamesTest, BadLinesNameTheFileAndLine) {
  const struct {
    const char* file;
    const char* text;
    const char* message;
  } cases[] = {
      {"a.csv", "id,name\n1,Liver\nx,Spleen\n", "a.csv:3: 'x' is not a label id"},
      {"b.csv", "1,Liver\n-2,Spleen\n", "b.csv:2: '-2' is not a label id"},
      {"c.csv", "1,Liver\n2\n", "c.csv:2: expected \"id,name\""},
      {"d.csv", "1,Liver\n1,Spleen\n", "d.csv:2: label 1 is named already (line 1)"},
      {"e.ctbl", "# t\n1 Liver 300 0 0 255\n", "e.ctbl:2: colour component '300'"},
      {"f.ctbl", "1 Liver 20 30\n", "f.ctbl:1: expected \"id name r g b a\""},
      {"g.txt", "1 Liver 1 2 3 255\n18446744073709551616 x 1 2 3 4\n",
       "g.txt:2: '18446744073709551616' is not a label id"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.file);
    auto n = io::ReadLabelNames(Write(c.file, c.text));
    ASSERT_FALSE(n.ok());
    EXPECT_EQ(n.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(n.status().message().find(dir_ + "/" + c.message), absl::string_view::npos)
        << n.status();
  }
  auto missing = io::ReadLabelNames(dir_ + "/none.csv");
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
}

// ---- Per-label figures ----

TEST(LabelMetricsTest, CubeFigures) {
  const LabelMetrics m = MeasureLabel(5, Cube(10));
  EXPECT_EQ(m.triangles, 12);
  EXPECT_EQ(m.vertices, 8);
  EXPECT_DOUBLE_EQ(m.area, 6.0);
  EXPECT_DOUBLE_EQ(m.volume, 1.0);
  EXPECT_EQ(m.euler, 2);
  EXPECT_EQ(m.components, 1);
  EXPECT_TRUE(m.closed);
  IndexedMesh open = Cube(0);
  open.indices.resize(30);  // one face removed
  const LabelMetrics o = MeasureLabel(6, open);
  EXPECT_FALSE(o.closed);
  EXPECT_TRUE(o.manifold);
  EXPECT_EQ(o.euler, 1);
  std::vector<LabelMetrics> all = {m, o, MeasureLabel((LabelId{1} << 60) + 1, Cube(3))};
  all[0].name = "Liver";
  const nlohmann::json j = nlohmann::json::parse(LabelMetricsToJson(all));
  ASSERT_EQ(j.size(), 3u);
  EXPECT_EQ(j[0]["label"], 5);
  EXPECT_EQ(j[0]["name"], "Liver");
  EXPECT_EQ(j[0]["volume"], 1.0);
  EXPECT_TRUE(j[1]["volume"].is_null());
  EXPECT_EQ(j[1]["closed"], false);
  EXPECT_EQ(j[2]["label"], "1152921504606846977");  // past 2^53: a string, exact
  const std::string table = LabelMetricsSummary(all);
  EXPECT_NE(table.find("5 Liver"), std::string::npos) << table;
  EXPECT_NE(table.find("open"), std::string::npos) << table;
}

}  // namespace
}  // namespace tandem
