// Watching a session from another call (tandem.proto: Watch).
//
// Every Extract stream publishes what it sends into a SessionFeed, registered under the
// stream's id in a FeedRegistry: the latest Progress and band Preview, every SealedChunk (the
// encoded bytes, kept for watchers that come late, up to a byte bound), and at the end
// FinalMetrics and the stream's status. A watcher (WatchCall, a write reactor) keeps a
// cursor into the chunks and sends, one write at a time: the next chunk, else a newer
// Progress, else a newer Preview, else, once the feed is finished and every chunk is out,
// FinalMetrics and the feed's status. The producer only appends under the feed's mutex and
// then wakes the watchers (outside it): a slow watcher holds nothing back. Lock order:
// a watcher's mutex, then its feed's; a feed's mutex is never held while a watcher's is
// taken.
//
// Privacy: a feed is read (watched, listed by GetInfo) only by a call that presents its watch
// key (random, given to the creator in its first Progress) or the bearer token its creator
// used (MayRead); to any other call it does not exist.
//
// Resume: the chunks also serve the session's own client, resumed after its connection
// dropped (tandem/server/resume.h), which asks for those it did not keep. A client that
// acknowledges the chunks it kept (SessionConfig.chunk_acks) has every chunk it did not acknowledge
// kept for it until the session ends (held_, beside the newest retain_bytes kept for watchers),
// counted in the session's memory budget; without acknowledgements only the newest
// retain_bytes are kept once the chunks outgrew it.
//
// Where: the kept chunks are written, encoded, to the session's SpillFile
// (tandem/server/chunk_spill.h) in the server's spill directory and read back when a
// watcher or a resume needs them, so that what a session keeps does not grow the process
// with the depth of its scan; a chunk the file cannot take (no spill directory, a directory
// that cannot be written, a full disk) is kept in memory instead.
#ifndef TANDEM_SERVER_WATCH_H_
#define TANDEM_SERVER_WATCH_H_

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "tandem/budget.h"
#include "tandem/server/chunk_spill.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::server {

class FeedWatcher {
 public:
  virtual ~FeedWatcher() = default;
  virtual void Wake() = 0;  // the feed has something new; called without the feed's mutex
};

// How every feed of a server keeps its chunks, and what they all keep (for the metrics).
struct ChunkRetention {
  ChunkRetention(int64_t retain, std::string dir)
      : retain_bytes(retain), spill_dir(std::move(dir)) {}
  const int64_t retain_bytes;
  const std::string spill_dir;                    // empty: chunks are kept in memory
  std::atomic<int64_t> memory_bytes{0};           // kept chunks' bytes in memory
  std::atomic<int64_t> spilled_bytes{0};          // and in spill files
  std::atomic<bool> spill_failure_logged{false};  // one log line per server, not per chunk
};

class SessionFeed {
 public:
  // `owner`: the creator's bearer token identity (TokenAuthenticator::Check).
  SessionFeed(std::string id, std::string watch_key, int owner,
              std::shared_ptr<ChunkRetention> retention)
      : id_(std::move(id)),
        watch_key_(std::move(watch_key)),
        owner_(owner),
        retention_(std::move(retention)),
        retain_bytes_(retention_->retain_bytes),
        start_(absl::Now()) {}
  // Keeps its chunks in memory.
  SessionFeed(std::string id, std::string watch_key, int owner, int64_t retain_bytes)
      : SessionFeed(std::move(id), std::move(watch_key), owner,
                    std::make_shared<ChunkRetention>(retain_bytes, "")) {}
  ~SessionFeed();
  const std::string& id() const { return id_; }
  const std::string& watch_key() const { return watch_key_; }
  // Whether a call that presents `watch_key` and bearer token `identity` may read it.
  bool MayRead(std::string_view watch_key, int identity) const;

  // Producer side (the Extract stream's threads). SetSealed: from its config.
  void SetSealed(bool sealed, const std::string& description, bool labels = false);
  void Progress(const v1::Progress& p);
  void Preview(const v1::Preview& p);
  void Chunk(const v1::SealedChunk& c);
  // `metrics`: one FinalMetrics per surface (none when the stream failed).
  void Finish(std::vector<v1::FinalMetrics> metrics, const grpc::Status& status);
  // Resume (tandem/server/resume.h): the session waits for its client to come back.
  void SetWaiting(bool waiting);
  bool finished() const;
  // The chunks from index `first` on, for a resumed stream; FAILED_PRECONDITION when some
  // of them are no longer kept (see Chunk).
  absl::Status ChunksFrom(size_t first, std::vector<v1::SealedChunk>* out) const;
  // The client acknowledges the chunks it keeps (SessionConfig.chunk_acks): from now on
  // every chunk it has not acknowledged is kept until the session ends, its bytes counted
  // in `budget` (the session's).
  void KeepUnacknowledged(std::shared_ptr<MemoryBudget> budget);
  bool keeps_unacknowledged() const;
  // The client holds chunks 0 .. count-1 (a lower count than before changes nothing);
  // INVALID_ARGUMENT when fewer were posted.
  absl::Status Acknowledge(int64_t count);
  // Bytes of the chunks kept only because the client has not acknowledged them (in memory
  // or spilled: the session's budget bounds what it keeps for its client either way).
  int64_t unacknowledged_bytes() const;

  // Watcher side. Attach fails (with the status to send) for a session that cannot be
  // watched now.
  grpc::Status Attach(std::weak_ptr<FeedWatcher> watcher);
  // The next message for a watcher at `cursor` (updated), or nothing for now; *done is set
  // with the status once everything was taken.
  struct Cursor {
    size_t next_chunk = 0;
    int64_t progress_seen = -1, preview_seen = -1;
    size_t metrics_sent = 0;
  };
  std::optional<v1::ExtractResponse> Next(Cursor* cursor, std::optional<grpc::Status>* done);

