#include "server/tandem_service.h"

#include <malloc.h>  // malloc_trim (glibc)

#include <algorithm>
#include <deque>
#include <optional>
#include <string>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "common/wire.h"
#include "server/extract_job.h"
#include "server/log.h"
#include "server/metrics.h"

namespace tandem::server {
namespace {

using Request = v1::ExtractRequest;
using Response = v1::ExtractResponse;

// How long the final OK waits for a client's half-close after End (see PumpLocked).
constexpr absl::Duration kOkGrace = absl::Seconds(1);

// A call refused before it started (authentication): finishes at once.
class RefusedCall final : public grpc::ServerBidiReactor<Request, Response> {
 public:
  explicit RefusedCall(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

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
  // client vanished mid-scan and the session may be resumed (server/resume.h).
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

// A parked session's wait (on its old worker thread), and its end when nobody resumed it.
// Its memory (counted in session_bytes meanwhile) includes the chunks its client has not
// acknowledged.
void HoldParked(ServiceState& state, ParkedSession parked) {
  const std::string id = parked.feed->id();
  const int64_t bytes = parked.memory_bytes;
  const int64_t slices = parked.job->slices();
  state.session_bytes.fetch_add(bytes);
  std::optional<ParkedSession> left = state.resumable.ParkAndWait(std::move(parked));
  state.session_bytes.fetch_sub(bytes);
  if (!left) return;  // another stream took it over
  const double window = absl::ToDoubleSeconds(state.resumable.window());
  left->feed->Finish({}, grpc::Status(grpc::StatusCode::CANCELLED,
                                           absl::StrFormat("the client left after %d slices and "
                                                           "did not resume within %g s",
                                                           slices, window)));
  LogEvent("session_expired", {{"id", LogField::Word{id}}, {"slices", slices}});
}

ExtractCall* ExtractCall::Start(std::shared_ptr<ServiceState> state,
                                grpc::CallbackServerContext* context, int identity) {
  auto call = std::make_shared<ExtractCall>(state, context);
  call->self_ = call;
  const int64_t max = state->limits.max_sessions;
  if (!state->resumable.AdmitStream(max)) {
    state->sessions_rejected.fetch_add(1);
    call->EndStream(grpc::Status(
        grpc::StatusCode::RESOURCE_EXHAUSTED,
        absl::StrCat("the server is busy: all ", max,
                     " sessions are in use (tandem-server --max-sessions); retry later")));
    return call.get();
  }
  call->accepted_ = true;
  state->active_sessions.fetch_add(1);
  call->feed_ = state->feeds.Create(NewSecret(), identity);
  call->resume_token_ = NewSecret();
  state->AddStream(call.get(), call);
  state->sessions_started.fetch_add(1);
  {
    absl::MutexLock lock(&call->mu_);
    call->MaybeStartReadLocked();
  }
  state->WorkerStarted();
  try {
    std::thread([call, state]() mutable {
      std::optional<ParkedSession> parked = call->RunWorker();
      call.reset();  // may destroy the stream (logs its line) if OnDone came first
      if (parked) HoldParked(*state, *std::move(parked));
      state->WorkerExited();
      state->TrimIfIdle();
    }).detach();
  } catch (const std::system_error& e) {
    state->WorkerExited();
    call->EndStream(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                                 absl::StrCat("cannot start a worker thread: ", e.what())));
  }
  return call.get();
}

ExtractCall::~ExtractCall() {
  if (!accepted_) return;  // rejected streams are counted in sessions_rejected only
  state_->RemoveStream(this);
  // One line per session for operators. (The lock is uncontended: last reference.)
  absl::MutexLock lock(&mu_);
  state_->buffered_bytes.fetch_sub(accounted_buffered_);
  grpc::Status status = finish_wanted_.value_or(
      grpc::Status(grpc::StatusCode::UNKNOWN, "the stream ended without a status"));
  if (cancelled_ && !stalled_ && status.error_code() != grpc::StatusCode::CANCELLED) {
    // The client never saw `status`; a cancelled stream's reads also end early, so the
    // worker may have reported a missing End first.
    status = grpc::Status(grpc::StatusCode::CANCELLED,
                          status.ok()
                              ? "the client left before the end"
                              : absl::StrCat("cancelled; before that: ", status.error_message()));
  }
  if (!parked_) {
    feed_->Finish({}, status);  // (no effect after the final metrics)
    state_->resumable.StreamEnded();  // (a parked session's slot went with it)
  }
  const std::string status_name =
      absl::StatusCodeToString(static_cast<absl::StatusCode>(status.error_code()));
  const double seconds = absl::ToDoubleSeconds(absl::Now() - start_);
  std::vector<LogField> fields = {{"peer", LogField::Str{peer_}},
                                  {"id", LogField::Word{feed_->id()}},
                                  {"input", LogField::Str{description_}},
                                  {"slices", slices_},
                                  {"triangles", triangles_},
                                  {"seconds", seconds},
                                  {"bytes_received", bytes_received_},
                                  {"bytes_sent", bytes_sent_},
                                  {"previews", previews_sent_},
                                  {"status", LogField::Word{status_name}}};
  if (resumed_) fields.push_back({"resumed", LogField::Word{"yes"}});
  if (parked_) fields.push_back({"waiting_for_resume", LogField::Word{"yes"}});
  const std::string message = status.error_message();  // by value: keep it for the view
  if (!status.ok()) fields.push_back({"message", LogField::Str{message, 1000}});
  if (!(status.ok() && LogQuiet())) LogEvent("session", fields);
  const auto code = static_cast<size_t>(status.error_code());
  if (code < state_->finished_by_code.size()) state_->finished_by_code[code].fetch_add(1);
  state_->sessions_finished.fetch_add(1);
  state_->active_sessions.fetch_sub(1);  // last: tests wait for it to read the log
}

void ExtractCall::MaybeStartReadLocked() {
  // Reading goes on after End (until the final status): a message after End is an error.
  if (read_in_flight_ || finish_called_ || StoppingLocked() || input_closed_) return;
  if (InflightLocked() >= state_->limits.max_inflight_bytes) return;  // resumed as it drains
  read_in_flight_ = true;
  StartRead(&read_buf_);
}

void ExtractCall::SyncBufferedLocked() {
  const int64_t bytes = InflightLocked();
  state_->buffered_bytes.fetch_add(bytes - accounted_buffered_);
  accounted_buffered_ = bytes;
}

void ExtractCall::OnReadDone(bool ok) {
  absl::MutexLock lock(&mu_);
  read_in_flight_ = false;
  if (!ok) {
    input_closed_ = true;  // half-close by the client, or the call is ending
    PumpLocked();          // a held OK goes now
    return;
  }
  last_activity_ = absl::Now();
  const int64_t bytes = static_cast<int64_t>(read_buf_.ByteSizeLong());
  bytes_received_ += bytes;
  state_->bytes_received_total.fetch_add(bytes);
  if (end_received_) {  // End must be the last message; replaces an OK not yet sent
    const std::string kind = read_buf_.has_chunk()             ? "a SliceChunk"
                             : read_buf_.has_config()          ? "a SessionConfig"
                             : read_buf_.has_end()             ? "a second End"
                             : read_buf_.has_chunks_received() ? "a ChunksReceived"
                                                               : "an empty message";
    read_buf_.Clear();
    EndStreamLocked(grpc::Status(
        grpc::StatusCode::INVALID_ARGUMENT,
        absl::StrCat("got ", kind, " after End: End must be the stream's last message "
                     "(half-close the stream after it)")));
    SyncBufferedLocked();
    return;
  }
  if (StoppingLocked()) {  // the stream is ending: nobody will take it
    read_buf_.Clear();
    return;
  }
  if (read_buf_.has_chunks_received()) {  // for the feed, not the job: taken here at once
    const int64_t count = read_buf_.chunks_received().count();
    read_buf_.Clear();
    AcknowledgeLocked(count);
    MaybeStartReadLocked();
    SyncBufferedLocked();
    return;
  }
  end_received_ = read_buf_.has_end();
  inbox_.push_back(Received{std::move(read_buf_), bytes});
  inbox_bytes_ += bytes;
  read_buf_.Clear();
  MaybeStartReadLocked();
  SyncBufferedLocked();
}

void ExtractCall::AcknowledgeLocked(int64_t count) {
  absl::Status st =
      acks_feed_ == nullptr
          ? absl::InvalidArgumentError(
                "got a ChunksReceived on a stream that does not take them: send them only "
                "after a first Progress that says chunk_acks (SessionConfig.chunk_acks with "
                "sealed_chunks)")
          : acks_feed_->Acknowledge(count);
  if (!st.ok()) EndStreamLocked(wire::ToGrpcStatus(st));
}

void ExtractCall::TakeAcknowledgements(const std::shared_ptr<MemoryBudget>& budget) {
  feed_->KeepUnacknowledged(budget);
  absl::MutexLock lock(&mu_);
  acks_feed_ = feed_;
}

void ExtractCall::OnWriteDone(bool ok) {
  absl::MutexLock lock(&mu_);
  write_in_flight_ = false;
  write_bytes_ = 0;
  if (!ok) {
    // The client is gone (disconnect or cancel): nothing more can be written.
    cancelled_ = true;
    EndStreamLocked(grpc::Status(grpc::StatusCode::CANCELLED, "the client stopped reading"));
    SyncBufferedLocked();
    return;
  }
  last_activity_ = absl::Now();
  PumpLocked();
  MaybeStartReadLocked();  // the output drained: reading may resume
  SyncBufferedLocked();
}

void ExtractCall::Abort(grpc::Status status) {
  absl::MutexLock lock(&mu_);
  EndStreamLocked(std::move(status));
  SyncBufferedLocked();
  if (job_budget_) job_budget_->Cancel();  // the server ends it: no resume
}

void ExtractCall::OnCancel() {
  absl::MutexLock lock(&mu_);
  // Without a resume window the session ends with its stream: its work stops now.
  if (state_->limits.resume_window_s <= 0 && job_budget_) job_budget_->Cancel();
  cancelled_ = true;
  EndStreamLocked(grpc::Status(
      grpc::StatusCode::CANCELLED,
      "the stream was cancelled (client cancel, deadline, or server shutdown)"));
  SyncBufferedLocked();
}

void ExtractCall::OnDone() {
  // Every operation has completed. Drop the reactor's reference; the worker (if still
  // running) sees cancelled_ or finish_called_ and lets go of its own.
  {
    absl::MutexLock lock(&ctx_mu_);
    context_ = nullptr;
  }
  std::shared_ptr<ServiceState> state = state_;
  { std::shared_ptr<ExtractCall> self = std::move(self_); }  // may destroy *this
  state->TrimIfIdle();
}

void ExtractCall::CancelCall() {
  absl::MutexLock lock(&ctx_mu_);
  if (context_ != nullptr) context_->TryCancel();
}

void ExtractCall::EndStream(grpc::Status status) {
  absl::MutexLock lock(&mu_);
  EndStreamLocked(std::move(status));
  SyncBufferedLocked();
}

void ExtractCall::EndStreamLocked(grpc::Status status) {
  if (finish_called_) return;
  if (finish_wanted_.has_value() && !finish_wanted_->ok()) {
    // The first error wins, but Finish may still be due (e.g. it waited for this write).
    PumpLocked();
    return;
  }
  if (status.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED && accepted_) {
    // A limit of this server (grid, slices, memory budget), not a busy moment: tell gRPC
    // clients with a retry policy not to retry. (Before Finish, the context is alive.)
    call_context_->AddTrailingMetadata("grpc-retry-pushback-ms", "-1");
  }
  if (!status.ok()) {
    progress_.reset();
    preview_.reset();
    final_.clear();
    progress_bytes_ = preview_bytes_ = final_bytes_ = 0;
    inbox_.clear();
    inbox_bytes_ = 0;
  }
  finish_wanted_ = std::move(status);
  PumpLocked();
}

void ExtractCall::PumpLocked() {
  if (finish_called_ || write_in_flight_) return;
  const bool failing = finish_wanted_.has_value() && !finish_wanted_->ok();
  std::optional<Response> next;
  if (!failing) {
    // Sealed chunks before a preview: a band preview is drawn with the chunks sent before it.
    if (progress_) {
      *(next.emplace().mutable_progress()) = std::move(*progress_);
      progress_.reset();
      progress_bytes_ = 0;
    } else if (!final_.empty() && (final_.front().has_sealed_chunk() || !preview_)) {
      next = std::move(final_.front());
      final_.pop_front();
      final_bytes_ -= static_cast<int64_t>(next->ByteSizeLong());
    } else if (preview_) {
      *(next.emplace().mutable_preview()) = std::move(*preview_);
      preview_.reset();
      preview_bytes_ = 0;
    }
  }
  if (next) {
    // Wire figures are filled in here, where they are known exactly.
    if (next->has_progress()) next->mutable_progress()->set_bytes_received(bytes_received_);
    if (next->has_preview()) {
      ++previews_sent_;
      state_->previews_sent_total.fetch_add(1);
    }
    if (next->has_final_metrics()) {
      v1::FinalMetrics* m = next->mutable_final_metrics();
      m->set_bytes_received(bytes_received_);
      m->set_bytes_sent(bytes_sent_);
      m->set_previews_sent(previews_sent_);
    }
    write_bytes_ = static_cast<int64_t>(next->ByteSizeLong());
    bytes_sent_ += write_bytes_;
    state_->bytes_sent_total.fetch_add(write_bytes_);
    write_buf_ = std::move(*next);
    write_in_flight_ = true;
    StartWrite(&write_buf_);
    return;
  }
  if (finish_wanted_.has_value()) {
    if (finish_wanted_->ok() && end_received_ && read_in_flight_ && !ok_hold_over_) {
      // A read after End is in flight: the client may have sent one message too many.
      // Hold the OK until that read completes (half-close or the message) or, for a
      // client that keeps its side open, until WaitForFinish ends the grace.
      if (ok_held_until_ == absl::InfinitePast()) ok_held_until_ = absl::Now() + kOkGrace;
      return;
    }
    finish_called_ = true;
    Finish(*finish_wanted_);
  }
}

void ExtractCall::PostProgress(v1::Progress progress) {
  feed_->Progress(progress);
  absl::MutexLock lock(&mu_);
  if (StoppingLocked()) return;
  if (!id_sent_) {  // the first Progress names the session (and gives its creator the token)
    progress.set_session_id(feed_->id());
    if (!resumed_) progress.set_resume_token(resume_token_);
    progress.set_watch_key(feed_->watch_key());  // (the resume token is more)
    progress.set_chunk_acks(acks_feed_ != nullptr);
    id_sent_ = true;
  }
  progress_bytes_ = static_cast<int64_t>(progress.ByteSizeLong());
  progress_ = std::move(progress);
  PumpLocked();
  SyncBufferedLocked();
}

void ExtractCall::PostPreview(v1::Preview preview) {
  feed_->Preview(preview);
  absl::MutexLock lock(&mu_);
  if (StoppingLocked()) return;
  preview_bytes_ = static_cast<int64_t>(preview.ByteSizeLong());
  preview_ = std::move(preview);  // an unsent older preview is dropped: latest wins
  PumpLocked();
  SyncBufferedLocked();
}

bool ExtractCall::PreviewPending() const {
  absl::MutexLock lock(&mu_);
  return preview_.has_value();
}

void ExtractCall::PostFinal(std::vector<Response> messages) {
  // Watchers get the metrics (the transport's byte counts are this stream's, not theirs).
  std::vector<v1::FinalMetrics> metrics;  // one per surface
  for (const Response& m : messages) {
    if (m.has_final_metrics()) metrics.push_back(m.final_metrics());
  }
  if (!metrics.empty()) feed_->Finish(std::move(metrics), grpc::Status::OK);
  absl::MutexLock lock(&mu_);
  if (StoppingLocked()) return;
  preview_.reset();  // a preview older than the final mesh is of no use any more
  preview_bytes_ = 0;
  for (Response& m : messages) {
    final_bytes_ += static_cast<int64_t>(m.ByteSizeLong());
    final_.push_back(std::move(m));
  }
  PumpLocked();
  SyncBufferedLocked();
}

void ExtractCall::PostChunk(v1::SealedChunk chunk) {
  feed_->Chunk(chunk);
  QueueChunk(std::move(chunk));
  const int64_t unacknowledged = feed_->unacknowledged_bytes();
  absl::MutexLock lock(&mu_);
  if (unacknowledged == 0 || job_budget_ == nullptr || job_budget_->limit() <= 0 ||
      job_budget_->held() <= job_budget_->limit()) {
    return;
  }
  constexpr double kMiB = 1 << 20;
  EndStreamLocked(grpc::Status(
      grpc::StatusCode::RESOURCE_EXHAUSTED,
      absl::StrFormat("session memory budget exceeded: %.1f MiB of sealed chunks the client has "
                      "not acknowledged (ChunksReceived) take the session to %.1f MiB, over this "
                      "server's per-session budget of %.1f MiB (tandem-server "
                      "--session-memory-mb); a client that asks for SessionConfig.chunk_acks "
                      "must acknowledge the chunks it keeps",
                      unacknowledged / kMiB, job_budget_->held() / kMiB,
                      job_budget_->limit() / kMiB)));
  SyncBufferedLocked();
  job_budget_->Cancel();  // the session's steps stop: the stream has failed
}

void ExtractCall::QueueChunk(v1::SealedChunk chunk) {
  absl::MutexLock lock(&mu_);
  if (StoppingLocked()) return;
  Response r;
  *r.mutable_sealed_chunk() = std::move(chunk);
  final_bytes_ += static_cast<int64_t>(r.ByteSizeLong());
  final_.push_back(std::move(r));  // never dropped: the mesh is the union of the chunks
  PumpLocked();
  SyncBufferedLocked();
}

bool ExtractCall::AwaitProgressLocked(const absl::Condition& cond) {
  const absl::Duration idle = absl::Seconds(state_->limits.idle_timeout_s);
  last_activity_ = std::max(last_activity_, absl::Now());
  while (!mu_.AwaitWithDeadline(cond, last_activity_ + idle)) {
    // Reads and writes that completed meanwhile moved last_activity_: wait on.
    if (absl::Now() >= last_activity_ + idle) return false;
  }
  return true;
}

bool ExtractCall::EndIdleStreamLocked() {
  const double idle_s = state_->limits.idle_timeout_s;
  const bool reading_paused = !read_in_flight_ && !input_closed_ && !end_received_ &&
                              inbox_.empty() && !finish_wanted_.has_value();
  std::string message;
  if (write_in_flight_ && (reading_paused || finish_wanted_.has_value())) {
    message = absl::StrFormat(
        "the client read none of the server's messages for %g s (%d response bytes waiting; "
        "the server stops reading a stream at tandem-server --max-inflight-bytes = %d and "
        "ends it after --idle-timeout-seconds)",
        idle_s, OutputBytesLocked(), state_->limits.max_inflight_bytes);
  } else {
    message = absl::StrFormat("no message for %g s (tandem-server --idle-timeout-seconds)%s",
                              idle_s, write_in_flight_ ? ", and the client is not reading" : "");
  }
  stalled_ = true;
  // Replaces an OK still waiting for its final messages to be read.
  if (finish_wanted_.has_value() && finish_wanted_->ok()) finish_wanted_.reset();
  EndStreamLocked(grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, message));
  SyncBufferedLocked();
  return write_in_flight_;
}

std::optional<ParkedSession> ExtractCall::RunWorker() {
  bool cancel = false;
  std::optional<ParkedSession> parked;
  {
    auto job = std::make_unique<ExtractJob>(state_->limits, this, state_->compute.get());
    {
      absl::MutexLock lock(&mu_);
      job_budget_ = job->budget();
    }
    int64_t accounted_bytes = 0;
    bool first = true, failed = false;
    while (true) {
      std::optional<Request> request;
      bool wants_acks = false;
      {
        absl::MutexLock lock(&mu_);
        const bool woken = AwaitProgressLocked(absl::Condition(
            +[](ExtractCall* c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->mu_) {
              return !c->inbox_.empty() || c->input_closed_ || c->StoppingLocked();
            },
            this));
        if (!woken) {
          // A silent client would hold its session slot forever.
          cancel = EndIdleStreamLocked();
          break;
        }
        if (StoppingLocked()) break;
        if (inbox_.empty() && job->resumable() && state_->limits.resume_window_s > 0) {
          // The input closed mid-scan. A client that vanished (its connection lost) also
          // has its call cancelled, an instant later: wait for that before taking the
          // close as a missing End, so that the session can wait for a resume.
          mu_.AwaitWithTimeout(absl::Condition(&cancelled_), absl::Seconds(1));
          if (StoppingLocked()) break;
        }
        if (!inbox_.empty()) {
          request = std::move(inbox_.front().request);
          inbox_bytes_ -= inbox_.front().bytes;
          inbox_.pop_front();
          if (request->has_config() && !request->config().has_resume()) {
            description_ = request->config().description();
            feed_->SetSealed(request->config().sealed_chunks(), description_);
          }
          wants_acks = request->has_config() && request->config().chunk_acks() &&
                       (request->config().has_resume() || request->config().sealed_chunks());
          MaybeStartReadLocked();  // room in the inbox again
          SyncBufferedLocked();
        }
      }
      absl::Status status;
      try {  // the barrier: nothing a client sends may end the process
        if (first && request && request->has_config() && request->config().has_resume()) {
          status = Resume(request->config().resume(), wants_acks, &job);
        } else {
          // Before the config's first Progress, which says whether acknowledgements are taken.
          if (wants_acks) TakeAcknowledgements(job->budget());
          status = request ? job->Handle(*request) : job->HandleEndOfInput();
        }
      } catch (...) {
        status = StatusOfException(std::current_exception());
      }
      first = false;
      request.reset();
      // What the sessions' own checks last saw, steps in flight included, if more: a failed
      // session holds its memory until it is destroyed below.
      const int64_t bytes =
          std::max(static_cast<int64_t>(job->MemoryBytes()), job->budget()->held());
      state_->session_bytes.fetch_add(bytes - accounted_bytes);
      accounted_bytes = bytes;
      {
        absl::MutexLock lock(&mu_);
        state_->slices_total.fetch_add(job->slices() - slices_);
        slices_ = job->slices();
        triangles_ = job->triangles();
        job_budget_ = job->budget();  // (a resumed stream's job is another)
      }
      if (!status.ok()) {
        failed = true;
        EndStream(wire::ToGrpcStatus(status));
        break;
      }
      if (job->done()) {
        EndStream(grpc::Status::OK);  // after the final messages already queued
        break;
      }
    }
    const ExtractJob::Phases phases = job->PhaseSeconds();
    auto micros = [](double s) { return static_cast<int64_t>(s * 1e6); };
    state_->extract_us_total.fetch_add(micros(phases.extract_s));
    state_->simplify_us_total.fetch_add(micros(phases.simplify_s));
    state_->encode_us_total.fetch_add(micros(phases.encode_s));
    // The client vanished between slices (not an error of the job, not the idle timeout,
    // not the server ending the stream): the session may wait for it to come back.
    {
      absl::MutexLock lock(&mu_);
      parked_ = cancelled_ && !stalled_ && !failed && job->resumable() &&
                state_->limits.resume_window_s > 0;
      if (parked_) {
        job_budget_.reset();  // the session is the resume table's now
        job->Detach();
        parked.emplace();
        // (The budget also counts the chunks the client has not acknowledged.)
        parked->memory_bytes =
            std::max(static_cast<int64_t>(job->MemoryBytes()), job->budget()->held());
        parked->job = std::move(job);
        parked->feed = feed_;
        parked->token = resume_token_;
      }
    }
    // The session stops its queued work and lets go of its memory here (unless parked),
    // before the output is delivered and before the slot is given back (~ExtractCall).
    job.reset();
    state_->session_bytes.fetch_sub(accounted_bytes);
  }
  if (cancel) CancelCall();
  WaitForFinish();
  return parked;
}

absl::Status ExtractCall::Resume(const v1::Resume& resume, bool acks,
                                 std::unique_ptr<ExtractJob>* job) {
  int64_t expected = -1;
  std::vector<v1::SealedChunk> replay;
  absl::StatusOr<ParkedSession> p =
      state_->resumable.Adopt(resume.session_id(), resume.token(), resume.next_slice(),
                              resume.chunks_received(), &expected, &replay);
  if (!p.ok()) {
    if (absl::IsNotFound(p.status())) {
      std::shared_ptr<SessionFeed> feed = state_->feeds.Find(resume.session_id());
      if (feed != nullptr && feed != feed_ && !feed->finished()) {
        return absl::UnavailableError(absl::StrCat(
            "session ", resume.session_id(), " is still attached to its previous stream (the "
            "server has not seen that stream end yet); resume again in a moment"));
      }
    }
    if (expected >= 0 && absl::IsFailedPrecondition(p.status())) {
      absl::MutexLock lock(&mu_);  // (call_context_ is alive before Finish)
      if (!finish_called_) {
        call_context_->AddTrailingMetadata("tandem-expected-slice", absl::StrCat(expected));
      }
    }
    return p.status();
  }
  state_->feeds.Remove(feed_->id());  // this stream's own, unused: it is the session's now
  feed_ = std::move(p->feed);
  resume_token_ = std::move(p->token);
  resumed_ = true;
  {
    absl::MutexLock lock(&mu_);
    description_ = p->job->description();
  }
  *job = std::move(p->job);
  if (acks || feed_->keeps_unacknowledged()) TakeAcknowledgements((*job)->budget());
  (*job)->Attach(this);  // its Progress goes first, naming the session
  for (v1::SealedChunk& c : replay) QueueChunk(std::move(c));
  return absl::OkStatus();
}

void ExtractCall::WaitForFinish() {
  bool cancel = false;
  {
    absl::MutexLock lock(&mu_);
    auto finished = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
      return finish_called_ || cancelled_;
    };
    auto finished_or_held = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
      return finish_called_ || cancelled_ || ok_held_until_ != absl::InfinitePast();
    };
    if (finished()) return;
    state_->sessions_draining.fetch_add(1);
    while (!finished() && !cancel) {
      if (ok_held_until_ != absl::InfinitePast()) {  // the OK waits for the half-close
        if (!mu_.AwaitWithDeadline(absl::Condition(&finished), ok_held_until_)) {
          ok_hold_over_ = true;
          PumpLocked();
        }
        continue;
      }
      if (!AwaitProgressLocked(absl::Condition(&finished_or_held))) {
        cancel = EndIdleStreamLocked();
      }
    }
    state_->sessions_draining.fetch_sub(1);
  }
  if (cancel) CancelCall();
}

}  // namespace

