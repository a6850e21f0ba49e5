#include "tandem/server/watch.h"

#include <random>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/common/tokens.h"
#include "tandem/server/auth.h"
#include "tandem/server/log.h"

namespace tandem::server {

using Response = v1::ExtractResponse;

namespace {

// Longer keys are never compared (keys are 32 hex digits).
constexpr size_t kMaxWatchKeyBytes = 64;
constexpr size_t kMaxInfoWatchKeys = 64;

}  // namespace

SessionFeed::~SessionFeed() {
  absl::MutexLock lock(&mu_);
  for (const Kept& k : chunks_) ReleaseLocked(k);
  for (const Kept& k : held_) ReleaseLocked(k);
  held_.clear();
  held_bytes_ = 0;
  AccountHeldLocked();
}

SessionFeed::Kept SessionFeed::KeepLocked(const v1::SealedChunk& c) {
  Kept k;
  k.bytes = static_cast<int64_t>(c.ByteSizeLong());
  absl::Status failed;
  if (spill_ == nullptr && !spill_failed_ && !retention_->spill_dir.empty()) {
    absl::StatusOr<std::unique_ptr<SpillFile>> file = SpillFile::Create(retention_->spill_dir);
    spill_failed_ = !file.ok();
    if (file.ok()) spill_ = *std::move(file);
    failed = file.status();
  }
  if (spill_ != nullptr) {
    absl::StatusOr<int64_t> offset = spill_->Append(c.SerializeAsString());
    if (offset.ok()) {
      k.offset = *offset;
      retention_->spilled_bytes += k.bytes;
      return k;
    }
    failed = offset.status();
  }
  if (!failed.ok() && !retention_->spill_failure_logged.exchange(true)) {
    const std::string error(failed.message());
    LogEvent("watch_spill_failed", {{"session", LogField::Word{id_}},
                                    {"error", LogField::Str{error}},
                                    {"fallback", LogField::Word{"memory"}}});
  }
  k.chunk = c;
  retention_->memory_bytes += k.bytes;
  return k;
}

absl::Status SessionFeed::LoadLocked(const Kept& k, v1::SealedChunk* out) const {
  if (k.offset < 0) {
    *out = k.chunk;
    return absl::OkStatus();
  }
  std::string bytes;
  if (absl::Status st = spill_->Read(k.offset, k.bytes, &bytes); !st.ok()) return st;
  if (!out->ParseFromString(bytes)) {
    return absl::DataLossError(absl::StrCat("a chunk of session ", id_,
                                            " read back from the watch spill file does not parse"));
  }
  return absl::OkStatus();
}

void SessionFeed::ReleaseLocked(const Kept& k) {
  if (k.offset < 0) {
    retention_->memory_bytes -= k.bytes;
    return;
  }
  spill_->Release(k.offset, k.bytes);
  retention_->spilled_bytes -= k.bytes;
}

bool SessionFeed::MayRead(std::string_view watch_key, int identity) const {
  if (identity != TokenAuthenticator::kNoIdentity && identity == owner_) return true;
  return !watch_key.empty() && watch_key.size() <= kMaxWatchKeyBytes &&
         common::ConstantTimeEquals(watch_key_, watch_key);
}

void SessionFeed::SetSealed(bool sealed, const std::string& description, bool labels) {
  absl::MutexLock lock(&mu_);
  sealed_ = sealed;
  labels_ = labels;
  description_ = description;
}

void SessionFeed::Progress(const v1::Progress& p) {
  {
    absl::MutexLock lock(&mu_);
    progress_ = p;
    ++progress_version_;
  }
  WakeAll();
}

void SessionFeed::Preview(const v1::Preview& p) {
  {
    absl::MutexLock lock(&mu_);
    if (!sealed_) return;  // only sealed sessions are watched
    preview_ = p;
    ++preview_version_;
  }
  WakeAll();
}

void SessionFeed::Chunk(const v1::SealedChunk& c) {
  {
    absl::MutexLock lock(&mu_);
    chunks_.push_back(KeepLocked(c));
    const int64_t bytes = chunks_.back().bytes;
    chunk_bytes_ += bytes;
    if (chunk_bytes_ > retain_bytes_) overflowed_ = true;
    kept_bytes_ += bytes;
    bool watched = false;
    for (const auto& w : watchers_) watched |= !w.expired();
    // Nobody can attach any more and nobody is attached: keep only the newest (a resumed
    // stream replays those its client missed; watchers' cursors index chunks_, and there
    // are none).
    while (overflowed_ && !watched && kept_bytes_ > retain_bytes_ && chunks_.size() > 1) {
      const int64_t front = chunks_.front().bytes;
      kept_bytes_ -= front;
      if (budget_ != nullptr && dropped_ >= acknowledged_) {  // the client may still need it
        held_.push_back(std::move(chunks_.front()));
        held_bytes_ += front;
      } else {
        ReleaseLocked(chunks_.front());
      }
      chunks_.pop_front();
      ++dropped_;
    }
    AccountHeldLocked();
  }
  WakeAll();
}

void SessionFeed::KeepUnacknowledged(std::shared_ptr<MemoryBudget> budget) {
  absl::MutexLock lock(&mu_);
  if (budget_ == nullptr) budget_ = std::move(budget);
}

bool SessionFeed::keeps_unacknowledged() const {
  absl::MutexLock lock(&mu_);
  return budget_ != nullptr;
}

absl::Status SessionFeed::Acknowledge(int64_t count) {
  absl::MutexLock lock(&mu_);
  const size_t posted = dropped_ + chunks_.size();
  if (count < 0 || static_cast<uint64_t>(count) > posted) {
    return absl::InvalidArgumentError(
        absl::StrFormat("ChunksReceived.count = %d, but session %s has sent %d sealed chunks",
                        count, id_, static_cast<int64_t>(posted)));
  }
  acknowledged_ = std::max(acknowledged_, static_cast<size_t>(count));
  while (!held_.empty() && dropped_ - held_.size() < acknowledged_) {
    held_bytes_ -= held_.front().bytes;
    ReleaseLocked(held_.front());
    held_.pop_front();
  }
  AccountHeldLocked();
  return absl::OkStatus();
}

int64_t SessionFeed::unacknowledged_bytes() const {
  absl::MutexLock lock(&mu_);
  return held_bytes_;
}

void SessionFeed::AccountHeldLocked() {
  if (budget_ != nullptr && held_bytes_ != held_accounted_) {
    budget_->AddOutside(held_bytes_ - held_accounted_);
  }
  held_accounted_ = held_bytes_;
}

void SessionFeed::SetWaiting(bool waiting) {
  absl::MutexLock lock(&mu_);
  waiting_ = waiting;
}

bool SessionFeed::finished() const {
  absl::MutexLock lock(&mu_);
  return status_.has_value();
}

absl::Status SessionFeed::ChunksFrom(size_t first, std::vector<v1::SealedChunk>* out) const {
  absl::MutexLock lock(&mu_);
  const size_t end = dropped_ + chunks_.size();
  const size_t kept_from = dropped_ - held_.size();
  if (first < kept_from || first > end) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "session %s cannot resend its sealed chunks from index %d: it keeps %d..%d (the "
        "newest tandem-server --watch-retain-mb of them, and those a client that keeps its "
        "chunks, tandem-client stream --chunks DIR, has not acknowledged)",
        id_, first, kept_from, static_cast<int64_t>(end) - 1));
  }
  out->clear();
  for (size_t i = first; i < end; ++i) {
    const Kept& k = i < dropped_ ? held_[i - kept_from] : chunks_[i - dropped_];
    if (absl::Status st = LoadLocked(k, &out->emplace_back()); !st.ok()) return st;
  }
  return absl::OkStatus();
}

