// The bearer-token file format (shared by tandem-server --auth-tokens-file and
// tandem-client --token-file) and the constant-time comparison.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "tandem/common/tokens.h"
#include "testutil/testutil.h"

namespace tandem::common {
namespace {

TEST(AuthTokens, ParsesLinesSkippingBlanksAndComments) {
  auto tokens = ParseTokens("# operators\n\n  alpha-1  \r\nbeta_2\n   # indented comment\n\n", "f");
  ASSERT_TRUE(tokens.ok()) << tokens.status();
  EXPECT_EQ(*tokens, (std::vector<std::string>{"alpha-1", "beta_2"}));
  auto none = ParseTokens("# nothing\n\n", "f");
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->empty());
}

TEST(AuthTokens, RejectsMalformedLinesWithoutEchoingThem) {
  auto spaced = ParseTokens("good\nsecret with spaces\n", "tokens.txt");
  ASSERT_FALSE(spaced.ok());
  EXPECT_NE(spaced.status().message().find("tokens.txt line 2"), std::string::npos)
      << spaced.status();
  EXPECT_EQ(spaced.status().message().find("secret"), std::string::npos) << spaced.status();
  auto control = ParseTokens(std::string("tok\x01"
                                         "en\n"),
                             "t");
  EXPECT_FALSE(control.ok());
  auto longer = ParseTokens(std::string(kMaxTokenBytes + 1, 'a'), "t");
  EXPECT_FALSE(longer.ok());
  EXPECT_TRUE(ParseTokens(std::string(kMaxTokenBytes, 'a'), "t").ok());
}

TEST(AuthTokens, ReadsAFileAndNamesAMissingOne) {
  const std::string dir = tandem::testing::MakeTempDir();
  std::ofstream(dir + "/t.txt") << "s3cr3t\n";
  auto tokens = ReadTokensFile(dir + "/t.txt");
  ASSERT_TRUE(tokens.ok()) << tokens.status();
  EXPECT_EQ(*tokens, std::vector<std::string>{"s3cr3t"});
  auto missing = ReadTokensFile(dir + "/absent.txt");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("absent.txt"), std::string::npos);
}

TEST(AuthTokens, ConstantTimeEqualsIsEquality) {
  EXPECT_TRUE(ConstantTimeEquals("abc", "abc"));
  EXPECT_FALSE(ConstantTimeEquals("abc", "abd"));
  EXPECT_FALSE(ConstantTimeEquals("abc", "ab"));
  EXPECT_FALSE(ConstantTimeEquals("abc", "abcabc"));  // cyclic reads do not fool it
  EXPECT_FALSE(ConstantTimeEquals("abc", ""));
  EXPECT_FALSE(ConstantTimeEquals("", "a"));
  EXPECT_TRUE(ConstantTimeEquals("", ""));
}

}  // namespace
}  // namespace tandem::common