  v1::SessionSummary Summary() const;
  bool finished_before(absl::Time t) const;  // finished, and before t

 private:
  // A kept chunk: its encoded bytes in the spill file at `offset`, or `chunk` itself.
  struct Kept {
    int64_t bytes = 0;
    int64_t offset = -1;  // -1: in memory
    v1::SealedChunk chunk;
  };
  void WakeAll();
  // Brings the budget's count of held_ up to date.
  void AccountHeldLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // `c` as kept: spilled when the spill file takes it, else a copy in memory.
  Kept KeepLocked(const v1::SealedChunk& c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  absl::Status LoadLocked(const Kept& k, v1::SealedChunk* out) const
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Forgets a kept chunk (its disk space back, the server's counts down).
  void ReleaseLocked(const Kept& k) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  const std::string id_;
  const std::string watch_key_;
  const int owner_;
  const std::shared_ptr<ChunkRetention> retention_;
  const int64_t retain_bytes_;
  const absl::Time start_;
  mutable absl::Mutex mu_;
  std::string description_ ABSL_GUARDED_BY(mu_);
  bool sealed_ ABSL_GUARDED_BY(mu_) = false;
  bool labels_ ABSL_GUARDED_BY(mu_) = false;  // a label session: its Progress says so to watchers
  bool waiting_ ABSL_GUARDED_BY(mu_) = false;
  // chunks_[i] is chunk dropped_ + i.
  std::deque<Kept> chunks_ ABSL_GUARDED_BY(mu_);
  std::unique_ptr<SpillFile> spill_ ABSL_GUARDED_BY(mu_);  // made at the first chunk
  bool spill_failed_ ABSL_GUARDED_BY(mu_) = false;         // the file could not be made
  int64_t chunk_bytes_ ABSL_GUARDED_BY(mu_) = 0;  // of every chunk ever added
  int64_t kept_bytes_ ABSL_GUARDED_BY(mu_) = 0;   // of chunks_
  // The chunks outgrew retain_bytes_: no new watcher; once none is attached, only the
  // newest retain_bytes_ of them are kept (for a resumed stream of the session's own
  // client, which may have missed the last few).
  bool overflowed_ ABSL_GUARDED_BY(mu_) = false;
  size_t dropped_ ABSL_GUARDED_BY(mu_) = 0;
  // Chunks dropped from chunks_ that the client has not acknowledged: held_[i] is chunk
  // dropped_ - held_.size() + i (kept while budget_ is set).
  std::shared_ptr<MemoryBudget> budget_ ABSL_GUARDED_BY(mu_);
  std::deque<Kept> held_ ABSL_GUARDED_BY(mu_);
  int64_t held_bytes_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t held_accounted_ ABSL_GUARDED_BY(mu_) = 0;  // what budget_ was told
  size_t acknowledged_ ABSL_GUARDED_BY(mu_) = 0;
  std::optional<v1::Progress> progress_ ABSL_GUARDED_BY(mu_);
  int64_t progress_version_ ABSL_GUARDED_BY(mu_) = 0;
  std::optional<v1::Preview> preview_ ABSL_GUARDED_BY(mu_);
  int64_t preview_version_ ABSL_GUARDED_BY(mu_) = 0;
  std::vector<v1::FinalMetrics> metrics_ ABSL_GUARDED_BY(mu_);
  std::optional<grpc::Status> status_ ABSL_GUARDED_BY(mu_);
  absl::Time finished_at_ ABSL_GUARDED_BY(mu_);
  std::vector<std::weak_ptr<FeedWatcher>> watchers_ ABSL_GUARDED_BY(mu_);
};

// The feeds of live sessions, and of finished ones for `linger` (then they expire).
class FeedRegistry {
 public:
  // `spill_dir`: where feeds keep their chunks (empty: in memory).
  FeedRegistry(absl::Duration linger, int64_t retain_bytes, std::string spill_dir = "")
      : linger_(linger),
        retention_(std::make_shared<ChunkRetention>(retain_bytes, std::move(spill_dir))) {}
  // With a fresh random id, for a creator of bearer token identity `owner`.
  std::shared_ptr<SessionFeed> Create(std::string watch_key, int owner);
  std::shared_ptr<SessionFeed> Find(const std::string& id);
  // Find, for a call that presents `watch_key` and bearer token `identity`: null as well
  // when it may not read the feed.
  std::shared_ptr<SessionFeed> FindReadable(const std::string& id, std::string_view watch_key,
                                            int identity);
  void Remove(const std::string& id);  // a feed never used (its stream resumed another)
  const ChunkRetention& retention() const { return *retention_; }
  // The sessions a call may read (see FindReadable), given any of `watch_keys`.
  std::vector<v1::SessionSummary> Summaries(const std::vector<std::string_view>& watch_keys,
                                            int identity);

 private:
  void ExpireLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  const absl::Duration linger_;
  const std::shared_ptr<ChunkRetention> retention_;
  absl::Mutex mu_;
  std::map<std::string, std::shared_ptr<SessionFeed>> feeds_ ABSL_GUARDED_BY(mu_);
};

// Starts a Watch call on `feed` (null: unknown id `id`, or one the call may not read), or one
// that ends at once with `refused` when that is not OK (authentication). The reactor owns
// itself.
grpc::ServerWriteReactor<v1::ExtractResponse>* StartWatch(
    std::shared_ptr<SessionFeed> feed, const std::string& id,
    const grpc::Status& refused = grpc::Status::OK);

}  // namespace tandem::server

#endif  // TANDEM_SERVER_WATCH_H_