void SessionFeed::Finish(std::vector<v1::FinalMetrics> metrics, const grpc::Status& status) {
  {
    absl::MutexLock lock(&mu_);
    if (status_) return;  // the first end counts
    metrics_ = std::move(metrics);
    status_ = status;
    preview_.reset();  // everything is in the chunks now
    finished_at_ = absl::Now();
    for (const Kept& k : held_) ReleaseLocked(k);
    held_.clear();  // no resume can follow
    held_bytes_ = 0;
    AccountHeldLocked();
  }
  WakeAll();
}

void SessionFeed::WakeAll() {
  std::vector<std::shared_ptr<FeedWatcher>> live;
  {
    absl::MutexLock lock(&mu_);
    size_t kept = 0;
    for (size_t i = 0; i < watchers_.size(); ++i) {
      if (auto w = watchers_[i].lock()) {
        live.push_back(std::move(w));
        if (kept != i) watchers_[kept] = std::move(watchers_[i]);  // (a self-move empties it)
        ++kept;
      }
    }
    watchers_.resize(kept);
  }
  for (auto& w : live) w->Wake();
}

grpc::Status SessionFeed::Attach(std::weak_ptr<FeedWatcher> watcher) {
  absl::MutexLock lock(&mu_);
  if (!sealed_) {
    return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                        absl::StrCat("session ", id_, " does not send sealed chunks "
                                     "(SessionConfig.sealed_chunks): it cannot be watched"));
  }
  if (overflowed_) {
    return grpc::Status(
        grpc::StatusCode::RESOURCE_EXHAUSTED,
        absl::StrCat("session ", id_, "'s chunks outgrew what this server keeps for late "
                     "watchers (tandem-server --watch-retain-mb); watch it from its start"));
  }
  watchers_.push_back(std::move(watcher));
  return grpc::Status::OK;
}

