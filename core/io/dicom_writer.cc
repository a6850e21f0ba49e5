// DICOM series writer (tandem/series.h): one file per z-slice through GDCM's module
// (dicom_codec.h), and the localizer grids of the test series.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>

#include "absl/strings/str_cat.h"
#include "dicom_codec.h"
#include "dicom_series.h"
#include "tandem/io/series.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"

namespace tandem::io {
namespace {

using internal::FormatDouble;
using internal::dicom_series::Cross;
using internal::dicom_series::Vec;

}  // namespace

absl::StatusOr<DicomSyntax> ParseDicomSyntax(const std::string& name) {
  static const std::pair<const char*, DicomSyntax> kNames[] = {
      {"explicit", DicomSyntax::kExplicitLittle}, {"implicit", DicomSyntax::kImplicitLittle},
      {"jpeg-lossless", DicomSyntax::kJpegLossless}, {"jpeg-ls", DicomSyntax::kJpegLs},
      {"jpeg2000", DicomSyntax::kJpeg2000},          {"rle", DicomSyntax::kRle}};
  for (const auto& [n, s] : kNames) {
    if (name == n) return s;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("unknown DICOM transfer syntax '", name,
                   "' (use explicit, implicit, jpeg-lossless, jpeg-ls, jpeg2000 or rle)"));
}

absl::StatusOr<DicomSliceWriter> DicomSliceWriter::Create(const VolumeInfo& info,
                                                          const DicomWriteOptions& opts) {
  TANDEM_RETURN_IF_ERROR(ValidateVolumeInfo(info));
  if (info.nx > 0xffff || info.ny > 0xffff) {
    return absl::InvalidArgumentError("DICOM slices are at most 65535 x 65535 pixels");
  }
  if (!(info.dtype == DType::kUInt8 || info.dtype == DType::kUInt16 ||
        info.dtype == DType::kInt16 || info.dtype == DType::kFloat32)) {
    return absl::InvalidArgumentError(
        absl::StrCat("DICOM is written from uint8, uint16, int16 or float32 voxels, not ",
                     std::string(DTypeName(info.dtype))));
  }
  DicomSliceWriter w;
  // DICOM positions are LPS: a RAS grid is turned into it (nothing moves in the patient).
  TANDEM_ASSIGN_OR_RETURN(VolumeInfo lps,
                          info.space == Space::kRAS ? InFrame(info, Space::kLPS) : info);
  w.info_ = std::move(lps);
  w.opts_ = opts;
  TANDEM_ASSIGN_OR_RETURN(const dicom::Codec* codec, dicom::LoadCodec());
  if (w.opts_.series_uid.empty()) w.opts_.series_uid = codec->generate_uid();
  if (w.opts_.study_uid.empty()) w.opts_.study_uid = codec->generate_uid();
  if (info.dtype == DType::kFloat32) {
    if (!(std::isfinite(opts.float_min) && std::isfinite(opts.float_max) &&
          opts.float_max >= opts.float_min)) {
      return absl::InvalidArgumentError("DICOM writer: float32 volume needs a finite value range");
    }
    // int16 codes -32767..32767 span [float_min, float_max].
    const double span = std::max(double{opts.float_max} - opts.float_min, 1e-30);
    w.opts_.rescale_slope = span / 65534.0;
    w.opts_.rescale_intercept = opts.float_min + 32767.0 * w.opts_.rescale_slope;
  }
  return w;
}

absl::Status DicomSliceWriter::Write(const std::string& path, int64_t z,
                                     const std::vector<uint8_t>& bytes) const {
  return Write(path, z, bytes, z + 1);
}

absl::Status DicomSliceWriter::Write(const std::string& path, int64_t z,
                                     const std::vector<uint8_t>& bytes, int64_t instance) const {
  if (bytes.size() != info_.slice_bytes()) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": slice ", z, " has ", bytes.size(),
                                                   " bytes, expected ", info_.slice_bytes()));
  }
  TANDEM_ASSIGN_OR_RETURN(const dicom::Codec* codec, dicom::LoadCodec());
  dicom::SliceImage image;
  image.path = path;
  image.pixels = bytes.data();
  image.nx = info_.nx;
  image.ny = info_.ny;
  std::vector<uint8_t> stored;
  switch (info_.dtype) {
    case DType::kUInt8:
      image.bits_allocated = 8;
      break;
    case DType::kUInt16:
      image.bits_allocated = 16;
      break;
    case DType::kInt16:
      image.bits_allocated = 16;
      image.is_signed = true;
      break;
    case DType::kFloat32: {
      image.bits_allocated = 16;
      image.is_signed = true;
      const size_t n = static_cast<size_t>(info_.slice_voxels());
      stored.resize(n * 2);
      for (size_t i = 0; i < n; ++i) {
        float v;
        std::memcpy(&v, bytes.data() + 4 * i, 4);
        const double code = std::clamp(
            std::round((double{v} - opts_.rescale_intercept) / opts_.rescale_slope), -32767.0,
            32767.0);
        const int16_t c = static_cast<int16_t>(std::isfinite(code) ? code : 0.0);
        std::memcpy(stored.data() + 2 * i, &c, 2);
      }
      image.pixels = stored.data();
      break;
    }
    case DType::kInt8:
    case DType::kUInt32:
    case DType::kInt32:
    case DType::kUInt64:
    case DType::kInt64:
      return absl::InternalError("DicomSliceWriter: a voxel type Create refuses");
  }
  image.bits_stored = opts_.bits_stored;
  image.spacing = info_.spacing;
  const auto& d = info_.directions;
  const double kz = static_cast<double>(z) * info_.spacing[2];
  for (int i = 0; i < 3; ++i) image.origin[i] = info_.origin[i] + kz * d[2][i];
  image.cosines = {d[0][0], d[0][1], d[0][2], d[1][0], d[1][1], d[1][2]};
  image.slope = opts_.rescale_slope;
  image.intercept = opts_.rescale_intercept;
  image.syntax = static_cast<int>(opts_.syntax);
  image.ct = opts_.modality == "CT";
  image.modality = opts_.modality;
  image.series_description = opts_.series_description;
  image.study_uid = opts_.study_uid;
  image.series_uid = opts_.series_uid;
  image.instance = instance;  // kNoInstanceNumber (< 0): none written
  image.image_type = opts_.image_type;
  image.slice_thickness = FormatDouble(info_.spacing[2]);
  return codec->write_slice(image);
}

