#include "tandem/options.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace tandem {

std::string_view ScheduleName(Schedule s) {
  switch (s) {
    case Schedule::kNone: return "none";
    case Schedule::kClassical: return "classical";
    case Schedule::kTandem: return "tandem";
    case Schedule::kTandemLag: return "tandem-lag";
  }
  return "?";
}

absl::StatusOr<Schedule> ParseSchedule(std::string_view name) {
  for (Schedule s : {Schedule::kNone, Schedule::kClassical, Schedule::kTandem,
                     Schedule::kTandemLag}) {
    if (name == ScheduleName(s)) return s;
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "unknown schedule '", std::string(name), "'; expected classical, tandem or tandem-lag"));
}

absl::Status SessionOptions::Validate() const {
  if (!std::isfinite(iso)) return absl::InvalidArgumentError("iso-value must be a finite number");
  if (schedule == Schedule::kNone) return absl::OkStatus();
  if (!(error > 0) || !std::isfinite(error)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "error threshold E0 must be a finite number > 0 (physical units), got ", error));
  }
  if (!(alpha >= 0 && alpha <= 1)) {
    return absl::InvalidArgumentError(
        absl::StrCat("isotropy alpha must lie in [0, 1], got ", alpha));
  }
  if (!(distance_guard >= 0) || !std::isfinite(distance_guard)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "distance guard must be a finite number >= 0 (a multiple of E0; 0 = off), got ",
        distance_guard));
  }
  if (!(sag_correction >= 0 && sag_correction <= 1)) {
    return absl::InvalidArgumentError(
        absl::StrCat("sag correction must lie in [0, 1] (0 = off), got ", sag_correction));
  }
  if (target_triangles < 0) {
    return absl::InvalidArgumentError("target triangle count must be >= 0");
  }
  if (seal && target_triangles > 0) {
    return absl::InvalidArgumentError(
        "a target triangle count needs the whole mesh at the end; it cannot be combined with "
        "sealed chunks");
  }
  if (!(seal_margin >= 0) || !std::isfinite(seal_margin)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "seal margin must be a finite number of slices >= 0, got ", seal_margin));
  }
  if (parts < 0 || parts > kMaxParts) {
    return absl::InvalidArgumentError(
        absl::StrCat("parts must lie in [0, ", kMaxParts, "] (0 = automatic), got ", parts));
  }
  return absl::OkStatus();
}

absl::Status SessionOptions::ValidateFor(const VolumeInfo& grid) const {
  if (absl::Status st = Validate(); !st.ok()) return st;
  if (schedule == Schedule::kNone) return absl::OkStatus();
  const double smallest = std::min({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  const double largest = std::max({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  if (error < kMinErrorVoxels * smallest) {
    return absl::InvalidArgumentError(absl::StrCat(
        "error threshold E0 = ", error, " is below ", kMinErrorVoxels,
        " x the smallest voxel spacing (", smallest,
        "): nothing could be simplified; use --no-simplify (schedule none) for the "
        "full-resolution surface, or give E0 in the volume's physical units"));
  }
  if (error > kMaxErrorVoxels * largest) {
    return absl::InvalidArgumentError(absl::StrCat(
        "error threshold E0 = ", error, " is above ", kMaxErrorVoxels,
        " x the largest voxel spacing (", largest,
        "); give E0 in the volume's physical units (e.g. 0.5 x the spacing)"));
  }
  return absl::OkStatus();
}

}  // namespace tandem
