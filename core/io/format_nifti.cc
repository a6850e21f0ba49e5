// NIfTI-1 single-file reader (.nii, and .nii.gz streamed through zlib). The 348-byte header
// is read in either byte order (sizeof_hdr tells which). World frame (RAS, the file's
// units), as the standard orders the methods: the sform when sform_code > 0 (and its axes
// are orthogonal), else the qform when qform_code > 0 (the quaternion turned into a matrix
// by nifticlib), else pixdim spacing on the storage axes at origin 0. The matrix's columns
// give each axis's spacing (length) and direction (rotations and flips applied), its last
// column the origin. Intensity scaling follows the standard:
// scl_slope == 0 means "none"; otherwise, unless it is the identity (slope 1, inter 0),
// slices are delivered as float32 value * scl_slope + scl_inter. WriteNifti (below) writes
// a single file, plain or gzip, with the frame in both the sform and the qform.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <utility>

#include <nifti1_io.h>

#include "absl/strings/str_cat.h"
#include "volume_io_internal.h"
#include "tandem/status_macros.h"

namespace tandem::io::internal {
namespace {

namespace nh = nifti;

// The sform may hold any affine; a sheared one cannot be a grid frame (the qform then).
bool OrthogonalColumns(const mat44& m) {
  double col[3][3];
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) col[a][b] = m.m[b][a];
  }
  for (int a = 0; a < 3; ++a) {
    for (int b = a + 1; b < 3; ++b) {
      const double dot = col[a][0] * col[b][0] + col[a][1] * col[b][1] + col[a][2] * col[b][2];
      const double la = std::sqrt(col[a][0] * col[a][0] + col[a][1] * col[a][1] + col[a][2] * col[a][2]);
      const double lb = std::sqrt(col[b][0] * col[b][0] + col[b][1] * col[b][1] + col[b][2] * col[b][2]);
      if (!(std::abs(dot) <= 1e-4 * la * lb)) return false;
    }
  }
  return true;
}

absl::Status NiftiError(const std::string& path, absl::string_view what) {
  return absl::InvalidArgumentError(absl::StrCat(path, ": ", what));
}

absl::string_view NiftiTypeName(int code) {
  switch (code) {
    case 1:
      return "binary";
    case 2:
      return "uint8";
    case 4:
      return "int16";
    case 8:
      return "int32";
    case 16:
      return "float32";
    case 32:
      return "complex64";
    case 64:
      return "float64";
    case 128:
      return "rgb24";
    case 256:
      return "int8";
    case 512:
      return "uint16";
    case 768:
      return "uint32";
    case 1024:
      return "int64";
    case 1280:
      return "uint64";
    case 1536:
      return "float128";
    case 1792:
      return "complex128";
    case 2048:
      return "complex256";
    case 2304:
      return "rgba32";
    default:
      return "unknown";
  }
}

// The NIfTI datatype codes of the DTypes, both ways.
constexpr std::pair<int16_t, DType> kNiftiTypes[] = {
    {nh::kTypeUInt8, DType::kUInt8},    {nh::kTypeInt8, DType::kInt8},
    {nh::kTypeUInt16, DType::kUInt16},  {nh::kTypeInt16, DType::kInt16},
    {nh::kTypeUInt32, DType::kUInt32},  {nh::kTypeInt32, DType::kInt32},
    {nh::kTypeUInt64, DType::kUInt64},  {nh::kTypeInt64, DType::kInt64},
    {nh::kTypeFloat32, DType::kFloat32}};

absl::StatusOr<DType> DTypeOfNifti(int16_t code) {
  std::string supported;
  for (const auto& [c, t] : kNiftiTypes) {
    if (c == code) return t;
    absl::StrAppend(&supported, supported.empty() ? "" : ", ", c, " (", Sv(DTypeName(t)), ")");
  }
  return absl::InvalidArgumentError(absl::StrCat("unsupported NIfTI datatype ", code, " (",
                                                 NiftiTypeName(code), "); supported: ", supported));
}

int16_t NiftiCode(DType t) {
  for (const auto& [c, type] : kNiftiTypes) {
    if (type == t) return c;
  }
  return nh::kTypeFloat32;  // every DType is in the table
}

