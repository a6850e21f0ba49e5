// TandemService: the gRPC callback service (reactors only; the work is in ExtractJob).
//
// Threading: each accepted Extract stream gets one worker thread (at most
// limits.max_sessions at once; more streams get RESOURCE_EXHAUSTED), which owns the
// TandemSession (core may briefly add a helper thread per slice: SessionOptions::pipeline).
// Reactions never block and never compute: they move messages between gRPC and the worker
// under a mutex.
//   * Flow control: the next read is started only when the worker has taken the previous
//     message, so at most one request waits per stream however fast the client sends.
//   * Output: one write in flight; Progress and Preview are latest-wins slots (a slow
//     reader gets fewer, newer previews), the final messages an ordered queue.
//   * Cleanup: client cancel, disconnect, deadline or server shutdown set the stream's
//     cancel flag; the worker checks it between messages, and the stream's resources go
//     when both the reactor (OnDone) and the worker have let go. A stream silent for
//     limits.idle_timeout_s ends with DEADLINE_EXCEEDED.
//   * Memory per stream: the session, one slice buffer, at most two request messages
//     (one being read, one being handled), the newest Progress and Preview, and the
//     encoded final mesh while it is sent.
#ifndef TANDEM_SERVER_TANDEM_SERVICE_H_
#define TANDEM_SERVER_TANDEM_SERVICE_H_

#include <atomic>
#include <cstdint>
#include <memory>

#include <grpcpp/grpcpp.h>

#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/request_validation.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::server {

// Shared by the service, its streams and their worker threads (which may outlive a
// stream's reactor), hence reference-counted.
struct ServiceState {
  explicit ServiceState(const ServerLimits& l) : limits(l) {}
  const ServerLimits limits;
  std::atomic<int64_t> active_sessions{0};
  std::atomic<int64_t> sessions_started{0};
  std::atomic<int64_t> sessions_finished{0};
  std::atomic<int64_t> sessions_rejected{0};
  std::atomic<int64_t> session_bytes{0};

  void WorkerStarted();
  void WorkerExited();
  int64_t worker_threads() const;
  // True when no worker thread is left, false at the deadline.
  bool WaitForWorkers(absl::Time deadline);

 private:
  mutable absl::Mutex mu_;
  int64_t workers_ ABSL_GUARDED_BY(mu_) = 0;
};

class TandemService final : public v1::Tandem::CallbackService {
 public:
  explicit TandemService(const ServerLimits& limits);
  // Waits (up to 5 s) for worker threads still finishing a message after Shutdown.
  ~TandemService() override;

  grpc::ServerBidiReactor<v1::ExtractRequest, v1::ExtractResponse>* Extract(
      grpc::CallbackServerContext* context) override;
  grpc::ServerUnaryReactor* GetInfo(grpc::CallbackServerContext* context,
                                    const v1::InfoRequest* request,
                                    v1::InfoResponse* response) override;

  // Call after grpc::Server::Shutdown: true once every worker thread has exited.
  bool WaitForWorkers(absl::Time deadline) { return state_->WaitForWorkers(deadline); }
  v1::Counters CountersSnapshot() const;

 private:
  std::shared_ptr<ServiceState> state_;
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_TANDEM_SERVICE_H_
