// Helpers shared by the volume readers and writers (not part of the public API): byte
// order, plain/gzip byte streams, one SliceSource for every format whose voxels are a
// contiguous (possibly gzip-compressed) run of bytes (raw + sidecar, NRRD and NIfTI), and
// the per-format entry points. Each format's reader and writer share one file, format_*.cc.
#ifndef TANDEM_SRC_READERS_INTERNAL_H_
#define TANDEM_SRC_READERS_INTERNAL_H_

#include <bit>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"

namespace tandem::io::internal {

inline constexpr bool kHostIsLittleEndian = std::endian::native == std::endian::little;

// This Abseil build's absl::string_view is not std::string_view; bridges the public API's
// std::string_view (DTypeName) into absl::StrCat.
inline absl::string_view Sv(std::string_view s) { return absl::string_view(s.data(), s.size()); }

// Reverses the bytes of each of the n elements of elem_size bytes in data.
void SwapBytesInPlace(uint8_t* data, size_t n, size_t elem_size);

// Unaligned scalar load/store with optional byte swap (binary headers: NIfTI).
template <typename T>
T LoadScalar(const uint8_t* p, bool swap) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  if (swap) SwapBytesInPlace(reinterpret_cast<uint8_t*>(&v), 1, sizeof(T));
  return v;
}
template <typename T>
void StoreScalar(uint8_t* p, T v, bool swap) {
  std::memcpy(p, &v, sizeof(T));
  if (swap) SwapBytesInPlace(p, 1, sizeof(T));
}

// Size of a regular file; NotFound / Internal errors name the path.
absl::StatusOr<uint64_t> FileSize(const std::string& path);

// FileSize, but an empty file is an error ("<path>: empty file").
absl::StatusOr<uint64_t> NonEmptyFileSize(const std::string& path);

// "<path>: <what>: <strerror(errno)>" with a code chosen from errno.
absl::Status ErrnoError(const std::string& path, absl::string_view what);

// The first min(file_size, max) bytes of a file (a text header).
absl::StatusOr<std::string> ReadHead(const std::string& path, uint64_t file_size, uint64_t max);

// Whitespace-separated numbers of a header field (NRRD, MetaImage): exactly `n` of them;
// errors name the path and the field.
template <typename T>
absl::Status ParseNumbers(const std::string& path, absl::string_view field, absl::string_view text,
                          size_t n, T* out) {
  std::vector<absl::string_view> parts =
      absl::StrSplit(text, absl::ByAnyChar(" \t"), absl::SkipEmpty());
  if (parts.size() != n) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": \"", field, "\" needs ", n, " values, got \"", text, "\""));
  }
  for (size_t i = 0; i < n; ++i) {
    bool ok;
    if constexpr (std::is_integral_v<T>) {
      ok = absl::SimpleAtoi(parts[i], &out[i]);
    } else {
      ok = absl::SimpleAtod(parts[i], &out[i]);
    }
    if (!ok) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": \"", field, "\": bad number \"", parts[i], "\""));
    }
  }
  return absl::OkStatus();
}

// Shortest decimal text that reads back as the same double ("0.5", "3.2", "1e-07").
std::string FormatDouble(double v);

// "64x64x93 int16" (for messages).
std::string DescribeGrid(const VolumeInfo& info);

// Total voxel bytes nx*ny*nz*DTypeSize (the caller has validated the info).
uint64_t VolumeBytes(const VolumeInfo& info);

// Lower-cased file name extension handling ".nii.gz"-style double extensions:
// "a/b.NII.gz" -> ".nii.gz", "x.nrrd" -> ".nrrd", "noext" -> "".
std::string VolumeExtension(const std::string& path);

// Sequential reader of a file's bytes from a start offset, plain or gzip (zlib's gzread
// decompresses incrementally, so neither form ever holds the whole file).
class ByteReader {
 public:
  // Opens path and positions it at byte `offset` of the file (the compressed stream, if
  // gzip, starts there).
  static absl::StatusOr<std::unique_ptr<ByteReader>> Open(const std::string& path, uint64_t offset,
                                                          bool gzip);
  // A zlib stream (RFC 1950, as MetaImage's CompressedData) from byte `offset`; gzip() is true.
  static absl::StatusOr<std::unique_ptr<ByteReader>> OpenZlib(const std::string& path,
                                                              uint64_t offset);
  virtual ~ByteReader() = default;
  // Reads up to n bytes; fewer only at the end of the data. Errors name the path.
  virtual absl::StatusOr<size_t> Read(void* dst, size_t n) = 0;
  // Discards n bytes; OutOfRange if the data ends first.
  absl::Status Skip(uint64_t n);
  // After a short Read: why the data ended, if known ("unexpected end of file"), else "".
  virtual std::string EndReason() { return ""; }
  bool gzip() const { return gzip_; }
  const std::string& path() const { return path_; }

