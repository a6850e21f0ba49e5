// DICOM series rules shared by the reader (format_dicom.cc) and follow mode (dicom_follow.cc):
// slice headers, the series' frame and step checks, value plans, and the choice of series.
#ifndef TANDEM_IO_DICOM_SERIES_H_
#define TANDEM_IO_DICOM_SERIES_H_

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "dicom_codec.h"
#include "tandem/volume.h"

namespace tandem::io::internal::dicom_series {

using Vec = std::array<double, 3>;
using dicom::SliceHeader;
using Note = std::function<void(const std::string&)>;

Vec Cross(const Vec& a, const Vec& b);
double Dot(const Vec& a, const Vec& b);
// The file name of a path, for messages.
std::string Base(const std::string& path);
// Calls note(line) when a note is set.
void Tell(const Note& note, const std::string& line);

// One file's header for a series reader (tandem/series.h): a slice; nothing, with *skip
// saying why, for a file that is not DICOM or a DICOM object that is no image slice (*skip
// empty: a DICOMDIR); or an error naming a DICOM file that does not read as a slice.
absl::StatusOr<std::optional<SliceHeader>> ReadSliceHeader(const std::string& path,
                                                           std::string* skip);
// ImageType says the image is a localizer (a scout, topogram, surview).
bool IsLocalizer(const SliceHeader& h);

// The series' frame from its first slice: unit row and column directions and the normal.
struct Frame {
  Vec row, col, normal;
};
absl::StatusOr<Frame> FrameOf(const SliceHeader& first);

// Every slice of a series has the first one's size, orientation, pixel spacing and type.
bool SameOrientation(const SliceHeader& a, const SliceHeader& b);
absl::Status CheckMatches(const std::string& dir, const SliceHeader& first, const SliceHeader& h);
// Neighbours (sorted by `along`) a..b: not at one position, not a step 10% off `step` (a
// gap names where the missing slice would be: `step` above a along `normal`).
absl::Status CheckStep(const std::string& dir, const SliceHeader& a, const SliceHeader& b,
                       double step, double in_plane, const Vec& normal);
// h lies on the line through `first` along `normal` (no gantry tilt).
absl::Status CheckInLine(const std::string& dir, const SliceHeader& first, const SliceHeader& h,
                         const Vec& normal, double in_plane);
// The z step, rounded to 1e-6 mm so that a series read finished and one followed while it
// was written (whose step is known from fewer slices) get the same grid.
double RoundStep(double step);

// How values are delivered: the stored type, int16 (slope 1, one integer intercept whose
// shift keeps BitsStored's range inside int16: the usual CT), or float32.
struct ValuePlan {
  DType stored = DType::kUInt8;
  DType out = DType::kUInt8;
  bool rescale = false;
};
ValuePlan PlanValues(const SliceHeader* begin, const SliceHeader* end);
VolumeInfo MakeInfo(const SliceHeader& first, const Frame& frame, int64_t nz, double step,
                    const ValuePlan& plan);
// Decodes one slice's pixels (through `buffer`) into `bytes` as info.dtype.
absl::Status ReadPixels(const SliceHeader& h, const VolumeInfo& info, const ValuePlan& plan,
                        std::vector<uint8_t>* buffer, std::vector<uint8_t>* bytes);

// The median distance between neighbours of slices sorted by `along`.
double MedianStep(const std::vector<SliceHeader>& sorted);
// The finer of the two pixel spacings.
double InPlane(const SliceHeader& first);

// One series of a folder, as the choice between series sees it.
struct SeriesSummary {
  std::string uid, description, example;  // example: one of its files
  int64_t images = 0;
  bool localizer = false;  // ImageType LOCALIZER
  bool parallel = true;    // every image's normal is parallel to the first one's
  Vec normal{0, 0, 0};
};
Vec NormalOf(const SliceHeader& h);
bool Parallel(const Vec& a, const Vec& b);
// "UID 'description' (N images, e.g. FILE)"; images 0 = not counted yet.
std::string Named(const std::string& uid, const std::string& description, int64_t images,
                  const std::string& example = "");
std::string Named(const SeriesSummary& s);
std::string IgnoredLine(const std::string& name, const std::string& reason);
// The series of a folder to read (tandem/series.h states the rule); one note per series
// set aside.
absl::StatusOr<std::string> PickSeries(const std::string& dir,
                                       const std::vector<SeriesSummary>& all,
                                       const std::string& want, const Note& note);

}  // namespace tandem::io::internal::dicom_series

#endif  // TANDEM_IO_DICOM_SERIES_H_
