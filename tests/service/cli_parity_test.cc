// The three programs' command lines side by side (issue: one consistent command line):
// the flags `tandem extract` and `tandem-client stream` share have the same names, value
// names and defaults; --quiet, --help and --version exist everywhere; and a repeated flag, a
// malformed number and a misspelt name are refused by each with the same words and exit 2.
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "service/service_testutil.h"
#include "tandem/io/mesh_io.h"
#include "tandem/eval/synthetic.h"
#include "tandem/io/volume_writers.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

struct FlagHelp {
  std::string value_name, default_text;
};

// The flags a --help lists ("  --name VALUE   help ... (default: X)"), by name.
std::map<std::string, FlagHelp> FlagsOf(const std::string& help) {
  std::map<std::string, FlagHelp> flags;
  const std::regex line(R"(^  --([a-z0-9-]+)( [^ ]+)?\s)");
  std::istringstream in(help);
  std::string text, current;
  while (std::getline(in, text)) {
    std::smatch m;
    if (std::regex_search(text, m, line)) {
      current = m[1];
      flags[current].value_name = m[2].matched ? std::string(m[2]).substr(1) : "";
    }
    const size_t at = text.find("(default: ");
    if (!current.empty() && at != std::string::npos) {
      flags[current].default_text = text.substr(at, text.find(')', at) - at + 1);
    }
  }
  return flags;
}

RunResult RunProgram(std::vector<std::string> args) {
  args[0] = BinPath(args[0]);
  return RunProcess(args, 60);
}

TEST(CliParity, SharedFlagsHaveTheSameNamesValuesAndDefaults) {
  const RunResult cli = RunProgram({"tandem", "extract", "--help"});
  const RunResult client = RunProgram({"tandem-client", "stream", "--help"});
  ASSERT_EQ(cli.exit_code, 0) << cli.err;
  ASSERT_EQ(client.exit_code, 0) << client.err;
  const auto a = FlagsOf(cli.out);
  const auto b = FlagsOf(client.out);
  for (const char* name :
       {"input", "zarr-array", "series", "follow", "expect-slices", "settle", "done-file", "out", "iso",
        "error", "alpha", "schedule", "no-simplify", "frame", "spacing", "distance-guard", "sag-correction",
        "lockstep-error",
        "target-triangles", "parts", "seal", "seal-margin", "metrics", "reference", "strict", "quiet"}) {
    SCOPED_TRACE(name);
    ASSERT_TRUE(a.count(name)) << cli.out;
    ASSERT_TRUE(b.count(name)) << client.out;
    EXPECT_EQ(a.at(name).value_name, b.at(name).value_name);
    EXPECT_EQ(a.at(name).default_text, b.at(name).default_text);
  }
  // The client defaults --iso and --error as the CLI does, no longer requires them.
  EXPECT_EQ(b.at("iso").default_text, "(default: the file's first suggested iso-value)");
  EXPECT_EQ(b.at("error").default_text, "(default: 0.2 x the smallest spacing)");
  // --quiet and --help everywhere; --version answers for each program.
  const RunResult server = RunProgram({"tandem-server", "--help"});
  ASSERT_EQ(server.exit_code, 0) << server.err;
  EXPECT_TRUE(FlagsOf(server.out).count("quiet")) << server.out;
  EXPECT_TRUE(FlagsOf(RunProgram({"tandem-client", "watch", "--help"}).out).count("quiet"));
  for (const char* program : {"tandem", "tandem-client", "tandem-server"}) {
    const RunResult v = RunProgram({program, "--version"});
    EXPECT_EQ(v.exit_code, 0) << program;
    EXPECT_EQ(v.out.rfind(std::string(program) + " 0.", 0), 0u) << v.out;
    EXPECT_NE(v.out.find("(git "), std::string::npos) << v.out;
  }
}

