// ServiceState: what the service, its streams and their worker threads share (limits, the
// compute threads, the feeds and the resume table, counters, the registry of live streams).
#ifndef TANDEM_SERVER_SERVICE_STATE_H_
#define TANDEM_SERVER_SERVICE_STATE_H_

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "tandem/executor.h"
#include "tandem/server/auth.h"
#include "tandem/server/request_validation.h"
#include "tandem/server/resume.h"
#include "tandem/server/watch.h"

namespace tandem::server {

// An accepted stream, as the service sees it when it ends them all.
class LiveStream {
 public:
  virtual ~LiveStream() = default;
  // Ends the stream with `status` (an error: pending output is dropped).
  virtual void Abort(grpc::Status status) = 0;
};

// Shared by the service, its streams and their worker threads (which may outlive a
// stream's reactor), hence reference-counted.
struct ServiceState {
  ServiceState(const ServerLimits& l, std::vector<std::string> tokens, bool tls_on)
      : limits(l),
        compute(NewThreadPool(
            l.compute_threads > 0
                ? l.compute_threads
                : static_cast<int>(std::max(1u, std::thread::hardware_concurrency())))),
        tls(tls_on),
        auth(std::move(tokens)),
        feeds(absl::Seconds(l.watch_linger_s), l.watch_retain_bytes, l.watch_spill_dir),
        resumable(absl::Seconds(l.resume_window_s)) {}
  const ServerLimits limits;
  // The threads every session computes on: however many streams arrive, they share these.
  const std::unique_ptr<Executor> compute;
  const bool tls;
  TokenAuthenticator auth;
  FeedRegistry feeds;     // what every stream sends, for Watch
  ResumeTable resumable;  // sessions whose client vanished, for Resume
  std::atomic<int64_t> active_sessions{0};
  std::atomic<int64_t> sessions_started{0};
  std::atomic<int64_t> sessions_finished{0};
  std::atomic<int64_t> sessions_rejected{0};
  std::atomic<int64_t> session_bytes{0};
  std::atomic<int64_t> buffered_bytes{0};
  std::atomic<int64_t> sessions_draining{0};
  // Totals since start, for the Prometheus endpoint (server/metrics.h).
  std::atomic<int64_t> slices_total{0};
  std::atomic<int64_t> bytes_received_total{0};
  std::atomic<int64_t> bytes_sent_total{0};
  std::atomic<int64_t> previews_sent_total{0};
  std::atomic<int64_t> extract_us_total{0}, simplify_us_total{0}, encode_us_total{0};
  // Finished accepted sessions by final gRPC status code (0..16).
  std::array<std::atomic<int64_t>, 17> finished_by_code{};

  // Returns freed heap to the OS (malloc_trim) when no session is active.
  void TrimIfIdle() const;
  void WorkerStarted();
  void WorkerExited();
  int64_t worker_threads() const;
  // True when no worker thread is left, false at the deadline.
  bool WaitForWorkers(absl::Time deadline);
  // Accepted streams, registered until they are destroyed.
  void AddStream(const LiveStream* key, std::weak_ptr<LiveStream> stream);
  void RemoveStream(const LiveStream* key);
  // Aborts every registered stream and ends every session waiting for a resume; returns
  // how many streams were still alive.
  int64_t AbortStreams(const grpc::Status& status);

 private:
  mutable absl::Mutex mu_;
  int64_t workers_ ABSL_GUARDED_BY(mu_) = 0;
  std::map<const LiveStream*, std::weak_ptr<LiveStream>> streams_ ABSL_GUARDED_BY(mu_);
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_SERVICE_STATE_H_
