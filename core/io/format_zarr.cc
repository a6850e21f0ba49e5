// Zarr v2 / v3 and OME-Zarr reader (see tandem/zarr.h for what is supported).
//
// Streaming: chunks are usually several planes deep and tiled in y and x, so the reader
// decodes one chunk-z layer at a time (every y/x chunk of that chunk row, for the chosen
// t/c indices), hands its planes out one per ReadSlice, then moves to the next layer. It
// holds one layer (chunk depth x ny x nx voxels) and one decoded chunk.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "nlohmann/json.hpp"
#include "tandem/status_macros.h"
#include "tandem/io/zarr.h"
#include "volume_io_internal.h"
#include "zarr_internal.h"
#include "zarr_metadata.h"

namespace tandem::io {
namespace internal {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;
using zarr::ArrayMeta;
using zarr::FileExists;
using zarr::MetaError;
using zarr::Resolve;
using zarr::Resolved;

// One decoded chunk, and one chunk-z layer, must fit in memory comfortably.
constexpr uint64_t kMaxChunkBytes = uint64_t{512} << 20;
constexpr uint64_t kMaxLayerBytes = uint64_t{1} << 30;
// Every chunk costs a file to open (or a range of a shard to read), a few microseconds: a
// store of tiny chunks takes hours, and metadata alone can claim billions of them. Arrays
// read in at most kFreeChunks chunks, or in chunks of kMinChunkVoxels voxels on average
// (the chosen t/c), per chunk row and in all.
constexpr uint64_t kFreeChunks = 1 << 16;
constexpr uint64_t kMinChunkVoxels = 4096;
// Shape values beyond this are refused before any arithmetic on them.
constexpr int64_t kMaxShape = int64_t{1} << 40;

class ZarrSliceSource final : public CountedSliceSource {
 public:
  ~ZarrSliceSource() override {
    if (shard_fd_ >= 0) ::close(shard_fd_);
  }
  ZarrSliceSource(std::string path, Resolved r, VolumeInfo info, std::vector<int64_t> lead,
                  int64_t first_plane)
      : CountedSliceSource(std::move(path), std::move(info), OnFailure::kKeep, first_plane),
        r_(std::move(r)),
        lead_(std::move(lead)) {
    const ArrayMeta& a = r_.array;
    es_ = DTypeSize(a.dtype);
    const size_t nd = a.shape.size();
    stride_.assign(nd, 1);
    for (size_t d = nd - 1; d-- > 0;) stride_[d] = stride_[d + 1] * a.chunks[d + 1];
    chunk_elems_ = static_cast<size_t>(stride_[0] * a.chunks[0]);
    swap_ = a.big_endian == kHostIsLittleEndian && es_ > 1;
  }

  // Planes 0..n-1 whose chunk rows have every chunk file on disk, capped at the shape; rows
  // below `known` planes are taken as complete without looking.
  int64_t CompletePlanes(int64_t known) const {
    const size_t nd = r_.array.shape.size();
    const int64_t cdz = r_.array.chunks[nd - 3], cdy = r_.array.chunks[nd - 2],
                  cdx = r_.array.chunks[nd - 1];
    int64_t cz = std::clamp<int64_t>(known, 0, info_.nz) / cdz;
    for (; cz * cdz < info_.nz; ++cz) {
      std::vector<int64_t> idx = ChunkIndex(cz, nullptr);
      bool all = true;
      for (int64_t cy = 0; all && cy * cdy < info_.ny; ++cy) {
        for (int64_t cx = 0; all && cx * cdx < info_.nx; ++cx) {
          idx[nd - 2] = cy;
          idx[nd - 1] = cx;
          all = FileExists(ChunkPath(idx));
        }
      }
      if (!all) break;
    }
    return std::max(std::min(cz * cdz, info_.nz), std::clamp<int64_t>(known, 0, info_.nz));
  }

