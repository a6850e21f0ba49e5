// Zarr chunk codecs through the Debian libraries (libblosc, libzstd, zlib) and the
// whole-file I/O of chunk and metadata files.
#include <blosc.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>
#include <zstd.h>

#include <cerrno>
#include <cstdio>
#include <limits>

#include "absl/strings/str_cat.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"
#include "zarr_internal.h"

namespace tandem::io::internal::zarr {
namespace {

// zlib's streams take unsigned counts; chunks are far below 4 GiB (the reader caps them).
absl::Status Inflate(const uint8_t* src, size_t n, uint8_t* dst, size_t dst_size, bool gzip) {
  if (n > std::numeric_limits<uInt>::max() || dst_size > std::numeric_limits<uInt>::max()) {
    return absl::InvalidArgumentError("chunk too large for zlib");
  }
  z_stream zs{};
  // 15 + 16: gzip wrapper only; 15: zlib wrapper only (numcodecs' "gzip" vs "zlib").
  if (inflateInit2(&zs, gzip ? 15 + 16 : 15) != Z_OK) {
    return absl::ResourceExhaustedError("cannot start the zlib decoder");
  }
  zs.next_in = const_cast<Bytef*>(src);
  zs.avail_in = static_cast<uInt>(n);
  zs.next_out = dst;
  zs.avail_out = static_cast<uInt>(dst_size);
  const int rc = inflate(&zs, Z_FINISH);
  const size_t produced = dst_size - zs.avail_out;
  std::string msg = zs.msg != nullptr ? zs.msg : "";
  inflateEnd(&zs);
  const char* name = gzip ? "gzip" : "zlib";
  if (rc == Z_STREAM_END && produced == dst_size) return absl::OkStatus();
  if (rc == Z_STREAM_END) {
    return absl::DataLossError(
        absl::StrCat(name, " data decodes to ", produced, " bytes, expected ", dst_size));
  }
  if (rc == Z_BUF_ERROR && zs.avail_out == 0) {
    return absl::DataLossError(
        absl::StrCat(name, " data decodes to more than the expected ", dst_size, " bytes"));
  }
  if (rc == Z_BUF_ERROR) {
    return absl::DataLossError(
        absl::StrCat(name, " data is truncated (", produced, " of ", dst_size, " bytes decoded)"));
  }
  return absl::DataLossError(absl::StrCat("corrupt ", name, " data", msg.empty() ? "" : ": ", msg));
}

absl::Status Deflate(const uint8_t* src, size_t n, int level, bool gzip,
                     std::vector<uint8_t>* out) {
  z_stream zs{};
  if (deflateInit2(&zs, level, Z_DEFLATED, gzip ? 15 + 16 : 15, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot start the zlib encoder (level ", level, ")"));
  }
  out->resize(deflateBound(&zs, static_cast<uLong>(n)));
  zs.next_in = const_cast<Bytef*>(src);
  zs.avail_in = static_cast<uInt>(n);
  zs.next_out = out->data();
  zs.avail_out = static_cast<uInt>(out->size());
  const int rc = deflate(&zs, Z_FINISH);
  out->resize(out->size() - zs.avail_out);
  deflateEnd(&zs);
  if (rc != Z_STREAM_END) return absl::InternalError("zlib compression failed");
  return absl::OkStatus();
}

}  // namespace

absl::Status Decode(const Compression& c, const uint8_t* src, size_t n, uint8_t* dst,
                    size_t dst_size) {
  TANDEM_RETURN_IF_ERROR(CheckDecodedSize(c, src, n, dst_size));
  switch (c.kind) {
    case Compression::kGzip:
    case Compression::kZlib:
      return Inflate(src, n, dst, dst_size, c.kind == Compression::kGzip);
    case Compression::kZstd: {
      const size_t got = ZSTD_decompress(dst, dst_size, src, n);
      if (ZSTD_isError(got)) {
        return absl::DataLossError(absl::StrCat("corrupt zstd data: ", ZSTD_getErrorName(got)));
      }
      if (got != dst_size) {
        return absl::DataLossError(
            absl::StrCat("zstd data decodes to ", got, " bytes, expected ", dst_size));
      }
      return absl::OkStatus();
    }
    case Compression::kBlosc: {
      if (dst_size == 0) return absl::OkStatus();
      const int got = blosc_decompress_ctx(src, dst, dst_size, 1);
      if (got <= 0 || static_cast<size_t>(got) != dst_size) {
        return absl::DataLossError(absl::StrCat("corrupt blosc data (decoder returned ", got,
                                                "; inner compressor unsupported or data "
                                                "damaged)"));
      }
      return absl::OkStatus();
    }
  }
  return absl::InternalError("unknown codec");
}

absl::Status CheckDecodedSize(const Compression& c, const uint8_t* src, size_t n, size_t expected) {
  // blosc and zstd expand zeros by up to ~65536 (a 128 KiB zstd block in a few bytes).
  constexpr uint64_t kMaxRatio = 65536, kMaxDeflateRatio = 1032;
  const auto cannot = [&](absl::string_view codec, uint64_t ratio) -> absl::Status {
    if (uint64_t{n} * ratio + 64 >= expected) return absl::OkStatus();
    return absl::DataLossError(
        absl::StrCat(codec, " data of ", n, " bytes cannot hold the chunk's ", expected));
  };
  switch (c.kind) {
    case Compression::kGzip:
    case Compression::kZlib:
      return cannot("deflate", kMaxDeflateRatio);
    case Compression::kZstd: {
      const unsigned long long content = ZSTD_getFrameContentSize(src, n);
      if (content == ZSTD_CONTENTSIZE_ERROR) {
        return absl::DataLossError("corrupt zstd data (no zstd frame header)");
      }
      if (content != ZSTD_CONTENTSIZE_UNKNOWN && content != expected) {
        return absl::DataLossError(
            absl::StrCat("zstd frame holds ", content, " bytes, expected ", expected));
      }
      return cannot("zstd", kMaxRatio);
    }
    case Compression::kBlosc: {
      size_t nbytes = 0;
      if (n < BLOSC_MIN_HEADER_LENGTH || blosc_cbuffer_validate(src, n, &nbytes) != 0) {
        return absl::DataLossError(
            absl::StrCat("corrupt or truncated blosc data (", n, " bytes, no valid blosc header)"));
      }
      if (nbytes != expected) {
        return absl::DataLossError(
            absl::StrCat("blosc data holds ", nbytes, " bytes, expected ", expected));
      }
      return cannot("blosc", kMaxRatio);
    }
  }
  return absl::InternalError("unknown codec");
}

absl::Status Encode(const Compression& c, const uint8_t* src, size_t n, size_t typesize,
                    std::vector<uint8_t>* out) {
  switch (c.kind) {
    case Compression::kGzip:
    case Compression::kZlib:
      return Deflate(src, n, c.level, c.kind == Compression::kGzip, out);
    case Compression::kZstd: {
      out->resize(ZSTD_compressBound(n));
      const size_t got = ZSTD_compress(out->data(), out->size(), src, n, c.level);
      if (ZSTD_isError(got)) {
        return absl::InternalError(
            absl::StrCat("zstd compression failed: ", ZSTD_getErrorName(got)));
      }
      out->resize(got);
      return absl::OkStatus();
    }
    case Compression::kBlosc: {
      if (n > static_cast<size_t>(BLOSC_MAX_BUFFERSIZE)) {
        return absl::InvalidArgumentError("chunk too large for blosc (2 GiB at most)");
      }
      out->resize(n + BLOSC_MAX_OVERHEAD);
      const int got =
          blosc_compress_ctx(c.level, c.blosc_shuffle, typesize, n, src, out->data(), out->size(),
                             c.blosc_cname.c_str(), /*blocksize=*/0, /*numinternalthreads=*/1);
      if (got <= 0) {
        return absl::InvalidArgumentError(
            absl::StrCat("blosc compression with '", c.blosc_cname,
                         "' failed (compressors available: ", blosc_list_compressors(), ")"));
      }
      out->resize(static_cast<size_t>(got));
      return absl::OkStatus();
    }
  }
  return absl::InternalError("unknown codec");
}

absl::Status ReadWholeFile(const std::string& path, uint64_t max_bytes, std::string* out) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ErrnoError(path, "cannot open");
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    absl::Status s = ErrnoError(path, "cannot stat");
    ::close(fd);
    return s;
  }
  if (S_ISDIR(st.st_mode)) {
    ::close(fd);
    return absl::InvalidArgumentError(absl::StrCat(path, ": is a directory, expected a file"));
  }
  if (static_cast<uint64_t>(st.st_size) > max_bytes) {
    ::close(fd);
    return absl::InvalidArgumentError(absl::StrCat(path, ": file of ", st.st_size,
                                                   " bytes is larger than the ", max_bytes,
                                                   " bytes it can hold (corrupt store?)"));
  }
  out->resize(static_cast<size_t>(st.st_size));
  size_t done = 0;
  while (done < out->size()) {
    const ssize_t got = ::read(fd, out->data() + done, out->size() - done);
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) {
      absl::Status s = ErrnoError(path, "read error");
      ::close(fd);
      return s;
    }
    if (got == 0) break;  // shrank meanwhile: the caller sees the short content
    done += static_cast<size_t>(got);
  }
  out->resize(done);
  ::close(fd);
  return absl::OkStatus();
}

