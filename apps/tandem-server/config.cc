// tandem-server's command line: its flags (each also a TANDEM_* variable), --help, --version
// and the checks of their values.
#include "config.h"

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "absl/algorithm/container.h"
#include "absl/strings/str_format.h"
#include "apps/common/flags.h"
#include "apps/common/version.h"
#include "tandem/server/chunk_spill.h"
#include "tandem/server/log.h"

namespace tandem::server_app {
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

constexpr int64_t kIntMax = std::numeric_limits<int>::max();
constexpr int64_t kInt64Max = std::numeric_limits<int64_t>::max();
constexpr double kInf = std::numeric_limits<double>::infinity();

// Registers a numeric flag with its bounds, so that one check after parsing covers them all.
class BoundedFlags {
 public:
  explicit BoundedFlags(tandem::cli::FlagSet* flags) : flags_(flags) {}
  void Int(const char* name, int64_t* var, int64_t lo, int64_t hi, const char* help) {
    flags_->AddInt(name, var, help);
    in_range_.push_back([var, lo, hi] { return *var >= lo && *var <= hi; });
  }
  // `above_lo`: the value must exceed `lo`. NaN is out of every range.
  void Real(const char* name, double* var, double lo, double hi, const char* help,
            bool above_lo = false) {
    flags_->AddDouble(name, var, help);
    in_range_.push_back(
        [var, lo, hi, above_lo] { return (above_lo ? *var > lo : *var >= lo) && *var <= hi; });
  }
  bool AllInRange() const {
    return absl::c_all_of(in_range_, [](const std::function<bool()>& ok) { return ok(); });
  }

 private:
  tandem::cli::FlagSet* flags_;
  std::vector<std::function<bool()>> in_range_;
};

}  // namespace