void ServiceState::TrimIfIdle() const {
#if defined(__GLIBC__)
  // Sessions allocate and free tens of MiB on worker threads, whose glibc arenas keep
  // freed pages mapped; hand them back once nothing is running, so the server's resident
  // size returns to its idle level.
  if (active_sessions.load() == 0) malloc_trim(0);
#endif
}

void ServiceState::WorkerStarted() {
  absl::MutexLock lock(&mu_);
  ++workers_;
}

void ServiceState::WorkerExited() {
  absl::MutexLock lock(&mu_);
  --workers_;
}

int64_t ServiceState::worker_threads() const {
  absl::MutexLock lock(&mu_);
  return workers_;
}

bool ServiceState::WaitForWorkers(absl::Time deadline) {
  absl::MutexLock lock(&mu_);
  auto none = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return workers_ == 0; };
  return mu_.AwaitWithDeadline(absl::Condition(&none), deadline);
}

void ServiceState::AddStream(const LiveStream* key, std::weak_ptr<LiveStream> stream) {
  absl::MutexLock lock(&mu_);
  streams_[key] = std::move(stream);
}

void ServiceState::RemoveStream(const LiveStream* key) {
  absl::MutexLock lock(&mu_);
  streams_.erase(key);
}

int64_t ServiceState::AbortStreams(const grpc::Status& status) {
  std::vector<std::shared_ptr<LiveStream>> alive;
  {
    absl::MutexLock lock(&mu_);
    for (const auto& [key, weak] : streams_) {
      if (auto s = weak.lock()) alive.push_back(std::move(s));
    }
  }
  resumable.Close();
  for (const auto& s : alive) s->Abort(status);  // without mu_: Abort takes the stream's lock
  return static_cast<int64_t>(alive.size());
}

