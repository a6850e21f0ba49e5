// The Extract stream's reactor side: reads, writes, its end, and what the worker posts.
#include "extract_call.h"

#include <algorithm>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/common/wire.h"
#include "tandem/server/log.h"

namespace tandem::server {
namespace {

// How long the final OK waits for a client's half-close after End (see PumpLocked).
constexpr absl::Duration kOkGrace = absl::Seconds(1);

}  // namespace

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
  if (!st.ok()) EndStreamLocked(common::ToGrpcStatus(st));
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

}  // namespace tandem::server
