// Resuming a session after its client's connection dropped (tandem.proto: Resume).
//
// When an Extract stream is cancelled before End (the client's process died, the connection
// was lost, the client cancelled) and its job is between slices, the stream's worker parks
// the job here under the session's id, with its feed (server/watch.h, so watchers stay
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
#include "server/extract_job.h"
#include "server/watch.h"

namespace tandem::server {

// A random secret of 128 bits in hex (OpenSSL's RAND_bytes).
std::string NewResumeToken();

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

  // Parks `parked` and blocks until it is adopted (returns nothing) or its window is over,
  // or Close was called (returns it: the caller ends it).
  std::optional<ParkedSession> ParkAndWait(ParkedSession parked);
  // Takes the parked session `id` for a new stream that sends `next_slice` first and holds
  // the session's first `chunks_received` sealed chunks (*replay: the ones after them).
  // Errors (the session stays parked): NOT_FOUND (none parked under this id),
  // PERMISSION_DENIED (token), FAILED_PRECONDITION (the next slice, and *expected_slice is
  // set to the one it needs; or chunks no longer kept).
  absl::StatusOr<ParkedSession> Adopt(const std::string& id, const std::string& token,
                                      int64_t next_slice, int64_t chunks_received,
                                      int64_t* expected_slice,
                                      std::vector<v1::SealedChunk>* replay);
  // Ends every wait now and refuses to park from now on (server shutdown).
  void Close();
  // Ends the wait of the session parked longest ago (a new stream needs its slot); false
  // when none is parked.
  bool EvictOldest();
  int64_t parked() const;

 private:
  const absl::Duration window_;
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
  struct Entry {
    ParkedSession session;
    absl::Time since;
    bool evicted = false;
  };
  mutable absl::Mutex mu_;
  std::map<std::string, Entry> parked_ ABSL_GUARDED_BY(mu_);
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_RESUME_H_
