// The Extract stream's worker thread: started with the stream, it feeds the job, resumes a
// parked session, waits for the last write, and holds a session its client left.
#include <algorithm>
#include <optional>
#include <string>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "extract_call.h"
#include "tandem/common/wire.h"
#include "tandem/server/log.h"

namespace tandem::server {
namespace {

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

}  // namespace

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
            feed_->SetSealed(request->config().sealed_chunks(), description_,
                             request->config().labels().enabled());
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
        EndStream(common::ToGrpcStatus(status));
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

}  // namespace tandem::server
