// The SliceSource for contiguous voxel data (raw sidecar, NRRD, NIfTI): mapped or streamed.
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
// The SliceSource for contiguous voxel data (raw sidecar, NRRD, NIfTI).

namespace {

// The voxel bytes of an uncompressed file, mapped read-only: slices are handed out in place
// (the page cache's pages, no copy), the pages behind the current slice are unmapped as it
// advances (peak RSS stays a few slices) and the next ones are read ahead. A file truncated
// while mapped would raise SIGBUS on access, so every slice first checks the file's size.
class MappedVoxels {
 public:
  // nullptr where mapping is not possible (the caller reads instead).
  static std::unique_ptr<MappedVoxels> Open(const std::string& path, uint64_t offset,
                                            uint64_t length) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return nullptr;
    const uint64_t page = static_cast<uint64_t>(::sysconf(_SC_PAGESIZE));
    const uint64_t start = offset / page * page;
    const size_t span = static_cast<size_t>(offset - start + length);
    void* base = span == 0 ? MAP_FAILED
                           : ::mmap(nullptr, span, PROT_READ, MAP_SHARED, fd,
                                    static_cast<off_t>(start));
    if (base == MAP_FAILED) {
      ::close(fd);
      return nullptr;
    }
    ::madvise(base, span, MADV_SEQUENTIAL);
    return std::unique_ptr<MappedVoxels>(
        new MappedVoxels(fd, static_cast<uint8_t*>(base), span, start, offset - start, page));
  }
  ~MappedVoxels() {
    ::munmap(base_, span_);
    ::close(fd_);
  }
  MappedVoxels(const MappedVoxels&) = delete;
  MappedVoxels& operator=(const MappedVoxels&) = delete;

  // Bytes [begin, end) of the voxel data, once the file is known to still hold them; the
  // pages before `begin` are released and [end, ahead) is read ahead.
  absl::StatusOr<const uint8_t*> Range(uint64_t begin, uint64_t end, uint64_t ahead) {
    struct stat st;
    if (::fstat(fd_, &st) != 0) return absl::DataLossError("cannot stat the file");
    if (static_cast<uint64_t>(st.st_size) < file_start_ + skew_ + end) {
      return absl::DataLossError(
          absl::StrCat("truncated while being read: the file shrank to ", st.st_size, " bytes"));
    }
    const uint64_t keep = (skew_ + begin) / page_ * page_;
    if (keep >= released_ + kReleaseStep) {
      ::madvise(base_ + released_, keep - released_, MADV_DONTNEED);
      released_ = keep;
    }
    const uint64_t lo = (skew_ + end) / page_ * page_;
    const uint64_t hi = std::min<uint64_t>(skew_ + ahead, span_);
    if (hi > lo) ::madvise(base_ + lo, hi - lo, MADV_WILLNEED);
    return base_ + skew_ + begin;
  }

 private:
  MappedVoxels(int fd, uint8_t* base, size_t span, uint64_t file_start, uint64_t skew,
               uint64_t page)
      : fd_(fd), base_(base), span_(span), file_start_(file_start), skew_(skew), page_(page) {}

  // Pages go back in steps of at least this much: each MADV_DONTNEED flushes the TLBs of the
  // session's other threads (an interrupt per core), and a 128² float slice is 16 pages
  // (tests/bench/DENSE.md).
  static constexpr uint64_t kReleaseStep = uint64_t{4} << 20;
  int fd_;
  uint8_t* base_;
  size_t span_;
  uint64_t file_start_;  // file offset of the first mapped page
  uint64_t skew_;        // offset of the voxel data within that page
  uint64_t page_;
  uint64_t released_ = 0;  // mapping bytes [0, released_) are given back
};

class StreamSliceSource final : public CountedSliceSource {
 public:
  StreamSliceSource(StreamVolumeSpec spec, std::unique_ptr<ByteReader> reader)
      : CountedSliceSource(spec.path, Delivered(spec), OnFailure::kKeep),
        spec_(std::move(spec)),
        reader_(std::move(reader)) {
    where_ = spec_.data_path == spec_.path
                 ? spec_.path
                 : absl::StrCat(spec_.path, " (data file ", spec_.data_path, ")");
    swap_ = spec_.big_endian == kHostIsLittleEndian && DTypeSize(spec_.info.dtype) > 1;
  }

  absl::Status ViewSlice(const uint8_t** data) override {
    *data = nullptr;
    if (!kept_failure().ok()) return kept_failure();
    // Only voxels usable as stored, from the start (ReadSlice has not moved the reader).
    if (spec_.gzip || swap_ || spec_.scale || (map_ == nullptr && (no_map_ || next_slice() > 0))) {
      return absl::OkStatus();
    }
    if (next_slice() >= info_.nz) return NoMoreSlices();
    if (map_ == nullptr) {
      map_ = MappedVoxels::Open(spec_.data_path, spec_.data_offset, VolumeBytes(info_));
      if (map_ == nullptr) {
        no_map_ = true;  // e.g. a file system without mmap: ReadSlice it is
        return absl::OkStatus();
      }
    }
    absl::StatusOr<const uint8_t*> view = MappedSlice();
    if (!view.ok()) return Keep(view.status());
    *data = *view;
    Advance();
    return absl::OkStatus();
  }

 private:
  // The volume as delivered: float32 when scaled.
  static VolumeInfo Delivered(const StreamVolumeSpec& spec) {
    VolumeInfo info = spec.info;
    if (spec.scale) info.dtype = DType::kFloat32;
    return info;
  }

