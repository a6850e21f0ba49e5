// Zarr (v2 and v3) and OME-Zarr volumes: a reader that streams one chunk-z layer at a time
// and a writer that appends planes to a growing array.
//
// Reading. A path names a Zarr array or group (a directory holding `.zarray` / `.zgroup` /
// `.zattrs` for v2 or `zarr.json` for v3). A group must carry OME-Zarr `multiscales`
// metadata (v0.1-0.4 in the attributes, v0.5 under attributes.ome); its level 0 is read
// unless ZarrReadOptions::array (or a "#SELECTOR" suffix on the path given to OpenVolume)
// names another: "2" is multiscale level 2, anything else an array path inside the group
// ("labels/cells/0"; a group there with its own multiscales gives its level 0).
// The three last axes are z, y, x (C order, x fastest); leading axes (OME t and c) are read
// at index ZarrReadOptions::t / ::c (default 0) — other leading axes at 0.
// Spacing and origin: the OME dataset's coordinateTransformations scale / translation of
// z, y, x (times the multiscale-wide ones, if any); plain arrays have spacing 1, origin 0.
// Units (OME `axes[].unit`) are reported in the description, not converted.
// Codecs: v2 compressor blosc (any cname libblosc decodes, any shuffle), zstd, gzip, zlib or
// null, no filters; v3 bytes (little/big endian) + blosc / zstd / gzip, optionally inside
// sharding_indexed (index at start or end; a crc32c on the index is skipped, not checked;
// the inner chunk is the unit decoded, read from its shard by range). Types uint8, uint16,
// int16, float32 in either byte order. A chunk file that does not exist holds fill_value.
// Bounds: an array read in more than 65536 chunks must average 4096 voxels a chunk or more
// (each chunk is a file to open), chunks are refused when their codec cannot hold the
// chunk's declared size before a buffer is allocated, shapes beyond 2^40 and metadata
// nested over 64 deep are refused, and OME dataset paths and selectors must stay inside
// the store (relative, no "..", no symlink out of it).
#ifndef TANDEM_ZARR_H_
#define TANDEM_ZARR_H_

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"

namespace tandem::io {

struct ZarrReadOptions {
  // "" = the array at the path, or level 0 of the group's multiscale image; "N" = level N;
  // otherwise an array (or multiscale group) path relative to the group.
  std::string array;
  int64_t t = 0;  // index on an OME "time" axis
  int64_t c = 0;  // index on an OME "channel" axis
  // The first plane ReadSlice returns (next_slice() starts there): a follower that reopens
  // a grown array resumes where it stopped (only that chunk row is decoded again).
  int64_t first_plane = 0;
};

// Opens a Zarr / OME-Zarr volume. Errors name the file (metadata or chunk) and the problem.
absl::StatusOr<std::unique_ptr<SliceSource>> OpenZarrVolume(const std::string& path,
                                                            const ZarrReadOptions& opts = {});

// For following an acquisition: how many leading planes of the selected array are complete
// now, reading the metadata afresh: the planes of the first chunk rows whose every chunk file
// exists, capped at the metadata's shape (0 while the array is empty). Rows below `known`
// planes are not looked at again. Writers that skip chunks holding only fill_value
// (zarr-python's write_empty_chunks=False) leave rows that never count as complete.
absl::StatusOr<int64_t> CountCompleteZarrPlanes(const std::string& path,
                                                const ZarrReadOptions& opts = {},
                                                int64_t known = 0);

// Splits "image.zarr#labels/0" into the store path and the selector, unless the whole
// string names an existing file or directory. Returns {path, ""} when there is no '#'.
std::pair<std::string, std::string> SplitZarrSelector(const std::string& path);

enum class ZarrCompressor : uint8_t { kNone, kGzip, kZstd, kBloscLz4, kBloscZstd };

// "none", "gzip", "zstd", "blosc-lz4", "blosc-zstd".
absl::StatusOr<ZarrCompressor> ParseZarrCompressor(const std::string& name);

struct ZarrWriteOptions {
  int version = 2;  // 2 or 3
  ZarrCompressor compressor = ZarrCompressor::kBloscLz4;
  int level = 5;  // compression level (gzip 1-9, zstd 1-22, blosc 1-9)
  // Chunk shape z, y, x; 0 on an axis = the whole extent of that axis.
  std::array<int64_t, 3> chunks{1, 256, 256};
  // true: an OME-Zarr image (a group with multiscales metadata, one level, array "0", axes
  // z/y/x with spacing as scale and origin as translation); false: a bare array at the path.
  bool ome = true;
  std::string unit = "micrometer";  // OME axes unit
  bool big_endian = false;          // stored byte order
  // v2: '.' (the v2 default) or '/'; v3 uses the default chunk key encoding ("c/z/y/x").
  char dimension_separator = '.';
};

// Writes an array plane by plane: Append() buffers planes until a chunk-z layer is full,
// then writes its chunks and rewrites the metadata's shape to the planes written so far, so
// a reader watching the store (follow mode) sees an array that grows one chunk-z layer at
// a time, in which every chunk file that exists is complete and every metadata file is
// whole (chunks and metadata are written to a temporary name and renamed into place).
// Finish() writes the last, partial layer (padded with fill_value 0) and the final shape.
// Holds one chunk-z layer of planes.
class ZarrAppender {
 public:
  // info.nz is ignored (the array grows); info.nx/ny/dtype/spacing/origin are used. The
  // directory path is created (and must not already hold a Zarr store).
  static absl::StatusOr<std::unique_ptr<ZarrAppender>> Create(const std::string& path,
                                                              const VolumeInfo& info,
                                                              const ZarrWriteOptions& opts = {});
  virtual ~ZarrAppender() = default;
  // One plane of info.slice_bytes() bytes in host byte order.
  virtual absl::Status Append(const uint8_t* plane) = 0;
  virtual absl::Status Finish() = 0;
  virtual int64_t planes() const = 0;          // appended so far
  virtual int64_t planes_visible() const = 0;  // in the metadata's shape so far
  // The array's directory ("<path>/0" for OME images, else path).
  virtual const std::string& array_path() const = 0;
};

// Writes a whole volume (info.nz known) through a ZarrAppender; a chunk depth of 0 means
// all nz planes in one chunk row.
absl::Status WriteZarr(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                       const ZarrWriteOptions& opts = {});

}  // namespace tandem::io

#endif  // TANDEM_ZARR_H_
