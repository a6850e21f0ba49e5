// DICOM series (one instance per z-slice): reader and writer. The rules are in
// tandem/series.h; GDCM, which reads and writes the files, is behind dicom_codec.h (a module
// loaded on first use). Headers are read up to the pixel data for every file at open time (to
// order and check the series); pixel data is decoded one file per ReadSlice.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <optional>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "dicom_codec.h"
#include "dicom_worker_client.h"
#include "follow_internal.h"
#include "tandem/series.h"
#include "volume_io_internal.h"

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
using Note = std::function<void(const std::string&)>;

void Tell(const Note& note, const std::string& line) {
  if (note) note(line);
}

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

double InPlane(const SliceHeader& first) { return std::min(first.row_spacing, first.col_spacing); }

// One series of a folder, as the choice between series sees it.
struct SeriesSummary {
  std::string uid, description, example;  // example: one of its files
  int64_t images = 0;
  bool localizer = false;  // ImageType LOCALIZER
  bool parallel = true;    // every image's normal is parallel to the first one's
  Vec normal{0, 0, 0};
};

Vec NormalOf(const SliceHeader& h) {
  absl::StatusOr<Frame> frame = FrameOf(h);
  return frame.ok() ? frame->normal : Vec{0, 0, 0};
}

bool Parallel(const Vec& a, const Vec& b) { return std::abs(Dot(a, b)) > 0.999; }

