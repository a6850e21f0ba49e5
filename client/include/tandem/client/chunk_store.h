// Sealed chunks kept in a folder as they arrive (tandem-client stream and watch --chunks DIR),
// so that a client started again after a crash resumes its session from what it kept.
//
// DIR/chunk_<index, 6 digits>.drc holds each chunk's Draco bytes (as tandem view DIR reads
// them), written under a temporary name (.part) and renamed once whole, so a chunk file is
// never half written under its name. DIR/chunks.tsv says what is there: a first line naming
// the session, then, appended once a chunk's file is in place, one line per chunk (index,
// surface, slices, counts, bytes and a checksum of the file). Load takes the chunks 0..n-1
// whose lines and files agree, in order, and stops at the first that does not (a line cut
// short, a file missing, of another size or checksum): those are what the client holds, and
// the server sends the rest. A kill of the client loses nothing that was saved; a power loss
// may (nothing is synced to the disk).
#ifndef TANDEM_CLIENT_CHUNK_STORE_H_
#define TANDEM_CLIENT_CHUNK_STORE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/v1/tandem.pb.h"

namespace tandem::client {

class ChunkStore {
 public:
  explicit ChunkStore(std::string dir) : dir_(std::move(dir)) {}
  const std::string& dir() const { return dir_; }

  // The chunks of session `session_id` kept in the folder, from index 0 on as far as they are
  // whole (none when the folder holds no chunks or another session's); the manifest is cut to
  // them, so that later ones are saved after them. Errors: the folder cannot be read or
  // written.
  absl::StatusOr<std::vector<v1::SealedChunk>> Load(const std::string& session_id);
  // Saves chunk `c` of session `session_id`: a session other than the one saved so far starts
  // the manifest again. A chunk already saved is skipped; one after a gap is an error.
  absl::Status Save(const std::string& session_id, const v1::SealedChunk& c);
  // Chunks 0 .. saved() - 1 of the current session are in the folder.
  int64_t saved() const { return saved_; }

  static constexpr char kManifest[] = "chunks.tsv";

 private:
  std::string ChunkPath(int64_t index) const;
  // Writes the manifest's first line and `lines` (a new session, or Load's cut).
  absl::Status RewriteManifest(const std::vector<std::string>& lines);

  const std::string dir_;
  std::string session_;  // whose chunks the manifest lists
  int64_t saved_ = 0;
};

}  // namespace tandem::client

#endif  // TANDEM_CLIENT_CHUNK_STORE_H_
