// FlagSet, the parser of all three programs (on CLI11): forms, defaults in --help,
// environment fallback, and mistakes worded the same way everywhere.
#include "apps/common/flags.h"

#include <cstdlib>
#include <fstream>
#include <limits>
#include <optional>
#include <vector>

#include <gtest/gtest.h>

#include "apps/common/extract_flags.h"
#include "tandem/options.h"
#ifdef TANDEM_HAVE_DRACO
#include "tandem/codec/draco_codec.h"
#endif

namespace tandem::cli {
namespace {

struct Args {
  explicit Args(std::vector<std::string> a) : strings(std::move(a)) {
    for (std::string& s : strings) ptrs.push_back(s.data());
  }
  int argc() const { return static_cast<int>(ptrs.size()); }
  char** argv() { return ptrs.data(); }
  std::vector<std::string> strings;
  std::vector<char*> ptrs;
};

TEST(FlagSet, ParsesEveryFormAndKeepsDefaults) {
  std::string s = "a";
  int64_t n = 3;
  double x = 0.5;
  bool b = false, c = false;
  FlagSet flags("usage");
  flags.AddString("name", &s, "S", "a string");
  flags.AddInt("count", &n, "an int");
  flags.AddDouble("ratio", &x, "a double");
  flags.AddBool("on", &b, "a bool");
  flags.AddBool("off", &c, "another bool");
  Args args({"prog", "--name", "zz", "--count=7", "--on", "--off=false", "pos"});
  ASSERT_TRUE(flags.Parse(args.argc(), args.argv()).ok());
  EXPECT_EQ(s, "zz");
  EXPECT_EQ(n, 7);
  EXPECT_EQ(x, 0.5);
  EXPECT_TRUE(b);
  EXPECT_FALSE(c);
  EXPECT_TRUE(flags.IsSet("count"));
  EXPECT_FALSE(flags.IsSet("ratio"));
  EXPECT_EQ(flags.positional(), std::vector<std::string>{"pos"});
}

TEST(FlagSet, HelpListsEveryFlagWithItsDefault) {
  std::string s = "127.0.0.1:50051";
  int64_t n = 8;
  double x = 0;
  FlagSet flags("usage: prog");
  flags.AddString("listen", &s, "HOST:PORT", "where");
  flags.AddInt("max-sessions", &n, "how many");
  flags.AddDouble("iso", &x, "iso-value", /*required=*/true);
  flags.UseEnvironment("TANDEM_", {"max-sessions"});
  const std::string help = flags.Help();
  EXPECT_NE(help.find("--listen HOST:PORT"), std::string::npos) << help;
  EXPECT_NE(help.find("(default: 127.0.0.1:50051)"), std::string::npos) << help;
  EXPECT_NE(help.find("(default: 8) [$TANDEM_MAX_SESSIONS]"), std::string::npos) << help;
  EXPECT_NE(help.find("--iso X"), std::string::npos) << help;
  EXPECT_NE(help.find("(required)"), std::string::npos) << help;
}

TEST(FlagSet, ErrorsNameTheFlag) {
  int64_t n = 0;
  double x = 0;
  FlagSet flags("usage");
  flags.AddInt("count", &n, "an int");
  flags.AddDouble("iso", &x, "required", /*required=*/true);
  Args unknown({"prog", "--nope", "1"});
  EXPECT_EQ(flags.Parse(unknown.argc(), unknown.argv()).message(), "unknown option --nope (see --help)");
  FlagSet f2("usage");
  f2.AddInt("count", &n, "an int");
  Args bad({"prog", "--count", "seven"});
  EXPECT_EQ(f2.Parse(bad.argc(), bad.argv()).message(),
            "--count: 'seven' is not an integer");
  FlagSet f3("usage");
  f3.AddDouble("iso", &x, "required", /*required=*/true);
  Args none({"prog"});
  EXPECT_EQ(f3.Parse(none.argc(), none.argv()).message(), "missing --iso (see --help)");
  FlagSet f4("usage");
  f4.AddDouble("iso", &x, "required", /*required=*/true);
  Args help({"prog", "--help"});
  EXPECT_TRUE(f4.Parse(help.argc(), help.argv()).ok());
  EXPECT_TRUE(f4.help_requested());
}

TEST(FlagSet, MisspeltFlagsGetTheClosestNameAndRepeatsAreErrors) {
  int64_t n = 0;
  double grace = 0;
  bool quiet = false;
  auto make = [&](FlagSet* f) {
    f->AddInt("count", &n, "an int");
    f->AddDouble("grace-seconds", &grace, "a double");
    f->AddBool("quiet", &quiet, "a bool");
  };
  FlagSet f1("usage");
  make(&f1);
  Args typo({"prog", "--cuont", "1"});
  EXPECT_EQ(f1.Parse(typo.argc(), typo.argv()).message(),
            "unknown option --cuont (did you mean --count?) (see --help)");
  FlagSet f2("usage");
  make(&f2);
  Args prefix({"prog", "--grace", "1"});
  EXPECT_EQ(f2.Parse(prefix.argc(), prefix.argv()).message(),
            "unknown option --grace (did you mean --grace-seconds?) (see --help)");
  FlagSet f3("usage");
  make(&f3);
  Args twice({"prog", "--count", "1", "--count=2"});
  EXPECT_EQ(f3.Parse(twice.argc(), twice.argv()).message(), "--count given twice ('1' and '2'): give it once");
  FlagSet f4("usage");
  make(&f4);
  Args bools({"prog", "--quiet", "--quiet", "--count", "3"});
  EXPECT_TRUE(f4.Parse(bools.argc(), bools.argv()).ok()) << "a repeated switch is harmless";
  EXPECT_EQ(n, 3);
}

TEST(ClosestName, NearestUnambiguousOrTheOnlyPrefix) {
  const std::vector<std::string> known = {"iso", "input", "error", "alpha", "max-sessions",
                                          "max-slices"};
  EXPECT_EQ(ClosestName("isoo", known), "iso");
  EXPECT_EQ(ClosestName("erorr", known), "error");     // a transposition
  EXPECT_EQ(ClosestName("max-sesions", known), "max-sessions");
  EXPECT_EQ(ClosestName("inp", known), "input");       // the only name it starts
  EXPECT_EQ(ClosestName("max", known), "");            // two names start with it
  EXPECT_EQ(ClosestName("frobnicate", known), "");
  EXPECT_EQ(DidYouMean("alpah", known), " (did you mean --alpha?)");
  EXPECT_EQ(DidYouMean("zzz", known), "");
}

TEST(FlagSet, CommandLineBeatsEnvironmentWhichBeatsDefault) {
  setenv("TANDEMTEST_MAX_SESSIONS", "4", 1);
  setenv("TANDEMTEST_GRACE_SECONDS", "2.5", 1);
  int64_t sessions = 8;
  double grace = 10;
  FlagSet flags("usage");
  flags.AddInt("max-sessions", &sessions, "n");
  flags.AddDouble("grace-seconds", &grace, "s");
  flags.UseEnvironment("TANDEMTEST_");
  Args args({"prog", "--grace-seconds", "1"});
  ASSERT_TRUE(flags.Parse(args.argc(), args.argv()).ok());
  EXPECT_EQ(sessions, 4);
  EXPECT_EQ(grace, 1);
  setenv("TANDEMTEST_MAX_SESSIONS", "many", 1);
  FlagSet again("usage");
  again.AddInt("max-sessions", &sessions, "n");
  again.UseEnvironment("TANDEMTEST_");
  Args plain({"prog"});
  EXPECT_EQ(again.Parse(plain.argc(), plain.argv()).message(),
            "TANDEMTEST_MAX_SESSIONS: 'many' is not an integer");
  unsetenv("TANDEMTEST_MAX_SESSIONS");
  unsetenv("TANDEMTEST_GRACE_SECONDS");
}

// A secret (a token) comes from --NAME-file FILE or its variable, kept off the command line
// every user can read; --NAME still works there, with a warning; the file beats the
// variable, --NAME and --NAME-file together are an error, a missing or empty file is named.
TEST(FlagSet, SecretsComeFromAFileOrTheirVariableAndTheCommandLineWarns) {
  const std::string dir = ::testing::TempDir();
  const std::string file = dir + "/secret_flag_test.txt";
  {
    std::ofstream out(file);
    out << "# the viewer's token\n\n  from-file  \nsecond-line\n";
  }
  const std::string empty = dir + "/secret_flag_test_empty.txt";
  { std::ofstream(empty) << "# nothing\n\n"; }
  auto parse = [](std::vector<std::string> argv, std::string* token, FlagSet* flags) {
    flags->AddSecret("view-token", token, "TOKEN", "TANDEMTEST_VIEW_TOKEN", "the token");
    Args args(std::move(argv));
    return flags->Parse(args.argc(), args.argv());
  };
  std::string token;
  {
    FlagSet flags("usage");
    ASSERT_TRUE(parse({"prog", "--view-token-file", file}, &token, &flags).ok());
    EXPECT_EQ(token, "from-file");
    EXPECT_TRUE(flags.IsSet("view-token"));
    EXPECT_TRUE(flags.warnings().empty());
    EXPECT_NE(flags.Help().find("--view-token-file FILE"), std::string::npos) << flags.Help();
    EXPECT_NE(flags.Help().find("[$TANDEMTEST_VIEW_TOKEN]"), std::string::npos) << flags.Help();
  }
  setenv("TANDEMTEST_VIEW_TOKEN", "from-env", 1);
  {
    FlagSet flags("usage");
    token.clear();
    ASSERT_TRUE(parse({"prog"}, &token, &flags).ok());
    EXPECT_EQ(token, "from-env");
    EXPECT_TRUE(flags.warnings().empty());
  }
  {
    FlagSet flags("usage");
    ASSERT_TRUE(parse({"prog", "--view-token-file=" + file}, &token, &flags).ok());
    EXPECT_EQ(token, "from-file") << "the command line beats the variable";
  }
  {
    FlagSet flags("usage");
    ASSERT_TRUE(parse({"prog", "--view-token", "on-argv"}, &token, &flags).ok());
    EXPECT_EQ(token, "on-argv");
    ASSERT_EQ(flags.warnings().size(), 1u);
    EXPECT_NE(flags.warnings()[0].find("--view-token on the command line can be read by every "
                                       "user of this machine"),
              std::string::npos)
        << flags.warnings()[0];
    EXPECT_NE(flags.warnings()[0].find("--view-token-file FILE or $TANDEMTEST_VIEW_TOKEN"),
              std::string::npos);
    EXPECT_EQ(flags.warnings()[0].find("on-argv"), std::string::npos) << "never the secret";
  }
  unsetenv("TANDEMTEST_VIEW_TOKEN");
  {
    FlagSet flags("usage");
    EXPECT_EQ(parse({"prog", "--view-token", "a", "--view-token-file", file}, &token, &flags)
                  .message(),
              "--view-token and --view-token-file: give one of them");
  }
  {
    FlagSet flags("usage");
    EXPECT_EQ(parse({"prog", "--view-token-file", empty}, &token, &flags).message(),
              "--view-token-file " + empty + ": no value in it (blank lines and #comments only)");
  }
  {
    FlagSet flags("usage");
    const absl::Status st = parse({"prog", "--view-token-file", dir + "/none"}, &token, &flags);
    EXPECT_EQ(st.message().rfind("--view-token-file " + dir + "/none: cannot open", 0), 0u) << st;
  }
}

// A refusal of SessionOptions::Validate() says which option, its value and the rule (core's
// words); each front end names the option in its own terms: the command line by its flag.
TEST(OptionFlags, RefusalsOfCoreNameTheFlag) {
  SessionOptions o;
  o.error = 0.5;
  o.alpha = 1.5;
  const absl::Status st = o.Validate();
  EXPECT_EQ(st.message(), "alpha = 1.5: isotropy alpha must lie in [0, 1]");
  const std::optional<OptionError> e = OptionErrorOf(st);
  ASSERT_TRUE(e.has_value());
  EXPECT_EQ(e->field, "alpha");
  EXPECT_EQ(e->value, "1.5");
  const absl::Status named = NameOptionFlag(st);
  EXPECT_EQ(named.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(named.message(), "--alpha 1.5: isotropy alpha must lie in [0, 1]");
  o.alpha = 0;
  o.distance_guard = -2;
  EXPECT_EQ(NameOptionFlag(o.Validate()).message().substr(0, 20), "--distance-guard -2:");
  o.distance_guard = 0;
  o.error = 1e-9;  // the grid's rule
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 8;
  EXPECT_EQ(OptionErrorOf(o.ValidateFor(grid))->field, "error");
  // Other statuses pass unchanged.
  const absl::Status other = absl::NotFoundError("x");
  EXPECT_FALSE(OptionErrorOf(other).has_value());
  EXPECT_EQ(NameOptionFlag(other), other);
}

// One rule for an iso list (core's), each front end naming its flag.
TEST(IsoList, CoreRuleWithTheFlagNamed) {
  const std::vector<double> eight = {1, 2, 3, 4, 5, 6, 7, 8};
  EXPECT_TRUE(ValidateIsoList(eight).ok());
  const std::vector<double> nine = {1, 2, 3, 4, 5, 6, 7, 8, 9};
  EXPECT_EQ(ValidateIsoList(nine).message(), "at most 8 iso-values in one pass, got 9");
  const std::vector<double> twice = {60, 120, 60};
  EXPECT_EQ(ValidateIsoList(twice).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ValidateIsoList(twice).message(), "iso-value 60 is given twice");
  const std::vector<double> inf = {60, std::numeric_limits<double>::infinity()};
  EXPECT_EQ(ValidateIsoList(inf).message(), "iso-value inf is not a finite number");
  EXPECT_EQ(ParseIsoList("60,120,60").status().message(),
            "--iso '60,120,60': iso-value 60 is given twice");
  EXPECT_EQ(ParseIsoList("1,2,3,4,5,6,7,8,9").status().message(),
            "--iso '1,2,3,4,5,6,7,8,9': at most 8 iso-values in one pass, got 9");
  EXPECT_EQ(ParseIsoList("60,inf").status().message(),
            "--iso '60,inf': iso-value inf is not a finite number");
  ASSERT_TRUE(ParseIsoList("60, 120").ok());
  EXPECT_EQ(ParseIsoList("60, 120")->at(1).text, "120");
}

#ifdef TANDEM_HAVE_DRACO
// The Draco flags take the codec's defaults and its range check, the refusal naming the flag.
TEST(DracoFlags, CodecDefaultsAndRangesWithTheFlagNamed) {
  FlagSet flags("usage");
  ExtractFlags f;
  f.Add(&flags, "mesh");
  EXPECT_EQ(f.quantization_bits, codec::kDefaultQuantizationBits);
  EXPECT_EQ(f.compression_level, codec::kDefaultCompressionLevel);
  EXPECT_TRUE(CheckDracoFlags(1, 0).ok());
  EXPECT_TRUE(CheckDracoFlags(30, 10).ok());
  const absl::Status bits = CheckDracoFlags(31, 7);
  EXPECT_EQ(bits.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(bits.message(), "--quantization-bits must be in [1, 30], got 31");
  EXPECT_EQ(CheckDracoFlags(16, -1).message(), "--compression-level must be in [0, 10], got -1");
  // Past int's range: refused, not wrapped into [1, 30] (2^32 + 16 would wrap to 16).
  EXPECT_FALSE(CheckDracoFlags((int64_t{1} << 32) + 16, 7).ok());
}
#endif

}  // namespace
}  // namespace tandem::cli
