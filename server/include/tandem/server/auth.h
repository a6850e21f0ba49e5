// Bearer-token authentication of tandem.v1.Tandem calls (tandem-server --auth-tokens-file).
//
// Where the check runs: at the start of each Tandem handler (Extract's reactor, GetInfo),
// before anything is read or allocated. The alternatives were weighed and rejected:
//   * grpc::AuthMetadataProcessor is only accepted by secure server credentials (gRPC
//     asserts on InsecureServerCredentials), but tokens must also work on a plaintext
//     listener behind a TLS-terminating proxy; it also runs for every service, so the
//     health service would need exempting by parsing :path.
//   * Server interceptors are experimental in gRPC 1.51 and cannot end a call with a
//     status of their choosing (only cancel it: the client would see CANCELLED).
// A handler check can answer UNAUTHENTICATED with a message, leaves grpc.health.v1 and
// reflection open by construction (they are other services), and is one line per handler.
//
// The token is compared in constant time against every configured token (all of them, no
// early exit). Refusals are counted and logged on stderr with the peer, the method and
// the reason, never the token (at most 20 lines per 10 s; the rest are counted in the
// next line that is printed).
#ifndef TANDEM_SERVER_AUTH_H_
#define TANDEM_SERVER_AUTH_H_

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace tandem::server {

class TokenAuthenticator {
 public:
  // No tokens: authentication off, every call passes.
  explicit TokenAuthenticator(std::vector<std::string> tokens = {}) : tokens_(std::move(tokens)) {}

  bool enabled() const { return !tokens_.empty(); }
  // OK, or UNAUTHENTICATED saying what is wrong (no metadata, not "Bearer", unknown token).
  // `method` and the peer are only for the log line. *identity (when given): on OK, which
  // configured token the call presented (its first line in the file among equal ones), or
  // kNoIdentity when authentication is off; a session is readable by calls of its creator's.
  static constexpr int kNoIdentity = -1;
  grpc::Status Check(const grpc::ServerContextBase& context, const char* method,
                     int* identity = nullptr);
  int64_t refused() const { return refused_.load(); }

 private:
  void LogRefusal(const std::string& peer, const char* method, const std::string& reason);

  const std::vector<std::string> tokens_;
  std::atomic<int64_t> refused_{0};
  absl::Mutex log_mu_;
  absl::Time window_start_ ABSL_GUARDED_BY(log_mu_) = absl::InfinitePast();
  int window_lines_ ABSL_GUARDED_BY(log_mu_) = 0;
  int64_t unlogged_ ABSL_GUARDED_BY(log_mu_) = 0;
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_AUTH_H_
