// Resuming a session after its client's connection dropped (tandem.proto: Resume).
//
// When an Extract stream is cancelled before End (the client's process died, the connection
// was lost, the client cancelled) and its job is between slices, the stream's worker parks
// the job here under the session's id, with its feed (tandem/server/watch.h, so watchers stay
// attached and the sealed chunks stay available for replay) and its resume token, and then
// waits, on its own thread, until another stream adopts the job or the window is over.
// Adopt checks the token and the next slice; a stream that adopts a job continues it
// exactly where it stopped, so the result is the uninterrupted stream's. Unadopted jobs
// are destroyed when their window ends, or at once when the server shuts down (Close).
#ifndef TANDEM_SERVER_RESUME_H_
#define TANDEM_SERVER_RESUME_H_

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "tandem/server/extract_job.h"
#include "tandem/server/watch.h"

namespace tandem::server {

// A random secret of 128 bits in hex (OpenSSL's RAND_bytes): resume tokens, watch keys.
std::string NewSecret();

struct ParkedSession {
  std::unique_ptr<ExtractJob> job;  // detached (ExtractJob::Detach)
  std::shared_ptr<SessionFeed> feed;
  std::string token;
  int64_t memory_bytes = 0;  // job->MemoryBytes() when parked (counted in session_bytes)
};

class ResumeTable {
 public:
  explicit ResumeTable(absl::Duration window) : window_(window) {}
  absl::Duration window() const { return window_; }

  // The slots tandem-server --max-sessions limits, counted here under one lock so that a
  // session is counted exactly once on its way from its stream to this table: as a stream
  // from AdmitStream until StreamEnded or until ParkAndWait takes it, then as a parked
  // session until it is adopted (the adopting stream holds its own slot), evicted or ended.
  // (Counting the stream until gRPC has finished with it counted a parked session twice for
  // a moment, and a new stream in that moment was refused as busy.)
  //
  // Takes a slot for a new stream, ending the wait of the oldest parked session if that
  // frees one; false when every slot is held by a stream.
  bool AdmitStream(int64_t max_sessions);
  // Gives back the slot of an admitted stream whose session was not parked.
  void StreamEnded();

  // Parks `parked` (its stream's slot becomes the parked session's) and blocks until it is
  // adopted (returns nothing) or its window is over, or Close was called (returns it: the
  // caller ends it).
  std::optional<ParkedSession> ParkAndWait(ParkedSession parked);
  // Takes the parked session `id` for a new stream that sends `next_slice` first and holds
  // the session's first `chunks_received` sealed chunks (*replay: the ones after them;
  // those it holds count as acknowledged, SessionFeed::Acknowledge).
  // Errors (the session stays parked): NOT_FOUND (none parked under this id),
  // PERMISSION_DENIED (token), FAILED_PRECONDITION (the next slice, and *expected_slice is
  // set to the one it needs; or chunks no longer kept).
  absl::StatusOr<ParkedSession> Adopt(const std::string& id, const std::string& token,
                                      int64_t next_slice, int64_t chunks_received,
                                      int64_t* expected_slice,
                                      std::vector<v1::SealedChunk>* replay);
  // Ends every wait now and refuses to park from now on (server shutdown).
  void Close();
  int64_t parked() const;

 private:
  const absl::Duration window_;
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
  struct Entry {
    ParkedSession session;
    absl::Time since;
    bool evicted = false;
  };
  // Ends the wait of the session parked longest ago; false when none is parked.
  bool EvictOldestLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  int64_t ParkedLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);

  mutable absl::Mutex mu_;
  std::map<std::string, Entry> parked_ ABSL_GUARDED_BY(mu_);
  int64_t streams_ ABSL_GUARDED_BY(mu_) = 0;  // admitted streams whose session is not parked
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_RESUME_H_