TEST(CliParity, MistakesAreWordedTheSameWayByEveryProgram) {
  struct Program {
    std::vector<std::string> prefix;  // program and subcommand
    std::string valued, number_flag, misspelt, meant;
  };
  const std::vector<Program> programs = {
      {{"tandem", "extract"}, "--out", "--alpha", "--alpah", "alpha"},
      {{"tandem-client", "stream"}, "--out", "--alpha", "--alpah", "alpha"},
      {{"tandem-server"}, "--listen", "--grace-seconds", "--max-sesions", "max-sessions"},
  };
  for (const Program& p : programs) {
    SCOPED_TRACE(p.prefix[0]);
    auto with = [&](std::vector<std::string> extra) {
      std::vector<std::string> args = p.prefix;
      args.insert(args.end(), extra.begin(), extra.end());
      return RunProgram(args);
    };
    const RunResult twice = with({p.valued, "a.ply", p.valued, "b.ply"});
    EXPECT_EQ(twice.exit_code, 2);
    EXPECT_NE(twice.err.find(p.valued + " given twice ('a.ply' and 'b.ply'): give it once"),
              std::string::npos) << twice.err;
    const RunResult malformed = with({p.number_flag, "1.5x"});
    EXPECT_EQ(malformed.exit_code, 2);
    EXPECT_NE(malformed.err.find(p.number_flag + ": '1.5x' is not a number"), std::string::npos)
        << malformed.err;
    const RunResult misspelt = with({p.misspelt, "3"});
    EXPECT_EQ(misspelt.exit_code, 2);
    EXPECT_NE(misspelt.err.find("unknown option " + p.misspelt + " (did you mean --" + p.meant +
                                "?)"),
              std::string::npos) << misspelt.err;
  }
}

