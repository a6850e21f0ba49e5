// Sealed chunks that a session keeps for late watchers and resumes, on disk rather than in
// the process's memory (tandem/server/watch.h): one temporary file per session, unlinked
// as soon as it is open (nothing is left behind, whatever ends the process), appended to
// and read back by offset. docs/decisions.md, "Chunks kept for watchers go to disk".
#ifndef TANDEM_SERVER_CHUNK_SPILL_H_
#define TANDEM_SERVER_CHUNK_SPILL_H_

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace tandem::server {

class SpillFile {
 public:
  // A new, already unlinked file in `dir`; the error names the directory and the cause.
  static absl::StatusOr<std::unique_ptr<SpillFile>> Create(const std::string& dir);
  SpillFile(const SpillFile&) = delete;
  SpillFile& operator=(const SpillFile&) = delete;
  ~SpillFile();

  // Appends `bytes` whole; returns their offset. On an error (a full disk) the file is as
  // it was before.
  absl::StatusOr<int64_t> Append(std::string_view bytes);
  // The `size` bytes at `offset` (a range Append returned).
  absl::Status Read(int64_t offset, int64_t size, std::string* out) const;
  // Gives the disk space of a range back (best effort: a file system that cannot punch
  // holes keeps it until the file is closed).
  void Release(int64_t offset, int64_t size);

 private:
  SpillFile(int fd, std::string dir) : fd_(fd), dir_(std::move(dir)) {}
  const int fd_;
  const std::string dir_;
  int64_t end_ = 0;
};

// tandem-server's default spill directory: $TMPDIR, else /tmp.
std::string DefaultSpillDir();

}  // namespace tandem::server

#endif  // TANDEM_SERVER_CHUNK_SPILL_H_
