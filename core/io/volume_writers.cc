// WriteVolume: raw + JSON sidecar, NRRD (attached/detached, raw/gzip), NIfTI-1 (.nii and
// .nii.gz), Zarr / OME-Zarr (ZarrAppender) and, through format_tiff.cc, multi-page TIFF.
// Every writer streams: one slice is requested, converted to the stored byte order and written
// before the next.
#include "tandem/volume_writers.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <string>
#include <utility>

#include <nifti1_io.h>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "nlohmann/json.hpp"
#include "volume_io_internal.h"
#include "tandem/zarr.h"
#include "zarr_internal.h"

namespace tandem {
namespace internal {
namespace {

// ---------------------------------------------------------------------------------------
// SHA-256 (FIPS 180-4), streamed, for the sidecar's "sha256" key (same as `sha256sum`).
class Sha256 {
 public:
  void Update(const uint8_t* data, size_t n) {
    total_ += n;
    if (used_ > 0) {
      const size_t take = std::min(n, sizeof(block_) - used_);
      std::memcpy(block_ + used_, data, take);
      used_ += take;
      data += take;
      n -= take;
      if (used_ < sizeof(block_)) return;
      Compress(block_);
      used_ = 0;
    }
    for (; n >= 64; data += 64, n -= 64) Compress(data);
    std::memcpy(block_, data, n);
    used_ = n;
  }
  std::string HexDigest() {
    const uint64_t bits = total_ * 8;
    const uint8_t pad = 0x80;
    Update(&pad, 1);
    const uint8_t zero = 0;
    while (used_ != 56) Update(&zero, 1);
    uint8_t len[8];
    for (int i = 0; i < 8; ++i) len[i] = static_cast<uint8_t>(bits >> (56 - 8 * i));
    Update(len, 8);
    std::string hex;
    static const char kDigits[] = "0123456789abcdef";
    for (uint32_t w : h_) {
      for (int shift = 28; shift >= 0; shift -= 4) hex.push_back(kDigits[(w >> shift) & 0xf]);
    }
    return hex;
  }