 protected:
  ByteReader(std::string path, bool gzip) : path_(std::move(path)), gzip_(gzip) {}
  std::string path_;
  bool gzip_;
};

// Sequential writer, plain or gzip. Close() must be called to see write errors.
class ByteWriter {
 public:
  // append: keep the existing content (a gzip member is appended after it).
  static absl::StatusOr<std::unique_ptr<ByteWriter>> Open(const std::string& path, bool gzip,
                                                          bool append = false);
  virtual ~ByteWriter() = default;
  virtual absl::Status Write(const void* src, size_t n) = 0;
  virtual absl::Status Close() = 0;

 protected:
  explicit ByteWriter(std::string path) : path_(std::move(path)) {}
  std::string path_;
};

// The base of the file readers' sources: slices next_slice()..nz-1 of a volume of known
// depth, handed out in order. ReadSlice returns a failure kept from an earlier call, then
// OutOfRange past the last slice ("<name>: no more slices (all <nz> were read)"); otherwise
// ReadNext reads slice next_slice() and the slice is counted once it is read.
class CountedSliceSource : public SliceSource {
 public:
  const VolumeInfo& info() const final { return info_; }
  int64_t next_slice() const final { return next_; }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) final;

 protected:
  // kKeep: a reader of one stream (a file read front to back, a TIFF's page directories, a
  // Zarr layer) loses its place when a read fails, so every later call returns that
  // failure. kRetry: a reader of one file per slice may ask for the same slice again.
  enum class OnFailure { kKeep, kRetry };
  CountedSliceSource(std::string name, VolumeInfo info, OnFailure on_failure,
                     int64_t first_slice = 0)
      : info_(std::move(info)),
        name_(std::move(name)),
        on_failure_(on_failure),
        next_(first_slice) {}

  // Reads slice next_slice() (< info_.nz) into *bytes, info_.slice_bytes() of them.
  virtual absl::Status ReadNext(std::vector<uint8_t>* bytes) = 0;
  // Once the last slice is counted: checks what follows it (a gzip stream: nothing).
  virtual absl::Status AfterLastSlice() { return absl::OkStatus(); }

  // For a ViewSlice of its own: the kept failure (ok if none), OutOfRange past the last
  // slice, a failure to keep, and a slice handed out.
  const absl::Status& kept_failure() const { return failure_; }
  absl::Status NoMoreSlices() const;
  absl::Status Keep(absl::Status failure) { return failure_ = std::move(failure); }
  void Advance() { ++next_; }

  const VolumeInfo info_;  // as delivered

 private:
  std::string name_;  // the file (or "DICOM series") named in NoMoreSlices
  OnFailure on_failure_;
  int64_t next_;
  absl::Status failure_;
};

// Where and how the voxels of a contiguous-data volume are stored.
struct StreamVolumeSpec {
  std::string path;          // the file the user opened (named in every message)
  std::string data_path;     // the file holding the voxels (== path unless detached)
  VolumeInfo info;           // geometry; info.dtype is the stored type
  uint64_t data_offset = 0;  // byte offset of the (compressed) data in data_path
  uint64_t skip_bytes = 0;   // decompressed bytes to discard before the voxels (gzip only)
  bool gzip = false;
  bool zlib = false;        // with gzip: a zlib stream (MetaImage), not a gzip file
  bool big_endian = false;  // byte order of the stored voxels
  // NIfTI scl_slope / scl_inter: when set, slices are delivered as float32 = v*slope+inter.
  bool scale = false;
  double scl_slope = 1.0, scl_inter = 0.0;
};

// Validates the geometry, checks the data size (exactly for plain files at open time; for
// gzip, truncation and trailing data are reported by ReadSlice), and returns the source.
absl::StatusOr<std::unique_ptr<SliceSource>> OpenStreamVolume(StreamVolumeSpec spec);

// Per-format entry points used by OpenVolume.
absl::StatusOr<std::unique_ptr<SliceSource>> OpenRawVolume(const std::string& json_path);
absl::StatusOr<std::unique_ptr<SliceSource>> OpenNrrdVolume(const std::string& path);
absl::StatusOr<std::unique_ptr<SliceSource>> OpenNiftiVolume(const std::string& path);
absl::StatusOr<std::unique_ptr<SliceSource>> OpenTiffVolume(const std::string& path);
absl::StatusOr<std::unique_ptr<SliceSource>> OpenMetaImageVolume(const std::string& path);

