// Volume basics: dtypes, the grid's validation and the conversion of voxels to floats (what
// the engine needs; the readers are in core/io).
#include "tandem/volume.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>
#include <utility>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace tandem {


std::string_view DTypeName(DType t) {
  switch (t) {
    case DType::kUInt8:
      return "uint8";
    case DType::kUInt16:
      return "uint16";
    case DType::kInt16:
      return "int16";
    case DType::kFloat32:
      return "float32";
    case DType::kInt8:
      return "int8";
    case DType::kUInt32:
      return "uint32";
    case DType::kInt32:
      return "int32";
    case DType::kUInt64:
      return "uint64";
    case DType::kInt64:
      return "int64";
  }
  return "unknown";
}

std::string DTypeNames() {
  std::string names;
  for (DType t : kAllDTypes)
    absl::StrAppend(&names, names.empty() ? "" : ", ", std::string(DTypeName(t)));
  return names;
}

absl::StatusOr<DType> ParseDType(std::string_view name) {
  for (DType t : kAllDTypes) {
    if (name == DTypeName(t)) return t;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("unsupported dtype '", std::string(name), "' (supported: ", DTypeNames(), ")"));
}

size_t DTypeSize(DType t) {
  switch (t) {
    case DType::kUInt8:
    case DType::kInt8:
      return 1;
    case DType::kUInt16:
    case DType::kInt16:
      return 2;
    case DType::kFloat32:
    case DType::kUInt32:
    case DType::kInt32:
      return 4;
    case DType::kUInt64:
    case DType::kInt64:
      return 8;
  }
  return 1;
}

const char* SpaceName(Space s) {
  switch (s) {
    case Space::kGrid:
      return "grid";
    case Space::kLPS:
      return "LPS";
    case Space::kRAS:
      return "RAS";
    case Space::kVoxel:
      return "voxel";
  }
  return "grid";
}

absl::StatusOr<Space> ParseSpace(std::string_view name) {
  for (Space s : {Space::kGrid, Space::kLPS, Space::kRAS, Space::kVoxel}) {
    if (absl::EqualsIgnoreCase(absl::string_view(name.data(), name.size()), SpaceName(s))) {
      return s;
    }
  }
  return absl::InvalidArgumentError(
      absl::StrCat("'", std::string(name), "': expected LPS, RAS, voxel or grid"));
}

absl::StatusOr<VolumeInfo> InFrame(const VolumeInfo& info, Space to) {
  if (to == info.space) return info;
  VolumeInfo out = info;
  out.space = to;
  if (to == Space::kVoxel) {
    out.origin = {0, 0, 0};
    out.spacing = {1, 1, 1};
    out.spacing_known = true;
    out.directions = VolumeInfo{}.directions;
    out.frame = absl::StrCat("voxel indices i, j, k of ", info.frame);
    return out;
  }
  const bool patient = info.space == Space::kLPS || info.space == Space::kRAS;
  if (to == Space::kGrid || !patient) {
    return absl::InvalidArgumentError(absl::StrCat(
        "the input's vertices are in ", info.frame, ", not in a patient frame (LPS or RAS): ",
        to == Space::kGrid ? "" : absl::StrCat(std::string(SpaceName(to)), " cannot be derived from it; "),
        "only voxel can be asked for"));
  }
  // A half turn about z: x and y change sign, z and the handedness stay.
  for (int a = 0; a < 2; ++a) out.origin[a] = -info.origin[a] + 0.0;
  for (auto& d : out.directions) {
    for (int a = 0; a < 2; ++a) d[a] = -d[a] + 0.0;
  }
  out.frame = absl::StrCat(std::string(SpaceName(to)), ": ", info.frame, " with x and y negated");
  return out;
}

namespace {

class RegridSource final : public SliceSource {
 public:
  RegridSource(std::unique_ptr<SliceSource> inner, VolumeInfo info)
      : inner_(std::move(inner)), info_(std::move(info)) {}
  const VolumeInfo& info() const override {
    info_.nz = inner_->info().nz;
    return info_;
  }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override { return inner_->ReadSlice(bytes); }
  absl::Status ViewSlice(const uint8_t** data) override { return inner_->ViewSlice(data); }
  int64_t next_slice() const override { return inner_->next_slice(); }

 private:
  std::unique_ptr<SliceSource> inner_;
  mutable VolumeInfo info_;  // nz kept up to date with inner_'s
};

}  // namespace

std::unique_ptr<SliceSource> Regrid(std::unique_ptr<SliceSource> inner, VolumeInfo info) {
  return std::make_unique<RegridSource>(std::move(inner), std::move(info));
}