// gzip is detected from the content, not the name, so a mis-named file still opens.
absl::StatusOr<bool> IsGzip(const std::string& path) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr) return ErrnoError(path, "cannot open");
  unsigned char magic[2] = {0, 0};
  const size_t got = std::fread(magic, 1, 2, f);
  std::fclose(f);
  return got == 2 && magic[0] == 0x1f && magic[1] == 0x8b;
}

absl::StatusOr<StreamVolumeSpec> ParseHeader(const std::string& path, const uint8_t* hdr,
                                             bool gzip) {
  StreamVolumeSpec spec;
  spec.path = path;
  spec.data_path = path;
  spec.gzip = gzip;
  VolumeInfo& info = spec.info;

  // sizeof_hdr is 348 in the file's byte order, which tells whether to swap.
  const int32_t sizeof_hdr = LoadScalar<int32_t>(hdr + nh::kSizeofHdr, false);
  const int32_t sizeof_swapped = LoadScalar<int32_t>(hdr + nh::kSizeofHdr, true);
  bool swap;
  if (sizeof_hdr == nh::kHeaderSize) {
    swap = false;
  } else if (sizeof_swapped == nh::kHeaderSize) {
    swap = true;
  } else if (sizeof_hdr == 540 || sizeof_swapped == 540) {
    return NiftiError(path, "NIfTI-2 files are not supported (only NIfTI-1)");
  } else {
    return NiftiError(
        path, absl::StrCat("not a NIfTI-1 file (sizeof_hdr is ", sizeof_hdr, ", expected 348)"));
  }
  spec.big_endian = swap == kHostIsLittleEndian;

  const absl::string_view magic(reinterpret_cast<const char*>(hdr + nh::kMagic), 4);
  if (magic == absl::string_view("ni1\0", 4)) {
    return NiftiError(path,
                      "this is the header of a NIfTI-1 .hdr/.img pair; only single-file "
                      ".nii / .nii.gz is supported");
  }
  if (magic != absl::string_view("n+1\0", 4)) {
    return NiftiError(path, "bad NIfTI-1 magic (expected \"n+1\")");
  }

  int16_t dim[8];
  for (int i = 0; i < 8; ++i) dim[i] = LoadScalar<int16_t>(hdr + nh::kDim + 2 * i, swap);
  if (dim[0] < 3 || dim[0] > 7) {
    return NiftiError(path, absl::StrCat("dim[0] is ", dim[0], "; only 3-D volumes are supported"));
  }
  for (int i = 4; i <= dim[0]; ++i) {
    if (dim[i] != 1) {
      return NiftiError(path, absl::StrCat("dim[", i, "] is ", dim[i],
                                           "; only 3-D volumes are supported (no time series)"));
    }
  }
  info.nx = dim[1];
  info.ny = dim[2];
  info.nz = dim[3];

  const int16_t datatype = LoadScalar<int16_t>(hdr + nh::kDatatype, swap);
  absl::StatusOr<DType> dtype = DTypeOfNifti(datatype);
  if (!dtype.ok()) return NiftiError(path, dtype.status().message());
  info.dtype = *dtype;
  const int16_t bitpix = LoadScalar<int16_t>(hdr + nh::kBitpix, swap);
  if (bitpix != static_cast<int16_t>(8 * DTypeSize(info.dtype))) {
    return NiftiError(path, absl::StrCat("bitpix ", bitpix, " does not match datatype ", datatype,
                                         " (", NiftiTypeName(datatype), ")"));
  }

  float pixdim[4];
  for (int i = 0; i < 4; ++i) pixdim[i] = LoadScalar<float>(hdr + nh::kPixdim + 4 * i, swap);
  for (int a = 0; a < 3; ++a) info.spacing[a] = std::abs(pixdim[a + 1]);
  const int16_t qform_code = LoadScalar<int16_t>(hdr + nh::kQformCode, swap);
  const int16_t sform_code = LoadScalar<int16_t>(hdr + nh::kSformCode, swap);
  mat44 m{};
  bool have = false;
  const char* method = "sform";
  if (sform_code > 0) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) m.m[r][c] = LoadScalar<float>(hdr + nh::kSrowX + 16 * r + 4 * c, swap);
    }
    have = OrthogonalColumns(m);
  }
  if (!have && qform_code > 0) {
    float q[3], o[3];
    for (int i = 0; i < 3; ++i) {
      q[i] = LoadScalar<float>(hdr + nh::kQuaternB + 4 * i, swap);
      o[i] = LoadScalar<float>(hdr + nh::kQoffsetX + 4 * i, swap);
    }
    method = "qform";
    m = nifti_quatern_to_mat44(q[0], q[1], q[2], o[0], o[1], o[2], pixdim[1], pixdim[2],
                               pixdim[3], pixdim[0] < 0 ? -1.0f : 1.0f);
    have = true;
  }
  if (have) {
    info.frame = absl::StrCat("NIfTI ", method, " RAS");
    info.space = Space::kRAS;
    for (int a = 0; a < 3; ++a) {
      const double col[3] = {m.m[0][a], m.m[1][a], m.m[2][a]};
      const double len = std::sqrt(col[0] * col[0] + col[1] * col[1] + col[2] * col[2]);
      if (!(len > 0) || !std::isfinite(len)) {
        return NiftiError(path, absl::StrCat(method, " axis ", a,
                                             " has length ", len));
      }
      // The float matrix holds pixdim only to float precision: where they agree, pixdim is
      // the spacing (so a rotated grid is simplified exactly as the unrotated one).
      const double pd = std::abs(pixdim[a + 1]);
      info.spacing[a] = std::abs(len - pd) <= 1e-5 * len ? pd : len;
      for (int b = 0; b < 3; ++b) info.directions[a][b] = col[b] / len + 0.0;
      info.origin[a] = m.m[a][3];
    }
  }
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) return NiftiError(path, st.message());

  const float vox_offset = LoadScalar<float>(hdr + nh::kVoxOffset, swap);
  if (!(vox_offset >= nh::kHeaderSize) || vox_offset != std::floor(vox_offset) ||
      vox_offset > 1e12f) {
    return NiftiError(
        path, absl::StrCat("bad vox_offset ", vox_offset, " (must be a whole number >= 348)"));
  }
  // In a .nii.gz the offset counts decompressed bytes, so it is skipped after inflating.
  if (gzip) {
    spec.skip_bytes = static_cast<uint64_t>(vox_offset);
  } else {
    spec.data_offset = static_cast<uint64_t>(vox_offset);
  }

  const float slope = LoadScalar<float>(hdr + nh::kSclSlope, swap);
  const float inter = LoadScalar<float>(hdr + nh::kSclInter, swap);
  if (std::isfinite(slope) && std::isfinite(inter) && slope != 0.0f &&
      (slope != 1.0f || inter != 0.0f)) {
    spec.scale = true;
    spec.scl_slope = slope;
    spec.scl_inter = inter;
  }

  const char* descrip = reinterpret_cast<const char*>(hdr + nh::kDescrip);
  info.description.assign(descrip, strnlen(descrip, 80));
  return spec;
}

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> OpenNiftiVolume(const std::string& path) {
  TANDEM_RETURN_IF_ERROR(NonEmptyFileSize(path).status());
  TANDEM_ASSIGN_OR_RETURN(bool gzip, IsGzip(path));

  uint8_t hdr[nh::kHeaderSize];
  {
    TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ByteReader> reader, ByteReader::Open(path, 0, gzip));
    TANDEM_ASSIGN_OR_RETURN(size_t got, reader->Read(hdr, sizeof(hdr)));
    if (got < sizeof(hdr)) {
      return absl::DataLossError(
          absl::StrCat(path, ": truncated: a NIfTI-1 header needs 348 bytes, ",
                       gzip ? "decompressed data has " : "file has ", got));
    }
  }
  TANDEM_ASSIGN_OR_RETURN(StreamVolumeSpec spec, ParseHeader(path, hdr, gzip));
  return OpenStreamVolume(std::move(spec));
}

