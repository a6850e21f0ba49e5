// Zarr v2 / v3 writer, optionally an OME-Zarr image (ZarrAppender, WriteZarr; tandem/zarr.h):
// it gathers one chunk-z layer of planes, then writes every chunk of that row.
#include <algorithm>
#include <array>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"
#include "tandem/status_macros.h"
#include "tandem/io/zarr.h"
#include "volume_io_internal.h"
#include "zarr_internal.h"

namespace tandem::io {
namespace internal {
namespace {

using ojson = nlohmann::ordered_json;

ojson ZarrCompressorJson(const ZarrWriteOptions& o, size_t typesize) {
  const bool v3 = o.version == 3;
  switch (o.compressor) {
    case ZarrCompressor::kNone:
      return nullptr;
    case ZarrCompressor::kGzip:
      return v3 ? ojson{{"name", "gzip"}, {"configuration", {{"level", o.level}}}}
                : ojson{{"id", "gzip"}, {"level", o.level}};
    case ZarrCompressor::kZstd:
      return v3 ? ojson{{"name", "zstd"},
                        {"configuration", {{"level", o.level}, {"checksum", false}}}}
                : ojson{{"id", "zstd"}, {"level", o.level}};
    case ZarrCompressor::kBloscLz4:
    case ZarrCompressor::kBloscZstd: {
      const char* cname = o.compressor == ZarrCompressor::kBloscLz4 ? "lz4" : "zstd";
      if (v3) {
        return ojson{{"name", "blosc"},
                     {"configuration",
                      {{"cname", cname},
                       {"clevel", o.level},
                       {"shuffle", typesize > 1 ? "shuffle" : "noshuffle"},
                       {"typesize", typesize},
                       {"blocksize", 0}}}};
      }
      return ojson{{"id", "blosc"},
                   {"cname", cname},
                   {"clevel", o.level},
                   {"shuffle", typesize > 1 ? 1 : 0},
                   {"blocksize", 0}};
    }
  }
  return nullptr;
}

class ZarrAppenderImpl final : public ZarrAppender {
 public:
  ZarrAppenderImpl(std::string path, const VolumeInfo& info, const ZarrWriteOptions& opts)
      : path_(std::move(path)), info_(info), opts_(opts) {
    array_path_ = opts_.ome ? (std::filesystem::path(path_) / "0").string() : path_;
    es_ = DTypeSize(info_.dtype);
    swap_ = opts_.big_endian == kHostIsLittleEndian && es_ > 1;
    // y and x chunks no larger than the plane (0: the whole plane); z as asked.
    chunks_[0] = opts_.chunks[0];
    chunks_[1] = opts_.chunks[1] > 0 ? std::min(opts_.chunks[1], info_.ny) : info_.ny;
    chunks_[2] = opts_.chunks[2] > 0 ? std::min(opts_.chunks[2], info_.nx) : info_.nx;
    layer_.assign(static_cast<size_t>(chunks_[0]) * info_.slice_bytes(), 0);
    if (opts_.compressor != ZarrCompressor::kNone) {
      compression_.level = opts_.level;
      switch (opts_.compressor) {
        case ZarrCompressor::kGzip:
          compression_.kind = zarr::Compression::kGzip;
          break;
        case ZarrCompressor::kZstd:
          compression_.kind = zarr::Compression::kZstd;
          break;
        default:
          compression_.kind = zarr::Compression::kBlosc;
          compression_.blosc_cname = opts_.compressor == ZarrCompressor::kBloscLz4 ? "lz4" : "zstd";
          compression_.blosc_shuffle = es_ > 1 ? 1 : 0;
          break;
      }
    }
  }

  absl::Status Start() {
    std::error_code ec;
    for (const char* f : {".zarray", ".zgroup", ".zattrs", "zarr.json"}) {
      if (std::filesystem::exists(std::filesystem::path(path_) / f, ec)) {
        return absl::AlreadyExistsError(
            absl::StrCat(path_, ": already holds a Zarr store (remove it first)"));
      }
    }
    std::filesystem::create_directories(array_path_, ec);
    if (ec) {
      return absl::InternalError(absl::StrCat(array_path_, ": cannot create: ", ec.message()));
    }
    if (opts_.ome) {
      TANDEM_RETURN_IF_ERROR(WriteGroup());
    }
    if (opts_.version == 2 && !info_.suggested_isovalues.empty()) {
      const std::string attrs = (std::filesystem::path(array_path_) / ".zattrs").string();
      TANDEM_RETURN_IF_ERROR(WriteJson(attrs, ArrayAttributes()));
    }
    return WriteArrayMeta();
  }

  absl::Status Append(const uint8_t* plane) override {
    if (finished_) return absl::FailedPreconditionError(absl::StrCat(path_, ": already finished"));
    const size_t bytes = info_.slice_bytes();
    uint8_t* dst = layer_.data() + static_cast<size_t>(planes_ - visible_) * bytes;
    std::memcpy(dst, plane, bytes);
    if (swap_) SwapBytesInPlace(dst, info_.slice_voxels(), es_);
    ++planes_;
    if (planes_ - visible_ == chunks_[0]) return FlushLayer(planes_);
    return absl::OkStatus();
  }