absl::Status ValidateVolumeInfo(const VolumeInfo& info) {
  // Each axis is bounded so that nx*ny*nz*4 cannot overflow int64 / size_t.
  constexpr int64_t kMaxAxis = int64_t{1} << 20;
  const int64_t dims[3] = {info.nx, info.ny, info.nz};
  const char* names[3] = {"nx", "ny", "nz"};
  for (int a = 0; a < 3; ++a) {
    if (a == 2 && dims[a] == 0) continue;  // nz not known yet
    if (dims[a] < 2) {
      return absl::InvalidArgumentError(
          absl::StrCat("invalid dimensions: ", names[a], " = ", dims[a],
                       a == 2 ? " (need at least 2 slices, or 0 if the count is unknown)"
                              : " (need at least 2 samples per axis)"));
    }
    if (dims[a] > kMaxAxis) {
      return absl::InvalidArgumentError(absl::StrCat(
          "invalid dimensions: ", names[a], " = ", dims[a], " (at most ", kMaxAxis, " per axis)"));
    }
  }
  // 2^28 = 16384^2 voxels per slice, beyond any scanner's slice; extraction needs about
  // 40 bytes per slice voxel, so a file declaring more (often a corrupt header) is refused
  // before anything that size is allocated.
  if (info.slice_voxels() > (int64_t{1} << 28)) {
    return absl::InvalidArgumentError(absl::StrCat("slice too large: ", info.nx, "x", info.ny,
                                                   " voxels (at most 2^28 = 16384x16384 per slice)"));
  }
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(info.spacing[a]) || info.spacing[a] <= 0.0) {
      return absl::InvalidArgumentError(absl::StrCat("invalid spacing ", info.spacing[a],
                                                     " on axis ", a, " (must be finite and > 0)"));
    }
    if (!std::isfinite(info.origin[a])) {
      return absl::InvalidArgumentError(
          absl::StrCat("invalid origin ", info.origin[a], " on axis ", a, " (must be finite)"));
    }
  }
  // Ranges past which the numbers are certainly a unit or header error, and the float32
  // vertex positions of every output format could not hold the mesh.
  for (int a = 0; a < 3; ++a) {
    if (info.spacing[a] < kMinSpacing || info.spacing[a] > kMaxSpacing) {
      return absl::InvalidArgumentError(absl::StrCat(
          "invalid spacing ", info.spacing[a], " on axis ", a, " (must lie in [", kMinSpacing,
          ", ", kMaxSpacing, "] physical units per voxel)"));
    }
  }
  const double smallest = std::min({info.spacing[0], info.spacing[1], info.spacing[2]});
  const double largest = std::max({info.spacing[0], info.spacing[1], info.spacing[2]});
  if (largest > kMaxAnisotropy * smallest) {
    return absl::InvalidArgumentError(absl::StrCat(
        "invalid spacing ", info.spacing[0], ", ", info.spacing[1], ", ", info.spacing[2],
        ": a voxel more than ", kMaxAnisotropy,
        " times longer on one axis than on another (check the units of each axis)"));
  }
  for (int a = 0; a < 3; ++a) {
    if (std::abs(info.origin[a]) > kMaxOriginVoxels * info.spacing[a]) {
      return absl::InvalidArgumentError(absl::StrCat(
          "invalid origin ", info.origin[a], " on axis ", a, ": more than ", kMaxOriginVoxels,
          " voxels (of ", info.spacing[a],
          ") from 0, where float32 vertex positions could not resolve a voxel; shift the "
          "origin nearer to the volume"));
    }
  }
  const auto& d = info.directions;
  for (int a = 0; a < 3; ++a) {
    for (int b = a; b < 3; ++b) {
      const double dot = d[a][0] * d[b][0] + d[a][1] * d[b][1] + d[a][2] * d[b][2];
      if (!(std::abs(dot - (a == b ? 1.0 : 0.0)) <= 1e-3)) {
        return absl::InvalidArgumentError(absl::StrCat(
            "invalid directions: the grid axes must be orthonormal unit vectors (axis ", a,
            a == b ? " has length^2 " : absl::StrCat(" . axis ", b, " = "), dot, ")"));
      }
    }
  }
  return absl::OkStatus();
}