// One exit status rule for the three programs (apps/common/cli_util.h): 2 for a mistake in the
// command line itself, 1 for what goes wrong with the input, the files, the server or the
// network. A corrupt input file is 1 for `tandem extract` and `tandem-client stream` alike,
// whether it fails as it is opened or in the middle of the session.
TEST(CliParity, ExitStatusIsTwoForTheCommandLineAndOneForTheRest) {
  const std::string dir = MakeTempDir();
  absl::StatusOr<std::string> good = WriteSyntheticVolume(
      dir, "good", eval::MakeSyntheticSource(eval::Shape::kSphere, 16, 16, 16));
  ASSERT_TRUE(good.ok()) << good.status();
  // A float32 volume with a NaN in slice 5: found by the session, not when it is opened.
  VolumeInfo info;
  info.nx = info.ny = info.nz = 12;
  info.dtype = DType::kFloat32;
  ASSERT_TRUE(io::WriteVolume(dir + "/nan.json", info, [&](int64_t k, std::vector<uint8_t>* bytes) {
                std::vector<float> v(static_cast<size_t>(info.slice_voxels()), 1.0f);
                v[0] = -1.0f;
                if (k == 5) v[40] = std::numeric_limits<float>::quiet_NaN();
                bytes->resize(v.size() * 4);
                std::memcpy(bytes->data(), v.data(), bytes->size());
                return absl::OkStatus();
              }).ok());
  // A raw file cut short: refused as it is opened.
  ASSERT_TRUE(
      WriteSyntheticVolume(dir, "cut", eval::MakeSyntheticSource(eval::Shape::kSphere, 16, 16, 16))
          .ok());
  std::filesystem::resize_file(dir + "/cut.raw", 1000);
  std::ofstream(dir + "/corrupt.ply") << "ply\nformat binary_little_endian 1.0\nelement vertex 3\n";
  std::filesystem::create_directories(dir + "/empty");
  absl::StatusOr<std::unique_ptr<TestServer>> server = TestServer::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string address = (*server)->address(), out = dir + "/o.ply";
  const std::string missing = dir + "/missing.json";
  auto stream = [&](const std::string& input, std::vector<std::string> more = {}) {
    std::vector<std::string> args = {"tandem-client", "stream", "--server", address, "--input",
                                     input, "--iso", "0", "--out", out, "--timeout", "30"};
    args.insert(args.end(), more.begin(), more.end());
    return args;
  };
  auto extract = [&](const std::string& input, std::vector<std::string> more = {}) {
    std::vector<std::string> args = {"tandem", "extract", "--input", input, "--iso", "0",
                                     "--out", out};
    args.insert(args.end(), more.begin(), more.end());
    return args;
  };
  struct Case {
    std::vector<std::string> args;
    int code;
    std::string says;  // in stderr
  };
  const std::vector<Case> cases = {
      // The command line: unknown, missing or malformed flags, a value a rule refuses, an
      // output extension no writer has, a subcommand that does not exist.
      {{"tandem", "frobnicate"}, 2, "unknown command 'frobnicate'"},
      {extract(*good, {"--bogus", "1"}), 2, "unknown option --bogus"},
      {{"tandem", "extract", "--input", *good, "--out", dir + "/o.off"}, 2, ".ply, .obj"},
      {extract(*good, {"--alpha", "2"}), 2, "--alpha 2"},
      {extract(*good, {"--frame", "up"}), 2, "--frame up: expected lps, ras or voxel"},
      {extract(*good, {"--frame", "lps"}), 2, "--frame lps: the input's vertices are in grid"},
      {{"tandem", "generate", "cube", "--size", "8", "--out", dir + "/c.json"}, 2, "cube"},
      {{"tandem", "generate", "sphere", "--size", "8", "--out", dir + "/c.xyz"}, 2, "c.xyz"},
      {{"tandem", "measure", dir + "/a.ply"}, 2, "expected two meshes"},
      {{"tandem", "measure", dir + "/a.off", dir + "/b.ply"}, 2, "expected a .ply, .obj or .stl"},
      {{"tandem", "info"}, 2, "--input"},
      {{"tandem", "simulate", "--input", *good, "--out", dir + "/sim", "--as", "png"}, 2, "--as 'png'"},
      {{"tandem", "view"}, 2, "expected one mesh file or folder"},
      {{"tandem-client", "frobnicate"}, 2, "usage: tandem-client"},
      {stream(*good, {"--bogus"}), 2, "unknown option --bogus"},
      {stream(*good, {"--frame", "up"}), 2, "--frame up"},
      {stream(*good, {"--frame", "ras"}), 2, "--frame ras: the input's vertices are in grid"},
      {stream(*good, {"--error", "0"}), 2, "E0 must be a finite number > 0"},
      {{"tandem-client", "stream", "--server", address, "--input", *good, "--out", dir + "/o.off"},
       2, ".drc, .ply"},
      {{"tandem-client", "info", "--lb", "random"}, 2, "--lb"},
      {{"tandem-client", "watch", "--server", address, "--out", out}, 2, "--session"},
      {{"tandem-client", "health", "--timeout", "soon"}, 2, "--timeout"},
      {{"tandem-server", "--bogus"}, 2, "unknown option --bogus"},
      {{"tandem-server", "--max-sessions", "0"}, 2, "--max-sessions"},
      {{"tandem-server", "--listen", "nonsense"}, 2, "expected HOST:PORT"},
      {{"tandem-server", "--listen", "127.0.0.1:0", "--tls-cert", dir + "/a.crt"}, 2,
       "--tls-cert and --tls-key go together"},
      // The input and the run: files, servers, the network, a session's failure.
      {extract(missing), 1, "missing.json"},
      {extract(dir + "/cut.json"), 1, "cut.raw"},
      {extract(dir + "/nan.json"), 1, "slice 5"},
      {{"tandem", "info", "--input", missing}, 1, "missing.json"},
      {{"tandem", "measure", dir + "/corrupt.ply", dir + "/corrupt.ply"}, 1, "corrupt.ply"},
      {{"tandem", "simulate", "--input", missing, "--out", dir + "/sim", "--as", "tiff"}, 1,
       "missing.json"},
      {{"tandem", "view", dir + "/empty"}, 1, "no chunk_*.drc files"},
      {stream(missing), 1, "missing.json"},
      {stream(dir + "/cut.json"), 1, "cut.raw"},
      {stream(dir + "/nan.json"), 1, "slice 5"},
      {stream(*good, {"--token-file", dir + "/no_tokens.txt"}), 1, "no_tokens.txt"},
      {{"tandem-client", "stream", "--server", "127.0.0.1:1", "--input", *good, "--iso", "0",
        "--out", out, "--retries", "0", "--timeout", "10"},
       1, "UNAVAILABLE"},
      {{"tandem-client", "health", "--server", "127.0.0.1:1", "--timeout", "2"}, 1, "UNAVAILABLE"},
      {{"tandem-client", "watch", "--server", address, "--session", "nosuch", "--out", out,
        "--timeout", "10"},
       1, "NOT_FOUND"},
      {{"tandem-server", "--listen", "127.0.0.1:0", "--tls-cert", dir + "/a.crt", "--tls-key",
        dir + "/a.key"},
       1, "a.crt"},
      {{"tandem-server", "--listen", "127.0.0.1:0", "--auth-tokens-file", dir + "/none.txt"}, 1,
       "none.txt"},
      {{"tandem-server", "--listen", address}, 1, "cannot listen"},  // the port is taken
  };
  for (const Case& c : cases) {
    std::string line;
    for (const std::string& a : c.args) line += " " + a;
    SCOPED_TRACE(line);
    const RunResult r = RunProgram(c.args);
    EXPECT_EQ(r.exit_code, c.code) << r.err;
    EXPECT_NE((r.err + r.out).find(c.says), std::string::npos) << r.err << r.out;
  }
}

