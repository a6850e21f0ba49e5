// Volume input: a slice source yields one z-slice at a time, so no reader ever needs the
// whole volume in memory. Geometry: voxel (i, j, k) sits at
//   origin + i*sx*directions[0] + j*sy*directions[1] + k*sz*directions[2]
// (with the default identity directions: origin + (i*sx, j*sy, k*sz)).
#ifndef TANDEM_VOLUME_H_
#define TANDEM_VOLUME_H_

#include <algorithm>
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace tandem {

// The voxel types. The wider integers (and int8) are what label maps come in: a numpy
// array's default int64, ITK's and FreeSurfer's int32, Neuroglancer's uint64 ids.
enum class DType : uint8_t {
  kUInt8,
  kUInt16,
  kInt16,
  kFloat32,
  kInt8,
  kUInt32,
  kInt32,
  kUInt64,
  kInt64,
};
// Every DType, in the order the names are listed to people.
inline constexpr DType kAllDTypes[] = {DType::kUInt8,  DType::kInt8,   DType::kUInt16,
                                       DType::kInt16,  DType::kUInt32, DType::kInt32,
                                       DType::kUInt64, DType::kInt64,  DType::kFloat32};

// "uint8", "int8", "uint16", "int16", "uint32", "int32", "uint64", "int64", "float32".
std::string_view DTypeName(DType t);
// DTypeName's names; otherwise an error listing them.
absl::StatusOr<DType> ParseDType(std::string_view name);
// "uint8, int8, ..., float32": DTypeName of every kAllDTypes, for messages.
std::string DTypeNames();
size_t DTypeSize(DType t);
constexpr bool IsIntegerDType(DType t) { return t != DType::kFloat32; }
constexpr bool IsSignedDType(DType t) {
  return t == DType::kInt8 || t == DType::kInt16 || t == DType::kInt32 || t == DType::kInt64 ||
         t == DType::kFloat32;
}

// Label ids (LabelId, tandem/labels.h) from n voxels of an integer type t (host byte order,
// any alignment): every value as it is, uint64 exactly. Refused (InvalidArgument): float32
// voxels, and a negative value (the message names its index among the n and the value).
absl::Status ToLabelIds(DType t, const uint8_t* bytes, size_t n, uint64_t* out);

// Where a grid's origin, spacing and directions put its vertices, for programs (VolumeInfo's
// `frame` says it for people): a patient frame, LPS (x toward the patient's left, y
// posterior, z superior: DICOM, ITK, MetaImage) or RAS (x right, y anterior: NIfTI, 3D
// Slicer's scene); a frame of the file's own with no anatomical meaning (kGrid: TIFF, Zarr,
// a sidecar without "space"); or the grid's index coordinates (kVoxel).
enum class Space : uint8_t { kGrid, kLPS, kRAS, kVoxel };
// "grid", "LPS", "RAS", "voxel".
const char* SpaceName(Space s);
// SpaceName's names, in any case; otherwise an error listing them.
absl::StatusOr<Space> ParseSpace(std::string_view name);

struct VolumeInfo {
  int64_t nx = 0, ny = 0, nz = 0;  // grid vertices per axis; nz = 0 means "not known yet"
  DType dtype = DType::kUInt8;
  std::array<double, 3> spacing{1.0, 1.0, 1.0};  // physical units per voxel step
  // False when the file gives no spacing (a TIFF stack without resolution tags, a plain
  // Zarr array, a NRRD or MetaImage header without one): 1 was assumed, and the programs'
  // --spacing flag supplies it.
  bool spacing_known = true;
  std::array<double, 3> origin{0.0, 0.0, 0.0};   // physical position of voxel (0,0,0)
  // World unit vectors of the grid's x, y and z axes (orthonormal; a flip or a rotation, as
  // DICOM ImageOrientationPatient or a NIfTI / NRRD orientation gives).
  std::array<std::array<double, 3>, 3> directions{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  std::vector<double> suggested_isovalues;       // optional, from sidecars
  // What world the vertices land in (origin, spacing and directions above), for people:
  // "DICOM patient LPS (mm)", "NIfTI sform RAS", "grid (spacing and origin)", ...
  std::string frame = "grid (spacing and origin)";
  Space space = Space::kGrid;  // the same, for programs
  std::string description;     // optional

  bool axis_aligned() const {
    return directions == std::array<std::array<double, 3>, 3>{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  }
  int64_t slice_voxels() const { return nx * ny; }
  size_t slice_bytes() const { return static_cast<size_t>(nx * ny) * DTypeSize(dtype); }
};

// Checks dims (>= 2 on x and y, nz >= 2 when known, at most 2^20 per axis and 2^28 per
// slice), spacing in [kMinSpacing, kMaxSpacing] with at most kMaxAnisotropy between axes,
// an origin at most kMaxOriginVoxels voxels from 0 on each axis, and directions that are
// orthonormal within 1e-3. The error names the field and the rule.
absl::Status ValidateVolumeInfo(const VolumeInfo& info);
inline constexpr double kMinSpacing = 1e-12, kMaxSpacing = 1e12;
inline constexpr double kMaxAnisotropy = 1e4;
inline constexpr double kMaxOriginVoxels = 1e6;

// The same grid with its vertices in the frame `to`: LPS <-> RAS negates the world x and y
// of the origin and of the directions (a half turn about z: nothing is mirrored, so the
// triangles keep their winding); kVoxel puts vertex (i, j, k) at (i, j, k) (origin 0, unit
// spacing, identity directions: E0 and distances are then in voxels). `to` == info.space
// returns `info`. Refused (InvalidArgument): LPS or RAS from a grid in neither (kGrid,
// kVoxel: nothing says where the patient is), and kGrid as a target.
absl::StatusOr<VolumeInfo> InFrame(const VolumeInfo& info, Space to);

// A sequential reader of z-slices 0, 1, ..., nz-1.
class SliceSource {
 public:
  virtual ~SliceSource() = default;
  virtual const VolumeInfo& info() const = 0;
  // Reads the next slice as raw voxels in host byte order (info().slice_bytes() bytes) into
  // *bytes (resized). Returns OutOfRange once all nz slices were read; any other error names
  // the file and the problem (truncated data, I/O failure).
  virtual absl::Status ReadSlice(std::vector<uint8_t>* bytes) = 0;
  // Index of the slice the next ReadSlice returns.
  virtual int64_t next_slice() const = 0;
  // Zero-copy reading, where a source offers it (an uncompressed file stored in host byte
  // order, mapped into memory): sets *data to the next slice's raw voxels in place
  // (info().slice_bytes() bytes, host order, not necessarily aligned), valid until the next
  // ViewSlice or ReadSlice call. Sources that cannot set *data = nullptr and read nothing:
  // the caller then uses ReadSlice. Errors as ReadSlice (a file truncated since it was
  // opened is reported before its pages are touched).
  virtual absl::Status ViewSlice(const uint8_t** data) {
    *data = nullptr;
    return absl::OkStatus();
  }
};

// `inner`'s voxels on the grid `info` (its nx, ny and dtype; nz follows `inner`'s, which
// grows while an acquisition is followed): another spacing or frame for the same slices.
std::unique_ptr<SliceSource> Regrid(std::unique_ptr<SliceSource> inner, VolumeInfo info);

// The smallest and largest of n voxels of type t (host byte order, any alignment) as float,
// NaNs skipped (infinities count); lo > hi when there is no other value. The same as
// converting them first, without the copy: one vectorised pass.
struct ValueRange {
  float lo = 1.0f, hi = -1.0f;
  bool empty() const { return !(lo <= hi); }
  // Widens this range to hold r too (an empty r changes nothing).
  void Merge(const ValueRange& r) {
    if (r.empty()) return;
    lo = empty() ? r.lo : std::min(lo, r.lo);
    hi = empty() ? r.hi : std::max(hi, r.hi);
  }
};
ValueRange RangeOf(DType t, const uint8_t* src, size_t n);

// Wraps a source and records the range of the finite values it hands out (read or viewed),
// so that a caller can tell a user that the iso-value lies outside the data. One extra pass
// over each slice's values, converted as the session converts them.
class ValueRangeSource final : public SliceSource {
 public:
  explicit ValueRangeSource(SliceSource* inner) : inner_(inner) {}
  // Reads from `inner` from now on (the same volume opened again, from its first slice),
  // keeping the range seen so far.
  void Replace(std::unique_ptr<SliceSource> inner) {
    owned_ = std::move(inner);
    inner_ = owned_.get();
  }
  const VolumeInfo& info() const override { return inner_->info(); }
  int64_t next_slice() const override { return inner_->next_slice(); }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override;
  absl::Status ViewSlice(const uint8_t** data) override;
  // Range of the finite values seen so far; lo > hi while there are none.
  double lo() const { return range_.lo; }
  double hi() const { return range_.hi; }
  // True when iso cannot cross the data seen: every value on one side of it (or none).
  bool Outside(double iso) const { return !(range_.lo < iso && iso < range_.hi); }

 private:
  void Scan(const uint8_t* data);
  SliceSource* inner_;
  std::unique_ptr<SliceSource> owned_;  // set by Replace
  ValueRange range_;
};

// Converts n voxels of type t (host byte order) to float. 8- and 16-bit integers are exact;
// 32- and 64-bit ones are rounded to the nearest float (exact up to 2^24 in magnitude).
void ConvertToFloat(DType t, const uint8_t* src, size_t n, float* dst);

// Every voxel must be a finite number. The one rule: a float32 whose exponent bits are all set
// is NaN or infinite (integer types are always finite).
constexpr bool NonFiniteBits(uint32_t float_bits) {
  return (float_bits & 0x7f800000u) == 0x7f800000u;
}
// The index of the first of n float32 values at `bytes` (host order, any alignment) that is
// not finite, or -1. One branch-free pass (vectorised) unless there is one.
int64_t FirstNonFinite(const uint8_t* bytes, size_t n);
// The refusal of such a value v at voxel (i, j) of a slice; the caller names the slice.
absl::Status NonFiniteVoxelError(int64_t i, int64_t j, float v);

}  // namespace tandem

#endif  // TANDEM_VOLUME_H_