// "UID 'description' (N images, e.g. FILE)"; images 0 = not counted yet.
std::string Named(const std::string& uid, const std::string& description, int64_t images,
                  const std::string& example = "") {
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

// How the first slice of a followed series is known to be the first (tandem/follow.h):
// a receiver stores files out of position order only within this many of each other...
constexpr int64_t kReorderWindow = 8;
// ...and a burst is over after this long with nothing new in the folder (or three of the
// writer's usual intervals between files, when it writes slower).
constexpr double kQuietSeconds = 1.0;

using Clock = std::chrono::steady_clock;
double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

// A series still arriving (follow mode): whole files are grouped by series, the one to follow
// is chosen (tandem/follow.h), and its slices are ordered by position and handed out from the
// lowest, each once the slice one step below it has gone.
class GrowingDicom final : public internal::Growing {
 public:
  GrowingDicom(std::string dir, double stable_s, std::string done_file, std::string want, Note note)
      : dir_(std::move(dir)),
        stable_s_(stable_s),
        done_file_(std::move(done_file)),
        want_(std::move(want)),
        note_(std::move(note)),
        last_change_(Clock::now()) {}

  absl::StatusOr<int64_t> Complete(bool* changed) override {
    if (absl::Status st = Scan(changed); !st.ok()) return st;
    return Release(/*final=*/false);
  }

  absl::StatusOr<int64_t> Final() override {
    bool changed = false;
    if (absl::Status st = Scan(&changed, /*final=*/true); !st.ok()) return st;
    for (const auto& [path, seen] : seen_) {
      if (seen.state == State::kPending && !seen.problem.empty()) {
        return absl::DataLossError(absl::StrCat(
            seen.problem, " (the acquisition ended with this file still not whole)"));
      }
    }
    return Release(/*final=*/true);
  }

  absl::StatusOr<VolumeInfo> Info() override {
    return MakeInfo(sent_.front(), followed_->frame, 0, step_, plan_);
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
  enum class State : uint8_t { kPending, kTaken, kSkipped };
  struct Seen {
    uint64_t size = 0;
    Clock::time_point since;
    int64_t order = 0;  // the look at the folder that first saw it (0, 1, ...)
    State state = State::kPending;
    std::string problem;  // why a pending file does not read as a slice (yet)
  };
  // One series' slices.
  struct Stack {
    SliceHeader first;
    // frame.normal points the way the series grows: ImageOrientationPatient's normal, or its
    // opposite once the series is followed head to feet (sweep -1); `along` is measured on it.
    Frame frame;
    int sweep = 1;
    std::vector<SliceHeader> held;  // by position, not handed out yet
    int64_t images = 0;
    int direction = 0;          // how InstanceNumber runs along the normal (+1, -1; 0 = unknown)
    bool numbers_agree = true;  // every slice is numbered, the numbers running with positions
    std::string contradiction;  // the first neighbours whose numbers contradict them
  };
  struct SetAside {
    std::string description, reason;
    int64_t images = 0;
  };

  // Reads the headers of files whose size has held for stable_s; a file that does not read
  // whole yet (still being written) is tried again when its size changes.
  // final: the acquisition is over, so every file is as whole as it will get (no waiting for
  // sizes to hold).
  absl::Status Scan(bool* changed, bool final = false) {
    absl::StatusOr<std::vector<std::string>> files = ListSliceFiles(dir_);
    if (absl::IsNotFound(files.status())) return absl::OkStatus();  // not created yet
    if (!files.ok()) return files.status();
    const auto now = Clock::now();
    const int64_t look = looks_++;
    bool arrived = false;
    for (const std::string& f : *files) {
      if (!done_file_.empty() && Base(f) == done_file_) continue;
      std::error_code ec;
      const uint64_t size = std::filesystem::file_size(f, ec);
      if (ec) continue;
      auto [it, inserted] = seen_.try_emplace(f);
      Seen& s = it->second;
      if (inserted) {
        s.order = look;
        arrived = true;
      }
      if (inserted || s.size != size) {
        if (s.state == State::kTaken) {
          return absl::FailedPreconditionError(
              absl::StrCat(f, ": rewritten after it was read as a slice of the followed series"));
        }
        s = Seen{size, now, s.order, State::kPending, ""};
        *changed = true;
        last_change_ = now;
      }
      if (s.state != State::kPending || !s.problem.empty() || size == 0 ||
          (!final && Seconds(now - s.since) < stable_s_)) {
        continue;
      }
      std::string skip;
      absl::StatusOr<std::optional<SliceHeader>> h = ReadSliceHeader(f, &skip);
      if (!h.ok()) {
        // Not whole (yet): a file still being written, or one that never will be, which the
        // end of the acquisition reports.
        s.problem = problem_ = std::string(h.status().message());
        continue;
      }
      s.state = State::kSkipped;
      if (!h->has_value()) {
        Tell(note_, skip);
        continue;
      }
      absl::StatusOr<bool> taken = Add(**h);
      if (!taken.ok()) return taken.status();
      if (*taken) s.state = State::kTaken;
    }
    if (arrived) {
      arrivals_.push_back(now);
      if (arrivals_.size() > 16) arrivals_.erase(arrivals_.begin());
    }
    return absl::OkStatus();
  }

  // How long the folder must stay still for a burst to be over (kQuietSeconds).
  double QuietNeeded() const {
    std::vector<double> gaps;
    for (size_t k = 1; k < arrivals_.size(); ++k) {
      gaps.push_back(Seconds(arrivals_[k] - arrivals_[k - 1]));
    }
    if (gaps.empty()) return kQuietSeconds;
    std::nth_element(gaps.begin(), gaps.begin() + gaps.size() / 2, gaps.end());
    return std::max(kQuietSeconds, 3 * gaps[gaps.size() / 2]);
  }

  // Sets the series of h aside, `images` of its files seen so far (counted, not kept from
  // now on), with one note; counted: the note gives the count.
  bool SetSeriesAside(const SliceHeader& h, int64_t images, const std::string& reason,
                      bool counted = false) {
    aside_[h.series_uid] = SetAside{h.description, reason, images};
    Tell(note_, IgnoredLine(Named(h.series_uid, h.description, counted ? images : 0), reason));
    return false;
  }

  // Why the series of h is not followed beside the followed stack.
  std::string BesideFollowed(const SliceHeader& h, int64_t images) const {
    if (!Parallel(NormalOf(h), followed_->frame.normal)) {
      return absl::StrCat("not parallel to the followed stack ", followed_uid_);
    }
    if (images > 0 && images <= 2) return "a scout (1 or 2 images beside the followed stack)";
    return absl::StrCat("another series beside the followed stack ", followed_uid_,
                        " (--series UID follows it instead)");
  }

  // Takes h into its series' stack (true) or sets it aside (false); an error for a slice
  // that cannot belong to the followed series.
  absl::StatusOr<bool> Add(SliceHeader h) {
    const std::string uid = h.series_uid;
    if (auto it = aside_.find(uid); it != aside_.end()) {
      ++it->second.images;
      return false;
    }
    if (!want_.empty() && uid != want_) {
      return SetSeriesAside(h, 1, "not the series --series picks");
    }
    if (want_.empty() && IsLocalizer(h)) {
      return SetSeriesAside(h, 1, "a localizer (ImageType LOCALIZER)");
    }
    if (followed_ != nullptr && uid != followed_uid_) {
      return SetSeriesAside(h, 1, BesideFollowed(h, 0));
    }
    auto [it, inserted] = stacks_.try_emplace(uid);
    Stack& s = it->second;
    const bool chosen = &s == followed_ || uid == want_;
    if (inserted) {
      absl::StatusOr<Frame> frame = FrameOf(h);
      if (!frame.ok()) return frame.status();
      s.frame = *frame;
      s.first = h;
    } else if (!SameOrientation(s.first, h) && !chosen) {
      const int64_t images = s.images + 1;
      Forget(it);
      return SetSeriesAside(h, images, "its images are not parallel (a multi-plane localizer?)",
                            /*counted=*/true);
    } else if (absl::Status st = CheckMatches(dir_, s.first, h); !st.ok()) {
      return st;
    }
    h.along = Dot(h.position, s.frame.normal);
    const double in_plane = InPlane(s.first);
    if (absl::Status st = CheckInLine(dir_, s.first, h, s.frame.normal, in_plane); !st.ok()) {
      return st;
    }
    auto by_along = [](const SliceHeader& a, double v) { return a.along < v; };
    const double eps = 1e-3 * in_plane;
    auto pos = std::lower_bound(s.held.begin(), s.held.end(), h.along - eps, by_along);
    if (pos != s.held.end() && pos->along <= h.along + eps) {
      return CheckStep(dir_, *pos, h, 0, in_plane, s.frame.normal);  // the same position
    }
    if (&s == followed_ && !sent_.empty()) {
      auto at = std::lower_bound(sent_.begin(), sent_.end(), h.along - eps, by_along);
      if (at != sent_.end() && at->along <= h.along + eps) {
        return CheckStep(dir_, *at, h, 0, in_plane, s.frame.normal);
      }
      if (h.along <= sent_.back().along) {
        return absl::FailedPreconditionError(absl::StrCat(
            "DICOM series in ", dir_, ": ", Base(h.path), " arrived at or ",
            s.sweep > 0 ? "below" : "above", " slices already meshed (",
            FormatDouble(s.sweep * h.along), " mm along the normal, the last sent is at ",
            FormatDouble(s.sweep * sent_.back().along), " mm; the series is followed ",
            s.sweep > 0 ? "feet to head, along" : "head to feet, against",
            " its normal); following needs a series that grows one way, its files out of "
            "order only within a burst (read a series acquired otherwise once it is finished, "
            "without --follow)"));
      }
    }
    const double step = &s == followed_ ? step_ : 0;
    const SliceHeader* below = pos != s.held.begin()               ? &*(pos - 1)
                               : &s == followed_ && !sent_.empty() ? &sent_.back()
                                                                   : nullptr;
    if (below != nullptr) CheckNumbers(s, *below, h, step);
    if (pos != s.held.end()) CheckNumbers(s, h, *pos, step);
    s.held.insert(pos, std::move(h));
    ++s.images;
    return true;
  }

  // A stack set aside before it was followed: its files are no longer the follower's.
  void Forget(std::map<std::string, Stack>::iterator it) {
    for (const SliceHeader& h : it->second.held) seen_[h.path].state = State::kSkipped;
    stacks_.erase(it);
  }

  // Records where the InstanceNumbers of position neighbours a < b contradict them: absent,
  // equal, running the other way than the series' so far, or not one apart where the
  // positions are one step apart (step 0: not known yet).
  static void CheckNumbers(Stack& s, const SliceHeader& a, const SliceHeader& b, double step) {
    if (!s.numbers_agree) return;
    if (a.instance < 0 || b.instance < 0) {
      s.numbers_agree = false;  // absent: nothing to say
      return;
    }
    const int64_t d = b.instance - a.instance;
    const int direction = d > 0 ? 1 : -1;
    const char* why = nullptr;
    if (d == 0) {
      why = "the same InstanceNumber";
    } else if (s.direction != 0 && direction != s.direction) {
      why = "InstanceNumbers running against the series'";
    } else if (step > 0 && std::abs(b.along - a.along - step) <= 0.1 * step && std::abs(d) != 1) {
      why = "neighbours whose InstanceNumbers are not one apart";
    }
    if (why == nullptr) {
      s.direction = direction;
      return;
    }
    s.numbers_agree = false;
    s.contradiction = absl::StrCat(why, ": ", Base(a.path), " (", a.instance, ", at ",
                                   FormatDouble(a.along), " mm) and ", Base(b.path), " (",
                                   b.instance, ", at ", FormatDouble(b.along), " mm)");
  }

  // Where a followed series starts: the z step, and the way it grows (+1: along the normal
  // of ImageOrientationPatient, feet to head for the usual axial slices; -1: against it).
  struct Start {
    double step = 0;
    int sweep = 1;
  };
  // The start when the slice at one end of those held of s can go now as its series' first,
  // else nothing. The rule (tandem/follow.h): it and the next two are one usual step apart
  // (the smallest gap between held neighbours), and (a) they are numbered 1, 2, 3 from that
  // end; or (b) kReorderWindow files of the series have appeared since it did (files seen in
  // the same look at the folder count as arriving together), more than since the slice at
  // the other end did (a receiver reorders files within a burst only: the series grows away
  // from the end that came first); or (c) nothing new has appeared in the folder for
  // QuietNeeded() and the InstanceNumbers, if they run with the positions, do not say a
  // slice is missing between the three: then from the end their numbers start at, or the
  // lowest without them. final: any two slices, from the lowest unless the way is known.
  std::optional<Start> FirstStep(const Stack& s, bool final) const {
    const std::vector<SliceHeader>& held = s.held;
    if (final) {
      if (held.size() < 2) return std::nullopt;
      return Start{RoundStep(MedianStep(held)), 1};
    }
    const size_t n = held.size();
    if (n < 3) return std::nullopt;
    double gap = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k + 1 < n; ++k) gap = std::min(gap, held[k + 1].along - held[k].along);
    // The k-th slice from an end (sweep +1: the lowest, -1: the highest).
    auto at = [&](int sweep, size_t k) -> const SliceHeader& {
      return sweep > 0 ? held[k] : held[n - 1 - k];
    };
    auto even = [&](int sweep) {
      for (size_t k = 0; k < 2; ++k) {
        if (std::abs(std::abs(at(sweep, k + 1).along - at(sweep, k).along) - gap) > 0.1 * gap) {
          return false;
        }
      }
      return true;
    };
    auto later = [&](int sweep) {  // files of the series seen after the end's slice was
      const int64_t first = seen_.at(at(sweep, 0).path).order;
      return std::count_if(held.begin(), held.end(),
                           [&](const SliceHeader& h) { return seen_.at(h.path).order > first; });
    };
    auto start = [&](int sweep) {
      return Start{RoundStep(std::abs(at(sweep, 2).along - at(sweep, 0).along) / 2), sweep};
    };
    auto numbered = [&](int sweep) {
      return at(sweep, 0).instance == 1 && at(sweep, 1).instance == 2 &&
             at(sweep, 2).instance == 3;
    };
    for (int sweep : {1, -1}) {
      if (even(sweep) && numbered(sweep)) return start(sweep);
    }
    const auto low = later(1), high = later(-1);
    if (even(1) && low >= kReorderWindow && low > high) return start(1);
    if (even(-1) && high >= kReorderWindow && high > low) return start(-1);
    // InstanceNumbers running with the positions start at one end: the first acquired.
    const int sweep = s.numbers_agree && s.direction < 0 ? -1 : 1;
    if (!even(sweep)) return std::nullopt;
    const int64_t n0 = at(sweep, 0).instance, n1 = at(sweep, 1).instance,
                  n2 = at(sweep, 2).instance;
    const bool numbers_gap = s.numbers_agree && (std::abs(n1 - n0) != 1 || std::abs(n2 - n1) != 1);
    if (!numbers_gap && Seconds(Clock::now() - last_change_) >= QuietNeeded()) return start(sweep);
    return std::nullopt;
  }

  // The stack grows against its normal: the normal turned around, positions measured on it.
  static void Reverse(Stack& s) {
    s.sweep = -s.sweep;
    for (double& c : s.frame.normal) c = -c;
    for (SliceHeader& h : s.held) h.along = -h.along;
    std::reverse(s.held.begin(), s.held.end());
    s.direction = -s.direction;
  }

  // Picks the series to follow: the stack whose first slice can go first; two at once are
  // told apart as in a finished folder (PickSeries). The other stacks are set aside.
  absl::Status Choose(bool final) {
    std::vector<SeriesSummary> ready;
    std::map<std::string, Start> starts;
    for (const auto& [uid, s] : stacks_) {
      if (std::optional<Start> start = FirstStep(s, final)) {
        ready.push_back(SeriesSummary{.uid = uid,
                                      .description = s.first.description,
                                      .example = s.first.path,
                                      .images = s.images,
                                      .normal = s.frame.normal});
        starts[uid] = *start;
      }
    }
    if (ready.empty()) {
      if (final && stacks_.empty() && !aside_.empty()) {
        std::vector<std::string> why;
        for (const auto& [uid, a] : aside_) {
          why.push_back(absl::StrCat(Named(uid, a.description, a.images), ": ", a.reason));
        }
        return absl::InvalidArgumentError(
            absl::StrCat(dir_, ": no slice stack to follow arrived, only ",
                         absl::StrJoin(why, "; "), " (--series UID follows one anyway)"));
      }
      return absl::OkStatus();
    }
    std::string uid = ready.front().uid;
    if (ready.size() > 1) {
      absl::StatusOr<std::string> picked = PickSeries(dir_, ready, "", nullptr);
      if (!picked.ok()) return picked.status();
      uid = *picked;
    }
    followed_uid_ = uid;
    followed_ = &stacks_[uid];
    step_ = starts[uid].step;
    if (starts[uid].sweep < 0) Reverse(*followed_);
    const std::vector<SliceHeader>& held = followed_->held;
    plan_ = PlanValues(held.data(), held.data() + 1);
    for (size_t k = 0; k + 1 < held.size(); ++k)
      CheckNumbers(*followed_, held[k], held[k + 1], step_);
    for (auto it = stacks_.begin(); it != stacks_.end();) {
      auto next = std::next(it);
      if (it->first != uid) {
        const SliceHeader first = it->second.first;
        const int64_t images = it->second.images;
        Forget(it);
        SetSeriesAside(first, images, BesideFollowed(first, images), /*counted=*/true);
      }
      it = next;
    }
    return absl::OkStatus();
  }

  // Hands out held slices while each is one step above the last sent (final: a gap still
  // open is an error).
  absl::StatusOr<int64_t> Release(bool final) {
    if (followed_ == nullptr) {
      if (absl::Status st = Choose(final); !st.ok()) return st;
      if (followed_ == nullptr) return 0;
    }
    Stack& s = *followed_;
    const double in_plane = InPlane(s.first);
    while (!s.held.empty()) {
      if (!sent_.empty()) {
        absl::Status st =
            CheckStep(dir_, sent_.back(), s.held.front(), step_, in_plane, s.frame.normal);
        if (!st.ok()) {
          if (final) return st;  // the gap never closed
          break;                 // wait for the slice in between
        }
      }
      sent_.push_back(std::move(s.held.front()));
      s.held.erase(s.held.begin());
    }
    if (!s.contradiction.empty() && !numbers_noted_) {
      numbers_noted_ = true;
      Tell(note_, absl::StrCat("DICOM series ", followed_uid_,
                               ": InstanceNumbers do not follow the slice positions (",
                               s.contradiction, "); ordering by position alone"));
    }
    return static_cast<int64_t>(sent_.size());
  }

  std::string dir_;
  double stable_s_;
  std::string done_file_;
  std::string want_;  // --series, "" = the stack that grows
  Note note_;
  std::map<std::string, Seen> seen_;
  int64_t looks_ = 0;
  Clock::time_point last_change_;          // a file appeared or changed size
  std::vector<Clock::time_point> arrivals_;  // the last looks that found new files
  std::map<std::string, Stack> stacks_;    // by series UID: candidates, then the followed one
  std::map<std::string, SetAside> aside_;  // by series UID
  Stack* followed_ = nullptr;
  std::string followed_uid_;
  double step_ = 0;
  ValuePlan plan_;
  std::vector<SliceHeader> sent_;  // handed out, in order
  bool numbers_noted_ = false;
  std::string problem_;
  std::vector<uint8_t> buffer_;
};

}  // namespace

