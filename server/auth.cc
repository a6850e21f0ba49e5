#include "tandem/server/auth.h"

#include <cstdio>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/common/tokens.h"
#include "tandem/server/log.h"

namespace tandem::server {
namespace {

constexpr char kHint[] =
    "send the metadata `authorization: Bearer <token>` (tandem-client: --token-file FILE or "
    "the TANDEM_TOKEN environment variable)";
constexpr int kLogLinesPerWindow = 20;
constexpr absl::Duration kLogWindow = absl::Seconds(10);

}  // namespace

grpc::Status TokenAuthenticator::Check(const grpc::ServerContextBase& context, const char* method,
                                       int* identity) {
  if (identity != nullptr) *identity = kNoIdentity;
  if (!enabled()) return grpc::Status::OK;
  const auto& metadata = context.client_metadata();
  std::string reason;
  const auto [first, last] = metadata.equal_range("authorization");
  if (first == last) {
    reason = "no authorization metadata";
  } else if (std::next(first) != last) {
    reason = "more than one authorization metadata entry";
  } else {
    const std::string_view value(first->second.data(), first->second.size());
    constexpr std::string_view kScheme = "bearer ";
    // RFC 6750: the scheme is case-insensitive; one or more spaces before the token.
    if (value.size() <= kScheme.size() ||
        absl::AsciiStrToLower(std::string(value.substr(0, kScheme.size()))) != kScheme) {
      reason = "the authorization metadata is not \"Bearer <token>\"";
    } else {
      std::string_view token = value.substr(kScheme.size());
      while (!token.empty() && token.front() == ' ') token.remove_prefix(1);
      while (!token.empty() && token.back() == ' ') token.remove_suffix(1);
      int match = kNoIdentity;
      if (token.size() <= common::kMaxTokenBytes) {
        // Every token compared (no early exit); the first equal one names the caller.
        for (size_t i = tokens_.size(); i-- > 0;) {
          if (common::ConstantTimeEquals(tokens_[i], token)) match = static_cast<int>(i);
        }
      }
      if (match != kNoIdentity) {
        if (identity != nullptr) *identity = match;
        return grpc::Status::OK;
      }
      reason = "unknown bearer token";
    }
  }
  refused_.fetch_add(1);
  LogRefusal(context.peer(), method, reason);
  return grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                      absl::StrCat("this server requires a bearer token: ", reason, "; ", kHint));
}

void TokenAuthenticator::LogRefusal(const std::string& peer, const char* method,
                                    const std::string& reason) {
  absl::MutexLock lock(&log_mu_);
  const absl::Time now = absl::Now();
  if (now - window_start_ >= kLogWindow) {
    window_start_ = now;
    window_lines_ = 0;
  }
  if (window_lines_ >= kLogLinesPerWindow) {
    ++unlogged_;
    return;
  }
  ++window_lines_;
  const int64_t unlogged = unlogged_;
  unlogged_ = 0;
  LogEvent("refused", {{"peer", LogField::Str{peer}},
                       {"method", LogField::Word{method}},
                       {"status", LogField::Word{"UNAUTHENTICATED"}},
                       {"reason", LogField::Str{reason}},
                       {"earlier_refusals_not_logged", unlogged}});
}

}  // namespace tandem::server
