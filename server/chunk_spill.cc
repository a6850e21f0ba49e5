#include "tandem/server/chunk_spill.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "absl/strings/str_cat.h"

namespace tandem::server {

absl::StatusOr<std::unique_ptr<SpillFile>> SpillFile::Create(const std::string& dir) {
  std::string name = absl::StrCat(dir, "/tandem-watch-XXXXXX");
  std::vector<char> path(name.begin(), name.end());
  path.push_back('\0');
  const int fd = mkostemp(path.data(), O_CLOEXEC);
  if (fd < 0) {
    return absl::UnavailableError(absl::StrCat("cannot create a file in watch spill directory '",
                                               dir, "': ", std::strerror(errno)));
  }
  unlink(path.data());  // the open descriptor keeps it; nothing outlives the process
  return std::unique_ptr<SpillFile>(new SpillFile(fd, dir));
}

SpillFile::~SpillFile() { close(fd_); }

absl::StatusOr<int64_t> SpillFile::Append(std::string_view bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = pwrite(fd_, bytes.data() + done, bytes.size() - done,
                             static_cast<off_t>(end_ + static_cast<int64_t>(done)));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int error = n < 0 ? errno : ENOSPC;
      if (ftruncate(fd_, static_cast<off_t>(end_)) != 0) {
        // The next Append writes over the partial bytes anyway.
      }
      return absl::ResourceExhaustedError(absl::StrCat("cannot write to watch spill directory '",
                                                       dir_, "': ", std::strerror(error)));
    }
    done += static_cast<size_t>(n);
  }
  const int64_t offset = end_;
  end_ += static_cast<int64_t>(bytes.size());
  return offset;
}

absl::Status SpillFile::Read(int64_t offset, int64_t size, std::string* out) const {
  out->resize(static_cast<size_t>(size));
  size_t done = 0;
  while (done < out->size()) {
    const ssize_t n = pread(fd_, out->data() + done, out->size() - done,
                            static_cast<off_t>(offset + static_cast<int64_t>(done)));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      return absl::DataLossError(
          absl::StrCat("cannot read a kept chunk back from watch spill directory '", dir_,
                       "': ", n < 0 ? std::strerror(errno) : "file too short"));
    }
    done += static_cast<size_t>(n);
  }
  return absl::OkStatus();
}

void SpillFile::Release(int64_t offset, int64_t size) {
  if (fallocate(fd_, FALLOC_FL_PUNCH_HOLE | FALLOC_FL_KEEP_SIZE, static_cast<off_t>(offset),
                static_cast<off_t>(size)) != 0) {
    // Not every file system punches holes: the space comes back when the session ends.
  }
}

std::string DefaultSpillDir() {
  const char* tmp = std::getenv("TMPDIR");
  return tmp != nullptr && *tmp != '\0' ? std::string(tmp) : std::string("/tmp");
}

}  // namespace tandem::server
