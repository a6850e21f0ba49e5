// TandemService: the gRPC callback service's entry points (each Extract stream is an ExtractCall,
// server/extract_call.h; its work is an ExtractJob, tandem/server/extract_job.h).
//
// Threading: each accepted Extract stream gets one worker thread (at most
// limits.max_sessions at once; more streams get RESOURCE_EXHAUSTED), which owns the
// TandemSession and feeds it. The sessions compute on one Executor that all of them share
// (limits.compute_threads threads), so the server's threads are bounded by max_sessions +
// compute_threads + gRPC's own, whatever the streams ask for.
// Reactions never block and never compute: they move messages between gRPC and the worker
// under a mutex.
//   * Watch: every accepted stream publishes into a SessionFeed (tandem/server/watch.h) under a
//     random id it sends in its first Progress; Watch calls read the feed.
//   * Resume: a stream cancelled between its config and End (its client vanished) parks
//     its job in ServiceState::resumable (tandem/server/resume.h) and its worker thread waits
//     there, up to limits.resume_window_s, for a stream whose config carries Resume; that
//     stream's worker adopts the job and its feed, and goes on with it.
//   * Authentication: with tokens configured, Extract, GetInfo and Watch check the bearer token
//     before anything else (tandem/server/auth.h explains why there and not in gRPC hooks).
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

#include <grpcpp/grpcpp.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/time/time.h"
#include "tandem/server/request_validation.h"
#include "tandem/server/service_state.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::server {

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
