// The three programs' command lines side by side (issue: one consistent command line):
// the flags `tandem extract` and `tandem-client stream` share have the same names, value
// names and defaults; --quiet, --help and --version exist everywhere; and a repeated flag, a
// malformed number and a misspelt name are refused by each with the same words and exit 2.
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "service/service_testutil.h"
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
        "error", "alpha", "schedule", "no-simplify", "distance-guard", "sag-correction",
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

}  // namespace
}  // namespace tandem::testing
