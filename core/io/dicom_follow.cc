// DICOM series in follow mode (tandem/follow.h): a series still arriving, its slices handed
// out in position order as the files come (internal::MakeGrowingDicom, follow_internal.h).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "dicom_series.h"
#include "follow_internal.h"
#include "tandem/io/series.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"

namespace tandem::io {
namespace {

using internal::FormatDouble;
using internal::dicom_series::Base;
using internal::dicom_series::CheckInLine;
using internal::dicom_series::CheckMatches;
using internal::dicom_series::CheckStep;
using internal::dicom_series::Dot;
using internal::dicom_series::Frame;
using internal::dicom_series::FrameOf;
using internal::dicom_series::IgnoredLine;
using internal::dicom_series::InPlane;
using internal::dicom_series::IsLocalizer;
using internal::dicom_series::MakeInfo;
using internal::dicom_series::MedianStep;
using internal::dicom_series::Named;
using internal::dicom_series::NormalOf;
using internal::dicom_series::Note;
using internal::dicom_series::Parallel;
using internal::dicom_series::PickSeries;
using internal::dicom_series::PlanValues;
using internal::dicom_series::ReadPixels;
using internal::dicom_series::ReadSliceHeader;
using internal::dicom_series::RoundStep;
using internal::dicom_series::SameOrientation;
using internal::dicom_series::SeriesSummary;
using internal::dicom_series::SliceHeader;
using internal::dicom_series::Tell;
using internal::dicom_series::ValuePlan;

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
    TANDEM_RETURN_IF_ERROR(Scan(changed));
    return Release(/*final=*/false);
  }

  absl::StatusOr<int64_t> Final() override {
    bool changed = false;
    TANDEM_RETURN_IF_ERROR(Scan(&changed, /*final=*/true));
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
      TANDEM_ASSIGN_OR_RETURN(bool taken, Add(**h));
      if (taken) s.state = State::kTaken;
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
      TANDEM_ASSIGN_OR_RETURN(Frame frame, FrameOf(h));
      s.frame = frame;
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
    TANDEM_RETURN_IF_ERROR(CheckInLine(dir_, s.first, h, s.frame.normal, in_plane));
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
      TANDEM_ASSIGN_OR_RETURN(std::string picked, PickSeries(dir_, ready, "", nullptr));
      uid = picked;
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
      TANDEM_RETURN_IF_ERROR(Choose(final));
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

}  // namespace tandem::io
