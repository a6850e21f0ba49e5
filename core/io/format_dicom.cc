// DICOM series (one instance per z-slice): the reader. The rules are in
// tandem/series.h; GDCM, which reads and writes the files, is behind dicom_codec.h (a module
// loaded on first use). Headers are read up to the pixel data for every file at open time (to
// order and check the series); pixel data is decoded one file per ReadSlice.
#include <algorithm>
#include <filesystem>
#include <map>
#include <optional>

#include "absl/strings/str_cat.h"
#include "dicom_series.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/series.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"

namespace tandem::io {
namespace {

using internal::dicom_series::CheckInLine;
using internal::dicom_series::CheckMatches;
using internal::dicom_series::CheckStep;
using internal::dicom_series::Dot;
using internal::dicom_series::Frame;
using internal::dicom_series::FrameOf;
using internal::dicom_series::IsLocalizer;
using internal::dicom_series::MakeInfo;
using internal::dicom_series::MedianStep;
using internal::dicom_series::NormalOf;
using internal::dicom_series::Parallel;
using internal::dicom_series::PickSeries;
using internal::dicom_series::PlanValues;
using internal::dicom_series::ReadPixels;
using internal::dicom_series::ReadSliceHeader;
using internal::dicom_series::RoundStep;
using internal::dicom_series::SeriesSummary;
using internal::dicom_series::SliceHeader;
using internal::dicom_series::Tell;
using internal::dicom_series::ValuePlan;

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

}  // namespace

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
    TANDEM_ASSIGN_OR_RETURN(std::optional<SliceHeader> h, ReadSliceHeader(f, &skip));
    if (h.has_value()) {
      slices.push_back(std::move(*h));
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
    TANDEM_ASSIGN_OR_RETURN(std::string uid, PickSeries(dir, all, opts.dicom_series, opts.note));
    std::erase_if(slices, [&](const SliceHeader& h) { return h.series_uid != uid; });
  }
  if (slices.size() < 2) {
    return absl::InvalidArgumentError(absl::StrCat(
        dir, ": a DICOM series needs at least 2 slices, found ", slices.size(),
        files.empty() ? " (empty folder)" : "",
        skipped > 0 ? absl::StrCat(" (", skipped, " files skipped: not DICOM images)") : ""));
  }
  // One geometry and one pixel type; ordered along the normal, evenly spaced, in line.
  const SliceHeader first = slices.front();
  TANDEM_ASSIGN_OR_RETURN(Frame frame, FrameOf(first));
  for (SliceHeader& h : slices) {
    TANDEM_RETURN_IF_ERROR(CheckMatches(dir, first, h));
    h.along = Dot(h.position, frame.normal);
  }
  std::sort(slices.begin(), slices.end(),
            [](const SliceHeader& a, const SliceHeader& b) { return a.along < b.along; });
  const int64_t nz = static_cast<int64_t>(slices.size());
  const double in_plane = std::min(first.row_spacing, first.col_spacing);
  for (int64_t k = 0; k + 1 < nz; ++k) {  // duplicates first: they would look like gaps
    const double d = slices[k + 1].along - slices[k].along;
    if (absl::Status st = CheckStep(dir, slices[k], slices[k + 1], d, in_plane, frame.normal);
        !st.ok()) {
      return st;
    }
  }
  const double median = MedianStep(slices);
  for (int64_t k = 0; k + 1 < nz; ++k) {
    if (absl::Status st = CheckStep(dir, slices[k], slices[k + 1], median, in_plane, frame.normal);
        !st.ok()) {
      return st;
    }
  }
  for (const SliceHeader& h : slices) {
    TANDEM_RETURN_IF_ERROR(CheckInLine(dir, slices.front(), h, frame.normal, in_plane));
  }
  const ValuePlan plan = PlanValues(slices.data(), slices.data() + slices.size());
  const double step = RoundStep((slices.back().along - slices.front().along) / static_cast<double>(nz - 1));
  VolumeInfo info = MakeInfo(slices.front(), frame, nz, step, plan);
  absl::StrAppend(&info.description, ", ", nz, " files");
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("DICOM series in ", dir, ": ", st.message()));
  }
  return std::unique_ptr<SliceSource>(new DicomSliceSource(std::move(slices), std::move(info), plan));
}

}  // namespace tandem::io