// ---------------------------------------------------------------------------------------
// Writer.

absl::Status WriteNifti(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                        const VolumeWriteOptions& opts) {
  if (info.nx > 32767 || info.ny > 32767 || info.nz > 32767) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": NIfTI-1 dimensions are limited to 32767 per axis (", DescribeGrid(info), ")"));
  }
  const bool gzip = VolumeExtension(path) == ".nii.gz";
  const bool swap = opts.big_endian == kHostIsLittleEndian;
  // 348-byte header + the 4-byte "no extensions" flag; voxels start at 352.
  std::array<uint8_t, 352> hdr{};
  StoreScalar<int32_t>(hdr.data() + nh::kSizeofHdr, nh::kHeaderSize, swap);
  const int16_t dim[8] = {3,
                          static_cast<int16_t>(info.nx),
                          static_cast<int16_t>(info.ny),
                          static_cast<int16_t>(info.nz),
                          1,
                          1,
                          1,
                          1};
  for (int i = 0; i < 8; ++i) StoreScalar<int16_t>(hdr.data() + nh::kDim + 2 * i, dim[i], swap);
  StoreScalar<int16_t>(hdr.data() + nh::kDatatype, NiftiCode(info.dtype), swap);
  StoreScalar<int16_t>(hdr.data() + nh::kBitpix, static_cast<int16_t>(8 * DTypeSize(info.dtype)),
                       swap);
  const float pixdim[8] = {1.0f,  // qfac
                           static_cast<float>(info.spacing[0]),
                           static_cast<float>(info.spacing[1]),
                           static_cast<float>(info.spacing[2]),
                           1.0f,
                           1.0f,
                           1.0f,
                           1.0f};
  for (int i = 0; i < 8; ++i) StoreScalar<float>(hdr.data() + nh::kPixdim + 4 * i, pixdim[i], swap);
  StoreScalar<float>(hdr.data() + nh::kVoxOffset, 352.0f, swap);
  StoreScalar<float>(hdr.data() + nh::kSclSlope, opts.nifti_scl_slope, swap);
  StoreScalar<float>(hdr.data() + nh::kSclInter, opts.nifti_scl_inter, swap);
  hdr[nh::kXyztUnits] = 2;  // NIFTI_UNITS_MM
  std::memcpy(hdr.data() + nh::kDescrip, info.description.data(),
              std::min<size_t>(info.description.size(), 79));
  // The grid's frame in both forms: the sform holds the matrix (axis a's column = spacing x
  // direction, the origin last), the qform the same as a quaternion (nifticlib converts).
  StoreScalar<int16_t>(hdr.data() + nh::kQformCode, 1, swap);
  StoreScalar<int16_t>(hdr.data() + nh::kSformCode, 1, swap);
  mat44 m{};
  for (int r = 0; r < 3; ++r) {
    for (int a = 0; a < 3; ++a) {
      m.m[r][a] = static_cast<float>(info.directions[a][r] * info.spacing[a]);
    }
    m.m[r][3] = static_cast<float>(info.origin[r]);
  }
  m.m[3][3] = 1.0f;
  float qb, qc, qd, qx, qy, qz, dx, dy, dz, qfac;
  nifti_mat44_to_quatern(m, &qb, &qc, &qd, &qx, &qy, &qz, &dx, &dy, &dz, &qfac);
  StoreScalar<float>(hdr.data() + nh::kPixdim, qfac, swap);
  const float quatern[3] = {qb, qc, qd};
  for (int i = 0; i < 3; ++i) StoreScalar<float>(hdr.data() + nh::kQuaternB + 4 * i, quatern[i], swap);
  for (int a = 0; a < 3; ++a) {
    const float origin = static_cast<float>(info.origin[a]);
    StoreScalar<float>(hdr.data() + nh::kQoffsetX + 4 * a, origin, swap);
    uint8_t* row = hdr.data() + nh::kSrowX + 16 * a;
    for (int c = 0; c < 3; ++c) StoreScalar<float>(row + 4 * c, m.m[a][c], swap);
    StoreScalar<float>(row + 12, origin, swap);
  }
  std::memcpy(hdr.data() + nh::kMagic, "n+1\0", 4);

  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ByteWriter> w, ByteWriter::Open(path, gzip));
  absl::Status st = w->Write(hdr.data(), hdr.size());
  if (st.ok()) st = StreamSlices(path, info, slice_fn, opts.big_endian, w.get());
  if (st.ok()) st = w->Close();
  return st;
}

}  // namespace tandem::io::internal
