// TandemService: the gRPC callback service (reactors only; the work is in ExtractJob).
//
// Threading: each accepted Extract stream gets one worker thread (at most
// limits.max_sessions at once; more streams get RESOURCE_EXHAUSTED), which owns the
// TandemSession and feeds it. The sessions compute on one Executor that all of them share
// (limits.compute_threads threads), so the server's threads are bounded by max_sessions +
// compute_threads + gRPC's own, whatever the streams ask for.
// Reactions never block and never compute: they move messages between gRPC and the worker
// under a mutex.
//   * Watch: every accepted stream publishes into a SessionFeed (server/watch.h) under a
//     random id it sends in its first Progress; Watch calls read the feed.
//   * Resume: a stream cancelled between its config and End (its client vanished) parks
//     its job in ServiceState::resumable (server/resume.h) and its worker thread waits
//     there, up to limits.resume_window_s, for a stream whose config carries Resume; that
//     stream's worker adopts the job and its feed, and goes on with it.
//   * Authentication: with tokens configured, Extract, GetInfo and Watch check the bearer token
//     before anything else (server/auth.h explains why there and not in gRPC hooks).
//   * Flow control: one read in flight; the next starts as soon as the previous message
//     is queued, while the stream's bytes in flight (received, not yet taken by the
//     worker, plus responses not yet sent) stay below limits.max_inflight_bytes. At that
//     level the server stops reading; HTTP/2 flow control then blocks the client's
//     writes until the worker has caught up or the client has read its responses.
//   * Output: one write in flight; Progress and Preview are latest-wins slots (a slow
//     reader gets fewer, newer previews), the final messages an ordered queue.
//   * Cleanup: client cancel, disconnect, deadline or server shutdown set the stream's
//     cancel flag; the worker checks it between messages, and the stream's resources go
//     when both the reactor (OnDone) and the worker have let go. A stream ended for good
//     (server shutdown; a client cancel when no resume can follow) also cancels its job's
//     MemoryBudget, so that the session's running steps stop at their next check. An ended
//     session is destroyed (queued steps dropped, running ones stopped) before its memory
//     leaves session_bytes and before its slot is given back: --max-sessions and the
//     budgets bound what the process holds, not only what live streams do. When the last
//     session goes, freed heap is handed back to the OS (malloc_trim).
//   * Idle streams: a stream on which nothing moves (no message read, no response
//     written, the worker waiting) for limits.idle_timeout_s ends with DEADLINE_EXCEEDED;
//     if a response is stuck because the client does not read, the call is also
//     cancelled (a blocked write would otherwise hold it open). The worker stays until the
//     final messages are written, so this holds after the last slice too.
//   * Shutdown: EndAllStreams ends every accepted stream still running with the given
//     status (tandem-server calls it when --grace-seconds are over: UNAVAILABLE), so a
//     client learns why its stream ended instead of a bare CANCELLED.
//   * Memory per stream: the session (budget limits.session_memory_bytes, enforced by
//     ExtractJob between messages and by the session inside its steps), one slice buffer,
//     the bytes in flight above, one message being read, and the encoded final mesh while
//     it is sent.
#ifndef TANDEM_SERVER_TANDEM_SERVICE_H_
#define TANDEM_SERVER_TANDEM_SERVICE_H_

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/auth.h"
#include "server/request_validation.h"
#include "server/resume.h"
#include "server/watch.h"
#include "tandem/executor.h"
#include "tandem/v1/tandem.grpc.pb.h"

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
            l.compute_threads > 0 ? l.compute_threads
                                  : static_cast<int>(std::max(1u, std::thread::hardware_concurrency())))),
        tls(tls_on), auth(std::move(tokens)),
        feeds(absl::Seconds(l.watch_linger_s), l.watch_retain_bytes),
        resumable(absl::Seconds(l.resume_window_s)) {}
  const ServerLimits limits;
  // The threads every session computes on: however many streams arrive, they share these.
  const std::unique_ptr<Executor> compute;
  const bool tls;
  TokenAuthenticator auth;
  FeedRegistry feeds;  // what every stream sends, for Watch
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

class TandemService final : public v1::Tandem::CallbackService {
 public:
  // `tokens`: accepted bearer tokens (empty = no authentication). `tls`: only reported.
  explicit TandemService(const ServerLimits& limits, std::vector<std::string> tokens = {},
                         bool tls = false);
  // Waits (up to 5 s) for worker threads still finishing a message after Shutdown.
  ~TandemService() override;

  grpc::ServerBidiReactor<v1::ExtractRequest, v1::ExtractResponse>* Extract(
      grpc::CallbackServerContext* context) override;
  grpc::ServerUnaryReactor* GetInfo(grpc::CallbackServerContext* context,
                                    const v1::InfoRequest* request,
                                    v1::InfoResponse* response) override;
  grpc::ServerWriteReactor<v1::ExtractResponse>* Watch(grpc::CallbackServerContext* context,
                                                       const v1::WatchRequest* request) override;

  // Ends every running stream with `status` (see Shutdown above); returns how many.
  int64_t EndAllStreams(const grpc::Status& status) { return state_->AbortStreams(status); }
  // Call after grpc::Server::Shutdown: true once every worker thread has exited.
  bool WaitForWorkers(absl::Time deadline) { return state_->WaitForWorkers(deadline); }
  v1::Counters CountersSnapshot() const;
  // The Prometheus text exposition of the counters above and more (server/metrics.h).
  std::string MetricsText() const;

 private:
  std::shared_ptr<ServiceState> state_;
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_TANDEM_SERVICE_H_
