// How tandem-client's subcommands report mistakes and failures, and the flags and parsing
// they share.
#include "command.h"

#include <algorithm>
#include <chrono>
#include <fstream>
#include <string>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "apps/common/cli_util.h"
#include "tandem/client/stream_client.h"

namespace tandem::client_app {

int Fail(const absl::Status& st) {
  absl::FPrintF(stderr, "tandem-client: error: %s\n", std::string(st.message()));
  return tandem::cli::kExitFailure;
}

int RpcFail(const absl::Status& st, const std::string& hint) {
  if (tandem::client::IsLocalError(st)) return Fail(st);  // reading the volume mid-stream
  absl::FPrintF(stderr, "tandem-client: error: %s: %s%s\n", absl::StatusCodeToString(st.code()),
                std::string(st.message()), hint.empty() ? "" : absl::StrCat(" (", hint, ")"));
  return tandem::cli::kExitFailure;
}

int UsageError(const absl::Status& st) {
  absl::FPrintF(stderr, "tandem-client: %s\n", st.message());
  return tandem::cli::kExitUsage;
}

void ConnectionFlags::Add(FlagSet& flags, bool token) {
  with_token = token;
  flags.AddString("server", &options.server, "HOST:PORT", "tandem-server address");
  flags.AddString("tls-ca", &options.tls_ca_file, "FILE",
                  "connect with TLS and verify the server against these PEM roots");
  flags.AddBool("tls", &options.tls, "connect with TLS, verified against the system's roots");
  flags.AddString("tls-server-name", &options.tls_server_name, "NAME",
                  "name the server's certificate must carry, when not the host of --server");
  flags.AddString("lb", &options.lb_policy, "pick_first|round_robin",
                  "how calls spread over the addresses --server resolves to (round_robin "
                  "with a DNS name of several replicas, or ipv4:HOST:PORT,HOST:PORT)");
  int64_t* retries = &retries_flag;
  flags.AddInt("retries", retries,
               "send a stream again when the server refuses it at the door (RESOURCE_EXHAUSTED: "
               "all session slots taken; UNAVAILABLE: going away or not there), up to N times "
               "(0..4), backoff 0.5 s doubling to 5 s; no slice is read before the server "
               "takes the stream, and limits it marks final are not retried");
  if (token) {
    flags.AddString("token-file", &token_file, "FILE",
                    "send the first token of FILE as `authorization: Bearer`; without it, "
                    "the token in $TANDEM_TOKEN (if set) is sent");
  }
}

int ConnectionFlags::Finish() {
  options.retries = static_cast<int>(std::clamp<int64_t>(retries_flag, -1, 5));
  if (absl::StatusOr<std::string> config = tandem::client::ServiceConfigJson(options);
      !config.ok()) {
    absl::FPrintF(stderr, "tandem-client: %s\n", std::string(config.status().message()));
    return 2;
  }
  if (!with_token) return -1;
  absl::StatusOr<std::string> token = tandem::client::LoadToken(token_file);
  if (!token.ok()) return client_app::Fail(token.status());  // a file or the environment, read
  options.token = *std::move(token);
  return -1;
}

int ConnectionFlags::Fail(const absl::Status& st) const {
  return RpcFail(st, tandem::client::ConnectionHint(options, st));
}

int ParseOrExit(FlagSet& flags, int argc, char** argv, ConnectionFlags* connection) {
  // TANDEM_SERVER etc., as in deploy/README.md (the token itself: TANDEM_TOKEN, no flag).
  flags.UseEnvironment("TANDEM_",
                       {"server", "tls-ca", "tls-server-name", "token-file", "lb", "retries"});
  if (absl::Status st = flags.Parse(argc, argv, 2); !st.ok()) {
    absl::FPrintF(stderr, "tandem-client: %s\n", std::string(st.message()));
    return 2;
  }
  if (flags.help_requested()) {
    absl::PrintF("%s", flags.Help());
    return 0;
  }
  if (!flags.positional().empty()) {
    absl::FPrintF(stderr, "tandem-client: unexpected argument '%s' (see --help)\n",
                  flags.positional().front());
    return 2;
  }
  return connection->Finish();
}

std::string Lower(std::string s) { return absl::AsciiStrToLower(s); }

absl::Status WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) return absl::UnavailableError(absl::StrCat(path, ": cannot write"));
  return absl::OkStatus();
}

void SetDeadline(grpc::ClientContext* context, double seconds) {
  context->set_deadline(std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000)));
}

}  // namespace tandem::client_app
