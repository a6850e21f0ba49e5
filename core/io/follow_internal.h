// Follow mode internals (not part of the public API): what each kind of growing input must
// answer for FollowVolume's polling loop (tandem/follow.h).
#ifndef TANDEM_SRC_FOLLOW_INTERNAL_H_
#define TANDEM_SRC_FOLLOW_INTERNAL_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/volume.h"

namespace tandem::io::internal {

class Growing {
 public:
  virtual ~Growing() = default;
  // Looks at the disk again; returns how many leading slices can be handed out now (never
  // fewer than before) and sets *changed if anything new was seen (a file or a size change).
  virtual absl::StatusOr<int64_t> Complete(bool* changed) = 0;
  // The acquisition is over: how many slices there are in all (slices held back so far may
  // be released now), or an error (a gap, a file that never became whole).
  virtual absl::StatusOr<int64_t> Final() {
    bool changed = false;
    return Complete(&changed);
  }
  // Geometry, once Complete() has returned >= 1 (nz is set by the caller).
  virtual absl::StatusOr<VolumeInfo> Info() = 0;
  // Reads slice k (k = 0, 1, ... in order, k < what Complete or Final returned).
  virtual absl::Status Read(int64_t k, const VolumeInfo& info, std::vector<uint8_t>* bytes) = 0;
  // Where a done-file is looked for.
  virtual std::string Dir() const = 0;
  // Why nothing is complete yet, if known ("" otherwise).
  virtual std::string Problem() const { return ""; }
};

// A DICOM series growing in a folder (format_dicom.cc). done_file is ignored in listings;
// series and note as FollowOptions::dicom_series and ::note.
std::unique_ptr<Growing> MakeGrowingDicom(const std::string& dir, double stable_s,
                                          const std::string& done_file, const std::string& series,
                                          std::function<void(const std::string&)> note);

}  // namespace tandem::io::internal

#endif  // TANDEM_SRC_FOLLOW_INTERNAL_H_