 private:
  absl::Status ReadNext(std::vector<uint8_t>* bytes) override {
    const int64_t depth = r_.array.chunks[r_.array.chunks.size() - 3];
    const int64_t cz = next_slice() / depth;
    if (cz != layer_cz_) {
      TANDEM_RETURN_IF_ERROR(LoadLayer(cz));
    }
    const size_t plane = info_.slice_bytes();
    const uint8_t* src = layer_.data() + static_cast<size_t>(next_slice() - cz * depth) * plane;
    bytes->assign(src, src + plane);
    return absl::OkStatus();
  }

  // The index of chunk (lead..., cz, 0, 0); *lead_offset (if set) gets the element offset of
  // the chosen t/c inside such a chunk.
  std::vector<int64_t> ChunkIndex(int64_t cz, size_t* lead_offset) const {
    const ArrayMeta& a = r_.array;
    const size_t nd = a.shape.size();
    std::vector<int64_t> idx(nd, 0);
    size_t offset = 0;
    for (size_t d = 0; d + 3 < nd; ++d) {
      idx[d] = lead_[d] / a.chunks[d];
      offset += static_cast<size_t>((lead_[d] % a.chunks[d]) * stride_[d]);
    }
    idx[nd - 3] = cz;
    if (lead_offset != nullptr) *lead_offset = offset;
    return idx;
  }

  // The file holding chunk idx (its shard's, for sharded arrays).
  std::string ChunkPath(const std::vector<int64_t>& idx) const {
    const std::string sep(1, r_.array.separator);
    std::vector<int64_t> key_idx = idx;
    if (r_.array.sharded) {
      for (size_t d = 0; d < idx.size(); ++d) {
        key_idx[d] = idx[d] / (r_.array.shard[d] / r_.array.chunks[d]);
      }
    }
    std::string key = absl::StrJoin(key_idx, sep);
    if (r_.array.v3_default_key) key = absl::StrCat("c", sep, key);
    return (fs::path(r_.array.dir) / key).string();
  }

  // The stored bytes of chunk idx into raw_: the whole chunk file, or the inner chunk's
  // range of its shard. NotFound when the chunk (or its shard) does not exist.
  absl::Status ReadChunk(const std::vector<int64_t>& idx, const std::string& file,
                         uint64_t max_bytes) {
    const ArrayMeta& a = r_.array;
    if (!a.sharded) return zarr::ReadWholeFile(file, max_bytes, &raw_);
    if (file != shard_file_) {  // open the shard and read its index once for its inner chunks
      shard_file_.clear();
      if (shard_fd_ >= 0) ::close(shard_fd_);
      shard_fd_ = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
      if (shard_fd_ < 0) return ErrnoError(file, "cannot open");  // NotFound: all fill_value
      size_t n = 1;
      for (size_t d = 0; d < idx.size(); ++d) n *= static_cast<size_t>(a.shard[d] / a.chunks[d]);
      const uint64_t index_bytes = 16 * uint64_t{n} + a.index_tail;
      struct stat file_info;
      if (::fstat(shard_fd_, &file_info) != 0) return ErrnoError(file, "cannot stat");
      const uint64_t size = static_cast<uint64_t>(file_info.st_size);
      if (size < index_bytes) {
        return absl::DataLossError(absl::StrCat(file, ": truncated shard: ", size,
                                                " bytes, its index alone needs ", index_bytes));
      }
      shard_size_ = size;
      const uint64_t at = a.index_at_start ? 0 : size - index_bytes;
      TANDEM_RETURN_IF_ERROR(zarr::ReadRangeAt(shard_fd_, file, at, 16 * n, &raw_));
      shard_index_.resize(2 * n);
      for (size_t i = 0; i < 2 * n; ++i) {
        shard_index_[i] = LoadScalar<uint64_t>(
            reinterpret_cast<const uint8_t*>(raw_.data()) + 8 * i, !kHostIsLittleEndian);
      }
      shard_file_ = file;
    }
    uint64_t inner = 0;  // C-order position of the inner chunk within its shard
    for (size_t d = 0; d < idx.size(); ++d) {
      const int64_t per = a.shard[d] / a.chunks[d];
      inner = inner * static_cast<uint64_t>(per) + static_cast<uint64_t>(idx[d] % per);
    }
    const uint64_t offset = shard_index_[2 * inner], nbytes = shard_index_[2 * inner + 1];
    if (offset == ~uint64_t{0} && nbytes == ~uint64_t{0}) {
      return absl::NotFoundError(absl::StrCat(file, ": inner chunk ", inner, " is empty"));
    }
    if (nbytes > max_bytes || offset > shard_size_ || nbytes > shard_size_ - offset) {
      return absl::DataLossError(
          absl::StrCat(file, ": shard index entry ", inner, " (offset ", offset, ", ", nbytes,
                       " bytes) lies outside the shard's ", shard_size_, " bytes"));
    }
    return zarr::ReadRangeAt(shard_fd_, file, offset, nbytes, &raw_);
  }

