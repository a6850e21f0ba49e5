// Byte streams: plain and gzip readers and writers (ByteReader, ByteWriter).
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "tandem/io/series.h"
#include "tandem/status_macros.h"
#include "tandem/volume.h"
#include "tandem/io/zarr.h"
#include "volume_io_internal.h"
#include "zarr_internal.h"

namespace tandem::io {
namespace internal {

// ---------------------------------------------------------------------------------------
// Byte streams.

absl::Status ByteReader::Skip(uint64_t n) {
  char buf[1 << 14];
  while (n > 0) {
    const size_t want = static_cast<size_t>(std::min<uint64_t>(n, sizeof(buf)));
    TANDEM_ASSIGN_OR_RETURN(size_t got, Read(buf, want));
    if (got == 0) return absl::OutOfRangeError(absl::StrCat(path_, ": data ends early"));
    n -= got;
  }
  return absl::OkStatus();
}

namespace {

class PlainReader final : public ByteReader {
 public:
  PlainReader(std::string path, FILE* f) : ByteReader(std::move(path), false), f_(f) {}
  ~PlainReader() override { std::fclose(f_); }
  absl::StatusOr<size_t> Read(void* dst, size_t n) override {
    const size_t got = std::fread(dst, 1, n, f_);
    if (got < n && std::ferror(f_)) return ErrnoError(path_, "read error");
    return got;
  }

 private:
  FILE* f_;
};

// gzerror() text without its "<path>: " or "<fd:3>: " prefix (callers name the file).
std::string GzErrorText(gzFile gz, int* errnum, const std::string& path) {
  std::string msg = gzerror(gz, errnum);
  if (msg.starts_with(path + ": ")) {
    msg.erase(0, path.size() + 2);
  } else if (msg.starts_with("<fd:")) {
    if (size_t colon = msg.find(": "); colon != std::string::npos) msg.erase(0, colon + 2);
  }
  return msg;
}

class GzipReader final : public ByteReader {
 public:
  GzipReader(std::string path, gzFile gz) : ByteReader(std::move(path), true), gz_(gz) {}
  ~GzipReader() override { gzclose(gz_); }
  absl::StatusOr<size_t> Read(void* dst, size_t n) override {
    size_t total = 0;
    auto* out = static_cast<uint8_t*>(dst);
    while (total < n) {
      // gzread takes an unsigned count; read huge requests in chunks.
      const unsigned chunk = static_cast<unsigned>(std::min<size_t>(n - total, 1u << 30));
      const int got = gzread(gz_, out + total, chunk);
      if (got < 0) return Error();
      if (got == 0) break;
      total += static_cast<size_t>(got);
    }
    return total;
  }
  // Why the stream ended early ("unexpected end of file", "invalid distance too far back").
  std::string EndReason() override {
    int errnum = Z_OK;
    std::string msg = GzErrorText(gz_, &errnum, path_);
    return errnum == Z_OK ? std::string() : msg;
  }

 private:
  absl::Status Error() {
    int errnum = Z_OK;
    const std::string msg = GzErrorText(gz_, &errnum, path_);
    if (errnum == Z_ERRNO) return ErrnoError(path_, "read error");
    return absl::DataLossError(absl::StrCat(path_, ": corrupt gzip data: ", msg));
  }
  gzFile gz_;
};

}  // namespace

namespace {

// inflate over a plain reader: zlib's gz* functions read gzip files only.
class ZlibReader final : public ByteReader {
 public:
  ZlibReader(std::string path, std::unique_ptr<ByteReader> in)
      : ByteReader(std::move(path), true), in_(std::move(in)), buf_(1 << 17) {
    started_ = inflateInit(&zs_) == Z_OK;
  }
  ~ZlibReader() override {
    if (started_) inflateEnd(&zs_);
  }
  absl::StatusOr<size_t> Read(void* dst, size_t n) override {
    if (!started_) return absl::ResourceExhaustedError(absl::StrCat(path_, ": cannot start zlib"));
    auto* out = static_cast<uint8_t*>(dst);
    size_t total = 0;
    while (total < n && !ended_) {
      if (zs_.avail_in == 0) {
        TANDEM_ASSIGN_OR_RETURN(size_t got, in_->Read(buf_.data(), buf_.size()));
        if (got == 0) {
          end_reason_ = "unexpected end of file";
          break;
        }
        zs_.next_in = buf_.data();
        zs_.avail_in = static_cast<uInt>(got);
      }
      const size_t want = std::min<size_t>(n - total, 1u << 30);
      zs_.next_out = out + total;
      zs_.avail_out = static_cast<uInt>(want);
      const int rc = inflate(&zs_, Z_NO_FLUSH);
      total += want - zs_.avail_out;
      if (rc == Z_STREAM_END) {
        ended_ = true;
      } else if (rc != Z_OK && rc != Z_BUF_ERROR) {
        return absl::DataLossError(absl::StrCat(
            path_, ": corrupt zlib data: ", zs_.msg != nullptr ? zs_.msg : "inflate failed"));
      }
    }
    return total;
  }
  std::string EndReason() override { return end_reason_; }

