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
//   - DICOM: a file whose size is stable and whose header and pixel data length are whole
//     (a file under a temporary name, see tandem/series.h, is not looked at before it is
//     renamed into place); files that are not DICOM or no image slice (a dose report) are
//     skipped with a note. Whole slices are grouped by series. A localizer (ImageType
//     LOCALIZER) is set aside with a note; the series followed is `dicom_series`, else the
//     first slice stack whose first slice can go (two at once are told apart as in a
//     finished folder, tandem/series.h: a scout beside the stack is set aside, two stacks
//     are an error pointing to --series); every other series is set aside with a note.
//     Slices are handed out in order of position along the way the series grows, each held
//     back until the slice one step before it has been handed out (the series grows one
//     way, in bursts, its files in any order within a burst). It grows along its normal
//     (feet to head for the usual axial slices) or against it (head to feet, as many CT
//     protocols acquire): the first slice, the lowest or the highest held, goes when it
//     and the next two lie one usual step apart (the smallest gap between held neighbours,
//     which becomes the z step) and
//       (a) their InstanceNumbers are 1, 2, 3 from that end; or
//       (b) 8 files of the series have appeared in later looks at the folder than it did,
//           more than after the slice at the other end (a receiver reorders files within
//           a burst, not across 8 files: the series grows away from the end that came
//           first); or
//       (c) nothing has appeared or grown in the folder for 1 s, or for three of the
//           writer's usual intervals between files when it writes slower (the burst is
//           over), unless InstanceNumbers running with the positions say a slice between
//           the three is missing: from the end those numbers start at (1 at the top: head
//           to feet), the lowest without them.
//     A series followed head to feet has its grid's z axis against the normal, its origin
//     at the first slice acquired (the highest): a mirrored frame, so the triangles' winding
//     is reversed and normals still point out. Its mesh is the finished folder's surface
//     (read from the lowest slice up): without simplification the same triangles, their
//     positions equal up to float rounding; simplified, the same surface swept the other
//     way (each within E0 of it).
//     InstanceNumbers are a hint, never a gate: where they contradict the positions
//     (repeated, running the other way, not one apart where the positions are one step
//     apart) one note says so and positions alone order the series; absent numbers are fine.
//     Errors: two slices at one position (at once, naming both files); a file that arrives
//     behind a slice already handed out (a writer that reorders files across more than a
//     burst, or more than a second apart; or a series that turns round); when the scan ends, a gap still open (naming the
//     position of the missing slice), a DICOM file that never became a whole slice (naming
//     it), or only localizers and scouts (naming them);
//   - Zarr: the planes of chunk rows whose every chunk file exists (CountCompleteZarrPlanes).
#ifndef TANDEM_FOLLOW_H_
#define TANDEM_FOLLOW_H_

#include <functional>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "tandem/volume.h"

namespace tandem::io {

struct FollowOptions {
  int64_t expect_slices = 0;  // 0 = unknown
  double settle_s = 10;       // end after this long without a new slice
  std::string done_file;      // "" = none
  double stable_s = 0.2;      // a file's size must hold this long before it is read
  double poll_s = 0.05;       // how often the folder is looked at
  // Called (from ReadSlice) with slices seen on disk so far and handed out so far.
  std::function<void(int64_t seen, int64_t sent)> progress;
  // A folder holding several DICOM series: follow the one with this SeriesInstanceUID (""
  // = the slice stack that grows; see below). Refused for TIFF folders and Zarr stores.
  std::string dicom_series;
  // Receives one line for each thing set aside or worth knowing (a series ignored, a file
  // that is not DICOM, InstanceNumbers that contradict the positions); unset = dropped.
  std::function<void(const std::string&)> note;
};

// Waits (up to settle_s) for the first slice(s) to learn the geometry, then returns the
// source. `path` is a folder or a Zarr store (with an optional "#SELECTOR").
absl::StatusOr<std::unique_ptr<SliceSource>> FollowVolume(const std::string& path,
                                                          const FollowOptions& opts);

}  // namespace tandem::io

#endif  // TANDEM_FOLLOW_H_