  // Decodes every chunk of chunk row cz into layer_ (host byte order).
  absl::Status LoadLayer(int64_t cz) {
    const ArrayMeta& a = r_.array;
    const size_t nd = a.shape.size();
    const int64_t cdz = a.chunks[nd - 3], cdy = a.chunks[nd - 2], cdx = a.chunks[nd - 1];
    const int64_t nx = info_.nx, ny = info_.ny;
    const int64_t depth = std::min(cdz, info_.nz - cz * cdz);
    layer_.resize(static_cast<size_t>(depth) * info_.slice_bytes());
    size_t lead_offset = 0;  // element offset of the chosen t/c inside a chunk
    std::vector<int64_t> idx = ChunkIndex(cz, &lead_offset);
    const size_t chunk_bytes = chunk_elems_ * es_;
    for (int64_t cy = 0; cy * cdy < ny; ++cy) {
      for (int64_t cx = 0; cx * cdx < nx; ++cx) {
        idx[nd - 2] = cy;
        idx[nd - 1] = cx;
        const std::string file = ChunkPath(idx);
        const int64_t rows = std::min(cdy, ny - cy * cdy), cols = std::min(cdx, nx - cx * cdx);
        const uint8_t* chunk = nullptr;
        absl::Status st =
            ReadChunk(idx, file, a.has_compression ? 2 * chunk_bytes + (1 << 20) : chunk_bytes);
        if (absl::IsNotFound(st)) {
          FillBlock(depth, cy * cdy, cx * cdx, rows, cols);
          continue;
        }
        if (!st.ok()) return st;
        const std::string where = absl::StrCat(file, ": chunk (", absl::StrJoin(idx, ", "), ")");
        if (a.has_compression) {
          const uint8_t* encoded = reinterpret_cast<const uint8_t*>(raw_.data());
          st = zarr::CheckDecodedSize(a.compression, encoded, raw_.size(), chunk_bytes);
          if (!st.ok()) return absl::DataLossError(absl::StrCat(where, ": ", st.message()));
          // Uninitialised: a damaged chunk fails before its declared size is touched.
          if (decoded_size_ < chunk_bytes) {
            decoded_.reset(new uint8_t[chunk_bytes]);
            decoded_size_ = chunk_bytes;
          }
          st = zarr::Decode(a.compression, reinterpret_cast<const uint8_t*>(raw_.data()),
                            raw_.size(), decoded_.get(), chunk_bytes);
          if (!st.ok()) return absl::DataLossError(absl::StrCat(where, ": ", st.message()));
          chunk = decoded_.get();
        } else {
          if (raw_.size() != chunk_bytes) {
            return absl::DataLossError(absl::StrCat(
                where, ": ", raw_.size() < chunk_bytes ? "truncated" : "size mismatch",
                ": uncompressed chunk has ", raw_.size(), " bytes, expected ", chunk_bytes));
          }
          chunk = reinterpret_cast<const uint8_t*>(raw_.data());
        }
        for (int64_t z = 0; z < depth; ++z) {
          for (int64_t y = 0; y < rows; ++y) {
            const size_t from =
                (lead_offset + static_cast<size_t>(z * stride_[nd - 3] + y * stride_[nd - 2])) *
                es_;
            const size_t to = static_cast<size_t>((z * ny + cy * cdy + y) * nx + cx * cdx) * es_;
            std::memcpy(layer_.data() + to, chunk + from, static_cast<size_t>(cols) * es_);
          }
        }
      }
    }
    if (swap_) SwapBytesInPlace(layer_.data(), layer_.size() / es_, es_);
    layer_cz_ = cz;
    return absl::OkStatus();
  }