absl::Status ReadRange(const std::string& path, uint64_t offset, uint64_t n, std::string* out) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ErrnoError(path, "cannot open");
  absl::Status st = ReadRangeAt(fd, path, offset, n, out);
  ::close(fd);
  return st;
}

absl::Status ReadRangeAt(int fd, const std::string& path, uint64_t offset, uint64_t n,
                         std::string* out) {
  out->resize(static_cast<size_t>(n));
  size_t done = 0;
  while (done < n) {
    const ssize_t got = ::pread(fd, out->data() + done, static_cast<size_t>(n) - done,
                                static_cast<off_t>(offset + done));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) return ErrnoError(path, "read error");
    if (got == 0) break;
    done += static_cast<size_t>(got);
  }
  if (done < n) {
    return absl::DataLossError(absl::StrCat(path, ": truncated: bytes ", offset, "..", offset + n,
                                            " expected, the file ends at ", offset + done));
  }
  return absl::OkStatus();
}

absl::Status WriteFileAtomic(const std::string& path, const void* data, size_t n) {
  const std::string tmp = path + ".tmp";
  FILE* f = std::fopen(tmp.c_str(), "wb");
  if (f == nullptr) return ErrnoError(tmp, "cannot create");
  const bool wrote = n == 0 || std::fwrite(data, 1, n, f) == n;
  if (std::fclose(f) != 0 || !wrote) return ErrnoError(tmp, "write failed");
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return ErrnoError(path, "cannot rename into");
  return absl::OkStatus();
}

}  // namespace tandem::io::internal::zarr