 private:
  std::unique_ptr<ByteReader> in_;
  std::vector<uint8_t> buf_;
  z_stream zs_{};
  bool started_ = false, ended_ = false;
  std::string end_reason_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<ByteReader>> ByteReader::OpenZlib(const std::string& path,
                                                                 uint64_t offset) {
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ByteReader> plain, Open(path, offset, /*gzip=*/false));
  return std::unique_ptr<ByteReader>(new ZlibReader(path, std::move(plain)));
}

absl::StatusOr<std::unique_ptr<ByteReader>> ByteReader::Open(const std::string& path,
                                                             uint64_t offset, bool gzip) {
  if (!gzip) {
    FILE* f = std::fopen(path.c_str(), "rb");
    if (f == nullptr) return ErrnoError(path, "cannot open");
    if (fseeko(f, static_cast<off_t>(offset), SEEK_SET) != 0) {
      absl::Status st = ErrnoError(path, "cannot seek");
      std::fclose(f);
      return st;
    }
    return std::unique_ptr<ByteReader>(new PlainReader(path, f));
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ErrnoError(path, "cannot open");
  // zlib would silently pass non-gzip bytes through; a file that claims gzip must be gzip.
  unsigned char magic[2] = {0, 0};
  if (::pread(fd, magic, 2, static_cast<off_t>(offset)) != 2 || magic[0] != 0x1f ||
      magic[1] != 0x8b) {
    ::close(fd);
    return absl::DataLossError(absl::StrCat(path, ": gzip-compressed data expected at byte ",
                                            offset, " but no gzip header found there"));
  }
  if (::lseek(fd, static_cast<off_t>(offset), SEEK_SET) < 0) {
    absl::Status st = ErrnoError(path, "cannot seek");
    ::close(fd);
    return st;
  }
  gzFile gz = gzdopen(fd, "rb");  // starts reading at the fd's current position
  if (gz == nullptr) {
    ::close(fd);
    return absl::ResourceExhaustedError(absl::StrCat(path, ": cannot start gzip decoder"));
  }
  gzbuffer(gz, 1 << 17);
  return std::unique_ptr<ByteReader>(new GzipReader(path, gz));
}

namespace {

class PlainWriter final : public ByteWriter {
 public:
  PlainWriter(std::string path, FILE* f) : ByteWriter(std::move(path)), f_(f) {}
  ~PlainWriter() override {
    if (f_ != nullptr) std::fclose(f_);
  }
  absl::Status Write(const void* src, size_t n) override {
    if (std::fwrite(src, 1, n, f_) != n) return ErrnoError(path_, "write failed");
    return absl::OkStatus();
  }
  absl::Status Close() override {
    FILE* f = std::exchange(f_, nullptr);
    if (f == nullptr) return absl::OkStatus();
    if (std::fclose(f) != 0) return ErrnoError(path_, "write failed");
    return absl::OkStatus();
  }

 private:
  FILE* f_;
};

class GzipWriter final : public ByteWriter {
 public:
  GzipWriter(std::string path, gzFile gz) : ByteWriter(std::move(path)), gz_(gz) {}
  ~GzipWriter() override {
    if (gz_ != nullptr) gzclose(gz_);
  }
  absl::Status Write(const void* src, size_t n) override {
    const auto* in = static_cast<const uint8_t*>(src);
    while (n > 0) {
      const unsigned chunk = static_cast<unsigned>(std::min<size_t>(n, 1u << 30));
      if (gzwrite(gz_, in, chunk) != static_cast<int>(chunk)) {
        int errnum = Z_OK;
        const std::string msg = GzErrorText(gz_, &errnum, path_);
        if (errnum == Z_ERRNO) return ErrnoError(path_, "write failed");
        return absl::InternalError(absl::StrCat(path_, ": gzip write failed: ", msg));
      }
      in += chunk;
      n -= chunk;
    }
    return absl::OkStatus();
  }
  absl::Status Close() override {
    gzFile gz = std::exchange(gz_, nullptr);
    if (gz == nullptr) return absl::OkStatus();
    errno = 0;
    if (gzclose(gz) != Z_OK) return ErrnoError(path_, "write failed");
    return absl::OkStatus();
  }

 private:
  gzFile gz_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<ByteWriter>> ByteWriter::Open(const std::string& path, bool gzip,
                                                             bool append) {
  if (!gzip) {
    FILE* f = std::fopen(path.c_str(), append ? "ab" : "wb");
    if (f == nullptr) return ErrnoError(path, "cannot create");
    return std::unique_ptr<ByteWriter>(new PlainWriter(path, f));
  }
  // Level 6 is zlib's default trade-off; "a" appends a new gzip member after the header.
  gzFile gz = gzopen(path.c_str(), append ? "ab6" : "wb6");
  if (gz == nullptr) return ErrnoError(path, "cannot create");
  gzbuffer(gz, 1 << 17);
  return std::unique_ptr<ByteWriter>(new GzipWriter(path, gz));
}

}  // namespace internal
}  // namespace tandem::io