VolumeInfo LocalizerGrid(const VolumeInfo& info, int image) {
  const int across = image == 0 ? 0 : 1, through = image == 0 ? 1 : 0;
  const auto& d = info.directions;
  const Vec down{-d[2][0], -d[2][1], -d[2][2]};
  VolumeInfo g = info;
  g.nx = image == 0 ? info.nx : info.ny;
  g.ny = info.nz;
  g.nz = 0;
  g.spacing = {info.spacing[across], info.spacing[2], info.spacing[through]};
  g.directions = {d[across], down, Cross(d[across], down)};
  const double up = static_cast<double>(info.nz - 1) * info.spacing[2];
  const double mid =
      static_cast<double>((image == 0 ? info.ny : info.nx) - 1) / 2 * info.spacing[through];
  for (int i = 0; i < 3; ++i) g.origin[i] = info.origin[i] + up * d[2][i] + mid * d[through][i];
  return g;
}

absl::Status WriteDicomSeries(const std::string& dir, const VolumeInfo& info,
                              const SliceFn& slice_fn, const DicomWriteOptions& opts) {
  TANDEM_RETURN_IF_ERROR(ValidateVolumeInfo(info));
  if (info.nz < 2) return absl::InvalidArgumentError("WriteDicomSeries: nz must be known");
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat(dir, ": cannot create: ", ec.message()));
  DicomWriteOptions o = opts;
  std::vector<uint8_t> bytes;
  if (info.dtype == DType::kFloat32) {  // a first pass finds the range to quantize
    float lo = std::numeric_limits<float>::infinity(), hi = -lo;
    for (int64_t z = 0; z < info.nz; ++z) {
      TANDEM_RETURN_IF_ERROR(internal::FetchSlice(dir, info, slice_fn, z, &bytes));
      for (size_t i = 0; i < bytes.size() / 4; ++i) {
        float v;
        std::memcpy(&v, bytes.data() + 4 * i, 4);
        if (std::isfinite(v)) lo = std::min(lo, v), hi = std::max(hi, v);
      }
    }
    o.float_min = std::isfinite(lo) ? lo : 0.0f;
    o.float_max = std::isfinite(hi) ? hi : 0.0f;
  }
  TANDEM_ASSIGN_OR_RETURN(DicomSliceWriter writer, DicomSliceWriter::Create(info, o));
  for (int64_t z = 0; z < info.nz; ++z) {
    TANDEM_RETURN_IF_ERROR(internal::FetchSlice(dir, info, slice_fn, z, &bytes));
    char name[32];
    std::snprintf(name, sizeof(name), "IM%05lld.dcm", static_cast<long long>(z + 1));
    if (absl::Status st = writer.Write((std::filesystem::path(dir) / name).string(), z, bytes);
        !st.ok()) {
      return st;
    }
  }
  return absl::OkStatus();
}

}  // namespace tandem::io