 private:
  static uint32_t Rotr(uint32_t x, int n) { return (x >> n) | (x << (32 - n)); }
  void Compress(const uint8_t* p) {
    static constexpr uint32_t kK[64] = {
        0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4,
        0xab1c5ed5, 0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe,
        0x9bdc06a7, 0xc19bf174, 0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f,
        0x4a7484aa, 0x5cb0a9dc, 0x76f988da, 0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7,
        0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967, 0x27b70a85, 0x2e1b2138, 0x4d2c6dfc,
        0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85, 0xa2bfe8a1, 0xa81a664b,
        0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070, 0x19a4c116,
        0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
        0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7,
        0xc67178f2};
    uint32_t w[64];
    for (int i = 0; i < 16; ++i) {
      w[i] = uint32_t{p[4 * i]} << 24 | uint32_t{p[4 * i + 1]} << 16 | uint32_t{p[4 * i + 2]} << 8 |
             uint32_t{p[4 * i + 3]};
    }
    for (int i = 16; i < 64; ++i) {
      const uint32_t s0 = Rotr(w[i - 15], 7) ^ Rotr(w[i - 15], 18) ^ (w[i - 15] >> 3);
      const uint32_t s1 = Rotr(w[i - 2], 17) ^ Rotr(w[i - 2], 19) ^ (w[i - 2] >> 10);
      w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    uint32_t a = h_[0], b = h_[1], c = h_[2], d = h_[3], e = h_[4], f = h_[5], g = h_[6], h = h_[7];
    for (int i = 0; i < 64; ++i) {
      const uint32_t t1 =
          h + (Rotr(e, 6) ^ Rotr(e, 11) ^ Rotr(e, 25)) + ((e & f) ^ (~e & g)) + kK[i] + w[i];
      const uint32_t t2 = (Rotr(a, 2) ^ Rotr(a, 13) ^ Rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
      h = g;
      g = f;
      f = e;
      e = d + t1;
      d = c;
      c = b;
      b = a;
      a = t1 + t2;
    }
    h_[0] += a;
    h_[1] += b;
    h_[2] += c;
    h_[3] += d;
    h_[4] += e;
    h_[5] += f;
    h_[6] += g;
    h_[7] += h;
  }

  uint32_t h_[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                    0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
  uint8_t block_[64] = {};
  size_t used_ = 0;
  uint64_t total_ = 0;
};

// Running min/max of the voxel values (NaNs skipped), for the sidecar's "value_range".
class ValueRange {
 public:
  void Add(DType t, const uint8_t* host, size_t n) {
    switch (t) {
      case DType::kUInt8:
        AddTyped<uint8_t>(host, n);
        break;
      case DType::kUInt16:
        AddTyped<uint16_t>(host, n);
        break;
      case DType::kInt16:
        AddTyped<int16_t>(host, n);
        break;
      case DType::kFloat32:
        AddTyped<float>(host, n);
        break;
    }
  }
  bool empty() const { return !(lo_ <= hi_); }
  double lo() const { return lo_; }
  double hi() const { return hi_; }

 private:
  template <typename T>
  void AddTyped(const uint8_t* p, size_t n) {
    for (size_t i = 0; i < n; ++i) {
      T v;
      std::memcpy(&v, p + i * sizeof(T), sizeof(T));
      const double d = static_cast<double>(v);
      if (std::isnan(d)) continue;
      lo_ = std::min(lo_, d);
      hi_ = std::max(hi_, d);
    }
  }
  double lo_ = std::numeric_limits<double>::infinity();
  double hi_ = -std::numeric_limits<double>::infinity();
};

// Streams slices 0..nz-1 from slice_fn to out in the requested byte order. observe (if set)
// sees each slice in host order; stored (if set) sees the bytes as written.
absl::Status StreamSlices(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                          bool big_endian, ByteWriter* out,
                          const std::function<void(const std::vector<uint8_t>&)>& observe = {},
                          Sha256* stored = nullptr) {
  const bool swap = big_endian == kHostIsLittleEndian && DTypeSize(info.dtype) > 1;
  std::vector<uint8_t> slice;
  for (int64_t z = 0; z < info.nz; ++z) {
    if (absl::Status st = FetchSlice(path, info, slice_fn, z, &slice); !st.ok()) return st;
    if (observe) observe(slice);
    if (swap) SwapBytesInPlace(slice.data(), info.slice_voxels(), DTypeSize(info.dtype));
    if (stored != nullptr) stored->Update(slice.data(), slice.size());
    if (absl::Status st = out->Write(slice.data(), slice.size()); !st.ok()) return st;
  }
  return absl::OkStatus();
}

absl::Status WriteText(const std::string& path, const std::string& text) {
  absl::StatusOr<std::unique_ptr<ByteWriter>> w = ByteWriter::Open(path, /*gzip=*/false);
  if (!w.ok()) return w.status();
  if (absl::Status st = (*w)->Write(text.data(), text.size()); !st.ok()) return st;
  return (*w)->Close();
}

// STEM of "dir/STEM.ext" (or "dir/STEM.nii.gz") and the folder it lives in.
std::filesystem::path SiblingPath(const std::string& path, absl::string_view new_ext) {
  const std::filesystem::path p(path);
  std::string name = p.filename().string();
  name.resize(name.size() - VolumeExtension(path).size());
  return p.parent_path() / (name + std::string(new_ext));
}

// ---------------------------------------------------------------------------------------
// Raw + JSON sidecar.

absl::Status WriteRawJson(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                          const VolumeWriteOptions& opts) {
  const std::filesystem::path raw_path = SiblingPath(path, ".raw");
  absl::StatusOr<std::unique_ptr<ByteWriter>> w = ByteWriter::Open(raw_path.string(), false);
  if (!w.ok()) return w.status();
  ValueRange range;
  Sha256 sha;
  absl::Status st = StreamSlices(
      path, info, slice_fn, opts.big_endian, w->get(),
      [&](const std::vector<uint8_t>& s) { range.Add(info.dtype, s.data(), info.slice_voxels()); },
      &sha);
  if (st.ok()) st = (*w)->Close();
  if (!st.ok()) return st;

  using ojson = nlohmann::ordered_json;
  ojson j;
  j["dims"] = {info.nx, info.ny, info.nz};
  j["dtype"] = std::string(DTypeName(info.dtype));
  j["spacing"] = {info.spacing[0], info.spacing[1], info.spacing[2]};
  j["origin"] = {info.origin[0], info.origin[1], info.origin[2]};
  if (!info.axis_aligned()) {
    const auto& d = info.directions;
    j["directions"] = {{d[0][0], d[0][1], d[0][2]}, {d[1][0], d[1][1], d[1][2]},
                       {d[2][0], d[2][1], d[2][2]}};
  }
  j["byte_order"] = opts.big_endian ? "big" : "little";
  j["layout"] = "x fastest, then y, then z: offset=((k*ny+j)*nx+i)*sizeof(dtype)";
  j["source"] = opts.source;
  j["license"] = opts.license;
  j["suggested_isovalues"] = info.suggested_isovalues;
  j["description"] = info.description;
  j["modality"] = opts.modality;
  if (range.empty()) {
    j["value_range"] = nullptr;
  } else if (info.dtype == DType::kFloat32) {
    j["value_range"] = {range.lo(), range.hi()};
  } else {
    j["value_range"] = {static_cast<int64_t>(range.lo()), static_cast<int64_t>(range.hi())};
  }
  j["raw_file"] = raw_path.filename().string();
  j["raw_bytes"] = VolumeBytes(info);
  j["sha256"] = sha.HexDigest();
  // replace: invalid UTF-8 in a description must not throw.
  return WriteText(path, j.dump(1, ' ', false, ojson::error_handler_t::replace));
}

// ---------------------------------------------------------------------------------------
// NRRD.

std::string OneLine(absl::string_view s) {
  return absl::StrReplaceAll(s, {{"\r", " "}, {"\n", " "}});
}

absl::Status WriteNrrd(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                       const VolumeWriteOptions& opts) {
  const bool detached = VolumeExtension(path) == ".nhdr";
  const char* type = info.dtype == DType::kUInt8    ? "uint8"
                     : info.dtype == DType::kUInt16 ? "uint16"
                     : info.dtype == DType::kInt16  ? "int16"
                                                    : "float";
  const auto& s = info.spacing;
  const auto& o = info.origin;
  std::string dirs;  // one voxel step per axis, in the world
  for (int a = 0; a < 3; ++a) {
    const auto& d = info.directions[a];
    absl::StrAppend(&dirs, a ? " (" : "(", FormatDouble(d[0] * s[a] + 0.0), ",",
                    FormatDouble(d[1] * s[a] + 0.0), ",", FormatDouble(d[2] * s[a] + 0.0), ")");
  }
  std::string header = absl::StrCat(
      "NRRD0004\n# written by tandem\ntype: ", type, "\ndimension: 3\nsizes: ", info.nx, " ",
      info.ny, " ", info.nz, "\nspace dimension: 3\nspace directions: ", dirs,
      "\nspace origin: (",
      FormatDouble(o[0]), ",", FormatDouble(o[1]), ",", FormatDouble(o[2]),
      ")\nkinds: domain domain domain\nendian: ", opts.big_endian ? "big" : "little",
      "\nencoding: ", opts.gzip ? "gzip" : "raw", "\n");
  if (!info.description.empty())
    absl::StrAppend(&header, "content: ", OneLine(info.description), "\n");
  if (!info.suggested_isovalues.empty()) {
    absl::StrAppend(&header, "suggested_isovalues:=");
    for (size_t i = 0; i < info.suggested_isovalues.size(); ++i) {
      absl::StrAppend(&header, i ? " " : "", FormatDouble(info.suggested_isovalues[i]));
    }
    absl::StrAppend(&header, "\n");
  }
  std::string data_path = path;
  if (detached) {
    data_path = SiblingPath(path, opts.gzip ? ".raw.gz" : ".raw").string();
    absl::StrAppend(&header, "data file: ", std::filesystem::path(data_path).filename().string(),
                    "\n");
  } else {
    absl::StrAppend(&header, "\n");  // the blank line that ends an attached header
  }
  if (absl::Status st = WriteText(path, header); !st.ok()) return st;
  // Attached: the data (a gzip member if compressed) is appended right after the header.
  absl::StatusOr<std::unique_ptr<ByteWriter>> w =
      ByteWriter::Open(data_path, opts.gzip, /*append=*/!detached);
  if (!w.ok()) return w.status();
  absl::Status st = StreamSlices(path, info, slice_fn, opts.big_endian, w->get());
  if (st.ok()) st = (*w)->Close();
  return st;
}

// ---------------------------------------------------------------------------------------
// NIfTI-1.

absl::Status WriteNifti(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                        const VolumeWriteOptions& opts) {
  if (info.nx > 32767 || info.ny > 32767 || info.nz > 32767) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": NIfTI-1 dimensions are limited to 32767 per axis (", DescribeGrid(info), ")"));
  }
  const bool gzip = VolumeExtension(path) == ".nii.gz";
  const bool swap = opts.big_endian == kHostIsLittleEndian;
  namespace nh = nifti;
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
  const int16_t datatype = info.dtype == DType::kUInt8    ? nh::kTypeUInt8
                           : info.dtype == DType::kUInt16 ? nh::kTypeUInt16
                           : info.dtype == DType::kInt16  ? nh::kTypeInt16
                                                          : nh::kTypeFloat32;
  StoreScalar<int16_t>(hdr.data() + nh::kDatatype, datatype, swap);
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