  absl::Status ReadNext(std::vector<uint8_t>* bytes) override {
    const VolumeInfo& stored = spec_.info;
    const size_t stored_bytes = stored.slice_bytes();
    if (map_ != nullptr) {  // mapped by an earlier ViewSlice: stay at the same position
      TANDEM_ASSIGN_OR_RETURN(const uint8_t* view, MappedSlice());
      bytes->assign(view, view + stored_bytes);
      return absl::OkStatus();
    }
    std::vector<uint8_t>* target = spec_.scale ? &stored_slice_ : bytes;
    target->resize(stored_bytes);
    TANDEM_ASSIGN_OR_RETURN(size_t got, reader_->Read(target->data(), stored_bytes));
    if (got < stored_bytes) {
      const uint64_t have = static_cast<uint64_t>(next_slice()) * stored_bytes + got;
      std::string why = reader_->EndReason();
      if (!why.empty()) why = absl::StrCat(" (", why, ")");
      return absl::DataLossError(
          absl::StrCat(where_, ": truncated: expected ", VolumeBytes(stored),
                       " bytes of voxel data (", DescribeGrid(stored), "), ",
                       spec_.gzip ? "compressed stream has " : "file has ", have, why));
    }
    if (swap_) SwapBytesInPlace(target->data(), stored.slice_voxels(), DTypeSize(stored.dtype));
    if (spec_.scale) {
      scaled_.resize(stored.slice_voxels());
      ConvertToFloat(stored.dtype, stored_slice_.data(), scaled_.size(), scaled_.data());
      const double slope = spec_.scl_slope, inter = spec_.scl_inter;
      for (float& v : scaled_) v = static_cast<float>(v * slope + inter);
      bytes->resize(scaled_.size() * sizeof(float));
      std::memcpy(bytes->data(), scaled_.data(), bytes->size());
    }
    return absl::OkStatus();
  }

  // A plain file's size was checked at open time; a gzip stream can only be checked here.
  absl::Status AfterLastSlice() override {
    if (!spec_.gzip) return absl::OkStatus();
    uint8_t extra;
    absl::StatusOr<size_t> more = reader_->Read(&extra, 1);
    if (more.ok() && *more > 0) {
      const VolumeInfo& stored = spec_.info;
      return absl::DataLossError(absl::StrCat(
          where_, ": size mismatch: compressed stream holds more than the ", VolumeBytes(stored),
          " bytes of voxel data that ", DescribeGrid(stored),
          " needs (wrong dims or dtype in the header?)"));
    }
    return absl::OkStatus();
  }

  // Slice next_slice() in the mapping (map_ is set), once the file still holds it.
  absl::StatusOr<const uint8_t*> MappedSlice() {
    const uint64_t slice = info_.slice_bytes();
    const uint64_t begin = static_cast<uint64_t>(next_slice()) * slice;
    absl::StatusOr<const uint8_t*> view =
        map_->Range(begin, begin + slice, begin + (1 + kReadAhead) * slice);
    if (!view.ok()) return absl::DataLossError(absl::StrCat(where_, ": ", view.status().message()));
    return *view;
  }

  static constexpr uint64_t kReadAhead = 4;  // slices asked of the disk ahead of the view
  StreamVolumeSpec spec_;
  std::unique_ptr<MappedVoxels> map_;  // set by the first ViewSlice where mapping works
  bool no_map_ = false;
  std::unique_ptr<ByteReader> reader_;
  std::string where_;
  bool swap_ = false;
  std::vector<uint8_t> stored_slice_;  // scaled volumes: the slice as stored
  std::vector<float> scaled_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> OpenStreamVolume(StreamVolumeSpec spec) {
  if (absl::Status st = ValidateVolumeInfo(spec.info); !st.ok()) {
    return absl::Status(st.code(), absl::StrCat(spec.path, ": ", st.message()));
  }
  if (spec.info.nz == 0) {
    return absl::InvalidArgumentError(absl::StrCat(spec.path, ": nz is missing"));
  }
  const uint64_t need = VolumeBytes(spec.info);
  absl::StatusOr<uint64_t> size = FileSize(spec.data_path);
  if (!size.ok()) {
    if (spec.data_path == spec.path) return size.status();
    return absl::Status(size.status().code(),
                        absl::StrCat(spec.path, ": data file: ", size.status().message()));
  }
  if (!spec.gzip) {
    const uint64_t have = *size > spec.data_offset ? *size - spec.data_offset : 0;
    const std::string where = spec.data_path == spec.path
                                  ? spec.path
                                  : absl::StrCat(spec.path, " (data file ", spec.data_path, ")");
    if (have < need) {
      return absl::DataLossError(absl::StrCat(where, ": truncated: expected ", need,
                                              " bytes of voxel data (", DescribeGrid(spec.info),
                                              "), file has ", have));
    }
    if (have > need) {
      return absl::DataLossError(absl::StrCat(where, ": size mismatch: file has ", have,
                                              " bytes of voxel data but ", DescribeGrid(spec.info),
                                              " needs ", need, " (wrong dims or dtype?)"));
    }
  }
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ByteReader> reader,
                          spec.zlib
                              ? ByteReader::OpenZlib(spec.data_path, spec.data_offset)
                              : ByteReader::Open(spec.data_path, spec.data_offset, spec.gzip));
  if (spec.skip_bytes > 0) {
    if (absl::Status st = reader->Skip(spec.skip_bytes); !st.ok()) {
      if (!absl::IsOutOfRange(st)) return st;
      return absl::DataLossError(absl::StrCat(spec.path, ": truncated: data ends before byte ",
                                              spec.skip_bytes, " where the voxels start"));
    }
  }
  return std::unique_ptr<SliceSource>(new StreamSliceSource(std::move(spec), std::move(reader)));
}

}  // namespace internal
}  // namespace tandem::io
