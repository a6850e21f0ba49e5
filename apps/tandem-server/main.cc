// tandem-server: serves tandem.v1.Tandem (see proto/tandem/v1/tandem.proto) over gRPC.
// This file only parses flags, builds the server and handles SIGTERM/SIGINT: it marks the
// server NOT_SERVING (health service "" and tandem.v1.Tandem; "liveness" stays SERVING),
// keeps accepting streams for --drain-delay-seconds (load balancers notice meanwhile; a
// second signal cuts the delay short), then stops accepting (a stand-in keeps answering
// health checks the same way on the port until the exit: server/drain_stand_in.h), lets
// running streams finish for --grace-seconds, ends the rest with UNAVAILABLE, waits for
// their worker threads, and exits 0.
#include <malloc.h>  // mallopt (glibc)
#include <pthread.h>
#include <signal.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <grpc/grpc.h>  // grpc_server_cancel_all_calls
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "apps/common/version.h"
#include "apps/common/cli_util.h"
#include "apps/common/flags.h"
#include "common/tokens.h"
#include "common/wire.h"
#include "net/http_guard.h"
#include "net/listen.h"
#include "server/drain_stand_in.h"
#include "server/log.h"
#include "server/request_validation.h"
#include "server/tandem_service.h"
#include "server/tls_check.h"

