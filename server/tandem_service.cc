#include "server/tandem_service.h"

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

namespace tandem::server {
namespace {

using Request = v1::ExtractRequest;
using Response = v1::ExtractResponse;

// One Extract stream: the reactor (gRPC side) and the JobSink (worker side) in one object,
// kept alive by shared_ptr: the reactor's own reference is dropped in OnDone, the
// worker's when its loop ends. Every gRPC operation is started under mu_ and only while
// Finish has not been called, so neither side can touch a finished stream.
class ExtractCall final : public grpc::ServerBidiReactor<Request, Response>, public JobSink {
 public:
  ExtractCall(std::shared_ptr<ServiceState> state, grpc::CallbackServerContext* context)
      : state_(std::move(state)), peer_(context->peer()), start_(absl::Now()) {}
  ~ExtractCall() override;

  // Accepts the stream (first read + worker thread) or finishes it at once when every
  // session slot is taken. Returns the reactor gRPC drives.
  static ExtractCall* Start(std::shared_ptr<ServiceState> state,
                            grpc::CallbackServerContext* context);

  void OnReadDone(bool ok) override;
  void OnWriteDone(bool ok) override;
  void OnCancel() override;
  void OnDone() override;

  void PostProgress(v1::Progress progress) override;
  void PostPreview(v1::Preview preview) override;
  void PostFinal(std::vector<Response> messages) override;

 private:
  void RunWorker();
  // Ends the stream: an error drops pending output; OK sends it all first.
  void EndStream(grpc::Status status);
  void EndStreamLocked(grpc::Status status) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void StartReadLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Starts the next write, or Finish once nothing is left to write.
  void PumpLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  bool StoppingLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    return cancelled_ || finish_wanted_.has_value();
  }

  const std::shared_ptr<ServiceState> state_;
  const std::string peer_;
  const absl::Time start_;
  bool accepted_ = false;
  std::shared_ptr<ExtractCall> self_;  // the reactor's reference, dropped in OnDone