  absl::Status Finish() override {
    if (finished_) return absl::OkStatus();
    finished_ = true;
    if (planes_ > visible_) {
      // Planes past the end of the array in the last chunk row hold the fill value (0).
      const size_t used = static_cast<size_t>(planes_ - visible_) * info_.slice_bytes();
      std::fill(layer_.begin() + static_cast<std::ptrdiff_t>(used), layer_.end(), 0);
      return FlushLayer(planes_);
    }
    return absl::OkStatus();
  }

  int64_t planes() const override { return planes_; }
  int64_t planes_visible() const override { return visible_; }
  const std::string& array_path() const override { return array_path_; }

 private:
  absl::Status WriteJson(const std::string& file, const ojson& j) {
    const std::string text = j.dump(2, ' ', false, ojson::error_handler_t::replace);
    return zarr::WriteFileAtomic(file, text.data(), text.size());
  }

  // The volume's suggested iso-values, which OpenVolume reads back (tandem's own key).
  ojson ArrayAttributes() const {
    ojson a = ojson::object();
    if (!info_.suggested_isovalues.empty()) a["suggested_isovalues"] = info_.suggested_isovalues;
    return a;
  }

  absl::Status WriteGroup() {
    const auto& s = info_.spacing;
    const auto& o = info_.origin;
    ojson axes = ojson::array();
    for (const char* name : {"z", "y", "x"}) {
      axes.push_back({{"name", name}, {"type", "space"}, {"unit", opts_.unit}});
    }
    ojson ms = {{"name", info_.description.empty() ? std::string("tandem") : info_.description},
                {"axes", axes},
                {"datasets",
                 {{{"path", "0"},
                   {"coordinateTransformations",
                    {{{"type", "scale"}, {"scale", {s[2], s[1], s[0]}}},
                     {{"type", "translation"}, {"translation", {o[2], o[1], o[0]}}}}}}}}};
    const std::filesystem::path root(path_);
    if (opts_.version == 3) {
      ojson ome = {{"version", "0.5"}, {"multiscales", {ms}}};
      return WriteJson(
          (root / "zarr.json").string(),
          {{"zarr_format", 3}, {"node_type", "group"}, {"attributes", {{"ome", ome}}}});
    }
    ms["version"] = "0.4";
    TANDEM_RETURN_IF_ERROR(WriteJson((root / ".zgroup").string(), {{"zarr_format", 2}}));
    return WriteJson((root / ".zattrs").string(), {{"multiscales", {ms}}});
  }

  absl::Status WriteArrayMeta() {
    const ojson shape = {visible_, info_.ny, info_.nx};
    const ojson chunks = {chunks_[0], chunks_[1], chunks_[2]};
    const ojson fill = info_.dtype == DType::kFloat32 ? ojson(0.0) : ojson(0);
    const std::filesystem::path dir(array_path_);
    if (opts_.version == 3) {
      ojson codecs = {{{"name", "bytes"},
                       {"configuration", {{"endian", opts_.big_endian ? "big" : "little"}}}}};
      if (opts_.compressor != ZarrCompressor::kNone)
        codecs.push_back(ZarrCompressorJson(opts_, es_));
      return WriteJson(
          (dir / "zarr.json").string(),
          {{"zarr_format", 3},
           {"node_type", "array"},
           {"shape", shape},
           {"data_type", std::string(DTypeName(info_.dtype))},
           {"chunk_grid", {{"name", "regular"}, {"configuration", {{"chunk_shape", chunks}}}}},
           {"chunk_key_encoding", {{"name", "default"}, {"configuration", {{"separator", "/"}}}}},
           {"fill_value", fill},
           {"codecs", codecs},
           {"attributes", ArrayAttributes()},
           {"dimension_names", {"z", "y", "x"}}});
    }
    const char kind = info_.dtype == DType::kFloat32 ? 'f' : IsSignedDType(info_.dtype) ? 'i' : 'u';
    const std::string dtype = absl::StrCat(es_ == 1           ? "|"
                                           : opts_.big_endian ? ">"
                                                              : "<",
                                           std::string(1, kind), es_);
    return WriteJson((dir / ".zarray").string(),
                     {{"zarr_format", 2},
                      {"shape", shape},
                      {"chunks", chunks},
                      {"dtype", dtype},
                      {"compressor", ZarrCompressorJson(opts_, es_)},
                      {"fill_value", fill},
                      {"order", "C"},
                      {"filters", nullptr},
                      {"dimension_separator", std::string(1, opts_.dimension_separator)}});
  }

