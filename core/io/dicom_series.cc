// DICOM series rules (dicom_series.h): slice headers, the series' frame and step checks,
// value plans, and the choice of series in a folder.
#include "dicom_series.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "dicom_worker_client.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"

namespace tandem::io::internal::dicom_series {

Vec Cross(const Vec& a, const Vec& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double Dot(const Vec& a, const Vec& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
namespace {
double Norm(const Vec& a) { return std::sqrt(Dot(a, a)); }
}  // namespace

std::string Base(const std::string& path) { return std::filesystem::path(path).filename(); }

void Tell(const Note& note, const std::string& line) {
  if (note) note(line);
}

namespace {

// Whether a file can be DICOM: "DICM" after the 128-byte preamble (Part 10), or a data set
// starting with an element of group 0002 or 0008 (files written without the preamble).
bool LooksLikeDicom(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char head[132] = {};
  in.read(reinterpret_cast<char*>(head), sizeof(head));
  const std::streamsize n = in.gcount();
  if (n == 132 && std::memcmp(head + 128, "DICM", 4) == 0) return true;
  const int group = n >= 2 ? head[0] | head[1] << 8 : -1;
  return group == 0x0002 || group == 0x0008;
}

}  // namespace

// One file's header for a series reader (tandem/series.h): a slice; nothing, with *skip
// saying why, for a file that is not DICOM or a DICOM object that is no image slice (*skip
// empty: a DICOMDIR); or an error naming a DICOM file that does not read as a slice.
absl::StatusOr<std::optional<SliceHeader>> ReadSliceHeader(const std::string& path,
                                                           std::string* skip) {
  skip->clear();
  if (!LooksLikeDicom(path)) {
    *skip = absl::StrCat("skipping ", path, ": not a DICOM file");
    return std::nullopt;
  }
  // Read in the DICOM reader process (dicom_worker_client.h).
  absl::StatusOr<std::optional<SliceHeader>> h = dicom::ReadHeader(path);
  if (absl::IsFailedPrecondition(h.status())) {
    *skip = absl::StrCat("skipping ", h.status().message());
    return std::nullopt;
  }
  return h;
}

// ImageType says the image is a localizer (a scout, topogram, surview).
bool IsLocalizer(const SliceHeader& h) {
  for (absl::string_view v : absl::StrSplit(h.image_type, '\\')) {
    if (absl::EqualsIgnoreCase(absl::StripAsciiWhitespace(v), "LOCALIZER")) return true;
  }
  return false;
}

namespace {

DType StoredType(const SliceHeader& h) {
  if (h.bits_allocated == 8) return DType::kUInt8;
  return h.pixel_representation ? DType::kInt16 : DType::kUInt16;
}

bool Near(double a, double b, double tol) { return std::abs(a - b) <= tol; }

}  // namespace

absl::StatusOr<Frame> FrameOf(const SliceHeader& first) {
  Frame f;
  f.row = {first.orientation[0], first.orientation[1], first.orientation[2]};
  f.col = {first.orientation[3], first.orientation[4], first.orientation[5]};
  if (!(Near(Norm(f.row), 1, 1e-2) && Near(Norm(f.col), 1, 1e-2) &&
        std::abs(Dot(f.row, f.col)) < 1e-2)) {
    return absl::InvalidArgumentError(
        absl::StrCat(first.path, ": ImageOrientationPatient is not two orthogonal unit vectors"));
  }
  for (Vec* v : {&f.row, &f.col}) {
    const double len = Norm(*v);
    for (double& c : *v) c /= len;
  }
  f.normal = Cross(f.row, f.col);
  const double len = Norm(f.normal);
  for (double& c : f.normal) c = c / len + 0.0;  // + 0.0: no "-0" in messages
  return f;
}

// Every slice of a series has the first one's size, orientation, pixel spacing and type.
bool SameOrientation(const SliceHeader& a, const SliceHeader& b) {
  for (int i = 0; i < 6; ++i) {
    if (!Near(a.orientation[i], b.orientation[i], 1e-4)) return false;
  }
  return true;
}

absl::Status CheckMatches(const std::string& dir, const SliceHeader& first, const SliceHeader& h) {
  auto mismatch = [&](const std::string& what) {
    return absl::InvalidArgumentError(
        absl::StrCat("DICOM series in ", dir, ": ", Base(h.path), " and ", Base(first.path),
                     " differ in ", what, " (every slice of a series must match)"));
  };
  if (h.rows != first.rows || h.cols != first.cols) {
    return mismatch(
        absl::StrCat("size (", h.cols, "x", h.rows, " vs ", first.cols, "x", first.rows, ")"));
  }
  if (!SameOrientation(h, first)) return mismatch("ImageOrientationPatient");
  if (h.has_spacing != first.has_spacing ||
      !Near(h.row_spacing, first.row_spacing, 1e-4 * first.row_spacing) ||
      !Near(h.col_spacing, first.col_spacing, 1e-4 * first.col_spacing)) {
    return mismatch("PixelSpacing");
  }
  if (StoredType(h) != StoredType(first) || h.bits_stored != first.bits_stored) {
    return mismatch("pixel type (BitsAllocated / BitsStored / PixelRepresentation)");
  }
  return absl::OkStatus();
}

// Neighbours (sorted by `along`) a..b: not at one position, not a step 10% off `step` (a
// gap names where the missing slice would be: `step` above a along `normal`).
absl::Status CheckStep(const std::string& dir, const SliceHeader& a, const SliceHeader& b,
                       double step, double in_plane, const Vec& normal) {
  const double d = b.along - a.along;
  if (d <= 1e-3 * in_plane) {
    return absl::InvalidArgumentError(
        absl::StrCat("DICOM series in ", dir, ": ", Base(a.path), " and ", Base(b.path),
                     " are at the same position (", FormatDouble(a.along),
                     " mm along the normal); duplicate slice?"));
  }
  if (std::abs(d - step) > 0.1 * step) {
    std::string where;
    if (d > step) {
      where =
          absl::StrFormat(" at ImagePositionPatient (%g, %g, %g)", a.position[0] + step * normal[0],
                          a.position[1] + step * normal[1], a.position[2] + step * normal[2]);
    }
    return absl::InvalidArgumentError(absl::StrCat(
        "DICOM series in ", dir, ": gap between ", Base(a.path), " and ", Base(b.path), ": ",
        FormatDouble(d), " mm apart where the series' usual step is ", FormatDouble(step),
        " mm (a missing slice", where, ", or an irregular series)"));
  }
  return absl::OkStatus();
}

absl::Status CheckInLine(const std::string& dir, const SliceHeader& first, const SliceHeader& h,
                         const Vec& normal, double in_plane) {
  const Vec off{h.position[0] - first.position[0], h.position[1] - first.position[1],
                h.position[2] - first.position[2]};
  const double along = Dot(off, normal);
  const Vec side{off[0] - along * normal[0], off[1] - along * normal[1],
                 off[2] - along * normal[2]};
  if (Norm(side) > 0.1 * in_plane) {
    return absl::InvalidArgumentError(absl::StrCat(
        "DICOM series in ", dir, ": ", Base(h.path), " is shifted ", FormatDouble(Norm(side)),
        " mm sideways from the slice normal (gantry tilt?); tilted series are not supported"));
  }
  return absl::OkStatus();
}

// The z step, rounded to 1e-6 mm so that a series read finished and one followed while it
// was written (whose step is known from fewer slices) get the same grid.
double RoundStep(double step) { return std::round(step * 1e6) / 1e6; }

ValuePlan PlanValues(const SliceHeader* begin, const SliceHeader* end) {
  const SliceHeader& first = *begin;
  ValuePlan plan;
  plan.stored = plan.out = StoredType(first);
  bool integer_shift = true;
  for (const SliceHeader* h = begin; h != end; ++h) {
    if (h->slope != 1.0 || h->intercept != 0.0) plan.rescale = true;
    if (h->slope != 1.0 || h->intercept != std::round(h->intercept) ||
        h->intercept != first.intercept) {
      integer_shift = false;
    }
  }
  if (!plan.rescale) return plan;
  plan.out = DType::kFloat32;
  if (integer_shift && plan.stored != DType::kUInt8) {
    const double lo = first.pixel_representation ? -std::ldexp(1.0, first.bits_stored - 1) : 0.0;
    const double hi = first.pixel_representation ? std::ldexp(1.0, first.bits_stored - 1) - 1
                                                 : std::ldexp(1.0, first.bits_stored) - 1;
    const double b = first.intercept;
    if (lo + b >= std::numeric_limits<int16_t>::min() &&
        hi + b <= std::numeric_limits<int16_t>::max()) {
      plan.out = DType::kInt16;
    }
  }
  return plan;
}

VolumeInfo MakeInfo(const SliceHeader& first, const Frame& frame, int64_t nz, double step,
                    const ValuePlan& plan) {
  VolumeInfo info;
  info.nx = first.cols;
  info.ny = first.rows;
  info.nz = nz;
  info.dtype = plan.out;
  info.spacing = {first.col_spacing, first.row_spacing, step};
  info.origin = first.position;
  info.directions = {frame.row, frame.col, frame.normal};
  info.frame = "DICOM patient LPS (mm)";
  info.space = Space::kLPS;
  info.description =
      absl::StrCat("DICOM ", first.modality.empty() ? "" : first.modality + " ", "series",
                   first.description.empty() ? "" : " '" + first.description + "'",
                   plan.rescale ? ", rescaled values" : "",
                   first.has_spacing ? "" : " (no PixelSpacing: 1 mm assumed)");
  return info;
}

// Decodes one slice's pixels (through `buffer`) into `bytes` as info.dtype.
absl::Status ReadPixels(const SliceHeader& h, const VolumeInfo& info, const ValuePlan& plan,
                        std::vector<uint8_t>* buffer, std::vector<uint8_t>* bytes) {
  const size_t n = static_cast<size_t>(info.slice_voxels());
  TANDEM_RETURN_IF_ERROR(dicom::ReadPixels(h.path, n * DTypeSize(plan.stored), buffer));
  bytes->resize(info.slice_bytes());
  if (!plan.rescale) {
    std::memcpy(bytes->data(), buffer->data(), buffer->size());
    return absl::OkStatus();
  }
  const double s = h.slope, b = h.intercept;
  auto convert = [&](auto out_tag) {
    using Out = decltype(out_tag);
    auto run = [&](auto in_tag) {
      using In = decltype(in_tag);
      for (size_t i = 0; i < n; ++i) {
        In v;
        std::memcpy(&v, buffer->data() + i * sizeof(In), sizeof(In));
        const Out o = static_cast<Out>(static_cast<double>(v) * s + b);
        std::memcpy(bytes->data() + i * sizeof(Out), &o, sizeof(Out));
      }
    };
    switch (plan.stored) {
      case DType::kUInt8:
        run(uint8_t{});
        break;
      case DType::kUInt16:
        run(uint16_t{});
        break;
      case DType::kInt16:
        run(int16_t{});
        break;
      case DType::kFloat32:
      case DType::kInt8:
      case DType::kUInt32:
      case DType::kInt32:
      case DType::kUInt64:
      case DType::kInt64:
        break;  // never stored in DICOM images (StoredType)
    }
  };
  // int16 only when the slope is 1 and the shifted range fits (PlanValues): exact.
  if (info.dtype == DType::kInt16) {
    convert(int16_t{});
  } else {
    convert(float{});
  }
  return absl::OkStatus();
}

double MedianStep(const std::vector<SliceHeader>& sorted) {
  std::vector<double> steps;
  for (size_t k = 0; k + 1 < sorted.size(); ++k) steps.push_back(sorted[k + 1].along - sorted[k].along);
  std::nth_element(steps.begin(), steps.begin() + steps.size() / 2, steps.end());
  return steps[steps.size() / 2];
}

double InPlane(const SliceHeader& first) { return std::min(first.row_spacing, first.col_spacing); }

Vec NormalOf(const SliceHeader& h) {
  absl::StatusOr<Frame> frame = FrameOf(h);
  return frame.ok() ? frame->normal : Vec{0, 0, 0};
}

bool Parallel(const Vec& a, const Vec& b) { return std::abs(Dot(a, b)) > 0.999; }

// "UID 'description' (N images, e.g. FILE)"; images 0 = not counted yet.
std::string Named(const std::string& uid, const std::string& description, int64_t images,
                  const std::string& example) {
  std::string s = absl::StrCat(uid, description.empty() ? "" : " '" + description + "'");
  if (images > 0) {
    absl::StrAppend(&s, " (", images, images == 1 ? " image" : " images",
                    example.empty() ? "" : ", e.g. " + Base(example), ")");
  }
  return s;
}
std::string Named(const SeriesSummary& s) {
  return Named(s.uid, s.description, s.images, s.example);
}
std::string IgnoredLine(const std::string& name, const std::string& reason) {
  return absl::StrCat("ignoring DICOM series ", name, ": ", reason);
}

// The series of a folder to read (tandem/series.h states the rule); one note per series
// set aside.
absl::StatusOr<std::string> PickSeries(const std::string& dir,
                                       const std::vector<SeriesSummary>& all,
                                       const std::string& want, const Note& note) {
  auto list = [](const std::vector<const SeriesSummary*>& v) {
    return absl::StrJoin(
        v, "; ", [](std::string* out, const SeriesSummary* s) { absl::StrAppend(out, Named(*s)); });
  };
  std::vector<const SeriesSummary*> stacks;
  for (const SeriesSummary& s : all) stacks.push_back(&s);
  if (!want.empty()) {
    auto hit = std::find_if(stacks.begin(), stacks.end(),
                            [&](const SeriesSummary* s) { return s->uid == want; });
    if (hit == stacks.end()) {
      return absl::InvalidArgumentError(absl::StrCat(
          dir, ": no DICOM series ", want, " (--series) here; the folder holds ", list(stacks)));
    }
    for (const SeriesSummary* s : stacks) {
      if (s != *hit) Tell(note, IgnoredLine(Named(*s), "not the series --series picks"));
    }
    return want;
  }
  std::vector<std::pair<const SeriesSummary*, std::string>> aside;
  std::erase_if(stacks, [&](const SeriesSummary* s) {
    if (s->localizer) aside.emplace_back(s, "a localizer (ImageType LOCALIZER)");
    return s->localizer;
  });
  if (stacks.size() > 1) {
    const SeriesSummary* main = *std::max_element(
        stacks.begin(), stacks.end(),
        [](const SeriesSummary* a, const SeriesSummary* b) { return a->images < b->images; });
    std::erase_if(stacks, [&](const SeriesSummary* s) {
      if (s == main) return false;
      std::string why;
      if (!s->parallel) {
        why = "its images are not parallel (a multi-plane localizer?)";
      } else if (!Parallel(s->normal, main->normal)) {
        why = absl::StrCat("not parallel to the main stack ", main->uid);
      } else if (s->images <= 2) {
        why = "a scout (1 or 2 images beside the main stack)";
      }
      if (!why.empty()) aside.emplace_back(s, why);
      return !why.empty();
    });
  }
  if (stacks.empty()) {
    std::vector<std::string> why;
    for (const auto& [s, reason] : aside) why.push_back(absl::StrCat(Named(*s), ": ", reason));
    return absl::InvalidArgumentError(absl::StrCat(dir, ": no slice stack to read, only ",
                                                   absl::StrJoin(why, "; "),
                                                   " (--series UID reads one anyway)"));
  }
  if (stacks.size() > 1) {
    return absl::InvalidArgumentError(absl::StrCat(dir, ": the folder holds ", stacks.size(),
                                                   " DICOM slice stacks: ", list(stacks),
                                                   "; pick one with --series UID"));
  }
  for (const auto& [s, reason] : aside) Tell(note, IgnoredLine(Named(*s), reason));
  return stacks.front()->uid;
}

}  // namespace tandem::io::internal::dicom_series