  absl::StatusOr<std::unique_ptr<ByteWriter>> w = ByteWriter::Open(path, gzip);
  if (!w.ok()) return w.status();
  absl::Status st = (*w)->Write(hdr.data(), hdr.size());
  if (st.ok()) st = StreamSlices(path, info, slice_fn, opts.big_endian, w->get());
  if (st.ok()) st = (*w)->Close();
  return st;
}

// ---------------------------------------------------------------------------------------
// Zarr (v2 / v3, optionally an OME-Zarr image), written one chunk-z layer at a time.

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
      if (absl::Status st = WriteGroup(); !st.ok()) return st;
    }
    if (opts_.version == 2 && !info_.suggested_isovalues.empty()) {
      const std::string attrs = (std::filesystem::path(array_path_) / ".zattrs").string();
      if (absl::Status st = WriteJson(attrs, ArrayAttributes()); !st.ok()) return st;
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
    if (absl::Status st = WriteJson((root / ".zgroup").string(), {{"zarr_format", 2}}); !st.ok()) {
      return st;
    }
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
    const char kind = info_.dtype == DType::kFloat32 ? 'f'
                      : info_.dtype == DType::kInt16 ? 'i'
                                                     : 'u';
    const std::string dtype =
        es_ == 1 ? "|u1" : absl::StrCat(opts_.big_endian ? ">" : "<", std::string(1, kind), es_);
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
        if (absl::Status st = zarr::WriteFileAtomic(file.string(), data, n); !st.ok()) return st;
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
  if (absl::Status st = appender->Start(); !st.ok()) return st;
  return std::unique_ptr<ZarrAppender>(std::move(appender));
}

absl::Status WriteZarr(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                       const ZarrWriteOptions& opts) {
  if (info.nz < 1) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": nz must be known to write a volume"));
  }
  ZarrWriteOptions o = opts;
  if (o.chunks[0] == 0) o.chunks[0] = info.nz;
  absl::StatusOr<std::unique_ptr<ZarrAppender>> w = ZarrAppender::Create(path, info, o);
  if (!w.ok()) return w.status();
  std::vector<uint8_t> slice;
  for (int64_t z = 0; z < info.nz; ++z) {
    if (absl::Status st = internal::FetchSlice(path, info, slice_fn, z, &slice); !st.ok()) {
      return st;
    }
    if (absl::Status st = (*w)->Append(slice.data()); !st.ok()) return st;
  }
  return (*w)->Finish();
}

