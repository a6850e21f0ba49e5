// Zarr internals: zarr_codecs.cc's chunk codecs (libblosc, libzstd, zlib) and whole-file I/O,
// which the reader (format_zarr.cc) and the writer (zarr_writer.cc) use, and LooksLikeZarr
// (format_zarr.cc) for OpenVolume and follow.
#ifndef TANDEM_SRC_ZARR_INTERNAL_H_
#define TANDEM_SRC_ZARR_INTERNAL_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace tandem::io::internal::zarr {

// One bytes-to-bytes compression step (v2's `compressor`, or one of v3's `codecs`).
struct Compression {
  enum Kind : uint8_t { kBlosc, kZstd, kGzip, kZlib } kind = kGzip;
  std::string blosc_cname = "lz4";  // blosc: the inner compressor
  int blosc_shuffle = 1;            // blosc: 0 none, 1 byte, 2 bit
  int level = 5;
};

// Decodes src (n bytes) into exactly dst_size bytes at dst. The error text names the
// codec and the problem, not the file (the caller adds it).
absl::Status Decode(const Compression& c, const uint8_t* src, size_t n, uint8_t* dst,
                    size_t dst_size);

// Refuses, before a buffer of `expected` bytes is allocated for it, an encoded chunk of n
// bytes that cannot decode to that size: blosc's and zstd's headers state their size, no
// codec expands more than 65536 times, deflate at most 1032 times (a tiny chunk must not
// make us allocate gigabytes).
absl::Status CheckDecodedSize(const Compression& c, const uint8_t* src, size_t n, size_t expected);

// Encodes n bytes of elements of typesize bytes (blosc's shuffle works per element).
absl::Status Encode(const Compression& c, const uint8_t* src, size_t n, size_t typesize,
                    std::vector<uint8_t>* out);

// Whole file into *out. NotFound when the file does not exist; a file over max_bytes is an
// error (a corrupt store must not make us allocate its claimed size). Errors name the path.
absl::Status ReadWholeFile(const std::string& path, uint64_t max_bytes, std::string* out);

// Bytes [offset, offset + n) of a file into *out; a file that ends first is DataLoss.
absl::Status ReadRange(const std::string& path, uint64_t offset, uint64_t n, std::string* out);
// The same from an open file (fd), named `path` in errors.
absl::Status ReadRangeAt(int fd, const std::string& path, uint64_t offset, uint64_t n,
                         std::string* out);

// Writes path.tmp and renames it onto path: readers see the old content or the new, never
// a part (a chunk file that exists is complete).
absl::Status WriteFileAtomic(const std::string& path, const void* data, size_t n);

}  // namespace tandem::io::internal::zarr

namespace tandem::io::internal {
// OpenVolume's test: a path ending in ".zarr", or a directory holding .zarray, .zgroup,
// .zattrs or zarr.json.
bool LooksLikeZarr(const std::string& path);
}  // namespace tandem::io::internal

#endif  // TANDEM_SRC_ZARR_INTERNAL_H_
