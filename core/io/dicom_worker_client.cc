#include "dicom_worker_client.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <mutex>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "dicom_wire.h"
#include "tandem/module/module_loader.h"
#include "tandem/status_macros.h"

extern char** environ;

namespace tandem::io::dicom {
namespace {

using Clock = std::chrono::steady_clock;

// A request's time: GDCM reads a header in milliseconds and decodes the largest slices in
// seconds; a file that takes longer has made it loop.
constexpr double kHeaderSeconds = 10;
constexpr double kPixelSeconds = 10;
constexpr double kPixelBytesPerSecond = 50e6;
constexpr size_t kMaxMessage = 1 << 20;
constexpr size_t kMaxHeader = 1 << 20;
constexpr size_t kMaxIdle = 4;

std::atomic<double> g_time_limit{0};

struct Worker {
  pid_t pid = -1;
  int fd = -1;
  int shared = -1;  // the memfd the worker decodes pixels into
  const uint8_t* map = nullptr;
  size_t mapped = 0;
};

std::mutex g_mu;
std::vector<Worker>& Idle() {
  static auto* idle = new std::vector<Worker>;  // never destroyed: workers exit on EOF
  return *idle;
}

absl::StatusOr<std::string> FindWorker() {
  std::vector<std::string> tried;
  for (const std::string& place : module::ModulePlaces(kWorkerName)) {
    if (::access(place.c_str(), X_OK) == 0) return place;
    tried.push_back(absl::StrCat(place, ": ", std::strerror(errno)));
  }
  return absl::FailedPreconditionError(absl::StrCat(
      "DICOM support is not available: its reader program ", kWorkerName,
      " (built and installed with tandem) was not found: ", absl::StrJoin(tried, "; ")));
}

absl::StatusOr<Worker> Spawn() {
  static const absl::StatusOr<std::string> exe = FindWorker();
  if (!exe.ok()) return exe.status();
  int sv[2];
  if (::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) != 0) {
    return absl::InternalError(absl::StrCat("socketpair: ", std::strerror(errno)));
  }
  // dup2 onto fd 3 clears close-on-exec in the child, but not when the fd is 3 already.
  // Both above the fds they become in the child, so that no dup2 clobbers the other.
  const int child_end = ::fcntl(sv[1], F_DUPFD_CLOEXEC, wire::kSharedFd + 1);
  ::close(sv[1]);
  const int shared_fd = ::memfd_create("tandem-dicom-pixels", MFD_CLOEXEC);
  const int shared = shared_fd < 0 ? -1 : ::fcntl(shared_fd, F_DUPFD_CLOEXEC, wire::kSharedFd + 1);
  if (shared_fd >= 0) ::close(shared_fd);
  if (child_end < 0 || shared < 0) {
    const int err = errno;
    for (int fd : {sv[0], child_end, shared}) {
      if (fd >= 0) ::close(fd);
    }
    return absl::ResourceExhaustedError(
        absl::StrCat("cannot set up the DICOM reader: ", std::strerror(err)));
  }
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, child_end, wire::kSocketFd);
  posix_spawn_file_actions_adddup2(&actions, shared, wire::kSharedFd);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sigset_t none;
  sigemptyset(&none);
  posix_spawnattr_setsigmask(&attr, &none);  // whatever this thread blocks
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGMASK);
  char* argv[] = {const_cast<char*>(exe->c_str()), nullptr};
  pid_t pid = -1;
  const int rc = ::posix_spawn(&pid, exe->c_str(), &actions, &attr, argv, environ);
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attr);
  ::close(child_end);
  if (rc != 0) {
    ::close(sv[0]);
    ::close(shared);
    return absl::FailedPreconditionError(
        absl::StrCat("cannot start the DICOM reader ", *exe, ": ", std::strerror(rc)));
  }
  return Worker{pid, sv[0], shared};
}