namespace {
template <typename T>
void ConvertTyped(const uint8_t* src, size_t n, float* dst) {
  // memcpy: src need not be aligned for T.
  for (size_t i = 0; i < n; ++i) {
    T v;
    std::memcpy(&v, src + i * sizeof(T), sizeof(T));
    dst[i] = static_cast<float>(v);
  }
}

// 16 bytes of each type (the attribute does not apply to a template parameter).
typedef uint8_t U8x16 __attribute__((vector_size(16)));
typedef int8_t I8x16 __attribute__((vector_size(16)));
typedef uint16_t U16x8 __attribute__((vector_size(16)));
typedef int16_t I16x8 __attribute__((vector_size(16)));
typedef uint32_t U32x4 __attribute__((vector_size(16)));
typedef int32_t I32x4 __attribute__((vector_size(16)));
typedef uint64_t U64x2 __attribute__((vector_size(16)));
typedef int64_t I64x2 __attribute__((vector_size(16)));
typedef float F32x4 __attribute__((vector_size(16)));

// Smallest and largest of n values of type T, NaNs skipped: `v < lo ? v : lo` keeps lo when v
// is NaN. On vectors V of 16 bytes (GCC/Clang vector extensions), which become minps, pminub
// and the like: independent lanes, so no floating-point reduction to reassociate (a plain
// loop over lanes, or 64-byte vectors, stayed scalar).
// Converting to float is monotone, so the extremes converted are the converted values'.
template <typename T, typename V>
ValueRange RangeTyped(const uint8_t* src, size_t n) {
  constexpr size_t kLanes = sizeof(V) / sizeof(T);
  constexpr size_t kStep = 4 * kLanes;  // four vectors a step: a cache line, four chains
  const T top = std::numeric_limits<T>::has_infinity ? std::numeric_limits<T>::infinity()
                                                     : std::numeric_limits<T>::max();
  const T bottom = std::numeric_limits<T>::has_infinity ? -std::numeric_limits<T>::infinity()
                                                        : std::numeric_limits<T>::lowest();
  V lo[4], hi[4];
  for (int j = 0; j < 4; ++j) {
    for (size_t k = 0; k < kLanes; ++k) {
      lo[j][k] = top;
      hi[j][k] = bottom;
    }
  }
  size_t i = 0;
  for (; i + kStep <= n; i += kStep) {
    for (int j = 0; j < 4; ++j) {
      V v;
      std::memcpy(&v, src + (i + j * kLanes) * sizeof(T), sizeof v);  // any alignment
      lo[j] = v < lo[j] ? v : lo[j];
      hi[j] = v > hi[j] ? v : hi[j];
    }
  }
  T tail_lo = top, tail_hi = bottom;  // apart: indexing lo and hi here kept them in memory
  for (; i < n; ++i) {
    T v;
    std::memcpy(&v, src + i * sizeof(T), sizeof v);
    tail_lo = v < tail_lo ? v : tail_lo;
    tail_hi = v > tail_hi ? v : tail_hi;
  }
  ValueRange r;
  bool any = false;
  auto add = [&](T l, T h) {
    if (l <= h) {  // the lane saw a value (a NaN-only lane did not)
      r.lo = any ? std::min(r.lo, static_cast<float>(l)) : static_cast<float>(l);
      r.hi = any ? std::max(r.hi, static_cast<float>(h)) : static_cast<float>(h);
      any = true;
    }
  };
  for (int j = 0; j < 4; ++j) {
    for (size_t k = 0; k < kLanes; ++k) add(lo[j][k], hi[j][k]);
  }
  add(tail_lo, tail_hi);
  return r;
}
}  // namespace

ValueRange RangeOf(DType t, const uint8_t* src, size_t n) {
  switch (t) {
    case DType::kUInt8:
      return RangeTyped<uint8_t, U8x16>(src, n);
    case DType::kUInt16:
      return RangeTyped<uint16_t, U16x8>(src, n);
    case DType::kInt16:
      return RangeTyped<int16_t, I16x8>(src, n);
    case DType::kFloat32:
      return RangeTyped<float, F32x4>(src, n);
    case DType::kInt8:
      return RangeTyped<int8_t, I8x16>(src, n);
    case DType::kUInt32:
      return RangeTyped<uint32_t, U32x4>(src, n);
    case DType::kInt32:
      return RangeTyped<int32_t, I32x4>(src, n);
    case DType::kUInt64:
      return RangeTyped<uint64_t, U64x2>(src, n);
    case DType::kInt64:
      return RangeTyped<int64_t, I64x2>(src, n);
  }
  return {};
}

absl::Status ValueRangeSource::ReadSlice(std::vector<uint8_t>* bytes) {
  absl::Status st = inner_->ReadSlice(bytes);
  if (st.ok()) Scan(bytes->data());
  return st;
}

