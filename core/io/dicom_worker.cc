// tandem-dicom-worker: the process that reads DICOM files for tandem_io
// (dicom_worker_client.cc), so that a file that crashes, hangs or exhausts GDCM or one of its
// codecs ends this process, not the program reading the series. It answers requests on
// fd 3 (dicom_wire.h) one at a time until the socket closes, under a memory limit; the
// caller bounds its time. Started by the programs, not by people.
#include <malloc.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "dicom_codec.h"
#include "dicom_wire.h"

// The sanitizers reserve terabytes of address space: no address-space limit under them.
#if defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(memory_sanitizer)
#define TANDEM_SANITIZED 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__)
#define TANDEM_SANITIZED 1
#endif

extern "C" const tandem::io::dicom::Codec* tandem_dicom_codec();

namespace {

using tandem::io::dicom::wire::Reader;
using tandem::io::dicom::wire::Writer;

const tandem::io::dicom::Codec* g_codec = nullptr;
bool g_assertion_failed = false;

bool ReadFull(void* dst, size_t n) {
  char* p = static_cast<char*>(dst);
  while (n > 0) {
    const ssize_t got = ::recv(tandem::io::dicom::wire::kSocketFd, p, n, 0);
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) return false;
    p += got;
    n -= static_cast<size_t>(got);
  }
  return true;
}

bool WriteFull(const void* src, size_t n) {
  const char* p = static_cast<const char*>(src);
  while (n > 0) {
    const ssize_t put = ::send(tandem::io::dicom::wire::kSocketFd, p, n, MSG_NOSIGNAL);
    if (put < 0 && errno == EINTR) continue;
    if (put <= 0) return false;
    p += put;
    n -= static_cast<size_t>(put);
  }
  return true;
}

// After GDCM failed an assertion (jumped out of, leaking what it held) the process retires.
bool Reply(const absl::Status& st, const char* payload, size_t n) {
  Writer w;
  const std::string msg(st.message());
  w.U32(static_cast<uint32_t>(st.code()));
  w.U32(static_cast<uint32_t>(msg.size()));
  w.U8(g_assertion_failed);
  w.U64(n);
  w.out() += msg;
  return WriteFull(w.out().data(), w.out().size()) && WriteFull(payload, n) && !g_assertion_failed;
}

// Tests of the caller's limits: a crash, a hang, an allocation without bound.
bool Misbehave(uint64_t what) {
  if (what == 1) {
    ::signal(SIGSEGV, SIG_DFL);
    ::raise(SIGSEGV);
  }
  if (what == 2) {
    for (;;) ::pause();
  }
  std::vector<char*> held;
  try {
    for (;;) held.push_back(new char[size_t{1} << 30]);  // untouched: address space only
  } catch (const std::bad_alloc&) {
  }
  for (char* p : held) delete[] p;
  return Reply(absl::ResourceExhaustedError("out of memory"), nullptr, 0);
}

bool Serve(uint8_t op, uint64_t arg, const std::string& path) {
  if (op == tandem::io::dicom::wire::kHeader) {
    absl::StatusOr<std::optional<tandem::io::dicom::SliceHeader>> h = g_codec->read_header(path);
    if (!h.ok()) return Reply(h.status(), nullptr, 0);
    Writer w;
    tandem::io::dicom::wire::EncodeHeader(*h, &w);
    return Reply(absl::OkStatus(), w.out().data(), w.out().size());
  }
  if (op == tandem::io::dicom::wire::kPixels) {
    // Straight into the caller's shared memory, mapped again when the caller grew it.
    static void* mapped = MAP_FAILED;
    static size_t mapped_size = 0;
    struct stat st;
    if (::fstat(tandem::io::dicom::wire::kSharedFd, &st) != 0 ||
        static_cast<uint64_t>(st.st_size) < arg) {
      return Reply(absl::InternalError("the shared pixel buffer is too small"), nullptr, 0);
    }
    if (static_cast<size_t>(st.st_size) != mapped_size) {
      if (mapped != MAP_FAILED) ::munmap(mapped, mapped_size);
      mapped_size = static_cast<size_t>(st.st_size);
      mapped = ::mmap(nullptr, mapped_size, PROT_READ | PROT_WRITE, MAP_SHARED,
                      tandem::io::dicom::wire::kSharedFd, 0);
      if (mapped == MAP_FAILED) {
        mapped_size = 0;
        return Reply(absl::ResourceExhaustedError("cannot map the shared pixel buffer"), nullptr,
                     0);
      }
    }
    return Reply(
        g_codec->read_pixels(path, static_cast<size_t>(arg), static_cast<uint8_t*>(mapped)),
        nullptr, 0);
  }
  if (op == tandem::io::dicom::wire::kMisbehave) return Misbehave(arg);
  return Reply(absl::InvalidArgumentError("unknown request"), nullptr, 0);
}

}  // namespace

// GDCM's assertions (Debian builds it with them on) jump back to the GDCM call in progress
// (dicom_codec.cc's GdcmGuarded), which reports the file as corrupt; the process then
// retires. The executable's definition takes precedence over glibc's for GDCM's libraries.
extern "C" void __assert_fail(const char* assertion, const char* file, unsigned int line,
                              const char* function) noexcept {
  g_assertion_failed = true;
  if (g_codec != nullptr) g_codec->on_failed_assertion(assertion);  // returns outside GDCM
  std::fprintf(stderr, "%s:%u: %s%sAssertion `%s' failed.\n", file, line, function ? function : "",
               function ? ": " : "", assertion);
  std::abort();
}

int main() {
  // Nothing the parent left open (a listening socket, a file being written) stays open here.
  ::close_range(tandem::io::dicom::wire::kSharedFd + 1, ~0u, 0);
  const rlimit no_core{0, 0};
  ::setrlimit(RLIMIT_CORE, &no_core);
#ifndef TANDEM_SANITIZED
  // Address space: a slice of 2^28 16-bit voxels held twice by GDCM, its codecs' buffers and
  // the libraries fit; a corrupt length asking for more fails as bad_alloc, an error.
  constexpr rlim_t kMemoryLimit = rlim_t{4} << 30;
  const rlimit memory{kMemoryLimit, kMemoryLimit};
  ::setrlimit(RLIMIT_AS, &memory);
#endif
  // GDCM allocates a slice's bytes afresh for every file: keep freed memory in the heap
  // rather than returning it to the kernel, which faulted every page in again per slice.
  ::mallopt(M_MMAP_THRESHOLD, 64 << 20);
  ::mallopt(M_TRIM_THRESHOLD, 256 << 20);
  g_codec = tandem_dicom_codec();
  for (;;) {
    uint32_t size = 0;
    if (!ReadFull(&size, 4) || size < tandem::io::dicom::wire::kRequestFixed || size > (1u << 20)) {
      _exit(0);  // the caller is gone (or confused): no leak check, no destructors
    }
    std::string request(size, '\0');
    if (!ReadFull(request.data(), size)) _exit(0);
    Reader r(request.data(), tandem::io::dicom::wire::kRequestFixed);
    const uint8_t op = r.U8();
    const uint64_t arg = r.U64();
    if (!Serve(op, arg, request.substr(tandem::io::dicom::wire::kRequestFixed))) _exit(0);
  }
}