std::optional<Response> SessionFeed::Next(Cursor* cursor, std::optional<grpc::Status>* done) {
  absl::MutexLock lock(&mu_);
  Response r;
  if (cursor->next_chunk < chunks_.size()) {
    if (absl::Status st = LoadLocked(chunks_[cursor->next_chunk++], r.mutable_sealed_chunk());
        !st.ok()) {
      *done = grpc::Status(grpc::StatusCode::DATA_LOSS, std::string(st.message()));
      return std::nullopt;
    }
    return r;
  }
  if (progress_ && cursor->progress_seen != progress_version_) {
    cursor->progress_seen = progress_version_;
    *r.mutable_progress() = *progress_;
    r.mutable_progress()->set_session_id(id_);
    r.mutable_progress()->set_labels(labels_);
    return r;
  }
  if (preview_ && cursor->preview_seen != preview_version_) {
    cursor->preview_seen = preview_version_;
    *r.mutable_preview() = *preview_;
    return r;
  }
  if (status_) {
    if (cursor->metrics_sent < metrics_.size()) {
      *r.mutable_final_metrics() = metrics_[cursor->metrics_sent++];
      return r;
    }
    *done = *status_;
  }
  return std::nullopt;
}

v1::SessionSummary SessionFeed::Summary() const {
  absl::MutexLock lock(&mu_);
  v1::SessionSummary s;
  s.set_id(id_);
  s.set_description(description_);
  s.set_slices_consumed(progress_ ? progress_->slices_consumed() : 0);
  s.set_sealed_chunks(sealed_);
  s.set_finished(status_.has_value());
  s.set_age_seconds(absl::ToDoubleSeconds(absl::Now() - start_));
  s.set_waiting_for_resume(waiting_ && !status_.has_value());
  return s;
}

bool SessionFeed::finished_before(absl::Time t) const {
  absl::MutexLock lock(&mu_);
  return status_.has_value() && finished_at_ < t;
}

std::shared_ptr<SessionFeed> FeedRegistry::Create(std::string watch_key, int owner) {
  static thread_local std::mt19937_64 random{std::random_device{}()};
  absl::MutexLock lock(&mu_);
  ExpireLocked();
  std::string id;
  do {
    id = absl::StrFormat("%016x%016x", random(), random());
  } while (feeds_.count(id) > 0);
  auto feed = std::make_shared<SessionFeed>(id, std::move(watch_key), owner, retention_);
  feeds_[id] = feed;
  return feed;
}

std::shared_ptr<SessionFeed> FeedRegistry::Find(const std::string& id) {
  absl::MutexLock lock(&mu_);
  ExpireLocked();
  auto it = feeds_.find(id);
  return it == feeds_.end() ? nullptr : it->second;
}

std::shared_ptr<SessionFeed> FeedRegistry::FindReadable(const std::string& id,
                                                        std::string_view watch_key, int identity) {
  std::shared_ptr<SessionFeed> feed = Find(id);
  // An unknown id costs the same comparison as a known one with the wrong key.
  static const SessionFeed kNobody("", std::string(32, '0'), TokenAuthenticator::kNoIdentity, 0);
  const bool may = (feed != nullptr ? *feed : kNobody).MayRead(watch_key, identity);
  return may && feed != nullptr ? feed : nullptr;
}

