// tandem-server: serves tandem.v1.Tandem (see proto/tandem/v1/tandem.proto) over gRPC. This
// file builds the server from its configuration (config.h): credentials, the listening port,
// the health and reflection services, the metrics endpoint; a thread takes SIGTERM/SIGINT and
// drains the server (drain.h); then the workers are waited for and the process exits 0.
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <malloc.h>  // mallopt (glibc)
#include <pthread.h>
#include <signal.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "apps/common/cli_util.h"
#include "config.h"
#include "drain.h"
#include "tandem/common/tokens.h"
#include "tandem/common/wire.h"
#include "tandem/net/http_guard.h"
#include "tandem/net/listen.h"
#include "tandem/server/chunk_spill.h"
#include "tandem/server/drain_stand_in.h"
#include "tandem/server/log.h"
#include "tandem/server/tandem_service.h"
#include "tandem/server/tls_check.h"

namespace {

absl::StatusOr<std::string> ReadFile(const std::string& flag, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::NotFoundError(
        absl::StrCat("--", flag, " ", path, ": cannot open (", std::strerror(errno), ")"));
  }
  std::stringstream ss;
  ss << in.rdbuf();
  if (ss.str().find("-----BEGIN ") == std::string::npos) {
    return absl::InvalidArgumentError(absl::StrCat("--", flag, " ", path, ": not a PEM file"));
  }
  return ss.str();
}

}  // namespace

