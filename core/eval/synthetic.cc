#include "tandem/eval/synthetic.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>
#include <string>

#include "absl/strings/str_cat.h"

namespace tandem::eval {
namespace {

constexpr double kSphereRadius = 0.8;
constexpr double kPillowRadius = 0.90;
constexpr double kLinkMajor = 0.546;
constexpr double kLinkMinor = 0.1365;
constexpr double kGyroidBall = 0.85;
constexpr double kGyroidPeriods = 3.0;

double TorusInside(double x, double y, double z, double major, double minor) {
  // Torus around the z axis: distance to the core circle in the plane z = 0.
  const double ring = std::sqrt(x * x + y * y) - major;
  return minor - std::sqrt(ring * ring + z * z);
}

double ShapeValue(Shape shape, double x, double y, double z) {
  switch (shape) {
    case Shape::kSphere:
      return kSphereRadius - std::sqrt(x * x + y * y + z * z);
    case Shape::kPillowBox:
      return kPillowRadius - std::pow(x * x * x * x + y * y * y * y + z * z * z * z, 0.25);
    case Shape::kLink: {
      // Ring 1 in the plane z = 0 centred at (-major/2, 0, 0); ring 2 in the plane y = 0
      // centred at (+major/2, 0, 0): each ring passes through the other's hole.
      const double h = 0.5 * kLinkMajor;
      const double t1 = TorusInside(x + h, y, z, kLinkMajor, kLinkMinor);
      const double t2 = TorusInside(x - h, z, y, kLinkMajor, kLinkMinor);
      return std::max(t1, t2);
    }
    case Shape::kGyroid: {
      const double w = 2.0 * std::numbers::pi * kGyroidPeriods / 2.0;  // periods over [-1, 1]
      const double g = std::sin(w * x) * std::cos(w * y) + std::sin(w * y) * std::cos(w * z) +
                       std::sin(w * z) * std::cos(w * x);
      const double ball = kGyroidBall - std::sqrt(x * x + y * y + z * z);
      return std::min(g / w, ball);  // g/w is roughly a distance near the surface
    }
  }
  return 0;
}

struct Frame {
  double cx, cy, cz, s;
};

Frame FrameOf(const VolumeInfo& box) {
  const double ex = 0.5 * static_cast<double>(box.nx - 1) * box.spacing[0];
  const double ey = 0.5 * static_cast<double>(box.ny - 1) * box.spacing[1];
  const double ez = 0.5 * static_cast<double>(box.nz - 1) * box.spacing[2];
  return {box.origin[0] + ex, box.origin[1] + ey, box.origin[2] + ez, std::min({ex, ey, ez})};
}

class SyntheticSource final : public SliceSource {
 public:
  SyntheticSource(Shape shape, const VolumeInfo& info) : shape_(shape), info_(info) {}
  const VolumeInfo& info() const override { return info_; }
  int64_t next_slice() const override { return next_; }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    if (next_ >= info_.nz) {
      return absl::OutOfRangeError(absl::StrCat("synthetic ", std::string(ShapeName(shape_)), ": all ",
                                                info_.nz, " slices were read"));
    }
    bytes->resize(info_.slice_bytes());
    const Frame fr = FrameOf(info_);
    const double pz = info_.origin[2] + static_cast<double>(next_) * info_.spacing[2];
    float* out = reinterpret_cast<float*>(bytes->data());
    for (int64_t j = 0; j < info_.ny; ++j) {
      const double py = info_.origin[1] + static_cast<double>(j) * info_.spacing[1];
      for (int64_t i = 0; i < info_.nx; ++i) {
        const double px = info_.origin[0] + static_cast<double>(i) * info_.spacing[0];
        out[j * info_.nx + i] = static_cast<float>(
            fr.s * ShapeValue(shape_, (px - fr.cx) / fr.s, (py - fr.cy) / fr.s, (pz - fr.cz) / fr.s));
      }
    }
    ++next_;
    return absl::OkStatus();
  }

 private:
  Shape shape_;
  VolumeInfo info_;
  int64_t next_ = 0;
};

}  // namespace

absl::StatusOr<Shape> ParseShape(std::string_view name) {
  for (Shape s : {Shape::kSphere, Shape::kPillowBox, Shape::kLink, Shape::kGyroid}) {
    if (name == ShapeName(s)) return s;
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "unknown shape '", std::string(name), "'; expected one of: sphere, pillowbox, link, gyroid"));
}

std::string_view ShapeName(Shape s) {
  switch (s) {
    case Shape::kSphere: return "sphere";
    case Shape::kPillowBox: return "pillowbox";
    case Shape::kLink: return "link";
    case Shape::kGyroid: return "gyroid";
  }
  return "?";
}

double SyntheticValue(Shape shape, const VolumeInfo& box, double px, double py, double pz) {
  const Frame fr = FrameOf(box);
  return fr.s * ShapeValue(shape, (px - fr.cx) / fr.s, (py - fr.cy) / fr.s, (pz - fr.cz) / fr.s);
}

std::unique_ptr<SliceSource> MakeSyntheticSource(Shape shape, int64_t nx, int64_t ny, int64_t nz,
                                                 std::array<double, 3> spacing) {
  VolumeInfo info;
  info.nx = nx;
  info.ny = ny;
  info.nz = nz;
  info.dtype = DType::kFloat32;
  info.spacing = spacing;
  info.suggested_isovalues = {0.0};
  info.description = absl::StrCat("synthetic ", std::string(ShapeName(shape)), " (tandem generate)");
  return std::make_unique<SyntheticSource>(shape, info);
}

}  // namespace tandem::eval