namespace {

constexpr char kUsage[] =
    "usage: tandem-server [flags]\n"
    "Serves tandem.v1.Tandem: streams of volume slices in, simplified iso-surface meshes\n"
    "(Draco) out, plus the standard gRPC health service and server reflection.\n"
    "Prints \"listening on HOST:PORT\" on stdout once ready (--listen with port 0 picks a\n"
    "free port), one line per session on stderr, and exits 0 after SIGTERM or SIGINT.\n"
    "Security: --tls-cert/--tls-key for TLS, --auth-tokens-file for bearer tokens (refused\n"
    "calls get UNAUTHENTICATED and a stderr line with the peer and the reason, never the\n"
    "token). Every flag can also be set by the TANDEM_* variable shown; the flag wins.";

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
  std::string listen = tandem::wire::kDefaultServerAddress;
  std::string tls_cert, tls_key, tokens_file, metrics_listen;
  std::string log_format = "text";
  tandem::server::ServerLimits limits;
  int64_t max_sessions = limits.max_sessions;
  int64_t compute_threads = limits.compute_threads;
  int64_t session_memory_mb = limits.session_memory_bytes >> 20;
  int64_t watch_retain_mb = limits.watch_retain_bytes >> 20;
  double grace_seconds = 10;
  double drain_delay_seconds = 0;
  int64_t malloc_arenas = 2;
  bool quiet = false;
  tandem::cli::FlagSet flags(kUsage);
  flags.AddString("listen", &listen, "HOST:PORT", "address to listen on (port 0 = any free port)");
  flags.AddString("log-format", &log_format, "text|json",
                  "stderr log: one line per event, \"<RFC 3339 time> tandem-server: event "
                  "key=value ...\" (text) or one JSON object (json)");
  flags.AddBool("quiet", &quiet,
                "no log line for a session that ended OK (failures, refusals and the server's "
                "own start and stop lines still go out)");
  flags.AddString("metrics-listen", &metrics_listen, "HOST:PORT",
                  "serve Prometheus metrics (text format) at http://HOST:PORT/metrics, no "
                  "authentication: bind it to loopback or where only Prometheus reaches it "
                  "(GET only, no request body, Host header checked; port 0 = any free port; "
                  "empty = off)");
  flags.AddString("tls-cert", &tls_cert, "FILE",
                  "PEM certificate chain: serve TLS instead of plaintext (needs --tls-key)");
  flags.AddString("tls-key", &tls_key, "FILE", "PEM private key of --tls-cert");
  flags.AddString("auth-tokens-file", &tokens_file, "FILE",
                  "require `authorization: Bearer <token>` on Tandem calls (Extract, GetInfo); "
                  "FILE: one token a line, blank lines and #comments ignored, read at start-up; "
                  "the health service stays open");
  flags.AddInt("max-sessions", &max_sessions,
               "concurrent Extract streams; more get RESOURCE_EXHAUSTED (one worker thread each)");
  flags.AddInt("compute-threads", &compute_threads,
               "threads all sessions share for extraction and simplification (each stream's "
               "worker thread helps too); 0 = one per core");
  flags.AddInt("max-voxels-per-slice", &limits.max_voxels_per_slice,
               "largest nx*ny accepted (RESOURCE_EXHAUSTED above)");
  flags.AddInt("max-slices", &limits.max_slices, "largest number of slices accepted per stream");
  flags.AddInt("max-message-bytes", &limits.max_message_bytes,
               "largest request message accepted (bounds SliceChunk size)");
  flags.AddInt("session-memory-mb", &session_memory_mb,
               "memory budget of one session in MiB (mesh, simplification queues, slice "
               "buffers), checked as the session grows, inside each slice's work; a stream "
               "that needs more ends with RESOURCE_EXHAUSTED and its work stops at once");
  flags.AddInt("max-inflight-bytes", &limits.max_inflight_bytes,
               "per stream: received-but-unprocessed plus unsent response bytes; at this level "
               "the server stops reading the stream until it drains (also the stream's HTTP/2 "
               "receive window)");
  flags.AddDouble("max-preview-share", &limits.max_preview_share,
                  "previews (and the sealed chunks they flush) take at most this share of a "
                  "stream's wall time; the next one waits while they took more (0 = no bound)");
  flags.AddDouble("max-band-bytes-share", &limits.max_band_bytes_share,
                  "sealed streams: band previews' bytes stay under this share of the chunks' "
                  "bytes (0 = no bound)");
  flags.AddInt("watch-retain-mb", &watch_retain_mb,
               "per session: sealed chunks kept (compressed) for watchers that come late; a "
               "session past it takes no new watcher (chunks a tandem-client stream --chunks DIR "
               "has not saved yet are kept for its resume besides, in the session's budget)");
  flags.AddDouble("watch-linger-seconds", &limits.watch_linger_s,
                  "how long a finished session stays watchable (tandem-client watch)");
  flags.AddDouble("resume-window-seconds", &limits.resume_window_s,
                  "a stream whose client vanishes mid-scan (connection lost, killed, cancelled) "
                  "keeps its session this long, for the client to resume it (tandem-client "
                  "does so by itself; 0 = the session ends at once)");
  flags.AddDouble("idle-timeout-seconds", &limits.idle_timeout_s,
                  "end a stream on which nothing moves for this long: the client sends nothing "
                  "(DEADLINE_EXCEEDED) or reads nothing (cancelled); frees its session slot");
  flags.AddInt("keepalive-time-ms", &limits.keepalive_time_ms,
               "ping a connection idle this long, to find vanished clients (0 = never)");
  flags.AddInt("keepalive-timeout-ms", &limits.keepalive_timeout_ms,
               "close the connection when a ping is not answered within this");
  flags.AddInt("keepalive-min-ping-interval-ms", &limits.min_ping_interval_ms,
               "client pings closer together than this (without data) are abuse; after 2 the "
               "connection is closed (GOAWAY too_many_pings)");
  flags.AddInt("min-preview-interval-ms", &limits.min_preview_interval_ms,
               "previews of a stream are at least this far apart, whatever the client asks "
               "(each snapshots and encodes the whole partial mesh); none is encoded while the "
               "previous one is still unsent (0 = only the client's interval)");
  flags.AddBool("keepalive-permit-without-calls", &limits.permit_keepalive_without_calls,
                "accept client keepalive pings on connections with no call open");
  flags.AddInt("malloc-arenas", &malloc_arenas,
               "glibc malloc arenas (0 = glibc's default, 8 per core): few arenas keep the "
               "resident size near the idle level after bursts of sessions");
  flags.AddDouble("drain-delay-seconds", &drain_delay_seconds,
                  "on SIGTERM/SIGINT, time the server still accepts new streams while its "
                  "health is NOT_SERVING, so that load balancers stop routing to it first (a "
                  "second signal ends the delay)");
  flags.AddDouble("grace-seconds", &grace_seconds,
                  "then, time running streams get to finish; the rest end with UNAVAILABLE");
  flags.UseEnvironment("TANDEM_");  // containers configure through TANDEM_* variables
  if (argc == 2 && std::string_view(argv[1]) == "--version") {
    absl::PrintF("%s", TANDEM_VERSION_LINE("tandem-server"));
    return 0;
  }
  if (absl::Status st = flags.Parse(argc, argv); !st.ok()) {
    absl::FPrintF(stderr, "tandem-server: %s\n", std::string(st.message()));
    return 2;
  }
  if (flags.help_requested()) {
    absl::PrintF("%s", flags.Help());
    return 0;
  }  tandem::server::SetLogQuiet(quiet);
  if (log_format == "json") {
    tandem::server::SetLogFormat(tandem::server::LogFormat::kJson);
  } else if (log_format != "text") {
    absl::FPrintF(stderr, "tandem-server: --log-format: expected text or json, got \"%s\"\n",
                  tandem::server::LogQuoted(log_format));
    return 2;
  }

