// DICOM series (one instance per z-slice): reader and writer. The rules are in
// tandem/series.h; GDCM, which reads and writes the files, is behind dicom_codec.h (a module
// loaded on first use). Headers are read up to the pixel data for every file at open time (to
// order and check the series); pixel data is decoded one file per ReadSlice.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <optional>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "dicom_codec.h"
#include "dicom_worker_client.h"
#include "follow_internal.h"
#include "volume_io_internal.h"
#include "tandem/series.h"

namespace tandem {
namespace {

using internal::FormatDouble;
using Vec = std::array<double, 3>;

Vec Cross(const Vec& a, const Vec& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double Dot(const Vec& a, const Vec& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
double Norm(const Vec& a) { return std::sqrt(Dot(a, a)); }

std::string Base(const std::string& path) { return std::filesystem::path(path).filename(); }
using dicom::SliceHeader;

// One file's header, read in the DICOM reader process (dicom_worker_client.h).
absl::StatusOr<std::optional<SliceHeader>> ReadHeader(const std::string& path) {
  return dicom::ReadHeader(path);
}

DType StoredType(const SliceHeader& h) {
  if (h.bits_allocated == 8) return DType::kUInt8;
  return h.pixel_representation ? DType::kInt16 : DType::kUInt16;
}

bool Near(double a, double b, double tol) { return std::abs(a - b) <= tol; }

// The series' frame from its first slice: unit row and column directions and the normal.
struct Frame {
  Vec row, col, normal;
};

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
absl::Status CheckMatches(const std::string& dir, const SliceHeader& first, const SliceHeader& h) {
  auto mismatch = [&](const std::string& what) {
    return absl::InvalidArgumentError(
        absl::StrCat("DICOM series in ", dir, ": ", Base(h.path), " and ", Base(first.path),
                     " differ in ", what, " (every slice of a series must match)"));
  };
  if (h.series_uid != first.series_uid) {
    return absl::InvalidArgumentError(absl::StrCat(
        "DICOM series in ", dir, ": ", Base(h.path), " belongs to series '", h.series_uid,
        "', not '", first.series_uid, "' of ", Base(first.path),
        "; put each series in its own folder"));
  }
  if (h.rows != first.rows || h.cols != first.cols) {
    return mismatch(
        absl::StrCat("size (", h.cols, "x", h.rows, " vs ", first.cols, "x", first.rows, ")"));
  }
  for (int i = 0; i < 6; ++i) {
    if (!Near(h.orientation[i], first.orientation[i], 1e-4)) {
      return mismatch("ImageOrientationPatient");
    }
  }
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

// Neighbours (sorted by `along`) a..b: not at one position, not a step 10% off `step`, not
// shifted sideways from the first slice.
absl::Status CheckStep(const std::string& dir, const SliceHeader& a, const SliceHeader& b,
                       double step, double in_plane) {
  const double d = b.along - a.along;
  if (d <= 1e-3 * in_plane) {
    return absl::InvalidArgumentError(
        absl::StrCat("DICOM series in ", dir, ": ", Base(a.path), " and ", Base(b.path),
                     " are at the same position (", FormatDouble(a.along),
                     " mm along the normal); duplicate slice?"));
  }
  if (std::abs(d - step) > 0.1 * step) {
    return absl::InvalidArgumentError(absl::StrCat(
        "DICOM series in ", dir, ": gap between ", Base(a.path), " and ", Base(b.path), ": ",
        FormatDouble(d), " mm apart where the series' usual step is ", FormatDouble(step),
        " mm (a missing slice, or an irregular series)"));
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

// How values are delivered: the stored type, int16 (slope 1, one integer intercept whose
// shift keeps BitsStored's range inside int16: the usual CT), or float32.
struct ValuePlan {
  DType stored = DType::kUInt8;
  DType out = DType::kUInt8;
  bool rescale = false;
};

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
  if (absl::Status st = dicom::ReadPixels(h.path, n * DTypeSize(plan.stored), buffer); !st.ok()) {
    return st;
  }
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
        break;  // never stored in DICOM images
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

// One file per slice (info.nz == slices.size()).
class DicomSliceSource final : public internal::CountedSliceSource {
 public:
  DicomSliceSource(std::vector<SliceHeader> slices, VolumeInfo info, ValuePlan plan)
      : CountedSliceSource("DICOM series", std::move(info), OnFailure::kRetry),
        slices_(std::move(slices)),
        plan_(plan) {}

 private:
  absl::Status ReadNext(std::vector<uint8_t>* bytes) override {
    return ReadPixels(slices_[next_slice()], info_, plan_, &buffer_, bytes);
  }

  std::vector<SliceHeader> slices_;
  ValuePlan plan_;
  std::vector<uint8_t> buffer_;
};

double MedianStep(const std::vector<SliceHeader>& sorted) {
  std::vector<double> steps;
  for (size_t k = 0; k + 1 < sorted.size(); ++k) steps.push_back(sorted[k + 1].along - sorted[k].along);
  std::nth_element(steps.begin(), steps.begin() + steps.size() / 2, steps.end());
  return steps[steps.size() / 2];
}

// A series still arriving (follow mode): complete files are ordered by position and handed
// out from the lowest, each once the slice one step below it has gone.
class GrowingDicom final : public internal::Growing {
 public:
  GrowingDicom(std::string dir, double stable_s, std::string done_file)
      : dir_(std::move(dir)), stable_s_(stable_s), done_file_(std::move(done_file)) {}

  absl::StatusOr<int64_t> Complete(bool* changed) override {
    if (absl::Status st = Scan(changed); !st.ok()) return st;
    return Release(/*final=*/false);
  }

  absl::StatusOr<int64_t> Final() override {
    bool changed = false;
    if (absl::Status st = Scan(&changed, /*final=*/true); !st.ok()) return st;
    for (const auto& [path, seen] : seen_) {
      if (!seen.whole && !seen.problem.empty()) {
        return absl::DataLossError(absl::StrCat(
            seen.problem, " (the acquisition ended with this file still not whole)"));
      }
    }
    return Release(/*final=*/true);
  }

  absl::StatusOr<VolumeInfo> Info() override {
    const SliceHeader& first = sent_.front();
    return MakeInfo(first, frame_, 0, step_, plan_);
  }

  absl::Status Read(int64_t k, const VolumeInfo& info, std::vector<uint8_t>* bytes) override {
    const SliceHeader& h = sent_[k];
    if (h.slope != sent_.front().slope || h.intercept != sent_.front().intercept) {
      if (info.dtype != DType::kFloat32 || !plan_.rescale) {
        return absl::InvalidArgumentError(absl::StrCat(
            h.path, ": RescaleSlope/Intercept differ from the first slice's; a followed series "
                    "needs one rescale unless its first slice already rescales to float"));
      }
    }
    return ReadPixels(h, info, plan_, &buffer_, bytes);
  }

  std::string Dir() const override { return dir_; }
  std::string Problem() const override { return problem_; }

 private:
  struct Seen {
    uint64_t size = 0;
    std::chrono::steady_clock::time_point since;
    bool whole = false;    // header read and pixel data complete
    std::string problem;  // why not (yet)
  };

  // Reads the headers of files whose size has held for stable_s; a file that does not read
  // whole yet (still being written) is tried again when its size changes.
  // final: the acquisition is over, so every file is as whole as it will get (no waiting for
  // sizes to hold).
  absl::Status Scan(bool* changed, bool final = false) {
    absl::StatusOr<std::vector<std::string>> files = ListSliceFiles(dir_);
    if (absl::IsNotFound(files.status())) return absl::OkStatus();  // not created yet
    if (!files.ok()) return files.status();
    const auto now = std::chrono::steady_clock::now();
    for (const std::string& f : *files) {
      if (!done_file_.empty() && Base(f) == done_file_) continue;
      std::error_code ec;
      const uint64_t size = std::filesystem::file_size(f, ec);
      if (ec) continue;
      auto [it, inserted] = seen_.try_emplace(f);
      Seen& s = it->second;
      if (inserted || s.size != size) {
        s.size = size;
        s.since = now;
        s.whole = false;
        s.problem.clear();
        *changed = true;
      }
      if (s.whole || !s.problem.empty() || size == 0 ||
          (!final && std::chrono::duration<double>(now - s.since).count() < stable_s_)) {
        continue;
      }
      absl::StatusOr<std::optional<SliceHeader>> h = ReadHeader(f);
      if (!h.ok()) {
        // Not whole (yet): a DataLoss is a file still being written; anything else is kept
        // as the problem to report if it never becomes a readable slice.
        s.problem = problem_ = std::string(h.status().message());
        continue;
      }
      s.whole = true;
      if (!h->has_value()) continue;  // DICOMDIR
      if (absl::Status st = Add(**h); !st.ok()) return st;
    }
    return absl::OkStatus();
  }

  absl::Status Add(SliceHeader h) {
    if (!have_first_) {
      absl::StatusOr<Frame> frame = FrameOf(h);
      if (!frame.ok()) return frame.status();
      frame_ = *frame;
      first_ = h;
      have_first_ = true;
    } else if (absl::Status st = CheckMatches(dir_, first_, h); !st.ok()) {
      return st;
    }
    numbered_ = numbered_ && h.instance >= 0;  // every slice so far has an InstanceNumber
    h.along = Dot(h.position, frame_.normal);
    const double in_plane = std::min(first_.row_spacing, first_.col_spacing);
    if (absl::Status st = CheckInLine(dir_, first_, h, frame_.normal, in_plane); !st.ok()) {
      return st;
    }
    if (!sent_.empty() && h.along <= sent_.back().along + 1e-3 * in_plane) {
      return absl::FailedPreconditionError(absl::StrCat(
          "DICOM series in ", dir_, ": ", Base(h.path), " arrived at or below slices already "
          "meshed (", FormatDouble(h.along), " mm along the normal, the last sent is at ",
          FormatDouble(sent_.back().along),
          " mm); following needs a series that grows along its normal (read a series "
          "acquired the other way once it is finished, without --follow)"));
    }
    auto pos = std::lower_bound(held_.begin(), held_.end(), h.along,
                                [](const SliceHeader& s, double a) { return s.along < a; });
    held_.insert(pos, std::move(h));
    return absl::OkStatus();
  }

  // Whether a and b are neighbours by InstanceNumber (one apart, the way the series counts:
  // `direction` +1 or -1 along the normal; 0 = not known yet, either).
  static bool Adjacent(const SliceHeader& a, const SliceHeader& b, int direction) {
    const int64_t d = b.instance - a.instance;
    return direction == 0 ? (d == 1 || d == -1) : d == direction;
  }

  // Moves held slices to sent_ while each is one step above the last sent. A receiver
  // stores a burst of files in any order, so the first slices seen can be every other one
  // of the burst (positions 0, 2, 4: a "step" twice the real one). When every slice has an
  // InstanceNumber, those say which are neighbours: the first slices go only as a run of
  // three neighbours from the lowest held (and, unless the lowest is instance 1, once it
  // has been on disk for 2 s, in case the series' first is still being written), the step
  // is taken from that run, and each next slice must also be the last one's neighbour.
  // Without instance numbers: the median gap of the first three. Final: positions decide.
  absl::StatusOr<int64_t> Release(bool final) {
    const double in_plane = std::min(first_.row_spacing, first_.col_spacing);
    const bool numbered = numbered_;
    if (sent_.empty()) {
      if (held_.size() < (final ? 2u : 3u)) return 0;
      for (size_t k = 0; k + 1 < held_.size(); ++k) {  // duplicates would look like steps
        const double d = held_[k + 1].along - held_[k].along;
        if (d <= 1e-3 * in_plane) return CheckStep(dir_, held_[k], held_[k + 1], d, in_plane);
      }
      if (numbered && !final) {
        const int direction = held_[1].instance > held_[0].instance ? 1 : -1;
        if (!Adjacent(held_[0], held_[1], 0) || !Adjacent(held_[1], held_[2], direction)) {
          return 0;  // the slices in between are still to come
        }
        const auto since = seen_[held_[0].path].since;
        if (held_[0].instance != 1 &&
            std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count() < 2) {
          return 0;
        }
        direction_ = direction;
        step_ = RoundStep((held_[2].along - held_[0].along) / 2);
      } else {
        step_ = RoundStep(MedianStep(held_));
      }
      plan_ = PlanValues(&held_.front(), &held_.front() + 1);
    }
    while (!held_.empty()) {
      const SliceHeader& next = held_.front();
      if (!sent_.empty()) {
        absl::Status st = CheckStep(dir_, sent_.back(), next, step_, in_plane);
        if (st.ok() && numbered && !final && !Adjacent(sent_.back(), next, direction_)) {
          break;  // a neighbour by position, not by number: wait for the one in between
        }
        if (!st.ok()) {
          if (final) return st;  // the gap never closed
          break;                 // wait for the slice in between
        }
      }
      sent_.push_back(next);
      held_.erase(held_.begin());
    }
    return static_cast<int64_t>(sent_.size());
  }

  std::string dir_;
  double stable_s_;
  std::string done_file_;
  std::map<std::string, Seen> seen_;
  bool have_first_ = false;
  SliceHeader first_;  // the first file read: the series' identity and geometry
  Frame frame_;
  double step_ = 0;
  int direction_ = 0;  // how InstanceNumber runs along the normal (+1, -1; 0 = unknown)
  bool numbered_ = true;  // every slice added had an InstanceNumber
  ValuePlan plan_;
  std::vector<SliceHeader> held_;  // complete, not yet handed out, by position
  std::vector<SliceHeader> sent_;  // handed out, in order
  std::string problem_;
  std::vector<uint8_t> buffer_;
};

}  // namespace

std::unique_ptr<internal::Growing> internal::MakeGrowingDicom(const std::string& dir,
                                                              double stable_s,
                                                              const std::string& done_file) {
  return std::make_unique<GrowingDicom>(dir, stable_s, done_file);
}

absl::StatusOr<std::unique_ptr<SliceSource>> OpenDicomSeries(
    const std::string& dir, const std::vector<std::string>& files) {
  std::vector<SliceHeader> slices;
  slices.reserve(files.size());
  for (const std::string& f : files) {
    std::error_code ec;
    if (std::filesystem::file_size(f, ec) == 0 && !ec) continue;  // a marker, not a slice
    absl::StatusOr<std::optional<SliceHeader>> h = ReadHeader(f);
    if (!h.ok()) return h.status();
    if (h->has_value()) slices.push_back(std::move(**h));
  }
  if (slices.size() < 2) {
    return absl::InvalidArgumentError(
        absl::StrCat(dir, ": a DICOM series needs at least 2 slices, found ", slices.size(),
                     files.empty() ? " (empty folder)" : ""));
  }
  // One series.
  std::map<std::string, std::vector<const SliceHeader*>> by_series;
  for (const SliceHeader& h : slices) by_series[h.series_uid].push_back(&h);
  if (by_series.size() > 1) {
    std::vector<std::string> parts;
    for (const auto& [uid, members] : by_series) {
      parts.push_back(absl::StrCat("'", uid, "' (", members.size(), " files, e.g. ",
                                   Base(members.front()->path), ")"));
    }
    return absl::InvalidArgumentError(
        absl::StrCat(dir, ": the folder holds ", by_series.size(), " DICOM series: ",
                     absl::StrJoin(parts, ", "), "; put each series in its own folder"));
  }
  // One geometry and one pixel type; ordered along the normal, evenly spaced, in line.
  const SliceHeader first = slices.front();
  absl::StatusOr<Frame> frame = FrameOf(first);
  if (!frame.ok()) return frame.status();
  for (SliceHeader& h : slices) {
    if (absl::Status st = CheckMatches(dir, first, h); !st.ok()) return st;
    h.along = Dot(h.position, frame->normal);
  }
  std::sort(slices.begin(), slices.end(),
            [](const SliceHeader& a, const SliceHeader& b) { return a.along < b.along; });
  const int64_t nz = static_cast<int64_t>(slices.size());
  const double in_plane = std::min(first.row_spacing, first.col_spacing);
  for (int64_t k = 0; k + 1 < nz; ++k) {  // duplicates first: they would look like gaps
    const double d = slices[k + 1].along - slices[k].along;
    if (absl::Status st = CheckStep(dir, slices[k], slices[k + 1], d, in_plane); !st.ok()) {
      return st;
    }
  }
  const double median = MedianStep(slices);
  for (int64_t k = 0; k + 1 < nz; ++k) {
    if (absl::Status st = CheckStep(dir, slices[k], slices[k + 1], median, in_plane); !st.ok()) {
      return st;
    }
  }
  for (const SliceHeader& h : slices) {
    if (absl::Status st = CheckInLine(dir, slices.front(), h, frame->normal, in_plane); !st.ok()) {
      return st;
    }
  }
  const ValuePlan plan = PlanValues(slices.data(), slices.data() + slices.size());
  const double step = RoundStep((slices.back().along - slices.front().along) / static_cast<double>(nz - 1));
  VolumeInfo info = MakeInfo(slices.front(), *frame, nz, step, plan);
  absl::StrAppend(&info.description, ", ", nz, " files");
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("DICOM series in ", dir, ": ", st.message()));
  }
  return std::unique_ptr<SliceSource>(new DicomSliceSource(std::move(slices), std::move(info), plan));
}

absl::StatusOr<DicomSyntax> ParseDicomSyntax(const std::string& name) {
  static const std::pair<const char*, DicomSyntax> kNames[] = {
      {"explicit", DicomSyntax::kExplicitLittle}, {"implicit", DicomSyntax::kImplicitLittle},
      {"jpeg-lossless", DicomSyntax::kJpegLossless}, {"jpeg-ls", DicomSyntax::kJpegLs},
      {"jpeg2000", DicomSyntax::kJpeg2000},          {"rle", DicomSyntax::kRle}};
  for (const auto& [n, s] : kNames) {
    if (name == n) return s;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("unknown DICOM transfer syntax '", name,
                   "' (use explicit, implicit, jpeg-lossless, jpeg-ls, jpeg2000 or rle)"));
}

absl::StatusOr<DicomSliceWriter> DicomSliceWriter::Create(const VolumeInfo& info,
                                                          const DicomWriteOptions& opts) {
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) return st;
  if (info.nx > 0xffff || info.ny > 0xffff) {
    return absl::InvalidArgumentError("DICOM slices are at most 65535 x 65535 pixels");
  }
  DicomSliceWriter w;
  w.info_ = info;
  w.opts_ = opts;
  absl::StatusOr<const dicom::Codec*> codec = dicom::LoadCodec();
  if (!codec.ok()) return codec.status();
  if (w.opts_.series_uid.empty()) w.opts_.series_uid = (*codec)->generate_uid();
  if (w.opts_.study_uid.empty()) w.opts_.study_uid = (*codec)->generate_uid();
  if (info.dtype == DType::kFloat32) {
    if (!(std::isfinite(opts.float_min) && std::isfinite(opts.float_max) &&
          opts.float_max >= opts.float_min)) {
      return absl::InvalidArgumentError("DICOM writer: float32 volume needs a finite value range");
    }
    // int16 codes -32767..32767 span [float_min, float_max].
    const double span = std::max(double{opts.float_max} - opts.float_min, 1e-30);
    w.opts_.rescale_slope = span / 65534.0;
    w.opts_.rescale_intercept = opts.float_min + 32767.0 * w.opts_.rescale_slope;
  }
  return w;
}

absl::Status DicomSliceWriter::Write(const std::string& path, int64_t z,
                                     const std::vector<uint8_t>& bytes) const {
  if (bytes.size() != info_.slice_bytes()) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": slice ", z, " has ", bytes.size(),
                                                   " bytes, expected ", info_.slice_bytes()));
  }
  absl::StatusOr<const dicom::Codec*> codec = dicom::LoadCodec();
  if (!codec.ok()) return codec.status();
  dicom::SliceImage image;
  image.path = path;
  image.pixels = bytes.data();
  image.nx = info_.nx;
  image.ny = info_.ny;
  std::vector<uint8_t> stored;
  switch (info_.dtype) {
    case DType::kUInt8:
      image.bits_allocated = 8;
      break;
    case DType::kUInt16:
      image.bits_allocated = 16;
      break;
    case DType::kInt16:
      image.bits_allocated = 16;
      image.is_signed = true;
      break;
    case DType::kFloat32: {
      image.bits_allocated = 16;
      image.is_signed = true;
      const size_t n = static_cast<size_t>(info_.slice_voxels());
      stored.resize(n * 2);
      for (size_t i = 0; i < n; ++i) {
        float v;
        std::memcpy(&v, bytes.data() + 4 * i, 4);
        const double code = std::clamp(
            std::round((double{v} - opts_.rescale_intercept) / opts_.rescale_slope), -32767.0,
            32767.0);
        const int16_t c = static_cast<int16_t>(std::isfinite(code) ? code : 0.0);
        std::memcpy(stored.data() + 2 * i, &c, 2);
      }
      image.pixels = stored.data();
      break;
    }
  }
  image.bits_stored = opts_.bits_stored;
  image.spacing = info_.spacing;
  const auto& d = info_.directions;
  const double kz = static_cast<double>(z) * info_.spacing[2];
  for (int i = 0; i < 3; ++i) image.origin[i] = info_.origin[i] + kz * d[2][i];
  image.cosines = {d[0][0], d[0][1], d[0][2], d[1][0], d[1][1], d[1][2]};
  image.slope = opts_.rescale_slope;
  image.intercept = opts_.rescale_intercept;
  image.syntax = static_cast<int>(opts_.syntax);
  image.ct = opts_.modality == "CT";
  image.modality = opts_.modality;
  image.series_description = opts_.series_description;
  image.study_uid = opts_.study_uid;
  image.series_uid = opts_.series_uid;
  image.instance = z + 1;
  image.slice_thickness = FormatDouble(info_.spacing[2]);
  return (*codec)->write_slice(image);
}

