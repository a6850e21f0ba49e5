// `tandem extract --labels` run as a user would: the refusals of what cannot work (a float
// volume, bad label ids, flags without --labels, outputs that cannot hold one mesh per
// label, a bad names table), each naming the culprit.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

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
      {"--labels --seal", "--seal does not go with --labels"},
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
  for (const char* file : {"Liver.ply", "7.ply"}) {
    SCOPED_TRACE(file);
    auto mesh = io::ReadMesh(out + file);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    const eval::TopologyReport t = eval::AnalyzeTopology(*mesh);
    EXPECT_TRUE(t.IsClosedManifold());
    EXPECT_EQ(t.euler, 2);
    EXPECT_EQ(t.components, 1u);
  }
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

TEST_F(CliLabels, TheClientRefusesLabels) {
  const std::string client = testing::BinPath("tandem-client");
  if (!std::filesystem::exists(client)) GTEST_SKIP() << "built without the service";
  const auto r = testing::RunCommand(client + " stream --input " +
                                     LabelVolume("u.mha", DType::kUInt32) + " --labels --out " +
                                     Path("out/"));
  EXPECT_EQ(r.code, 2) << r.text;
  EXPECT_NE(r.text.find("--labels: tandem-server does not mesh label volumes"), std::string::npos)
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

}  // namespace
}  // namespace tandem
