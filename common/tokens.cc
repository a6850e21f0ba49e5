#include "tandem/common/tokens.h"

#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace tandem::common {

absl::StatusOr<std::vector<std::string>> ParseTokens(std::string_view text,
                                                     const std::string& source) {
  std::vector<std::string> tokens;
  int line_number = 0;
  for (absl::string_view line : absl::StrSplit(absl::string_view(text.data(), text.size()), '\n')) {
    ++line_number;
    line = absl::StripAsciiWhitespace(line);
    if (line.empty() || line[0] == '#') continue;
    if (line.size() > kMaxTokenBytes) {
      return absl::InvalidArgumentError(absl::StrCat(
          source, " line ", line_number, ": a token is at most ", kMaxTokenBytes, " characters"));
    }
    for (char c : line) {
      if (c <= ' ' || c > '~') {
        return absl::InvalidArgumentError(
            absl::StrCat(source, " line ", line_number,
                         ": a token is printable ASCII without spaces (one token per line)"));
      }
    }
    tokens.emplace_back(line);
  }
  return tokens;
}

absl::StatusOr<std::vector<std::string>> ReadTokensFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    const int err = errno;
    const std::string what = absl::StrCat(path, ": cannot open (", std::strerror(err), ")");
    return err == EACCES ? absl::PermissionDeniedError(what) : absl::NotFoundError(what);
  }
  std::stringstream ss;
  ss << in.rdbuf();
  return ParseTokens(ss.str(), path);
}

bool ConstantTimeEquals(std::string_view a, std::string_view b) {
  // Accumulate differences over every byte of b; a's bytes are read cyclically so that
  // neither a branch nor the loop length depends on a. Lengths are compared the same way.
  volatile unsigned char diff = a.size() == b.size() ? 0 : 1;
  if (a.empty()) return b.empty();
  for (size_t i = 0; i < b.size(); ++i) {
    diff = static_cast<unsigned char>(
        diff | (static_cast<unsigned char>(a[i % a.size()]) ^ static_cast<unsigned char>(b[i])));
  }
  return diff == 0;
}

}  // namespace tandem::common