absl::Status WriteDicomSeries(const std::string& dir, const VolumeInfo& info,
                              const SliceFn& slice_fn, const DicomWriteOptions& opts) {
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) return st;
  if (info.nz < 2) return absl::InvalidArgumentError("WriteDicomSeries: nz must be known");
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat(dir, ": cannot create: ", ec.message()));
  DicomWriteOptions o = opts;
  std::vector<uint8_t> bytes;
  if (info.dtype == DType::kFloat32) {  // a first pass finds the range to quantize
    float lo = std::numeric_limits<float>::infinity(), hi = -lo;
    for (int64_t z = 0; z < info.nz; ++z) {
      if (absl::Status st = internal::FetchSlice(dir, info, slice_fn, z, &bytes); !st.ok()) {
        return st;
      }
      for (size_t i = 0; i < bytes.size() / 4; ++i) {
        float v;
        std::memcpy(&v, bytes.data() + 4 * i, 4);
        if (std::isfinite(v)) lo = std::min(lo, v), hi = std::max(hi, v);
      }
    }
    o.float_min = std::isfinite(lo) ? lo : 0.0f;
    o.float_max = std::isfinite(hi) ? hi : 0.0f;
  }
  absl::StatusOr<DicomSliceWriter> writer = DicomSliceWriter::Create(info, o);
  if (!writer.ok()) return writer.status();
  for (int64_t z = 0; z < info.nz; ++z) {
    if (absl::Status st = internal::FetchSlice(dir, info, slice_fn, z, &bytes); !st.ok()) return st;
    char name[32];
    std::snprintf(name, sizeof(name), "IM%05lld.dcm", static_cast<long long>(z + 1));
    if (absl::Status st = writer->Write((std::filesystem::path(dir) / name).string(), z, bytes);
        !st.ok()) {
      return st;
    }
  }
  return absl::OkStatus();
}

}  // namespace tandem