  if (!flags.positional().empty()) {
    absl::FPrintF(stderr, "tandem-server: unexpected argument '%s' (see --help)\n",
                  flags.positional().front());
    return 2;
  }
  constexpr int64_t kIntMax = std::numeric_limits<int>::max();
  auto ms_ok = [](int64_t v, int64_t lo) { return v >= lo && v <= kIntMax; };
  if (max_sessions < 1 || max_sessions > 4096 || compute_threads < 0 || compute_threads > 1024 ||
      limits.max_voxels_per_slice < 4 ||
      limits.max_slices < 2 || limits.max_message_bytes < 1024 ||
      limits.max_message_bytes > (int64_t{1} << 30) || !(grace_seconds >= 0) ||
      !(grace_seconds <= 86400) || !(drain_delay_seconds >= 0) || !(drain_delay_seconds <= 3600) ||
      !(limits.idle_timeout_s > 0) || session_memory_mb < 1 || session_memory_mb > (1 << 20) ||
      limits.max_inflight_bytes < 1 || limits.max_inflight_bytes > (int64_t{1} << 40) ||
      !ms_ok(limits.keepalive_time_ms, 0) || !ms_ok(limits.keepalive_timeout_ms, 1) ||
      !ms_ok(limits.min_ping_interval_ms, 0) || !ms_ok(limits.min_preview_interval_ms, 0) ||
      malloc_arenas < 0 || malloc_arenas > 1024 || watch_retain_mb < 0 ||
      watch_retain_mb > (1 << 20) || !(limits.watch_linger_s >= 0) ||
      !(limits.watch_linger_s <= 86400) || !(limits.resume_window_s >= 0) ||
      !(limits.resume_window_s <= 86400) || !(limits.max_preview_share >= 0) ||
      !(limits.max_preview_share <= 1) || !(limits.max_band_bytes_share >= 0) ||
      !(limits.max_band_bytes_share <= 1e6)) {
    absl::FPrintF(stderr,
                  "tandem-server: out of range: need 1 <= --max-sessions <= 4096, "
                  "0 <= --compute-threads <= 1024, "
                  "--max-voxels-per-slice >= 4, --max-slices >= 2, 1024 <= "
                  "--max-message-bytes <= 2^30, 0 <= --grace-seconds <= 86400, "
                  "0 <= --drain-delay-seconds <= 3600, "
                  "--idle-timeout-seconds > 0, 1 <= --session-memory-mb <= 2^20, "
                  "1 <= --max-inflight-bytes <= 2^40, 0 <= --keepalive-time-ms and "
                  "--keepalive-min-ping-interval-ms, --min-preview-interval-ms <= 2^31-1, "
                  "1 <= --keepalive-timeout-ms <= 2^31-1, 0 <= --malloc-arenas <= 1024, "
                  "0 <= --watch-retain-mb <= 2^20, 0 <= --watch-linger-seconds <= 86400, "
                  "0 <= --resume-window-seconds <= 86400, "
                  "0 <= --max-preview-share <= 1, 0 <= --max-band-bytes-share\n");
    return 2;
  }
  limits.max_sessions = static_cast<int>(max_sessions);
  limits.compute_threads = static_cast<int>(compute_threads);
  limits.session_memory_bytes = session_memory_mb << 20;
  limits.watch_retain_bytes = watch_retain_mb << 20;
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
    absl::StatusOr<std::vector<std::string>> read = tandem::auth::ReadTokensFile(tokens_file);
    if (read.ok() && read->empty()) {
      read = absl::InvalidArgumentError(absl::StrCat(
          tokens_file, ": no token in the file (one per line; blank lines and #comments are "
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
    tandem::server::LogLine(absl::StrFormat(
        "cannot listen on --listen %s: %s", listen,
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
  // --max-inflight-bytes says, not what gRPC's BDP probing would grow it to. With probing, a
  // fast client made each stream's window grow to tens of MiB on loopback, buffered by gRPC
  // outside every budget: 4 full-resolution streams at --session-memory-mb 80 peaked at up
  // to 394 MiB against the 371 MiB the budgets allow (without probing, 259-303 MiB).
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
  server->GetHealthCheckService()->SetServingStatus(tandem::v1::Tandem::service_full_name(),
                                                    true);
  absl::PrintF("listening on %s:%d\n", host, port);
  std::fflush(stdout);
  tandem::server::LogLine(
      absl::StrFormat("%s listening on %s:%d (max %d sessions, %d MiB each; %s; %s)",
                      tandem::wire::ServiceVersion(), host, port, limits.max_sessions,
                      session_memory_mb, tls ? "TLS" : "plaintext",
                      token_count > 0 ? absl::StrCat("bearer tokens: ", token_count)
                                      : std::string("no authentication")));
  if (token_count > 0 && !tls && host != "127.0.0.1" && host != "localhost" && host != "[::1]") {
    tandem::server::LogLine(
        absl::StrFormat("warning: bearer tokens without TLS travel in clear text; use "
                        "--tls-cert/--tls-key or a TLS-terminating proxy on a trusted network"));
  }

  // The metrics endpoint: its own small HTTP server (cpp-httplib behind net/http_guard.h).
  std::unique_ptr<tandem::net::GuardedHttpServer> http;
  if (!metrics_listen.empty()) {
    const size_t colon = metrics_listen.rfind(':');
    int mport = -1;
    std::string mhost = metrics_listen.substr(0, colon == std::string::npos ? 0 : colon);
    if (mhost.size() >= 2 && mhost.front() == '[' && mhost.back() == ']') {
      mhost = mhost.substr(1, mhost.size() - 2);
    }
    if (colon == std::string::npos || mhost.empty() ||
        !absl::SimpleAtoi(metrics_listen.substr(colon + 1), &mport) || mport < 0 ||
        mport > 65535) {
      tandem::server::LogLine(absl::StrFormat(
          "--metrics-listen \"%s\": expected HOST:PORT", tandem::server::LogQuoted(metrics_listen)));
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
    tandem::server::LogLine(absl::StrFormat("metrics on http://%s:%d/metrics",
                                            colon > 0 && metrics_listen[0] == '['
                                                ? absl::StrCat("[", mhost, "]")
                                                : mhost,
                                            *bound));
  }

  std::unique_ptr<tandem::server::DrainStandIn> stand_in;  // from the end of the drain delay
  std::thread signal_thread([&] {
    int sig = 0;
    sigwait(&signals, &sig);
    const char* name = sig == SIGTERM ? "SIGTERM" : "SIGINT";
    // Readiness fails from now on; liveness (its own service name) does not.
    grpc::HealthCheckServiceInterface* health = server->GetHealthCheckService();
    health->SetServingStatus("", false);
    health->SetServingStatus(tandem::v1::Tandem::service_full_name(), false);
    auto seconds = [](double s) {
      return std::chrono::milliseconds(static_cast<int64_t>(s * 1000));
    };
    // Waits up to `s` seconds for another signal; true if one came.
    auto another_signal = [&](double s) {
      const int64_t ms = static_cast<int64_t>(s * 1000);
      timespec ts{static_cast<time_t>(ms / 1000), static_cast<long>(ms % 1000) * 1000000};
      while (true) {
        const int got = sigtimedwait(&signals, nullptr, &ts);
        if (got > 0) return true;
        if (errno != EINTR) return false;  // EAGAIN: the time is up
      }
    };
    if (drain_delay_seconds > 0) {
      tandem::server::LogLine(absl::StrFormat(
          "%s: NOT_SERVING; still accepting streams for %.1f s (--drain-delay-seconds)", name,
          drain_delay_seconds));
      if (another_signal(drain_delay_seconds)) {
        tandem::server::LogLine("second signal: the drain delay is cut short");
      }
    }
    tandem::server::LogLine(absl::StrFormat(
        "%s: draining: new streams are refused; running ones (%d) have %.1f s to finish", name,
        service.CountersSnapshot().active_sessions(), grace_seconds));
    const auto deadline = std::chrono::steady_clock::now() + seconds(grace_seconds);
    // Shutdown returns as soon as every call is done; its own deadline (a little after
    // ours) only cancels what did not even take UNAVAILABLE (a client that does not read).
    std::atomic<bool> shutdown_started{false}, shutdown_done{false};
    std::thread stopper([&] {
      shutdown_started = true;
      server->Shutdown(std::chrono::system_clock::now() + seconds(grace_seconds + 5));
      shutdown_done = true;
    });
    stand_in = tandem::server::DrainStandIn::Start(host, port, credentials, absl::Seconds(2));
    if (stand_in == nullptr) {
      tandem::server::LogLine(absl::StrFormat(
          "%s:%d was taken by another process while draining: health checks go unanswered",
          host, port));
    }
    while (service.CountersSnapshot().active_sessions() > 0 &&
           std::chrono::steady_clock::now() < deadline) {
      if (another_signal(0.05)) break;  // yet another signal: end the streams now
    }
    const int64_t ended = service.EndAllStreams(grpc::Status(
        grpc::StatusCode::UNAVAILABLE,
        absl::StrFormat("tandem-server is shutting down and the stream did not finish within "
                        "its --grace-seconds (%g s); send the scan again (to another replica)",
                        grace_seconds)));
    if (ended > 0) {
      tandem::server::LogLine(
          absl::StrFormat("grace period over: %d streams ended with UNAVAILABLE", ended));
    }
    // Once every stream has delivered its status (a client that does not read keeps its
    // own until Shutdown's deadline), nothing is left but connections, and gRPC's graceful
    // GOAWAY waits for each client to answer a ping: an idle C++ client channel answers
    // only at its 5 s backup poll, one that never answers after 20 s. Cut them.
    // (grpc::Server::c_server is marked experimental; grpc_server_cancel_all_calls is
    // the C API's documented way to end a shutdown early, and it closes the connections.)
    const auto slack = std::chrono::steady_clock::now() + seconds(5);
    while (!shutdown_done &&
           (!shutdown_started || service.CountersSnapshot().active_sessions() > 0) &&
           std::chrono::steady_clock::now() < slack) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    // One more second for connections that close by themselves (a client reading its
    // last status answers the GOAWAY at once), so that none is cut with bytes in flight.
    const auto settle = std::chrono::steady_clock::now() + seconds(1);
    while (!shutdown_done && std::chrono::steady_clock::now() < settle) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    if (!shutdown_done && shutdown_started && service.CountersSnapshot().active_sessions() == 0) {
      grpc_server_cancel_all_calls(server->c_server());
    }
    stopper.join();
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
