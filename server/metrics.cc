#include "metrics.h"

#include <cstdint>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace tandem::server {
namespace {

class Writer {
 public:
  // One metric family: HELP, TYPE, then its samples.
  void Family(const char* name, const char* type, const char* help) {
    absl::StrAppendFormat(&out_, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
  }
  void Sample(const char* name, int64_t value, const std::string& labels = "") {
    absl::StrAppend(&out_, name, labels, " ", value, "\n");
  }
  void Sample(const char* name, double value, const std::string& labels) {
    absl::StrAppendFormat(&out_, "%s%s %.6f\n", name, labels, value);
  }
  void One(const char* name, const char* type, const char* help, int64_t value) {
    Family(name, type, help);
    Sample(name, value);
  }
  std::string Take() { return std::move(out_); }

 private:
  std::string out_;
};

}  // namespace

std::string PrometheusText(const ServiceState& s) {
  Writer w;
  w.One("tandem_active_sessions", "gauge", "Extract streams accepted and not yet cleaned up.",
        s.active_sessions.load());
  w.One("tandem_max_sessions", "gauge", "tandem-server --max-sessions.", s.limits.max_sessions);
  w.One("tandem_sessions_waiting_for_resume", "gauge",
        "Sessions whose client vanished mid-scan, kept for a resume (--resume-window-seconds).",
        s.resumable.parked());
  w.One("tandem_sessions_started_total", "counter", "Extract streams accepted.",
        s.sessions_started.load());
  w.One("tandem_sessions_rejected_total", "counter",
        "Extract streams refused because every session slot was taken.",
        s.sessions_rejected.load());
  w.Family("tandem_sessions_finished_total", "counter",
           "Accepted Extract streams that ended, by final gRPC status.");
  for (size_t code = 0; code < s.finished_by_code.size(); ++code) {
    const int64_t n = s.finished_by_code[code].load();
    if (n == 0 && code != 0) continue;  // OK always, the others once they happened
    w.Sample("tandem_sessions_finished_total", n,
             absl::StrCat("{status=\"",
                          absl::StatusCodeToString(static_cast<absl::StatusCode>(code)), "\"}"));
  }
  w.One("tandem_unauthenticated_calls_total", "counter", "Calls refused with UNAUTHENTICATED.",
        s.auth.refused());
  w.One("tandem_slices_total", "counter", "Slices consumed by all sessions.",
        s.slices_total.load());
  w.One("tandem_received_bytes_total", "counter", "Request bytes read from Extract streams.",
        s.bytes_received_total.load());
  w.One("tandem_sent_bytes_total", "counter", "Response bytes written to Extract streams.",
        s.bytes_sent_total.load());
  w.One("tandem_previews_sent_total", "counter", "Preview messages written.",
        s.previews_sent_total.load());
  w.Family("tandem_phase_seconds_total", "counter",
           "Time finished sessions spent in each phase (extract: marching cubes, simplify: "
           "edge contraction, encode: Draco).");
  for (const auto& [phase, us] : {std::pair{"extract", &s.extract_us_total},
                                  std::pair{"simplify", &s.simplify_us_total},
                                  std::pair{"encode", &s.encode_us_total}}) {
    w.Sample("tandem_phase_seconds_total", static_cast<double>(us->load()) * 1e-6,
             absl::StrCat("{phase=\"", phase, "\"}"));
  }
  w.One("tandem_inflight_bytes", "gauge",
        "Bytes queued in streams: received and not yet processed, plus responses not yet "
        "sent (per stream at most --max-inflight-bytes).",
        s.buffered_bytes.load());
  w.One("tandem_sessions_draining", "gauge",
        "Sessions done computing whose final messages are still being sent.",
        s.sessions_draining.load());
  w.One("tandem_session_memory_bytes", "gauge",
        "Memory held by live sessions (mesh, queues, buffers), as the budget counts it.",
        s.session_bytes.load());
  w.One("tandem_session_memory_limit_bytes", "gauge",
        "Per-session budget (--session-memory-mb) times --max-sessions.",
        s.limits.session_memory_bytes * s.limits.max_sessions);
  w.One("tandem_watch_memory_bytes", "gauge",
        "Sealed chunk bytes kept for watchers and resumes in the server's memory (those the "
        "spill directory could not take).",
        s.feeds.retention().memory_bytes.load());
  w.One("tandem_watch_spilled_bytes", "gauge",
        "Sealed chunk bytes kept for watchers and resumes in spill files (--watch-spill-dir).",
        s.feeds.retention().spilled_bytes.load());
  w.One("tandem_worker_threads", "gauge", "Session worker threads alive.", s.worker_threads());
  return w.Take();
}

}  // namespace tandem::server
