// WriteVolume, which picks a writer by the file's extension, and what the writers share
// (FetchSlice, StreamSlices, SHA-256, WriteText, SiblingPath). Each writer lives beside its
// reader: format_raw.cc (.json + .raw), format_nrrd.cc, format_nifti.cc, format_tiff.cc and
// format_zarr.cc (ZarrAppender, WriteZarr). Every writer streams: one slice is requested,
// converted to the stored byte order and written before the next.
#include "tandem/io/volume_writers.h"

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "tandem/status_macros.h"
#include "tandem/io/zarr.h"
#include "volume_io_internal.h"

namespace tandem::io {
namespace internal {

absl::Status FetchSlice(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                        int64_t z, std::vector<uint8_t>* bytes) {
  absl::Status st = slice_fn(z, bytes);
  if (!st.ok()) {
    return absl::Status(st.code(), absl::StrCat(path, ": slice ", z, ": ", st.message()));
  }
  if (bytes->size() != info.slice_bytes()) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": slice ", z, " has ", bytes->size(), " bytes, expected ", info.slice_bytes(), " (",
        info.nx, "x", info.ny, " ", Sv(DTypeName(info.dtype)), ")"));
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------
// SHA-256 (FIPS 180-4).

namespace {
uint32_t Rotr(uint32_t x, int n) { return (x >> n) | (x << (32 - n)); }
}  // namespace

void Sha256::Update(const uint8_t* data, size_t n) {
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

std::string Sha256::HexDigest() {
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

void Sha256::Compress(const uint8_t* p) {
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

// ---------------------------------------------------------------------------------------

absl::Status StreamSlices(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                          bool big_endian, ByteWriter* out,
                          const std::function<void(const std::vector<uint8_t>&)>& observe,
                          Sha256* stored) {
  const bool swap = big_endian == kHostIsLittleEndian && DTypeSize(info.dtype) > 1;
  std::vector<uint8_t> slice;
  for (int64_t z = 0; z < info.nz; ++z) {
    TANDEM_RETURN_IF_ERROR(FetchSlice(path, info, slice_fn, z, &slice));
    if (observe) observe(slice);
    if (swap) SwapBytesInPlace(slice.data(), info.slice_voxels(), DTypeSize(info.dtype));
    if (stored != nullptr) stored->Update(slice.data(), slice.size());
    TANDEM_RETURN_IF_ERROR(out->Write(slice.data(), slice.size()));
  }
  return absl::OkStatus();
}

absl::Status WriteText(const std::string& path, const std::string& text) {
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ByteWriter> w, ByteWriter::Open(path, /*gzip=*/false));
  TANDEM_RETURN_IF_ERROR(w->Write(text.data(), text.size()));
  return w->Close();
}

absl::Status WriteHeaderThenVoxels(const std::string& path, const std::string& header,
                                   const std::string& data_path, const VolumeInfo& info,
                                   const SliceFn& slice_fn, const VolumeWriteOptions& opts) {
  TANDEM_RETURN_IF_ERROR(WriteText(path, header));
  // Attached: the data (a gzip member if compressed) is appended right after the header.
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ByteWriter> w,
                          ByteWriter::Open(data_path, opts.gzip, /*append=*/data_path == path));
  absl::Status st = StreamSlices(path, info, slice_fn, opts.big_endian, w.get());
  if (st.ok()) st = w->Close();
  return st;
}

std::filesystem::path SiblingPath(const std::string& path, absl::string_view new_ext) {
  const std::filesystem::path p(path);
  std::string name = p.filename().string();
  name.resize(name.size() - VolumeExtension(path).size());
  return p.parent_path() / (name + std::string(new_ext));
}

}  // namespace internal

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
        path,
        ": this writer stores spacing and origin only, not rotated or flipped grid "
        "directions (.json, .nrrd, .nhdr, .nii, .nii.gz, .mha, .mhd and a DICOM series "
        "store them)"));
  }
  if (ext == ".json") return internal::WriteRawJson(path, info, slice_fn, opts);
  if (ext == ".nrrd" || ext == ".nhdr") return internal::WriteNrrd(path, info, slice_fn, opts);
  // NIfTI holds RAS, MetaImage LPS: a grid in the other patient frame is turned into it.
  auto in = [&](Space fixed, Space other) -> absl::StatusOr<VolumeInfo> {
    return info.space == other ? InFrame(info, fixed) : info;
  };
  if (ext == ".nii" || ext == ".nii.gz") {
    TANDEM_ASSIGN_OR_RETURN(VolumeInfo ras, in(Space::kRAS, Space::kLPS));
    return internal::WriteNifti(path, ras, slice_fn, opts);
  }
  if (ext == ".tif" || ext == ".tiff") return internal::WriteTiffVolume(path, info, slice_fn, opts);
  if (ext == ".mha" || ext == ".mhd") {
    TANDEM_ASSIGN_OR_RETURN(VolumeInfo lps, in(Space::kLPS, Space::kRAS));
    return internal::WriteMetaImage(path, lps, slice_fn, opts);
  }
  if (ext == ".zarr") {
    ZarrWriteOptions zo;
    zo.big_endian = opts.big_endian;
    return WriteZarr(path, info, slice_fn, zo);
  }
  return absl::InvalidArgumentError(
      absl::StrCat(path, ": cannot write format '", ext.empty() ? "(no extension)" : ext,
                   "'; supported: .json (raw + JSON sidecar), .nrrd, .nhdr, .nii, .nii.gz, "
                   ".tif, .tiff, .mha, .mhd, .zarr"));
}

}  // namespace tandem::io
