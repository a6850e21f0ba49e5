// ExtractCall: one Extract stream, the gRPC reactor and the JobSink its worker thread posts
// to (extract_call.cc), and that worker (extract_call_worker.cc).
#ifndef TANDEM_SERVER_EXTRACT_CALL_H_
#define TANDEM_SERVER_EXTRACT_CALL_H_

#include <grpcpp/grpcpp.h>

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "tandem/server/extract_job.h"
#include "tandem/server/resume.h"
#include "tandem/server/service_state.h"
#include "tandem/server/watch.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::server {

using Request = v1::ExtractRequest;
using Response = v1::ExtractResponse;

// One Extract stream: the reactor (gRPC side) and the JobSink (worker side) in one object,
// kept alive by shared_ptr: the reactor's own reference is dropped in OnDone, the
// worker's when it has seen the stream finish. Every gRPC operation is started under mu_
// and only while Finish has not been called, so neither side can touch a finished stream.
class ExtractCall final : public grpc::ServerBidiReactor<Request, Response>,
                          public JobSink,
                          public LiveStream {
 public:
  ExtractCall(std::shared_ptr<ServiceState> state, grpc::CallbackServerContext* context)
      : state_(std::move(state)),
        peer_(context->peer()),
        start_(absl::Now()),
        context_(context),
        call_context_(context),
        last_activity_(start_) {}
  ~ExtractCall() override;

  // Accepts the stream (first read + worker thread) or finishes it at once when every
  // session slot is taken. `identity`: the caller's bearer token (TokenAuthenticator), which
  // may read the session it creates. Returns the reactor gRPC drives.
  static ExtractCall* Start(std::shared_ptr<ServiceState> state,
                            grpc::CallbackServerContext* context, int identity);

  void OnReadDone(bool ok) override;
  void OnWriteDone(bool ok) override;
  void OnCancel() override;
  void OnDone() override;

  void PostProgress(v1::Progress progress) override;
  void PostPreview(v1::Preview preview) override;
  bool PreviewPending() const override;
  void PostFinal(std::vector<Response> messages) override;
  void PostChunk(v1::SealedChunk chunk) override;
  void Abort(grpc::Status status) override;

 private:
  // The worker: takes messages to the job until the stream ends. Returns the job when the
  // client vanished mid-scan and the session may be resumed (tandem/server/resume.h).
  std::optional<ParkedSession> RunWorker();
  // The first message carried SessionConfig.resume: adopts the parked session into *job
  // (`acks`: the config asks for SessionConfig.chunk_acks).
  absl::Status Resume(const v1::Resume& resume, bool acks, std::unique_ptr<ExtractJob>* job);
  // Queues a sealed chunk for this stream only (PostChunk also publishes it to the feed).
  void QueueChunk(v1::SealedChunk chunk);
  // SessionConfig.chunk_acks: the feed keeps what the client has not acknowledged, and this
  // stream takes ChunksReceived.
  void TakeAcknowledgements(const std::shared_ptr<MemoryBudget>& budget);
  // A ChunksReceived message (OnReadDone).
  void AcknowledgeLocked(int64_t count) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // After the job: waits until Finish has been called (every response written, or
  // dropped after an error) or the call is cancelled; cancels a call whose client stopped
  // reading for limits.idle_timeout_s.
  void WaitForFinish();
  // Waits for `cond`; false when the stream made no progress (nothing read, nothing
  // written) for limits.idle_timeout_s. Counts the wait from now at the latest.
  bool AwaitProgressLocked(const absl::Condition& cond) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Ends a stream that made no progress for the idle timeout. True when the call must
  // also be cancelled (a write is stuck: Finish would wait for it forever).
  bool EndIdleStreamLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // grpc::ServerContext::TryCancel, unless OnDone came first. Call without mu_.
  void CancelCall();
  // Ends the stream: an error drops pending output; OK sends it all first.
  void EndStream(grpc::Status status);
  void EndStreamLocked(grpc::Status status) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Starts the next read if none is in flight, the input is open and the bytes in
  // flight are below limits.max_inflight_bytes.
  void MaybeStartReadLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Starts the next write, or Finish once nothing is left to write.
  void PumpLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  bool StoppingLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    return cancelled_ || finish_wanted_.has_value();
  }
  int64_t OutputBytesLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    return progress_bytes_ + preview_bytes_ + final_bytes_ + write_bytes_;
  }
  int64_t InflightLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    return inbox_bytes_ + OutputBytesLocked();
  }
  // Brings ServiceState::buffered_bytes up to date with this stream's bytes in flight.
  void SyncBufferedLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);

  const std::shared_ptr<ServiceState> state_;
  const std::string peer_;
  const absl::Time start_;
  bool accepted_ = false;
  std::shared_ptr<ExtractCall> self_;  // the reactor's reference, dropped in OnDone

  absl::Mutex ctx_mu_;  // never held together with mu_
  grpc::CallbackServerContext* context_ ABSL_GUARDED_BY(ctx_mu_);  // null after OnDone
  // The same, for use under mu_ before Finish only (OnDone, hence the end of the
  // context, comes after Finish).
  grpc::CallbackServerContext* const call_context_;

  mutable absl::Mutex mu_;
  Request read_buf_;  // owned by gRPC between StartRead and OnReadDone
  bool read_in_flight_ ABSL_GUARDED_BY(mu_) = false;
  struct Received {
    Request request;
    int64_t bytes;
  };
  std::deque<Received> inbox_ ABSL_GUARDED_BY(mu_);  // read, not yet taken by the worker
  int64_t inbox_bytes_ ABSL_GUARDED_BY(mu_) = 0;
  bool end_received_ ABSL_GUARDED_BY(mu_) = false;  // a message after it is an error
  bool input_closed_ ABSL_GUARDED_BY(mu_) = false;
  // The final OK waits a moment for the half-close while a read after End is in flight,
  // so that a message sent after End is refused whether or not the job was quick to end.
  absl::Time ok_held_until_ ABSL_GUARDED_BY(mu_) = absl::InfinitePast();
  bool ok_hold_over_ ABSL_GUARDED_BY(mu_) = false;
  bool cancelled_ ABSL_GUARDED_BY(mu_) = false;
  bool stalled_ ABSL_GUARDED_BY(mu_) = false;  // ended by the idle timeout
  absl::Time last_activity_ ABSL_GUARDED_BY(mu_);  // last read or write completed
  bool write_in_flight_ ABSL_GUARDED_BY(mu_) = false;
  bool finish_called_ ABSL_GUARDED_BY(mu_) = false;
  std::optional<grpc::Status> finish_wanted_ ABSL_GUARDED_BY(mu_);
  Response write_buf_ ABSL_GUARDED_BY(mu_);  // the message in flight
  std::optional<v1::Progress> progress_ ABSL_GUARDED_BY(mu_);  // latest wins
  std::optional<v1::Preview> preview_ ABSL_GUARDED_BY(mu_);    // latest wins
  std::deque<Response> final_ ABSL_GUARDED_BY(mu_);            // all, in order
  int64_t progress_bytes_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t preview_bytes_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t final_bytes_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t write_bytes_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t accounted_buffered_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t bytes_received_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t bytes_sent_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t previews_sent_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t slices_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t triangles_ ABSL_GUARDED_BY(mu_) = 0;
  std::string description_ ABSL_GUARDED_BY(mu_);
  // Set by Start before any other thread sees the call; replaced by the worker when it
  // resumes a session (only the worker and the destructor use it).
  std::shared_ptr<SessionFeed> feed_;
  // feed_, once the session keeps what its client has not acknowledged: the reactor passes
  // ChunksReceived to it.
  std::shared_ptr<SessionFeed> acks_feed_ ABSL_GUARDED_BY(mu_);
  std::string resume_token_;  // the session's (same ownership as feed_)
  bool resumed_ = false;      // the worker adopted a parked session
  bool id_sent_ ABSL_GUARDED_BY(mu_) = false;
  bool parked_ ABSL_GUARDED_BY(mu_) = false;  // the session outlives this stream
  // The budget of the job the worker runs: cancelled when the stream ends and its session
  // cannot wait for a resume, so that the worker's call into it returns at once.
  std::shared_ptr<MemoryBudget> job_budget_ ABSL_GUARDED_BY(mu_);
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_EXTRACT_CALL_H_
