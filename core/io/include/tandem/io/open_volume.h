// OpenVolume: the reader for a path, chosen by its extension or its folder's files.

#ifndef TANDEM_IO_OPEN_VOLUME_H_
#define TANDEM_IO_OPEN_VOLUME_H_

#include <functional>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "tandem/volume.h"

namespace tandem::io {

// Opens a volume by file name: *.json (raw + JSON sidecar), *.nrrd / *.nhdr, *.nii /
// *.nii.gz, *.tif / *.tiff (multi-page stack), *.mha / *.mhd (ITK MetaImage), a Zarr /
// OME-Zarr store (*.zarr, or a directory holding Zarr metadata; "X.zarr#SELECTOR" picks a
// level or an array, see tandem/io/zarr.h), or a folder of one file per slice: a DICOM series
// or numbered TIFFs (see tandem/io/series.h). Errors name the file and the problem.
absl::StatusOr<std::unique_ptr<SliceSource>> OpenVolume(const std::string& path);

// What OpenVolume may be told besides the path.
struct OpenOptions {
  // A folder holding several DICOM series: read the one with this SeriesInstanceUID (""
  // = the folder's one slice stack; see tandem/io/series.h). Refused for any other input.
  std::string dicom_series = "";
  // Receives one line for each thing set aside on the way (a localizer series, a file that
  // is not DICOM), for the user; unset = dropped.
  std::function<void(const std::string&)> note = nullptr;
};
absl::StatusOr<std::unique_ptr<SliceSource>> OpenVolume(const std::string& path,
                                                        const OpenOptions& opts);

}  // namespace tandem::io

#endif  // TANDEM_IO_OPEN_VOLUME_H_