absl::Status WriteVolume(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                         const VolumeWriteOptions& opts) {
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) {
    return absl::Status(st.code(), absl::StrCat(path, ": ", st.message()));
  }
  if (info.nz == 0) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": nz must be known to write a volume"));
  }
  const std::string ext = internal::VolumeExtension(path);
  if (!info.axis_aligned() && (ext == ".tif" || ext == ".tiff" || ext == ".zarr")) {
    return absl::UnimplementedError(absl::StrCat(
        path, ": this writer stores spacing and origin only, not rotated or flipped grid "
              "directions (.json, .nrrd, .nhdr, .nii, .nii.gz and a DICOM series store them)"));
  }
  if (ext == ".json") return internal::WriteRawJson(path, info, slice_fn, opts);
  if (ext == ".nrrd" || ext == ".nhdr") return internal::WriteNrrd(path, info, slice_fn, opts);
  if (ext == ".nii" || ext == ".nii.gz") return internal::WriteNifti(path, info, slice_fn, opts);
  if (ext == ".tif" || ext == ".tiff") return internal::WriteTiffVolume(path, info, slice_fn, opts);
  if (ext == ".zarr") {
    ZarrWriteOptions zo;
    zo.big_endian = opts.big_endian;
    return WriteZarr(path, info, slice_fn, zo);
  }
  return absl::InvalidArgumentError(
      absl::StrCat(path, ": cannot write format '", ext.empty() ? "(no extension)" : ext,
                   "'; supported: .json (raw + JSON sidecar), .nrrd, .nhdr, .nii, .nii.gz, "
                   ".tif, .tiff, .zarr"));
}

}  // namespace tandem