  // A missing chunk: its part of the layer holds fill_value (one row built, then copied).
  void FillBlock(int64_t depth, int64_t y0, int64_t x0, int64_t rows, int64_t cols) {
    fill_row_.resize(static_cast<size_t>(cols) * es_);
    for (int64_t x = 0; x < cols; ++x) {
      std::memcpy(fill_row_.data() + x * es_, r_.array.fill.data(), es_);
    }
    for (int64_t z = 0; z < depth; ++z) {
      for (int64_t y = 0; y < rows; ++y) {
        uint8_t* dst =
            layer_.data() + static_cast<size_t>((z * info_.ny + y0 + y) * info_.nx + x0) * es_;
        std::memcpy(dst, fill_row_.data(), fill_row_.size());
      }
    }
  }

  Resolved r_;
  std::vector<int64_t> lead_;    // indices on the leading (t, c, ...) axes
  std::vector<int64_t> stride_;  // element strides inside a chunk
  size_t chunk_elems_ = 0;
  size_t es_ = 1;
  bool swap_ = false;
  int64_t layer_cz_ = -1;
  std::vector<uint8_t> layer_;  // one chunk-z layer: depth x ny x nx
  std::string raw_;             // one chunk file
  std::string shard_file_;      // the shard whose index is in shard_index_
  int shard_fd_ = -1;           // that shard, open
  uint64_t shard_size_ = 0;
  std::vector<uint64_t> shard_index_;
  std::vector<uint8_t> fill_row_;
  std::unique_ptr<uint8_t[]> decoded_;  // one decoded chunk
  size_t decoded_size_ = 0;
};

uint64_t CeilDiv(uint64_t a, uint64_t b) { return (a + b - 1) / b; }

// See kFreeChunks. info's extents are validated (at most 2^20 on each axis).
absl::Status CheckChunkCount(const std::string& file, const ArrayMeta& a, const VolumeInfo& info) {
  const size_t nd = a.chunks.size();
  const uint64_t cz = static_cast<uint64_t>(a.chunks[nd - 3]),
                 cy = static_cast<uint64_t>(a.chunks[nd - 2]),
                 cx = static_cast<uint64_t>(a.chunks[nd - 1]);
  const uint64_t nx = static_cast<uint64_t>(info.nx), ny = static_cast<uint64_t>(info.ny),
                 nz = static_cast<uint64_t>(std::max<int64_t>(info.nz, 1));
  const uint64_t per_row = CeilDiv(ny, cy) * CeilDiv(nx, cx);
  const uint64_t total = per_row * CeilDiv(nz, cz);
  const uint64_t row_voxels = nx * ny * std::min(cz, nz), voxels = nx * ny * nz;
  const bool row_ok = per_row <= std::max(kFreeChunks, row_voxels / kMinChunkVoxels);
  if (row_ok && total <= std::max(kFreeChunks, voxels / kMinChunkVoxels)) return absl::OkStatus();
  return MetaError(
      file, absl::StrCat("chunks of ", cz, "x", cy, "x", cx, " voxels: its ", nz, "x", ny, "x", nx,
                         " voxels lie in ", row_ok ? total : per_row,
                         row_ok ? " chunks" : " chunks per chunk row",
                         ", each a file or shard range to read; tandem reads arrays of at most ",
                         kFreeChunks, " chunks, or whose chunks hold ", kMinChunkVoxels,
                         " voxels or more on average (1x64x64, 16x16x16 or larger): rechunk it"));
}

// growing: an array with fewer than 2 planes (so far) is not an error (follow mode counts
// its planes).
absl::StatusOr<std::unique_ptr<ZarrSliceSource>> OpenResolved(const std::string& path, Resolved r,
                                                              const ZarrReadOptions& opts,
                                                              bool growing) {
  const ArrayMeta& a = r.array;
  const std::string& file = a.meta_file;
  const size_t nd = a.shape.size();
  if (a.chunks.size() != nd) {
    return MetaError(file, absl::StrCat("inconsistent metadata: shape has ", nd,
                                        " dimensions but chunks has ", a.chunks.size()));
  }
  if (nd < 3) {
    return MetaError(file,
                     absl::StrCat("array has ", nd, " dimensions; a volume needs 3 (z, y, x)"));
  }
  uint64_t chunk_elems = 1;
  for (size_t d = 0; d < nd; ++d) {
    if (a.shape[d] < 0) return MetaError(file, "negative shape");
    if (a.shape[d] > kMaxShape) {
      return MetaError(file, absl::StrCat("shape ", a.shape[d], " on axis ", d,
                                          " is beyond any volume (at most 2^40)"));
    }
    if (a.chunks[d] < 1 || a.chunks[d] > (int64_t{1} << 31)) {
      return MetaError(file, absl::StrCat("inconsistent metadata: chunk size ", a.chunks[d],
                                          " on axis ", d, " (must be at least 1)"));
    }
    chunk_elems *= static_cast<uint64_t>(a.chunks[d]);
    if (chunk_elems * DTypeSize(a.dtype) > kMaxChunkBytes) {
      return MetaError(file, absl::StrCat("chunks of ", absl::StrJoin(a.chunks, "x"),
                                          " elements are too large (at most 512 MiB a chunk)"));
    }
  }
  uint64_t inner_per_shard = 1;
  if (a.sharded) {
    for (size_t d = 0; d < nd; ++d) {
      if (a.shard.size() != nd || a.shard[d] < 1 || a.shard[d] > kMaxShape ||
          a.shard[d] % a.chunks[d] != 0) {
        return MetaError(
            file, absl::StrCat("inconsistent metadata: shard shape ", absl::StrJoin(a.shard, "x"),
                               " is not a multiple of the inner chunk shape ",
                               absl::StrJoin(a.chunks, "x")));
      }
      // Both factors at most 2^40 and 2^24 before the check: no overflow.
      inner_per_shard *= static_cast<uint64_t>(a.shard[d] / a.chunks[d]);
      if (inner_per_shard > (uint64_t{1} << 24)) {
        return MetaError(file, "sharding: more than 2^24 inner chunks per shard");
      }
    }
  }
  // Axis roles: the last three must be z, y, x (when named).
  if (!r.axis_names.empty()) {
    const std::string order =
        absl::StrCat(r.axis_names[nd - 3], r.axis_names[nd - 2], r.axis_names[nd - 1]);
    if (order != "zyx") {
      return MetaError(file, absl::StrCat("axes ", absl::StrJoin(r.axis_names, ","),
                                          ": the last three must be z, y, x"));
    }
  }
  std::vector<int64_t> lead(nd - 3, 0);
  std::string lead_text;
  for (size_t d = 0; d + 3 < nd; ++d) {
    const std::string name = r.axis_names.empty() ? "" : r.axis_names[d];
    const std::string type = r.axis_types.empty() ? "" : r.axis_types[d];
    if (type == "time" || name == "t") lead[d] = opts.t;
    if (type == "channel" || name == "c") lead[d] = opts.c;
    if (lead[d] < 0 || lead[d] >= a.shape[d]) {
      return absl::InvalidArgumentError(absl::StrCat(path, ": index ", lead[d], " on axis ",
                                                     name.empty() ? absl::StrCat(d) : name,
                                                     " is outside its ", a.shape[d], " entries"));
    }
    absl::StrAppend(&lead_text, lead_text.empty() ? "" : ", ",
                    name.empty() ? absl::StrCat("axis ", d) : name, "=", lead[d]);
  }
  VolumeInfo info;
  info.nz = a.shape[nd - 3];
  info.ny = a.shape[nd - 2];
  info.nx = a.shape[nd - 1];
  info.dtype = a.dtype;
  info.spacing_known = !r.scale.empty();
  if (!r.scale.empty()) {
    for (int k = 0; k < 3; ++k) {
      info.spacing[k] = r.scale[nd - 1 - k];
      info.origin[k] = r.translation[nd - 1 - k];
    }
  }
  if (info.nz == 0 && !growing) {
    return MetaError(file, "the array has no planes yet (shape 0 along z)");
  }
  VolumeInfo checked = info;
  if (growing && checked.nz < 2) checked.nz = 0;
  if (absl::Status st = ValidateVolumeInfo(checked); !st.ok()) {
    return absl::Status(st.code(), absl::StrCat(file, ": ", st.message()));
  }
  if (static_cast<uint64_t>(std::min(a.chunks[nd - 3], info.nz)) * info.slice_bytes() >
      kMaxLayerBytes) {
    return MetaError(file, absl::StrCat("a layer of chunks ", a.chunks[nd - 3],
                                        " planes deep is too large to hold (at most 1 GiB)"));
  }
  TANDEM_RETURN_IF_ERROR(CheckChunkCount(file, a, info));
  info.suggested_isovalues = a.isovalues;
  info.description = r.what;
  if (!lead_text.empty()) absl::StrAppend(&info.description, ", ", lead_text);
  if (!r.axis_units.empty() && !r.axis_units[nd - 1].empty()) {
    absl::StrAppend(&info.description, "; units z ", r.axis_units[nd - 3], ", y ",
                    r.axis_units[nd - 2], ", x ", r.axis_units[nd - 1]);
  }
  if (opts.first_plane < 0 || opts.first_plane > info.nz) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": first plane ", opts.first_plane,
                                                   " is outside the array's ", info.nz, " planes"));
  }
  return std::make_unique<ZarrSliceSource>(path, std::move(r), std::move(info), std::move(lead),
                                           opts.first_plane);
}