int main(int argc, char** argv) {
  tandem::server_app::ServerConfig config;
  if (int rc = tandem::server_app::ParseServerFlags(argc, argv, &config); rc >= 0) return rc;
  tandem::server::ServerLimits& limits = config.limits;
  const std::string &listen = config.listen, &metrics_listen = config.metrics_listen;
  const std::string &tls_cert = config.tls_cert, &tls_key = config.tls_key;
  const std::string& tokens_file = config.tokens_file;
  const int64_t malloc_arenas = config.malloc_arenas;
#if defined(__GLIBC__)
  // Every session runs on a new thread, and glibc gives new threads new arenas (up to 8
  // per core); each keeps a few hundred KiB after malloc_trim, so a burst of sessions
  // would leave the server a few MiB larger for good. Set before any thread exists.
  if (malloc_arenas > 0) mallopt(M_ARENA_MAX, static_cast<int>(malloc_arenas));
#endif

  // Block the shutdown signals in every thread (gRPC's included, so set before any is
  // created: before the first gRPC object, credentials included); one thread takes them
  // with sigwait.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  // Credentials: TLS when a certificate is given; tokens when a file is.
  if (tls_cert.empty() != tls_key.empty()) {
    absl::FPrintF(stderr, "tandem-server: --tls-cert and --tls-key go together\n");
    return 2;
  }
  std::shared_ptr<grpc::ServerCredentials> credentials = grpc::InsecureServerCredentials();
  const bool tls = !tls_cert.empty();
  if (tls) {
    absl::StatusOr<std::string> cert = ReadFile("tls-cert", tls_cert);
    absl::StatusOr<std::string> key = ReadFile("tls-key", tls_key);
    for (const auto* pem : {&cert, &key}) {
      if (!pem->ok()) {
        absl::FPrintF(stderr, "tandem-server: %s\n", std::string(pem->status().message()));
        return tandem::cli::kExitFailure;
      }
    }
    if (absl::Status pair = tandem::server::CheckCertificateAndKey(*cert, *key, tls_cert, tls_key);
        !pair.ok()) {
      absl::FPrintF(stderr, "tandem-server: %s\n", std::string(pair.message()));
      return tandem::cli::kExitFailure;
    }
    grpc::SslServerCredentialsOptions ssl;
    ssl.pem_key_cert_pairs.push_back({*key, *cert});
    credentials = grpc::SslServerCredentials(ssl);
  }
  std::vector<std::string> tokens;
  if (!tokens_file.empty()) {
    absl::StatusOr<std::vector<std::string>> read = tandem::common::ReadTokensFile(tokens_file);
    if (read.ok() && read->empty()) {
      read = absl::InvalidArgumentError(
          absl::StrCat(tokens_file,
                       ": no token in the file (one per line; blank lines and #comments are "
                       "ignored)"));
    }
    if (!read.ok()) {
      absl::FPrintF(stderr, "tandem-server: --auth-tokens-file: %s\n",
                    std::string(read.status().message()));
      return tandem::cli::kExitFailure;
    }
    tokens = *std::move(read);
  }

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  const size_t token_count = tokens.size();
  tandem::server::TandemService service(limits, std::move(tokens), tls);
  // HOST:PORT of --listen, for messages ("" and -1 when it is not of that form).
  const std::string host = listen.substr(0, listen.rfind(':'));
  std::string bare_host = host;
  if (bare_host.size() >= 2 && bare_host.front() == '[' && bare_host.back() == ']') {
    bare_host = bare_host.substr(1, bare_host.size() - 2);
  }
  int wanted_port = -1;
  if (listen.find(':') == std::string::npos ||
      !absl::SimpleAtoi(listen.substr(listen.rfind(':') + 1), &wanted_port)) {
    wanted_port = -1;
  }
  auto cannot_listen = [&] {
    tandem::server::LogLine(
        absl::StrFormat("cannot listen on --listen %s: %s", listen,
                        wanted_port >= 0 ? tandem::net::DescribeBindFailure(bare_host, wanted_port)
                                         : std::string("expected HOST:PORT")));
    // A malformed address is the command line's mistake; a port taken is the machine's.
    return wanted_port >= 0 ? tandem::cli::kExitFailure : tandem::cli::kExitUsage;
  };
  // A port another process listens on is refused here, before gRPC logs its own error.
  if (wanted_port > 0 && tandem::net::ListenError(bare_host, wanted_port) != 0) {
    return cannot_listen();
  }
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(listen, credentials, &port);
  builder.SetMaxReceiveMessageSize(static_cast<int>(limits.max_message_bytes));
  // Keepalive: find connections whose peer vanished without a FIN or RST (a powered-off
  // scanner PC, a NAT that dropped the flow) long before the idle timeout would.
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS,
                             limits.keepalive_time_ms > 0
                                 ? static_cast<int>(limits.keepalive_time_ms)
                                 : std::numeric_limits<int>::max());
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS,
                             static_cast<int>(limits.keepalive_timeout_ms));
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS,
                             static_cast<int>(limits.min_ping_interval_ms));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS,
                             limits.permit_keepalive_without_calls ? 1 : 0);
  // The receive window of a stream: what it may have received but not yet processed, as
  // --max-inflight-bytes says, not what gRPC's BDP probing would grow it to: that is buffered
  // by gRPC outside every budget (docs/decisions.md 38).
  builder.AddChannelArgument(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  // gRPC binds with SO_REUSEPORT by default: a second server on a port another one listens on
  // would start too, and the kernel would split new connections between them.
  builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
  builder.AddChannelArgument(
      GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES,
      static_cast<int>(std::min<int64_t>(limits.max_inflight_bytes, int64_t{1} << 30)));
  builder.RegisterService(&service);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (server == nullptr || port == 0) return cannot_listen();
  // Kubernetes probes: readiness checks "" (NOT_SERVING from the first signal on),
  // liveness checks "liveness" (SERVING until the process exits).
  server->GetHealthCheckService()->SetServingStatus("liveness", true);
  server->GetHealthCheckService()->SetServingStatus(tandem::v1::Tandem::service_full_name(), true);
  absl::PrintF("listening on %s:%d\n", host, port);
  std::fflush(stdout);
  tandem::server::LogLine(
      absl::StrFormat("%s listening on %s:%d (max %d sessions, %d MiB each; %s; %s)",
                      tandem::common::ServiceVersion(), host, port, limits.max_sessions,
                      limits.session_memory_bytes >> 20, tls ? "TLS" : "plaintext",
                      token_count > 0 ? absl::StrCat("bearer tokens: ", token_count)
                                      : std::string("no authentication")));
  if (token_count > 0 && !tls && host != "127.0.0.1" && host != "localhost" && host != "[::1]") {
    tandem::server::LogLine(
        absl::StrFormat("warning: bearer tokens without TLS travel in clear text; use "
                        "--tls-cert/--tls-key or a TLS-terminating proxy on a trusted network"));
  }
  if (!limits.watch_spill_dir.empty()) {
    // Checked once here so that an operator reads it at start-up, not at the first sealed chunk.
    if (auto spill = tandem::server::SpillFile::Create(limits.watch_spill_dir); !spill.ok()) {
      tandem::server::LogLine(absl::StrCat("warning: ", spill.status().message(),
                                           "; sealed chunks kept for watchers and resumes stay "
                                           "in memory (--watch-spill-dir)"));
    }
  }

  // The metrics endpoint: its own small HTTP server (cpp-httplib behind tandem/net/http_guard.h).
  std::unique_ptr<tandem::net::GuardedHttpServer> http;
  if (!metrics_listen.empty()) {
    const size_t colon = metrics_listen.rfind(':');
    int mport = -1;
    std::string mhost = metrics_listen.substr(0, colon == std::string::npos ? 0 : colon);
    if (mhost.size() >= 2 && mhost.front() == '[' && mhost.back() == ']') {
      mhost = mhost.substr(1, mhost.size() - 2);
    }
    if (colon == std::string::npos || mhost.empty() ||
        !absl::SimpleAtoi(metrics_listen.substr(colon + 1), &mport) || mport < 0 || mport > 65535) {
      tandem::server::LogLine(absl::StrFormat("--metrics-listen \"%s\": expected HOST:PORT",
                                              tandem::server::LogQuoted(metrics_listen)));
      server->Shutdown();
      return 2;
    }
    http = std::make_unique<tandem::net::GuardedHttpServer>();
    http->Get("/metrics", [&service](const httplib::Request&, httplib::Response& res) {
      res.set_content(service.MetricsText(), "text/plain; version=0.0.4; charset=utf-8");
    });
    absl::StatusOr<int> bound = http->Start(mhost, mport);
    if (!bound.ok()) {
      tandem::server::LogLine(absl::StrCat("--metrics-listen: ", bound.status().message()));
      server->Shutdown();
      return 1;
    }
    tandem::server::LogLine(absl::StrFormat(
        "metrics on http://%s:%d/metrics",
        colon > 0 && metrics_listen[0] == '[' ? absl::StrCat("[", mhost, "]") : mhost, *bound));
  }

  std::unique_ptr<tandem::server::DrainStandIn> stand_in;  // from the end of the drain delay
  std::thread signal_thread([&] {
    int sig = 0;
    sigwait(&signals, &sig);
    tandem::server_app::Drain(
        sig == SIGTERM ? "SIGTERM" : "SIGINT", signals, *server, service,
        {config.drain_delay_seconds, config.grace_seconds, host, port, credentials}, &stand_in);
  });
  server->Wait();
  signal_thread.join();
  if (http) http->Stop();
  // Workers notice the cancellation between slices; a slice takes well under a second.
  if (!service.WaitForWorkers(absl::Now() + absl::Seconds(30))) {
    tandem::server::LogLine(absl::StrFormat("worker threads still busy after 30 s; exiting"));
    return 1;
  }
  tandem::server::LogLine(absl::StrFormat("stopped"));
  return 0;
}