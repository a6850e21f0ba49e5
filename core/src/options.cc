#include "tandem/options.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/cord.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "tandem/status_macros.h"

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

namespace {

// A status payload per part of an OptionError.
constexpr char kFieldUrl[] = "tandem.OptionError.field";
constexpr char kValueUrl[] = "tandem.OptionError.value";
constexpr char kRuleUrl[] = "tandem.OptionError.rule";

template <class T>
absl::Status Refuse(const std::string& field, const T& value, const std::string& rule) {
  const std::string text = absl::StrCat(value);
  absl::Status st = absl::InvalidArgumentError(absl::StrCat(field, " = ", text, ": ", rule));
  st.SetPayload(kFieldUrl, absl::Cord(field));
  st.SetPayload(kValueUrl, absl::Cord(text));
  st.SetPayload(kRuleUrl, absl::Cord(rule));
  return st;
}

}  // namespace

std::optional<OptionError> OptionErrorOf(const absl::Status& status) {
  const auto field = status.GetPayload(kFieldUrl);
  const auto value = status.GetPayload(kValueUrl);
  const auto rule = status.GetPayload(kRuleUrl);
  if (!field || !value || !rule) return std::nullopt;
  return OptionError{std::string(*field), std::string(*value), std::string(*rule)};
}

absl::Status NameOptionError(const absl::Status& status,
                             std::string (*label)(const std::string& field),
                             const std::string& separator) {
  std::optional<OptionError> e = OptionErrorOf(status);
  if (!e) return status;
  return absl::Status(status.code(),
                      absl::StrCat(label(e->field), separator, e->value, ": ", e->rule));
}

absl::Status ValidateIsoList(std::span<const double> isos) {
  // The count first: the pairwise check below is quadratic in it.
  if (isos.size() > static_cast<size_t>(kMaxIsoValues)) {
    return absl::InvalidArgumentError(absl::StrCat("at most ", kMaxIsoValues,
                                                   " iso-values in one pass, got ", isos.size()));
  }
  for (size_t i = 0; i < isos.size(); ++i) {
    if (!std::isfinite(isos[i])) {
      return absl::InvalidArgumentError(
          absl::StrCat("iso-value ", isos[i], " is not a finite number"));
    }
    if (std::find(isos.begin(), isos.begin() + i, isos[i]) != isos.begin() + i) {
      return absl::InvalidArgumentError(absl::StrCat("iso-value ", isos[i], " is given twice"));
    }
  }
  return absl::OkStatus();
}

absl::Status SessionOptions::Validate() const {
  if (!std::isfinite(iso)) return Refuse("iso", iso, "iso-value must be a finite number");
  if (labels.enabled) {
    const std::vector<LabelId>& only = labels.only;
    for (size_t i = 1; i < only.size(); ++i) {
      if (only[i] <= only[i - 1]) {
        return Refuse("labels.only", absl::StrJoin(only, ","),
                      "the labels to keep must be given in increasing order, each once");
      }
    }
    if (std::binary_search(only.begin(), only.end(), labels.background)) {
      return Refuse("labels.background", labels.background,
                    "the background label has no surface; it cannot be one of the labels to "
                    "keep (labels.only)");
    }
  }
  if (schedule == Schedule::kNone) return absl::OkStatus();
  if (!(error > 0) || !std::isfinite(error)) {
    return Refuse("error", error,
                  "error threshold E0 must be a finite number > 0 (physical units, e.g. 0.5 x "
                  "the voxel spacing)");
  }
  if (!(alpha >= 0 && alpha <= 1)) {
    return Refuse("alpha", alpha, "isotropy alpha must lie in [0, 1]");
  }
  if (!(distance_guard >= 0) || !std::isfinite(distance_guard)) {
    return Refuse("distance_guard", distance_guard,
                  "distance guard must be a finite number >= 0 (a multiple of E0; 0 = off)");
  }
  if (!(sag_correction >= 0 && sag_correction <= 1)) {
    return Refuse("sag_correction", sag_correction, "sag correction must lie in [0, 1] (0 = off)");
  }
  if (!(lockstep_error > 0 && lockstep_error <= 1)) {
    return Refuse("lockstep_error", lockstep_error,
                  "the lock-step's share of E0 must lie in (0, 1] (1 = no finishing pass)");
  }
  if (target_triangles < 0) {
    return Refuse("target_triangles", target_triangles,
                  "target triangle count must be >= 0 (0 = no target)");
  }
  if (seal && target_triangles > 0) {
    return Refuse("target_triangles", target_triangles,
                  "a target triangle count needs the whole mesh at the end; it cannot be "
                  "combined with sealed chunks");
  }
  if (!(seal_margin >= 0) || !std::isfinite(seal_margin)) {
    return Refuse("seal_margin", seal_margin,
                  "seal margin must be a finite number of slices >= 0");
  }
  if (seal && seam_settle_slices < 1) {
    return Refuse("seam_settle_slices", seam_settle_slices,
                  "seams settle at least 1 slice behind the front");
  }
  if (seal && seam_hold_vertices < 1) {
    return Refuse("seam_hold_vertices", seam_hold_vertices,
                  "a seam holds at least 1 vertex before its oldest settle");
  }
  if (parts < 0 || parts > kMaxParts) {
    return Refuse("parts", parts,
                  absl::StrCat("parts must lie in [0, ", kMaxParts, "] (0 = automatic)"));
  }
  return absl::OkStatus();
}

absl::Status SessionOptions::ValidateFor(const VolumeInfo& grid) const {
  TANDEM_RETURN_IF_ERROR(Validate());
  if (labels.enabled && grid.dtype == DType::kFloat32) {
    return Refuse("labels.enabled", "true",
                  "a label volume needs integer voxels (uint8, uint16, int16, ...); this volume "
                  "is float32");
  }
  if (schedule == Schedule::kNone) return absl::OkStatus();
  const double smallest = std::min({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  const double largest = std::max({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  if (error < kMinErrorVoxels * smallest) {
    return Refuse("error", error,
                  absl::StrCat("error threshold E0 is below ", kMinErrorVoxels,
                               " x the smallest voxel spacing (", smallest,
                               "): nothing could be simplified; use --no-simplify (schedule "
                               "none) for the full-resolution surface, or give E0 in the "
                               "volume's physical units"));
  }
  if (error > kMaxErrorVoxels * largest) {
    return Refuse("error", error,
                  absl::StrCat("error threshold E0 is above ", kMaxErrorVoxels,
                               " x the largest voxel spacing (", largest,
                               "); give E0 in the volume's physical units (e.g. 0.5 x the "
                               "spacing)"));
  }
  return absl::OkStatus();
}

}  // namespace tandem