void FeedRegistry::Remove(const std::string& id) {
  absl::MutexLock lock(&mu_);
  feeds_.erase(id);
}

std::vector<v1::SessionSummary> FeedRegistry::Summaries(
    const std::vector<std::string_view>& watch_keys, int identity) {
  absl::MutexLock lock(&mu_);
  ExpireLocked();
  std::vector<v1::SessionSummary> out;
  const size_t keys = std::min(watch_keys.size(), kMaxInfoWatchKeys);
  for (const auto& [id, feed] : feeds_) {
    bool may = feed->MayRead("", identity);
    for (size_t k = 0; k < keys && !may; ++k) may = feed->MayRead(watch_keys[k], identity);
    if (may) out.push_back(feed->Summary());
  }
  return out;
}

void FeedRegistry::ExpireLocked() {
  const absl::Time before = absl::Now() - linger_;
  for (auto it = feeds_.begin(); it != feeds_.end();) {
    it = it->second->finished_before(before) ? feeds_.erase(it) : std::next(it);
  }
}

namespace {

// One watcher: one write in flight, the next message taken from the feed when it is done
// or when the feed wakes it.
class WatchCall final : public grpc::ServerWriteReactor<Response>,
                        public FeedWatcher,
                        public std::enable_shared_from_this<WatchCall> {
 public:
  explicit WatchCall(std::shared_ptr<SessionFeed> feed) : feed_(std::move(feed)) {}

  void Begin(const std::string& id, const grpc::Status& refused) {
    self_ = shared_from_this();
    absl::MutexLock lock(&mu_);
    if (!refused.ok()) {
      FinishLocked(refused);
      return;
    }
    if (feed_ == nullptr) {
      FinishLocked(grpc::Status(
          grpc::StatusCode::NOT_FOUND,
          absl::StrCat("no session '", absl::string_view(id).substr(0, 64),
                       "' that this call may watch on this server: unknown, finished longer ago "
                       "than tandem-server --watch-linger-seconds, or the watch key is missing "
                       "or wrong (the streaming client prints it; tandem-client watch takes it "
                       "from --watch-key-file FILE or $TANDEM_WATCH_KEY)")));
      return;
    }
    if (grpc::Status st = feed_->Attach(weak_from_this()); !st.ok()) {
      FinishLocked(st);
      return;
    }
    PumpLocked();
  }
  void Wake() override {
    absl::MutexLock lock(&mu_);
    PumpLocked();
  }
  void OnWriteDone(bool ok) override {
    absl::MutexLock lock(&mu_);
    write_in_flight_ = false;
    if (!ok) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "the watcher went away"));
      return;
    }
    PumpLocked();
  }
  void OnCancel() override {
    absl::MutexLock lock(&mu_);
    cancelled_ = true;
    if (!write_in_flight_) FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"));
  }
  void OnDone() override {
    std::shared_ptr<WatchCall> last = std::move(self_);  // goes at the end of this call
  }

 private:
  void PumpLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    if (write_in_flight_ || finished_ || cancelled_) return;
    std::optional<grpc::Status> done;
    std::optional<Response> next = feed_->Next(&cursor_, &done);
    if (next) {
      buf_ = *std::move(next);
      write_in_flight_ = true;
      StartWrite(&buf_);
    } else if (done) {
      FinishLocked(*done);
    }
  }
  void FinishLocked(const grpc::Status& status) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    if (finished_) return;
    finished_ = true;
    Finish(status);
  }

  const std::shared_ptr<SessionFeed> feed_;
  std::shared_ptr<WatchCall> self_;  // until OnDone
  absl::Mutex mu_;
  SessionFeed::Cursor cursor_ ABSL_GUARDED_BY(mu_);
  Response buf_ ABSL_GUARDED_BY(mu_);
  bool write_in_flight_ ABSL_GUARDED_BY(mu_) = false;
  bool finished_ ABSL_GUARDED_BY(mu_) = false;
  bool cancelled_ ABSL_GUARDED_BY(mu_) = false;
};

}  // namespace

grpc::ServerWriteReactor<Response>* StartWatch(std::shared_ptr<SessionFeed> feed,
                                               const std::string& id,
                                               const grpc::Status& refused) {
  auto call = std::make_shared<WatchCall>(std::move(feed));
  call->Begin(id, refused);
  return call.get();
}

}  // namespace tandem::server