absl::StatusOr<std::unique_ptr<ZarrSliceSource>> OpenZarrSource(const std::string& path,
                                                                const ZarrReadOptions& opts,
                                                                bool growing) {
  std::string root = path;
  while (root.size() > 1 && root.back() == '/') root.pop_back();
  try {  // the checks should make json access safe; never let an exception escape
    TANDEM_ASSIGN_OR_RETURN(Resolved r, Resolve(root, opts.array));
    return OpenResolved(path, std::move(r), opts, growing);
  } catch (const json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": bad Zarr metadata: ", e.what()));
  }
}

}  // namespace

bool LooksLikeZarr(const std::string& path) {
  std::string p = path;
  while (p.size() > 1 && p.back() == '/') p.pop_back();
  if (absl::AsciiStrToLower(p).ends_with(".zarr")) return true;
  std::error_code ec;
  if (!fs::is_directory(p, ec)) return false;
  for (const char* f : {".zarray", ".zgroup", ".zattrs", "zarr.json"}) {
    if (FileExists(fs::path(p) / f)) return true;
  }
  return false;
}

}  // namespace internal

std::pair<std::string, std::string> SplitZarrSelector(const std::string& path) {
  std::error_code ec;
  const size_t hash = path.rfind('#');
  if (hash == std::string::npos || std::filesystem::exists(path, ec)) return {path, ""};
  return {path.substr(0, hash), path.substr(hash + 1)};
}

absl::StatusOr<std::unique_ptr<SliceSource>> OpenZarrVolume(const std::string& path,
                                                            const ZarrReadOptions& opts) {
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<internal::ZarrSliceSource> src,
                          internal::OpenZarrSource(path, opts, /*growing=*/false));
  return std::unique_ptr<SliceSource>(std::move(src));
}

absl::StatusOr<int64_t> CountCompleteZarrPlanes(const std::string& path,
                                                const ZarrReadOptions& opts, int64_t known) {
  ZarrReadOptions o = opts;
  o.first_plane = 0;
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<internal::ZarrSliceSource> src,
                          internal::OpenZarrSource(path, o, /*growing=*/true));
  return src->CompletePlanes(known);
}

}  // namespace tandem::io
