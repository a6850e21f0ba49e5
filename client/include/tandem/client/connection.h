// How tandem-client reaches tandem-server: plaintext or TLS, with or without a bearer
// token, with HTTP/2 keepalive. Shared by the stream, info and health commands (and the
// service tests, which link the client library).
#ifndef TANDEM_CLIENT_CONNECTION_H_
#define TANDEM_CLIENT_CONNECTION_H_

#include <grpcpp/grpcpp.h>

#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace tandem::client {

struct ConnectionOptions {
  std::string server;             // HOST:PORT or any gRPC target (dns:///name:port)
  std::string tls_ca_file;        // PEM roots to verify the server with; "" = see `tls`
  bool tls = false;               // TLS with the system's roots when tls_ca_file is ""
  std::string tls_server_name;    // name expected in the certificate ("" = the target's host)
  std::string token;              // bearer token, "" = none
  int64_t keepalive_time_ms = 0;  // ping an idle connection this often while a call is open
  int max_receive_bytes = 0;      // 0 = gRPC's default
  // How calls are spread over the addresses the target resolves to: "pick_first" (one
  // connection, gRPC's default) or "round_robin" (every ready address in turn: with a
  // headless Service's DNS name, streams spread over the replicas).
  std::string lb_policy = "pick_first";
  // Extract streams refused with UNAVAILABLE (no server, or one shutting down) or
  // RESOURCE_EXHAUSTED (all sessions busy) before anything came back are sent again up to
  // this many times (0..4), with exponential backoff from 0.5 s to 5 s (StreamVolume does
  // it; no slice is sent before the server's first message); errors the server marks final
  // (a request over its limits) are never retried.
  int retries = 4;

  bool uses_tls() const { return tls || !tls_ca_file.empty(); }
};

// The gRPC service config for lb_policy (JSON; retries checked too), or an error naming
// the flag.
absl::StatusOr<std::string> ServiceConfigJson(const ConnectionOptions& options);

// The channel for `options` (reads tls_ca_file: an error names it).
absl::StatusOr<std::shared_ptr<grpc::Channel>> MakeChannel(const ConnectionOptions& options);

// Adds `authorization: Bearer <token>` to a call when options.token is set.
void AddToken(const ConnectionOptions& options, grpc::ClientContext* context);

// The client's token: the first token of `token_file` when given (the server's tokens
// file format: tandem/common/tokens.h), else $TANDEM_TOKEN, else "". Errors name the file or the
// variable, never the token.
absl::StatusOr<std::string> LoadToken(const std::string& token_file);

// A hint for a failed call: what to check given how it connected ("" = none).
std::string ConnectionHint(const ConnectionOptions& options, const absl::Status& status);

}  // namespace tandem::client

#endif  // TANDEM_CLIENT_CONNECTION_H_