// How a worker that stopped answering ended: "killed by signal 11 (Segmentation fault)".
std::string Reap(const Worker& w) {
  ::close(w.fd);
  ::close(w.shared);
  if (w.map != nullptr) ::munmap(const_cast<uint8_t*>(w.map), w.mapped);
  int status = 0;
  pid_t got;
  do {
    got = ::waitpid(w.pid, &status, 0);
  } while (got < 0 && errno == EINTR);
  if (got != w.pid) return "ended";
  if (WIFSIGNALED(status)) {
    return absl::StrCat("killed by signal ", WTERMSIG(status), " (", strsignal(WTERMSIG(status)),
                        ")");
  }
  return absl::StrCat("exited with status ", WEXITSTATUS(status));
}

void Kill(const Worker& w) {
  ::kill(w.pid, SIGKILL);
  Reap(w);
}

void Release(const Worker& w) {
  std::lock_guard<std::mutex> lock(g_mu);
  if (Idle().size() < kMaxIdle) {
    Idle().push_back(w);
    return;
  }
  Reap(w);  // it exits on EOF
}

bool SendAll(int fd, const std::string& bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t put = ::send(fd, bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
    if (put < 0 && errno == EINTR) continue;
    if (put <= 0) return false;
    done += static_cast<size_t>(put);
  }
  return true;
}

enum class Got { kOk, kClosed, kLate };

Got RecvAll(int fd, void* dst, size_t n, Clock::time_point deadline) {
  char* p = static_cast<char*>(dst);
  while (n > 0) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) return Got::kLate;
    pollfd pfd{fd, POLLIN, 0};
    const int ready = ::poll(&pfd, 1, static_cast<int>(std::min<int64_t>(left.count(), 1 << 30)));
    if (ready < 0 && errno == EINTR) continue;
    if (ready < 0) return Got::kClosed;
    if (ready == 0) continue;
    const ssize_t got = ::recv(fd, p, n, 0);
    if (got < 0 && (errno == EINTR || errno == EAGAIN)) continue;
    if (got <= 0) return Got::kClosed;
    p += got;
    n -= static_cast<size_t>(got);
  }
  return Got::kOk;
}

// The worker's shared memory, grown to hold n bytes.
absl::Status Reserve(Worker& w, size_t n) {
  if (w.mapped >= n) return absl::OkStatus();
  if (w.map != nullptr) ::munmap(const_cast<uint8_t*>(w.map), w.mapped);
  w.map = nullptr;
  w.mapped = 0;
  const size_t size = (n + (1 << 20) - 1) & ~size_t{(1 << 20) - 1};
  if (::ftruncate(w.shared, static_cast<off_t>(size)) != 0) {
    return absl::ResourceExhaustedError(
        absl::StrCat("cannot size the DICOM reader's pixel buffer: ", std::strerror(errno)));
  }
  void* m = ::mmap(nullptr, size, PROT_READ, MAP_SHARED, w.shared, 0);
  if (m == MAP_FAILED) {
    return absl::ResourceExhaustedError(
        absl::StrCat("cannot map the DICOM reader's pixel buffer: ", std::strerror(errno)));
  }
  w.map = static_cast<const uint8_t*>(m);
  w.mapped = size;
  return absl::OkStatus();
}