// --frame through the server: the stream's mesh lands where `tandem extract`'s does, the
// file says the frame as 3D Slicer reads it, and the metrics name it (the server echoes
// it, so a watcher's files carry it too).
TEST(CliParity, TheFrameTravelsWithTheStreamedMesh) {
  const std::string dir = MakeTempDir();
  const RunResult gen = RunProgram({"tandem", "generate", "link", "--size", "24", "--series",
                                    "dicom", "--origin", "10,-20,30", "--out", dir + "/ct"});
  ASSERT_EQ(gen.exit_code, 0) << gen.err;
  absl::StatusOr<std::unique_ptr<TestServer>> server = TestServer::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::vector<std::string> common = {"--input", dir + "/ct", "--iso", "0", "--frame",
                                           "ras", "--parts", "1"};
  std::vector<std::string> local = {"tandem", "extract", "--out", dir + "/local.ply",
                                    "--metrics", dir + "/local.json"};
  std::vector<std::string> streamed = {"tandem-client", "stream", "--server",
                                       (*server)->address(), "--out", dir + "/streamed.ply",
                                       "--metrics", dir + "/streamed.json", "--seal",
                                       "--chunks", dir + "/chunks"};
  local.insert(local.end(), common.begin(), common.end());
  streamed.insert(streamed.end(), common.begin(), common.end());
  const RunResult l = RunProgram(local), r = RunProgram(streamed);
  ASSERT_EQ(l.exit_code, 0) << l.err;
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* name : {"local", "streamed"}) {
    SCOPED_TRACE(name);
    const std::string ply = ReadFileOrEmpty(dir + "/" + name + ".ply");
    EXPECT_NE(ply.find("\ncomment SPACE=RAS\n"), std::string::npos) << ply.substr(0, 200);
    const std::string json = ReadFileOrEmpty(dir + "/" + name + ".json");
    EXPECT_NE(json.find("\"frame\": \"RAS\""), std::string::npos) << json;
    EXPECT_NE(json.find("\"frame_text\": \"RAS: DICOM patient LPS (mm) with x and y negated\""),
              std::string::npos)
        << json;
  }
  // The same place: the generated grid is at x 10..33, y -20..3 in LPS, so in RAS x is
  // negative and y positive.
  absl::StatusOr<IndexedMesh> a = io::ReadMesh(dir + "/local.ply"),
                              b = io::ReadMesh(dir + "/streamed.ply");
  ASSERT_TRUE(a.ok() && b.ok());
  for (const IndexedMesh* m : {&*a, &*b}) {
    for (const Vec3& p : m->positions) {
      ASSERT_LT(p.x, -9.9);
      ASSERT_GT(p.y, -3.1);
    }
  }
}

// After the last slice, while the session finishes (here: --schedule classical, whose whole
// simplification runs then), `tandem extract` and `tandem-client stream` say so, with the
// share done and an estimate of the time left. TANDEM_PROGRESS_SECONDS=0 asks for a line at
// every update on a stderr that is not a terminal (a log gets one every 10 s by default).
TEST(CliParity, AStatusLineWithAnEstimateWhileTheSessionFinishes) {
  const std::string dir = MakeTempDir();
  absl::StatusOr<std::string> input = WriteSyntheticVolume(
      dir, "g", eval::MakeSyntheticSource(eval::Shape::kGyroid, 224, 224, 224));
  ASSERT_TRUE(input.ok()) << input.status();
  absl::StatusOr<std::unique_ptr<TestServer>> server = TestServer::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::vector<std::string> env = {"TANDEM_PROGRESS_SECONDS=0"};
  const std::regex line(
      R"((tandem extract|tandem-client): finishing: simplifying the whole mesh, ([0-9]+)%, about [0-9]+ s left \([0-9.]+ s so far\))");
  const std::regex so_far(R"(finishing: [^\n]*\(([0-9.]+) s so far\))");
  for (std::vector<std::string> args :
       {std::vector<std::string>{"tandem", "extract"},
        {"tandem-client", "stream", "--server", (*server)->address()}}) {
    SCOPED_TRACE(args[0]);
    args[0] = BinPath(args[0]);
    args.insert(args.end(), {"--input", *input, "--iso", "0", "--schedule", "classical",
                             "--out", dir + "/g.ply"});
    const RunResult r = RunProcess(args, 300, env);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    std::smatch m;
    EXPECT_TRUE(std::regex_search(r.err, m, line)) << r.err;
    // Without the variable, a log (not a terminal) gets a line only once the finish has
    // taken 10 s: none for a finish this short on an idle machine, a late one on a busy one.
    const RunResult quiet = RunProcess(args, 300);
    ASSERT_EQ(quiet.exit_code, 0) << quiet.err;
    for (auto it = std::sregex_iterator(quiet.err.begin(), quiet.err.end(), so_far);
         it != std::sregex_iterator(); ++it) {
      EXPECT_GE(std::stod((*it)[1].str()), 9.5) << quiet.err;
    }
    if (quiet.err.find("finishing:") != std::string::npos) {
      EXPECT_TRUE(std::regex_search(quiet.err, so_far)) << quiet.err;
    }
  }
}

}  // namespace
}  // namespace tandem::testing
