// Synthetic scalar fields for tests, benchmarks and the paper's experiments.
//
// Every field is defined in physical coordinates: q = (p - box centre) / s, where s is the
// smallest half-extent of the box, and F = s * f(q) with f roughly a signed distance
// (positive inside). The iso-value is 0 for all shapes; voxels are float32.
//   sphere     radius 0.8
//   pillowbox  the paper's "Pillow Box": a rounded cube, (x^4 + y^4 + z^4)^(1/4) <= 0.90
//   link       the paper's "Link": two interlocked tori (major radius 0.546, minor 0.1365)
//   gyroid     a solid gyroid (sin x cos y + sin y cos z + sin z cos x >= 0, 3 periods
//              across the box) clipped to a ball of radius 0.85: closed, high genus
// Sizes were tuned so that at 128^3 the Pillow Box and the Link cross about the paper's
// 3.53% and 1.71% of cubes (checked in tests/core/extraction_test.cc).
#ifndef TANDEM_SYNTHETIC_H_
#define TANDEM_SYNTHETIC_H_

#include <array>
#include <memory>
#include <string_view>

#include "absl/status/statusor.h"
#include "tandem/volume.h"

namespace tandem::eval {

enum class Shape { kSphere, kPillowBox, kLink, kGyroid };

absl::StatusOr<Shape> ParseShape(std::string_view name);  // "sphere", "pillowbox", ...
std::string_view ShapeName(Shape s);

// A slice source computing the field on the fly (nothing but one slice is ever held).
std::unique_ptr<SliceSource> MakeSyntheticSource(Shape shape, int64_t nx, int64_t ny, int64_t nz,
                                                 std::array<double, 3> spacing = {1, 1, 1});

// The field's value at a physical point, for a box with the given dims and spacing.
double SyntheticValue(Shape shape, const VolumeInfo& box, double px, double py, double pz);

}  // namespace tandem::eval

#endif  // TANDEM_SYNTHETIC_H_
