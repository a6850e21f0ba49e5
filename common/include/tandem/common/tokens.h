// Bearer tokens: the file format shared by tandem-server --auth-tokens-file and
// tandem-client --token-file, and the constant-time comparison the server uses.
//
// Format: one token per line; leading and trailing whitespace (CR included) is dropped;
// blank lines and lines starting with '#' are ignored. A token is 1..4096 printable ASCII
// characters without spaces (what fits in an HTTP/2 header value after "Bearer ").
// Error messages name the file and the line, never a token's text.
#ifndef TANDEM_PROTO_COMMON_TOKENS_H_
#define TANDEM_PROTO_COMMON_TOKENS_H_

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"

namespace tandem::common {

inline constexpr size_t kMaxTokenBytes = 4096;

// Every token of `text`; `source` names the file in errors. InvalidArgument for a
// malformed line; an empty list is not an error here (the caller decides).
absl::StatusOr<std::vector<std::string>> ParseTokens(std::string_view text,
                                                     const std::string& source);
// Reads and parses `path` (NotFound / PermissionDenied name the file).
absl::StatusOr<std::vector<std::string>> ReadTokensFile(const std::string& path);

// True when a == b. The time taken depends on b.size() only, not on where the strings
// differ nor on a's length (b is what the caller sent, a the secret).
bool ConstantTimeEquals(std::string_view a, std::string_view b);

}  // namespace tandem::common

#endif  // TANDEM_PROTO_COMMON_TOKENS_H_