// One request to a reader process; the reply's payload (at most max_payload bytes) goes to
// the buffer `sink` returns for its size, and on success `shared` bytes of its shared memory
// to shared_out.
template <typename Sink>
absl::Status Call(const std::string& path, uint8_t op, uint64_t arg, size_t max_payload,
                  double seconds, Sink sink, size_t shared = 0, uint8_t* shared_out = nullptr) {
  wire::Writer req;
  req.U32(static_cast<uint32_t>(wire::kRequestFixed + path.size()));
  req.U8(op);
  req.U64(arg);
  req.out() += path;
  Worker w;
  for (int attempt = 0;; ++attempt) {
    bool fresh = false;
    {
      std::lock_guard<std::mutex> lock(g_mu);
      if (!Idle().empty()) {
        w = Idle().back();
        Idle().pop_back();
      } else {
        fresh = true;
      }
    }
    if (fresh) {
      TANDEM_ASSIGN_OR_RETURN(Worker spawned, Spawn());
      w = spawned;
    }
    if (absl::Status st = Reserve(w, shared); !st.ok()) {
      Release(w);
      return st;
    }
    if (SendAll(w.fd, req.out())) break;
    Kill(w);  // an idle process that died meanwhile: try a fresh one
    if (fresh || attempt > 0) {
      return absl::UnavailableError(
          absl::StrCat(path, ": the DICOM reader process does not take requests"));
    }
  }
  if (const double t = g_time_limit.load(); t > 0) seconds = t;
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(seconds));
  char fixed[wire::kReplyFixed];
  Got got = RecvAll(w.fd, fixed, sizeof fixed, deadline);
  wire::Reader r(fixed, sizeof fixed);
  const uint32_t code = r.U32(), message_size = r.U32();
  const bool retiring = r.U8() != 0;
  const uint64_t payload_size = r.U64();
  std::string message;
  if (got == Got::kOk) {
    if (message_size > kMaxMessage || payload_size > max_payload || code > 16) {
      Kill(w);
      return absl::InternalError(absl::StrCat(path, ": garbled reply from the DICOM reader"));
    }
    message.resize(message_size);
    got = RecvAll(w.fd, message.data(), message.size(), deadline);
  }
  if (got == Got::kOk) {
    got = RecvAll(w.fd, sink(static_cast<size_t>(payload_size)), payload_size, deadline);
  }
  if (got == Got::kLate) {
    Kill(w);
    return absl::DataLossError(
        absl::StrCat(path, ": the DICOM reader took more than ", seconds,
                     " s on this file and was stopped (a corrupt file can make the decoder loop)"));
  }
  if (got == Got::kClosed) {
    return absl::DataLossError(
        absl::StrCat(path, ": the DICOM reader process died reading this file (", Reap(w),
                     "): GDCM or one of its codecs cannot read it (corrupt, or crafted?)"));
  }
  if (code == 0 && shared > 0) std::memcpy(shared_out, w.map, shared);
  if (retiring) {
    Reap(w);
  } else {
    Release(w);
  }
  if (code == 0) return absl::OkStatus();
  return absl::Status(static_cast<absl::StatusCode>(code), message);
}

}  // namespace

absl::StatusOr<std::optional<SliceHeader>> ReadHeader(const std::string& path) {
  std::string payload;
  absl::Status st = Call(path, wire::kHeader, 0, kMaxHeader, kHeaderSeconds, [&](size_t n) {
    payload.resize(n);
    return payload.data();
  });
  if (!st.ok()) return st;
  wire::Reader r(payload.data(), payload.size());
  std::optional<SliceHeader> h;
  if (!wire::DecodeHeader(&r, &h)) {
    return absl::InternalError(absl::StrCat(path, ": garbled header from the DICOM reader"));
  }
  return h;
}

absl::Status ReadPixels(const std::string& path, size_t stored_bytes, std::vector<uint8_t>* out) {
  const double seconds = kPixelSeconds + static_cast<double>(stored_bytes) / kPixelBytesPerSecond;
  out->resize(stored_bytes);
  std::string none;
  return Call(
      path, wire::kPixels, stored_bytes, 0, seconds, [&](size_t) { return none.data(); },
      stored_bytes, out->data());
}

namespace testing {

absl::Status Misbehave(int what) {
  std::string none;
  return Call("(test)", wire::kMisbehave, static_cast<uint64_t>(what), 0, kHeaderSeconds,
              [&](size_t) { return none.data(); });
}

void SetTimeLimit(double seconds) { g_time_limit.store(seconds); }

}  // namespace testing
}  // namespace tandem::io::dicom