absl::Status ValueRangeSource::ViewSlice(const uint8_t** data) {
  absl::Status st = inner_->ViewSlice(data);
  if (st.ok() && *data != nullptr) Scan(*data);
  return st;
}

void ValueRangeSource::Scan(const uint8_t* data) {
  const VolumeInfo& info = inner_->info();
  range_.Merge(RangeOf(info.dtype, data, static_cast<size_t>(info.slice_voxels())));
}

void ConvertToFloat(DType t, const uint8_t* src, size_t n, float* dst) {
  if (n == 0) return;  // dst may be null then (an empty vector's data), which memcpy may not get
  switch (t) {
    case DType::kUInt8:
      ConvertTyped<uint8_t>(src, n, dst);
      break;
    case DType::kUInt16:
      ConvertTyped<uint16_t>(src, n, dst);
      break;
    case DType::kInt16:
      ConvertTyped<int16_t>(src, n, dst);
      break;
    case DType::kFloat32:
      std::memcpy(dst, src, n * sizeof(float));
      break;
    case DType::kInt8:
      ConvertTyped<int8_t>(src, n, dst);
      break;
    case DType::kUInt32:
      ConvertTyped<uint32_t>(src, n, dst);
      break;
    case DType::kInt32:
      ConvertTyped<int32_t>(src, n, dst);
      break;
    case DType::kUInt64:
      ConvertTyped<uint64_t>(src, n, dst);
      break;
    case DType::kInt64:
      ConvertTyped<int64_t>(src, n, dst);
      break;
  }
}

namespace {
template <typename T>
absl::Status LabelsTyped(const uint8_t* src, size_t n, uint64_t* out) {
  T any_negative = 0;  // the OR of all values: its sign bit says whether one is negative
  for (size_t i = 0; i < n; ++i) {
    T v;
    std::memcpy(&v, src + i * sizeof(T), sizeof(T));  // may be unaligned
    out[i] = static_cast<uint64_t>(v);
    any_negative |= v;
  }
  if constexpr (std::is_signed_v<T>) {
    if (any_negative < 0) {
      for (size_t i = 0; i < n; ++i) {
        T v;
        std::memcpy(&v, src + i * sizeof(T), sizeof(T));
        if (v < 0) {
          return absl::InvalidArgumentError(
              absl::StrCat("voxel ", i, " holds ", static_cast<int64_t>(v),
                           ": label ids must not be negative (a signed label map holds ids >= 0)"));
        }
      }
    }
  }
  return absl::OkStatus();
}
}  // namespace

absl::Status ToLabelIds(DType t, const uint8_t* bytes, size_t n, uint64_t* out) {
  switch (t) {
    case DType::kUInt8:
      return LabelsTyped<uint8_t>(bytes, n, out);
    case DType::kInt8:
      return LabelsTyped<int8_t>(bytes, n, out);
    case DType::kUInt16:
      return LabelsTyped<uint16_t>(bytes, n, out);
    case DType::kInt16:
      return LabelsTyped<int16_t>(bytes, n, out);
    case DType::kUInt32:
      return LabelsTyped<uint32_t>(bytes, n, out);
    case DType::kInt32:
      return LabelsTyped<int32_t>(bytes, n, out);
    case DType::kUInt64:
      return LabelsTyped<uint64_t>(bytes, n, out);
    case DType::kInt64:
      return LabelsTyped<int64_t>(bytes, n, out);
    case DType::kFloat32:
      break;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("label ids must be integers; the voxels are ", std::string(DTypeName(t))));
}

int64_t FirstNonFinite(const uint8_t* bytes, size_t n) {
  uint32_t bad = 0;
  for (size_t i = 0; i < n; ++i) {
    uint32_t bits;
    std::memcpy(&bits, bytes + i * sizeof(float), sizeof bits);  // may be unaligned
    bad |= static_cast<uint32_t>(NonFiniteBits(bits));
  }
  if (bad == 0) return -1;
  for (size_t i = 0; i < n; ++i) {
    uint32_t bits;
    std::memcpy(&bits, bytes + i * sizeof(float), sizeof bits);
    if (NonFiniteBits(bits)) return static_cast<int64_t>(i);
  }
  return -1;
}

absl::Status NonFiniteVoxelError(int64_t i, int64_t j, float v) {
  return absl::InvalidArgumentError(
      absl::StrFormat("voxel (i=%d, j=%d) is %s; float32 volumes must hold finite values", i, j,
                      std::isnan(v) ? "NaN" : "infinite"));
}

}  // namespace tandem