  absl::Mutex mu_;
  Request read_buf_;  // owned by gRPC between StartRead and OnReadDone
  std::optional<Request> inbox_ ABSL_GUARDED_BY(mu_);  // read, not yet taken by the worker
  bool input_closed_ ABSL_GUARDED_BY(mu_) = false;
  bool cancelled_ ABSL_GUARDED_BY(mu_) = false;
  bool write_in_flight_ ABSL_GUARDED_BY(mu_) = false;
  bool finish_called_ ABSL_GUARDED_BY(mu_) = false;
  std::optional<grpc::Status> finish_wanted_ ABSL_GUARDED_BY(mu_);
  Response write_buf_ ABSL_GUARDED_BY(mu_);  // the message in flight
  std::optional<v1::Progress> progress_ ABSL_GUARDED_BY(mu_);  // latest wins
  std::optional<v1::Preview> preview_ ABSL_GUARDED_BY(mu_);    // latest wins
  std::deque<Response> final_ ABSL_GUARDED_BY(mu_);            // all, in order
  int64_t bytes_received_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t bytes_sent_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t previews_sent_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t slices_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t triangles_ ABSL_GUARDED_BY(mu_) = 0;
  std::string description_ ABSL_GUARDED_BY(mu_);
};

ExtractCall* ExtractCall::Start(std::shared_ptr<ServiceState> state,
                                grpc::CallbackServerContext* context) {
  auto call = std::make_shared<ExtractCall>(state, context);
  call->self_ = call;
  const int64_t max = state->limits.max_sessions;
  if (state->active_sessions.fetch_add(1) >= max) {
    state->active_sessions.fetch_sub(1);
    state->sessions_rejected.fetch_add(1);
    call->EndStream(grpc::Status(
        grpc::StatusCode::RESOURCE_EXHAUSTED,
        absl::StrCat("the server is busy: all ", max,
                     " sessions are in use (tandem-server --max-sessions); retry later")));
    return call.get();
  }
  call->accepted_ = true;
  state->sessions_started.fetch_add(1);
  {
    absl::MutexLock lock(&call->mu_);
    call->StartReadLocked();
  }
  state->WorkerStarted();
  try {
    std::thread([call, state]() mutable {
      call->RunWorker();
      call.reset();  // may destroy the stream (logs its line) if OnDone came first
      state->WorkerExited();
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
  state_->active_sessions.fetch_sub(1);
  state_->sessions_finished.fetch_add(1);
  // One line per session for operators. (The lock is uncontended: last reference.)
  absl::MutexLock lock(&mu_);
  grpc::Status status = finish_wanted_.value_or(
      grpc::Status(grpc::StatusCode::UNKNOWN, "the stream ended without a status"));
  if (cancelled_ && status.error_code() != grpc::StatusCode::CANCELLED) {
    // The client never saw `status`; a cancelled stream's reads also end early, so the
    // worker may have reported a missing End first.
    status = grpc::Status(grpc::StatusCode::CANCELLED,
                          status.ok() ? "the client left before the end"
                                      : absl::StrCat("cancelled; before that: ",
                                                     status.error_message()));
  }
  absl::FPrintF(stderr,
                "tandem-server: session peer=%s input=\"%s\" slices=%d triangles=%d seconds=%.3f "
                "bytes_received=%d bytes_sent=%d previews=%d status=%s%s\n",
                peer_, description_, slices_, triangles_, absl::ToDoubleSeconds(absl::Now() - start_),
                bytes_received_, bytes_sent_, previews_sent_,
                absl::StatusCodeToString(static_cast<absl::StatusCode>(status.error_code())),
                status.ok() ? "" : absl::StrCat(" message=\"", status.error_message(), "\""));
}

void ExtractCall::StartReadLocked() {
  if (finish_called_ || StoppingLocked() || input_closed_) return;
  StartRead(&read_buf_);
}

void ExtractCall::OnReadDone(bool ok) {
  absl::MutexLock lock(&mu_);
  if (!ok) {
    input_closed_ = true;  // half-close by the client, or the call is ending
    return;
  }
  bytes_received_ += static_cast<int64_t>(read_buf_.ByteSizeLong());
  inbox_.emplace(std::move(read_buf_));
  read_buf_.Clear();
  // No new read here: the worker starts it when it takes this message (flow control).
}

void ExtractCall::OnWriteDone(bool ok) {
  absl::MutexLock lock(&mu_);
  write_in_flight_ = false;
  if (!ok) {
    // The client is gone (disconnect or cancel): nothing more can be written.
    cancelled_ = true;
    EndStreamLocked(grpc::Status(grpc::StatusCode::CANCELLED, "the client stopped reading"));
    return;
  }
  PumpLocked();
}

void ExtractCall::OnCancel() {
  absl::MutexLock lock(&mu_);
  cancelled_ = true;
  EndStreamLocked(grpc::Status(
      grpc::StatusCode::CANCELLED,
      "the stream was cancelled (client cancel, deadline, or server shutdown)"));
}

void ExtractCall::OnDone() {
  // Every operation has completed. Drop the reactor's reference; the worker (if still
  // running) sees cancelled_ or finish_wanted_ and lets go of its own.
  std::shared_ptr<ExtractCall> self = std::move(self_);
}

void ExtractCall::EndStream(grpc::Status status) {
  absl::MutexLock lock(&mu_);
  EndStreamLocked(std::move(status));
}

void ExtractCall::EndStreamLocked(grpc::Status status) {
  if (finish_called_) return;
  if (finish_wanted_.has_value() && !finish_wanted_->ok()) {
    // The first error wins, but Finish may still be due (e.g. it waited for this write).
    PumpLocked();
    return;
  }
  if (!status.ok()) {
    progress_.reset();
    preview_.reset();
    final_.clear();
  }
  finish_wanted_ = std::move(status);
  PumpLocked();
}

void ExtractCall::PumpLocked() {
  if (finish_called_ || write_in_flight_) return;
  const bool failing = finish_wanted_.has_value() && !finish_wanted_->ok();
  std::optional<Response> next;
  if (!failing) {
    if (progress_) {
      *(next.emplace().mutable_progress()) = std::move(*progress_);
      progress_.reset();
    } else if (preview_) {
      *(next.emplace().mutable_preview()) = std::move(*preview_);
      preview_.reset();
    } else if (!final_.empty()) {
      next = std::move(final_.front());
      final_.pop_front();
    }
  }
  if (next) {
    // Wire figures are filled in here, where they are known exactly.
    if (next->has_progress()) next->mutable_progress()->set_bytes_received(bytes_received_);
    if (next->has_preview()) ++previews_sent_;
    if (next->has_final_metrics()) {
      v1::FinalMetrics* m = next->mutable_final_metrics();
      m->set_bytes_received(bytes_received_);
      m->set_bytes_sent(bytes_sent_);
      m->set_previews_sent(previews_sent_);
    }
    bytes_sent_ += static_cast<int64_t>(next->ByteSizeLong());
    write_buf_ = std::move(*next);
    write_in_flight_ = true;
    StartWrite(&write_buf_);
    return;
  }
  if (finish_wanted_.has_value()) {
    finish_called_ = true;
    Finish(*finish_wanted_);
  }
}

void ExtractCall::PostProgress(v1::Progress progress) {
  absl::MutexLock lock(&mu_);
  if (StoppingLocked()) return;
  progress_ = std::move(progress);
  PumpLocked();
}

void ExtractCall::PostPreview(v1::Preview preview) {
  absl::MutexLock lock(&mu_);
  if (StoppingLocked()) return;
  preview_ = std::move(preview);  // an unsent older preview is dropped: latest wins
  PumpLocked();
}

void ExtractCall::PostFinal(std::vector<Response> messages) {
  absl::MutexLock lock(&mu_);
  if (StoppingLocked()) return;
  preview_.reset();  // a preview older than the final mesh is of no use any more
  for (Response& m : messages) final_.push_back(std::move(m));
  PumpLocked();
}

void ExtractCall::RunWorker() {
  ExtractJob job(state_->limits, this);
  int64_t accounted_bytes = 0;
  while (true) {
    std::optional<Request> request;
    {
      absl::MutexLock lock(&mu_);
      const bool woken = mu_.AwaitWithTimeout(
          absl::Condition(
              +[](ExtractCall* c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->mu_) {
                return c->inbox_.has_value() || c->input_closed_ || c->StoppingLocked();
              },
              this),
          absl::Seconds(state_->limits.idle_timeout_s));
      if (!woken) {
        // A silent client would hold its session slot forever.
        EndStreamLocked(grpc::Status(
            grpc::StatusCode::DEADLINE_EXCEEDED,
            absl::StrFormat("no message for %g s (tandem-server --idle-timeout-seconds)",
                            state_->limits.idle_timeout_s)));
        break;
      }
      if (StoppingLocked()) break;
      if (inbox_.has_value()) {
        request = std::move(inbox_);
        inbox_.reset();
        if (request->has_config()) description_ = request->config().description();
        // The slot is free again: read the next message while this one is processed.
        if (!request->has_end()) StartReadLocked();
      }
    }
    const absl::Status status = request ? job.Handle(*request) : job.HandleEndOfInput();
    request.reset();
    const int64_t bytes = static_cast<int64_t>(job.MemoryBytes());
    state_->session_bytes.fetch_add(bytes - accounted_bytes);
    accounted_bytes = bytes;
    {
      absl::MutexLock lock(&mu_);
      slices_ = job.slices();
      triangles_ = job.triangles();
    }
    if (!status.ok()) {
      EndStream(wire::ToGrpcStatus(status));
      break;
    }
    if (job.done()) {
      EndStream(grpc::Status::OK);  // after the final messages already queued
      break;
    }
  }
  state_->session_bytes.fetch_sub(accounted_bytes);
}

}  // namespace

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

TandemService::TandemService(const ServerLimits& limits)
    : state_(std::make_shared<ServiceState>(limits)) {}

TandemService::~TandemService() { state_->WaitForWorkers(absl::Now() + absl::Seconds(5)); }

grpc::ServerBidiReactor<Request, Response>* TandemService::Extract(
    grpc::CallbackServerContext* context) {
  return ExtractCall::Start(state_, context);
}

v1::Counters TandemService::CountersSnapshot() const {
  v1::Counters c;
  c.set_active_sessions(state_->active_sessions.load());
  c.set_sessions_started(state_->sessions_started.load());
  c.set_sessions_finished(state_->sessions_finished.load());
  c.set_sessions_rejected(state_->sessions_rejected.load());
  c.set_worker_threads(state_->worker_threads());
  c.set_session_bytes(state_->session_bytes.load());
  return c;
}

grpc::ServerUnaryReactor* TandemService::GetInfo(grpc::CallbackServerContext* context,
                                                 const v1::InfoRequest* /*request*/,
                                                 v1::InfoResponse* response) {
  response->set_version(wire::ServiceVersion());
  v1::Limits* l = response->mutable_limits();
  l->set_max_voxels_per_slice(state_->limits.max_voxels_per_slice);
  l->set_max_slices(state_->limits.max_slices);
  l->set_max_sessions(state_->limits.max_sessions);
  l->set_max_message_bytes(state_->limits.max_message_bytes);
  l->set_idle_timeout_seconds(state_->limits.idle_timeout_s);
  for (v1::DType d : {v1::DTYPE_UINT8, v1::DTYPE_UINT16, v1::DTYPE_INT16, v1::DTYPE_FLOAT32}) {
    response->add_dtypes(d);
  }
  for (v1::Schedule s : {v1::SCHEDULE_NONE, v1::SCHEDULE_CLASSICAL, v1::SCHEDULE_TANDEM,
                         v1::SCHEDULE_TANDEM_LAG}) {
    response->add_schedules(s);
  }
  *response->mutable_counters() = CountersSnapshot();
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  reactor->Finish(grpc::Status::OK);
  return reactor;
}

}  // namespace tandem::server