int ParseServerFlags(int argc, char** argv, ServerConfig* config) {
  std::string log_format = "text";
  tandem::server::ServerLimits& limits = config->limits;
  int64_t max_sessions = limits.max_sessions;
  int64_t compute_threads = limits.compute_threads;
  int64_t session_memory_mb = limits.session_memory_bytes >> 20;
  int64_t watch_retain_mb = limits.watch_retain_bytes >> 20;
  bool quiet = false;
  tandem::cli::FlagSet flags(kUsage);
  BoundedFlags bounded(&flags);
  flags.AddString("listen", &config->listen, "HOST:PORT",
                  "address to listen on (port 0 = any free port)");
  flags.AddString("log-format", &log_format, "text|json",
                  "stderr log: one line per event, \"<RFC 3339 time> tandem-server: event "
                  "key=value ...\" (text) or one JSON object (json)");
  flags.AddBool("quiet", &quiet,
                "no log line for a session that ended OK (failures, refusals and the server's "
                "own start and stop lines still go out)");
  flags.AddString("metrics-listen", &config->metrics_listen, "HOST:PORT",
                  "serve Prometheus metrics (text format) at http://HOST:PORT/metrics, no "
                  "authentication: bind it to loopback or where only Prometheus reaches it "
                  "(GET only, no request body, Host header checked; port 0 = any free port; "
                  "empty = off)");
  flags.AddString("tls-cert", &config->tls_cert, "FILE",
                  "PEM certificate chain: serve TLS instead of plaintext (needs --tls-key)");
  flags.AddString("tls-key", &config->tls_key, "FILE", "PEM private key of --tls-cert");
  flags.AddString("auth-tokens-file", &config->tokens_file, "FILE",
                  "require `authorization: Bearer <token>` on Tandem calls (Extract, GetInfo); "
                  "FILE: one token a line, blank lines and #comments ignored, read at start-up; "
                  "the health service stays open");
  bounded.Int("max-sessions", &max_sessions, 1, 4096,
              "concurrent Extract streams; more get RESOURCE_EXHAUSTED (one worker thread each)");
  bounded.Int("compute-threads", &compute_threads, 0, 1024,
              "threads all sessions share for extraction and simplification (each stream's "
              "worker thread helps too); 0 = one per core");
  bounded.Int("max-voxels-per-slice", &limits.max_voxels_per_slice, 4, kInt64Max,
              "largest nx*ny accepted (RESOURCE_EXHAUSTED above)");
  bounded.Int("max-slices", &limits.max_slices, 2, kInt64Max,
              "largest number of slices accepted per stream");
  bounded.Int("max-message-bytes", &limits.max_message_bytes, 1024, int64_t{1} << 30,
              "largest request message accepted (bounds SliceChunk size)");
  bounded.Int("session-memory-mb", &session_memory_mb, 1, 1 << 20,
              "memory budget of one session in MiB (mesh, simplification queues, slice "
              "buffers), checked as the session grows, inside each slice's work; a stream "
              "that needs more ends with RESOURCE_EXHAUSTED and its work stops at once");
  bounded.Int("max-inflight-bytes", &limits.max_inflight_bytes, 1, int64_t{1} << 40,
              "per stream: received-but-unprocessed plus unsent response bytes; at this level "
              "the server stops reading the stream until it drains (also the stream's HTTP/2 "
              "receive window)");
  bounded.Real("max-preview-share", &limits.max_preview_share, 0, 1,
               "previews (and the sealed chunks they flush) take at most this share of a "
               "stream's wall time; the next one waits while they took more (0 = no bound)");
  bounded.Real("max-band-bytes-share", &limits.max_band_bytes_share, 0, 1e6,
               "sealed streams: band previews' bytes stay under this share of the chunks' "
               "bytes (0 = no bound)");
  bounded.Int("watch-retain-mb", &watch_retain_mb, 0, 1 << 20,
              "per session: sealed chunks kept (compressed) for watchers that come late; a "
              "session past it takes no new watcher (chunks a tandem-client stream --chunks DIR "
              "has not saved yet are kept for its resume besides, in the session's budget)");
  limits.watch_spill_dir = tandem::server::DefaultSpillDir();
  flags.AddString("watch-spill-dir", &limits.watch_spill_dir, "DIR",
                  "where a sealed session keeps the chunks for late watchers and resumes "
                  "($TMPDIR, else /tmp, unless set; empty = in memory): an unlinked temporary "
                  "file per session, so they take disk, not the server's memory; chunks the "
                  "directory cannot take (unwritable, full) stay in memory, logged once");
  bounded.Real("watch-linger-seconds", &limits.watch_linger_s, 0, 86400,
               "how long a finished session stays watchable (tandem-client watch)");
  bounded.Real("resume-window-seconds", &limits.resume_window_s, 0, 86400,
               "a stream whose client vanishes mid-scan (connection lost, killed, cancelled) "
               "keeps its session this long, for the client to resume it (tandem-client "
               "does so by itself; 0 = the session ends at once)");
  bounded.Real("idle-timeout-seconds", &limits.idle_timeout_s, 0, kInf,
               "end a stream on which nothing moves for this long: the client sends nothing "
               "(DEADLINE_EXCEEDED) or reads nothing (cancelled); frees its session slot",
               /*above_lo=*/true);
  bounded.Int("keepalive-time-ms", &limits.keepalive_time_ms, 0, kIntMax,
              "ping a connection idle this long, to find vanished clients (0 = never)");
  bounded.Int("keepalive-timeout-ms", &limits.keepalive_timeout_ms, 1, kIntMax,
              "close the connection when a ping is not answered within this");
  bounded.Int("keepalive-min-ping-interval-ms", &limits.min_ping_interval_ms, 0, kIntMax,
              "client pings closer together than this (without data) are abuse; after 2 the "
              "connection is closed (GOAWAY too_many_pings)");
  bounded.Int("min-preview-interval-ms", &limits.min_preview_interval_ms, 0, kIntMax,
              "previews of a stream are at least this far apart, whatever the client asks "
              "(each snapshots and encodes the whole partial mesh); none is encoded while the "
              "previous one is still unsent (0 = only the client's interval)");
  flags.AddBool("keepalive-permit-without-calls", &limits.permit_keepalive_without_calls,
                "accept client keepalive pings on connections with no call open");
  bounded.Int("malloc-arenas", &config->malloc_arenas, 0, 1024,
              "glibc malloc arenas (0 = glibc's default, 8 per core): few arenas keep the "
              "resident size near the idle level after bursts of sessions");
  bounded.Real("drain-delay-seconds", &config->drain_delay_seconds, 0, 3600,
               "on SIGTERM/SIGINT, time the server still accepts new streams while its "
               "health is NOT_SERVING, so that load balancers stop routing to it first (a "
               "second signal ends the delay)");
  bounded.Real("grace-seconds", &config->grace_seconds, 0, 86400,
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
  }
  tandem::server::SetLogQuiet(quiet);
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
  if (!bounded.AllInRange()) {
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
  return -1;
}

}  // namespace tandem::server_app