std::unique_ptr<internal::Growing> internal::MakeGrowingDicom(
    const std::string& dir, double stable_s, const std::string& done_file,
    const std::string& series, std::function<void(const std::string&)> note) {
  return std::make_unique<GrowingDicom>(dir, stable_s, done_file, series, std::move(note));
}

absl::StatusOr<std::unique_ptr<SliceSource>> OpenDicomSeries(const std::string& dir,
                                                             const std::vector<std::string>& files,
                                                             const OpenOptions& opts) {
  std::vector<SliceHeader> slices;
  slices.reserve(files.size());
  int64_t skipped = 0;
  for (const std::string& f : files) {
    std::error_code ec;
    if (std::filesystem::file_size(f, ec) == 0 && !ec) continue;  // a marker, not a slice
    std::string skip;
    absl::StatusOr<std::optional<SliceHeader>> h = ReadSliceHeader(f, &skip);
    if (!h.ok()) return h.status();
    if (h->has_value()) {
      slices.push_back(std::move(**h));
    } else if (!skip.empty()) {
      Tell(opts.note, skip);
      ++skipped;
    }
  }
  // The series to read.
  std::map<std::string, SeriesSummary> by_series;
  for (const SliceHeader& h : slices) {
    auto [it, inserted] = by_series.try_emplace(h.series_uid);
    SeriesSummary& s = it->second;
    if (inserted) {
      s = SeriesSummary{.uid = h.series_uid,
                        .description = h.description,
                        .example = h.path,
                        .normal = NormalOf(h)};
    }
    ++s.images;
    s.localizer = s.localizer || IsLocalizer(h);
    s.parallel = s.parallel && Parallel(NormalOf(h), s.normal);
  }
  if (!by_series.empty()) {
    std::vector<SeriesSummary> all;
    for (auto& [uid, s] : by_series) all.push_back(std::move(s));
    absl::StatusOr<std::string> uid = PickSeries(dir, all, opts.dicom_series, opts.note);
    if (!uid.ok()) return uid.status();
    std::erase_if(slices, [&](const SliceHeader& h) { return h.series_uid != *uid; });
  }
  if (slices.size() < 2) {
    return absl::InvalidArgumentError(absl::StrCat(
        dir, ": a DICOM series needs at least 2 slices, found ", slices.size(),
        files.empty() ? " (empty folder)" : "",
        skipped > 0 ? absl::StrCat(" (", skipped, " files skipped: not DICOM images)") : ""));
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
    if (absl::Status st = CheckStep(dir, slices[k], slices[k + 1], d, in_plane, frame->normal);
        !st.ok()) {
      return st;
    }
  }
  const double median = MedianStep(slices);
  for (int64_t k = 0; k + 1 < nz; ++k) {
    if (absl::Status st = CheckStep(dir, slices[k], slices[k + 1], median, in_plane, frame->normal);
        !st.ok()) {
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
  // DICOM positions are LPS: a RAS grid is turned into it (nothing moves in the patient).
  absl::StatusOr<VolumeInfo> lps = info.space == Space::kRAS ? InFrame(info, Space::kLPS) : info;
  if (!lps.ok()) return lps.status();
  w.info_ = *std::move(lps);
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
  return Write(path, z, bytes, z + 1);
}

absl::Status DicomSliceWriter::Write(const std::string& path, int64_t z,
                                     const std::vector<uint8_t>& bytes, int64_t instance) const {
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
  image.instance = instance;  // kNoInstanceNumber (< 0): none written
  image.image_type = opts_.image_type;
  image.slice_thickness = FormatDouble(info_.spacing[2]);
  return (*codec)->write_slice(image);
}

VolumeInfo LocalizerGrid(const VolumeInfo& info, int image) {
  const int across = image == 0 ? 0 : 1, through = image == 0 ? 1 : 0;
  const auto& d = info.directions;
  const Vec down{-d[2][0], -d[2][1], -d[2][2]};
  VolumeInfo g = info;
  g.nx = image == 0 ? info.nx : info.ny;
  g.ny = info.nz;
  g.nz = 0;
  g.spacing = {info.spacing[across], info.spacing[2], info.spacing[through]};
  g.directions = {d[across], down, Cross(d[across], down)};
  const double up = static_cast<double>(info.nz - 1) * info.spacing[2];
  const double mid =
      static_cast<double>((image == 0 ? info.ny : info.nx) - 1) / 2 * info.spacing[through];
  for (int i = 0; i < 3; ++i) g.origin[i] = info.origin[i] + up * d[2][i] + mid * d[through][i];
  return g;
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