TandemService::TandemService(const ServerLimits& limits, std::vector<std::string> tokens,
                             bool tls)
    : state_(std::make_shared<ServiceState>(limits, std::move(tokens), tls)) {}

TandemService::~TandemService() {
  state_->resumable.Close();
  state_->WaitForWorkers(absl::Now() + absl::Seconds(5));
}

grpc::ServerBidiReactor<Request, Response>* TandemService::Extract(
    grpc::CallbackServerContext* context) {
  int identity = TokenAuthenticator::kNoIdentity;
  if (grpc::Status st = state_->auth.Check(*context, "Extract", &identity); !st.ok()) {
    return new RefusedCall(st);
  }
  return ExtractCall::Start(state_, context, identity);
}

v1::Counters TandemService::CountersSnapshot() const {
  v1::Counters c;
  c.set_active_sessions(state_->active_sessions.load());
  c.set_sessions_started(state_->sessions_started.load());
  c.set_sessions_finished(state_->sessions_finished.load());
  c.set_sessions_rejected(state_->sessions_rejected.load());
  c.set_worker_threads(state_->worker_threads());
  c.set_session_bytes(state_->session_bytes.load());
  c.set_unauthenticated_calls(state_->auth.refused());
  c.set_buffered_bytes(state_->buffered_bytes.load());
  c.set_sessions_draining(state_->sessions_draining.load());
  c.set_sessions_waiting_for_resume(state_->resumable.parked());
  return c;
}