// TIFF sequences (a folder of single-page files): the geometry the first file gives (nz = 1;
// ImageJ spacing, else resolution in cm/inch as mm with z = x, else 1), and one slice read
// and checked against info (errors name path, and `first` for the expected geometry).
absl::StatusOr<VolumeInfo> TiffSequenceInfo(const std::string& first_file);
absl::Status ReadTiffSequenceSlice(const std::string& path, const std::string& first,
                                   const VolumeInfo& info, std::vector<uint8_t>* bytes);

// The writers WriteVolume picks by extension, each in its format's file (Zarr's, WriteZarr
// and ZarrAppender, are public: tandem/zarr.h). info is validated by the caller.
absl::Status WriteRawJson(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                          const VolumeWriteOptions& opts);  // format_raw.cc
absl::Status WriteNrrd(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                       const VolumeWriteOptions& opts);  // format_nrrd.cc
absl::Status WriteNifti(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                        const VolumeWriteOptions& opts);  // format_nifti.cc
absl::Status WriteTiffVolume(const std::string& path, const VolumeInfo& info,  // format_tiff.cc
                             const SliceFn& slice_fn, const VolumeWriteOptions& opts);
absl::Status WriteMetaImage(const std::string& path, const VolumeInfo& info,  // format_metaimage.cc
                            const SliceFn& slice_fn, const VolumeWriteOptions& opts);

// What the writers share (volume_writers.cc).

// Asks slice_fn for slice z and checks that it produced info.slice_bytes() bytes.
absl::Status FetchSlice(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                        int64_t z, std::vector<uint8_t>* bytes);

// SHA-256 (FIPS 180-4), streamed, for the sidecar's "sha256" key (same as `sha256sum`).
class Sha256 {
 public:
  void Update(const uint8_t* data, size_t n);
  std::string HexDigest();

 private:
  void Compress(const uint8_t* p);

  uint32_t h_[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                    0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
  uint8_t block_[64] = {};
  size_t used_ = 0;
  uint64_t total_ = 0;
};

// Streams slices 0..nz-1 from slice_fn to out in the requested byte order. observe (if set)
// sees each slice in host order; stored (if set) sees the bytes as written.
absl::Status StreamSlices(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                          bool big_endian, ByteWriter* out,
                          const std::function<void(const std::vector<uint8_t>&)>& observe = {},
                          Sha256* stored = nullptr);

// Writes a small text file whole (headers, sidecars).
absl::Status WriteText(const std::string& path, const std::string& text);

// A header format's file: the header at path, then the voxels (gzip if opts.gzip, in
// opts' byte order) appended to it when data_path == path, else written to data_path.
absl::Status WriteHeaderThenVoxels(const std::string& path, const std::string& header,
                                   const std::string& data_path, const VolumeInfo& info,
                                   const SliceFn& slice_fn, const VolumeWriteOptions& opts);

// "dir/STEM" + new_ext for "dir/STEM.ext" (or "dir/STEM.nii.gz"): a detached data file.
std::filesystem::path SiblingPath(const std::string& path, absl::string_view new_ext);

// NIfTI-1 header layout (byte offsets into the 348-byte header), shared by reader and writer.
namespace nifti {
inline constexpr int kHeaderSize = 348;
inline constexpr int kSizeofHdr = 0;
inline constexpr int kDim = 40;         // int16[8]
inline constexpr int kDatatype = 70;    // int16
inline constexpr int kBitpix = 72;      // int16
inline constexpr int kPixdim = 76;      // float[8]
inline constexpr int kVoxOffset = 108;  // float
inline constexpr int kSclSlope = 112;   // float
inline constexpr int kSclInter = 116;   // float
inline constexpr int kXyztUnits = 123;  // char
inline constexpr int kDescrip = 148;    // char[80]
inline constexpr int kQformCode = 252;  // int16
inline constexpr int kSformCode = 254;  // int16
inline constexpr int kQuaternB = 256;   // float x3 (b, c, d)
inline constexpr int kQoffsetX = 268;   // float x3
inline constexpr int kSrowX = 280;      // float[4] x3 (srow_x, srow_y, srow_z)
inline constexpr int kMagic = 344;      // char[4]
inline constexpr int16_t kTypeUInt8 = 2, kTypeInt16 = 4, kTypeInt32 = 8, kTypeFloat32 = 16,
                         kTypeInt8 = 256, kTypeUInt16 = 512, kTypeUInt32 = 768, kTypeInt64 = 1024,
                         kTypeUInt64 = 1280;
}  // namespace nifti

}  // namespace tandem::io::internal

#endif  // TANDEM_SRC_READERS_INTERNAL_H_
