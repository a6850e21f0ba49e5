// Following an acquisition in progress: a SliceSource over a folder (DICOM series or numbered
// TIFFs, told apart by the first files to appear) or a Zarr array that is still being
// written. The folder or store need not exist yet. ReadSlice hands out each slice as soon
// as it is complete and every slice before it has been handed out, waiting (polling) for it
// otherwise; it returns OutOfRange when the acquisition is over:
//   - after `expect_slices` slices, when given;
//   - when a file named `done_file` appears in the folder (or the Zarr store), when given;
//   - when nothing new has appeared for `settle_s` seconds.
// info().nz is expect_slices, or 0 ("unknown") without it.
//
// When a slice is complete:
//   - TIFF: the next file in natural name order whose size has not changed for `stable_s`
//     and that libtiff reads as one whole page;
//   - DICOM: a file whose size is stable and whose header and pixel data length are whole;
//     slices are handed out in order of position along the normal, and one is held back
//     until the slice one step below it has been handed out (the series grows along the
//     normal, in bursts, in any order within a burst; the step is the median gap once three
//     slices have arrived). A file that arrives below a slice already handed out, or at its
//     position, is an error naming it, and so is a gap still open when the scan ends;
//   - Zarr: the planes of chunk rows whose every chunk file exists (CountCompleteZarrPlanes).
#ifndef TANDEM_FOLLOW_H_
#define TANDEM_FOLLOW_H_

#include <functional>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "tandem/volume.h"

namespace tandem {

struct FollowOptions {
  int64_t expect_slices = 0;  // 0 = unknown
  double settle_s = 10;       // end after this long without a new slice
  std::string done_file;      // "" = none
  double stable_s = 0.2;      // a file's size must hold this long before it is read
  double poll_s = 0.05;       // how often the folder is looked at
  // Called (from ReadSlice) with slices seen on disk so far and handed out so far.
  std::function<void(int64_t seen, int64_t sent)> progress;
};

// Waits (up to settle_s) for the first slice(s) to learn the geometry, then returns the
// source. `path` is a folder or a Zarr store (with an optional "#SELECTOR").
absl::StatusOr<std::unique_ptr<SliceSource>> FollowVolume(const std::string& path,
                                                          const FollowOptions& opts);

}  // namespace tandem

#endif  // TANDEM_FOLLOW_H_