std::string TandemService::MetricsText() const { return PrometheusText(*state_); }

grpc::ServerWriteReactor<v1::ExtractResponse>* TandemService::Watch(
    grpc::CallbackServerContext* context, const v1::WatchRequest* request) {
  int identity = TokenAuthenticator::kNoIdentity;
  if (grpc::Status st = state_->auth.Check(*context, "Watch", &identity); !st.ok()) {
    return StartWatch(nullptr, "", st);
  }
  return StartWatch(
      state_->feeds.FindReadable(request->session_id(), request->watch_key(), identity),
      request->session_id());
}

grpc::ServerUnaryReactor* TandemService::GetInfo(grpc::CallbackServerContext* context,
                                                 const v1::InfoRequest* request,
                                                 v1::InfoResponse* response) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  int identity = TokenAuthenticator::kNoIdentity;
  if (grpc::Status st = state_->auth.Check(*context, "GetInfo", &identity); !st.ok()) {
    reactor->Finish(st);
    return reactor;
  }
  response->set_version(wire::ServiceVersion());
  v1::Limits* l = response->mutable_limits();
  l->set_max_voxels_per_slice(state_->limits.max_voxels_per_slice);
  l->set_max_slices(state_->limits.max_slices);
  l->set_max_sessions(state_->limits.max_sessions);
  l->set_max_message_bytes(state_->limits.max_message_bytes);
  l->set_idle_timeout_seconds(state_->limits.idle_timeout_s);
  l->set_session_memory_bytes(state_->limits.session_memory_bytes);
  l->set_max_inflight_bytes(state_->limits.max_inflight_bytes);
  l->set_keepalive_time_ms(state_->limits.keepalive_time_ms);
  l->set_keepalive_timeout_ms(state_->limits.keepalive_timeout_ms);
  l->set_min_ping_interval_ms(state_->limits.min_ping_interval_ms);
  l->set_permit_keepalive_without_calls(state_->limits.permit_keepalive_without_calls);
  l->set_min_preview_interval_ms(state_->limits.min_preview_interval_ms);
  l->set_max_preview_share(state_->limits.max_preview_share);
  l->set_max_band_bytes_share(state_->limits.max_band_bytes_share);
  l->set_resume_window_seconds(state_->limits.resume_window_s);
  l->set_compute_threads(state_->compute->threads());
  l->set_watch_retain_bytes(state_->limits.watch_retain_bytes);
  l->set_watch_linger_seconds(state_->limits.watch_linger_s);
  for (v1::DType d : {v1::DTYPE_UINT8, v1::DTYPE_UINT16, v1::DTYPE_INT16, v1::DTYPE_FLOAT32}) {
    response->add_dtypes(d);
  }
  for (v1::Schedule s : {v1::SCHEDULE_NONE, v1::SCHEDULE_CLASSICAL, v1::SCHEDULE_TANDEM,
                         v1::SCHEDULE_TANDEM_LAG}) {
    response->add_schedules(s);
  }
  *response->mutable_counters() = CountersSnapshot();
  response->set_tls(state_->tls);
  response->set_token_required(state_->auth.enabled());
  // Only the sessions this call may read: ids and descriptions are the creators' (patient
  // data, for a scan); everyone gets the counters.
  const std::vector<std::string_view> keys(request->watch_keys().begin(),
                                           request->watch_keys().end());
  for (v1::SessionSummary& summary : state_->feeds.Summaries(keys, identity)) {
    *response->add_sessions() = std::move(summary);
  }
  reactor->Finish(grpc::Status::OK);
  return reactor;
}

}  // namespace tandem::server