  // Writes chunk row visible_ / chunks_[0] from layer_, then shows `shown` planes.
  absl::Status FlushLayer(int64_t shown) {
    const int64_t cz = visible_ / chunks_[0];
    const int64_t cdz = chunks_[0], cdy = chunks_[1], cdx = chunks_[2];
    chunk_.resize(static_cast<size_t>(cdz * cdy * cdx) * es_);
    for (int64_t cy = 0; cy * cdy < info_.ny; ++cy) {
      for (int64_t cx = 0; cx * cdx < info_.nx; ++cx) {
        std::fill(chunk_.begin(), chunk_.end(), 0);  // edge chunks: fill value past the edge
        const int64_t rows = std::min(cdy, info_.ny - cy * cdy);
        const int64_t cols = std::min(cdx, info_.nx - cx * cdx);
        for (int64_t z = 0; z < cdz; ++z) {
          for (int64_t y = 0; y < rows; ++y) {
            const size_t from =
                static_cast<size_t>((z * info_.ny + cy * cdy + y) * info_.nx + cx * cdx) * es_;
            std::memcpy(chunk_.data() + static_cast<size_t>((z * cdy + y) * cdx) * es_,
                        layer_.data() + from, static_cast<size_t>(cols) * es_);
          }
        }
        const std::string key =
            opts_.version == 3 ? absl::StrCat("c/", cz, "/", cy, "/", cx)
                               : absl::StrCat(cz, std::string(1, opts_.dimension_separator), cy,
                                              std::string(1, opts_.dimension_separator), cx);
        const std::filesystem::path file = std::filesystem::path(array_path_) / key;
        if (key.find('/') != std::string::npos) {
          std::error_code ec;
          std::filesystem::create_directories(file.parent_path(), ec);
        }
        const uint8_t* data = chunk_.data();
        size_t n = chunk_.size();
        if (opts_.compressor != ZarrCompressor::kNone) {
          if (absl::Status st =
                  zarr::Encode(compression_, chunk_.data(), chunk_.size(), es_, &encoded_);
              !st.ok()) {
            return absl::Status(st.code(), absl::StrCat(file.string(), ": ", st.message()));
          }
          data = encoded_.data();
          n = encoded_.size();
        }
        TANDEM_RETURN_IF_ERROR(zarr::WriteFileAtomic(file.string(), data, n));
      }
    }
    visible_ = shown;
    return WriteArrayMeta();
  }

  std::string path_, array_path_;
  VolumeInfo info_;
  ZarrWriteOptions opts_;
  std::array<int64_t, 3> chunks_{};
  size_t es_ = 1;
  bool swap_ = false;
  zarr::Compression compression_;
  int64_t planes_ = 0, visible_ = 0;
  bool finished_ = false;
  std::vector<uint8_t> layer_, chunk_, encoded_;
};

}  // namespace
}  // namespace internal

absl::StatusOr<ZarrCompressor> ParseZarrCompressor(const std::string& name) {
  if (name == "none") return ZarrCompressor::kNone;
  if (name == "gzip") return ZarrCompressor::kGzip;
  if (name == "zstd") return ZarrCompressor::kZstd;
  if (name == "blosc-lz4") return ZarrCompressor::kBloscLz4;
  if (name == "blosc-zstd") return ZarrCompressor::kBloscZstd;
  return absl::InvalidArgumentError(absl::StrCat("unknown Zarr compressor '", name,
                                                 "' (none, gzip, zstd, blosc-lz4, blosc-zstd)"));
}

absl::StatusOr<std::unique_ptr<ZarrAppender>> ZarrAppender::Create(const std::string& path,
                                                                   const VolumeInfo& info,
                                                                   const ZarrWriteOptions& opts) {
  VolumeInfo grid = info;
  grid.nz = 0;
  if (absl::Status st = ValidateVolumeInfo(grid); !st.ok()) {
    return absl::Status(st.code(), absl::StrCat(path, ": ", st.message()));
  }
  if (opts.version != 2 && opts.version != 3) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": Zarr version ", opts.version, " (2 or 3)"));
  }
  if (opts.chunks[0] < 1 || opts.chunks[1] < 0 || opts.chunks[2] < 0) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": chunk shape ", opts.chunks[0], ",", opts.chunks[1], ",", opts.chunks[2],
        " (z at least 1; y and x at least 1, or 0 for the whole extent)"));
  }
  if (opts.dimension_separator != '.' && opts.dimension_separator != '/') {
    return absl::InvalidArgumentError(absl::StrCat(path, ": dimension separator must be . or /"));
  }
  if (!info.axis_aligned()) {
    return absl::UnimplementedError(
        absl::StrCat(path, ": OME-Zarr stores scale and translation only, not rotated or "
                           "flipped grid directions"));
  }
  auto appender = std::make_unique<internal::ZarrAppenderImpl>(path, info, opts);
  TANDEM_RETURN_IF_ERROR(appender->Start());
  return std::unique_ptr<ZarrAppender>(std::move(appender));
}

absl::Status WriteZarr(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                       const ZarrWriteOptions& opts) {
  if (info.nz < 1) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": nz must be known to write a volume"));
  }
  ZarrWriteOptions o = opts;
  if (o.chunks[0] == 0) o.chunks[0] = info.nz;
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ZarrAppender> w, ZarrAppender::Create(path, info, o));
  std::vector<uint8_t> slice;
  for (int64_t z = 0; z < info.nz; ++z) {
    TANDEM_RETURN_IF_ERROR(internal::FetchSlice(path, info, slice_fn, z, &slice));
    TANDEM_RETURN_IF_ERROR(w->Append(slice.data()));
  }
  return w->Finish();
}

}  // namespace tandem::io
