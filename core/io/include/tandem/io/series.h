// Folders that hold one file per z-slice, as instruments write them:
//   - a DICOM series (clinical CT / MR: one instance per slice, any file names, any order);
//   - numbered single-slice TIFFs (micro-CT / synchrotron reconstructions: slice_00000.tif,
//     slice_00001.tif, ...).
// OpenVolume(dir) reads both (a directory that is not a Zarr store): a folder holding files
// that end in .tif/.tiff is a TIFF sequence of those files (other files, such as logs or a
// done-marker, are ignored); otherwise it is read as a DICOM series. Both stream: one file
// is decoded per ReadSlice.
//
// DICOM (through GDCM, which decodes the transfer syntaxes its codecs support: implicit and
// explicit VR little endian, deflate, RLE, JPEG lossless and lossy, JPEG-LS, JPEG 2000):
//   - files: every regular, non-hidden, non-empty file whose name does not end in a
//     temporary suffix (below) is looked at. DICOMDIR files and empty marker files are
//     skipped; so are, with a note naming them, files that are not DICOM (no "DICM" after
//     the preamble and no DICOM element at the start) and DICOM objects that are no image
//     slice (no Rows/Columns or no ImagePositionPatient: a dose report, a secondary
//     capture). A DICOM file that cannot be read (truncated, corrupt), multi-frame or colour
//     images are errors that name the file;
//   - series: a folder may hold several (SeriesInstanceUID). OpenOptions::dicom_series
//     (--series UID) picks one, the others are set aside with a note each. Without it, a
//     localizer (ImageType holding LOCALIZER) is set aside with a note; when more than one
//     series is left, so is a scout beside the main stack (the series with the most
//     images): a series of 1 or 2 images, one whose images do not share one orientation,
//     or one not parallel to the main stack. One series left is read; none left (only a
//     localizer) is an error naming it; two or more slice stacks are refused with a
//     message listing each (UID, description, image count) that points to --series;
//   - slices are ordered by ImagePositionPatient projected on the slice normal (the cross
//     product of the ImageOrientationPatient row and column directions), not by file name or
//     InstanceNumber; two slices at the same position, or a step between neighbours that
//     differs from the series' median step by more than 10% (a missing slice: the message
//     also gives the ImagePositionPatient where one is missing), are errors that name the
//     two files; so are positions that drift sideways (gantry tilt);
//   - spacing: x and y from PixelSpacing (column, row), z from the positions (never
//     SliceThickness); origin: the first slice's ImagePositionPatient; directions: the row,
//     column and normal directions (so vertices come out in the patient LPS frame, mm);
//   - values: stored values times RescaleSlope plus RescaleIntercept (e.g. Hounsfield units).
//     Delivered as the stored type when no slice rescales, as int16 when the slope is 1 and
//     the intercept an integer that keeps BitsStored's range inside int16 (the usual CT
//     case), else as float32.
// TIFF sequence: files in natural order of their names ("s2.tif" before "s10.tif"), every page
// of the same size and type (8/16-bit unsigned, 16-bit signed, 32-bit float, one sample);
// spacing from an ImageJ description when the first file has one (as for TIFF stacks), else
// from XResolution/YResolution with a centimetre or inch ResolutionUnit (in mm), else 1.
#ifndef TANDEM_SERIES_H_
#define TANDEM_SERIES_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/io/open_volume.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"

namespace tandem::io {

// The regular, non-hidden files of dir in natural order of their names (digit runs compare as
// numbers: "s2" < "s10"), leaving out names that say the file is still being written under
// a temporary name (IsTemporaryName). NotFound / InvalidArgument errors name dir.
absl::StatusOr<std::vector<std::string>> ListSliceFiles(const std::string& dir);

// A name writers give a file before renaming it into place: ending (case-insensitive) in
// .part, .partial, .filepart, .crdownload, .download, .tmp, .temp, .swp or ~.
bool IsTemporaryName(const std::string& name);

// The names that end in .tif or .tiff (case-insensitive), in the given order.
std::vector<std::string> TiffNames(const std::vector<std::string>& files);

// Readers over an explicit list of files (full paths), e.g. what a follower has seen so far.
// The DICOM list is sorted by position; the TIFF list is read in the given order.
// opts: the series to read and where notes go (tandem/volume.h).
absl::StatusOr<std::unique_ptr<SliceSource>> OpenDicomSeries(const std::string& dir,
                                                             const std::vector<std::string>& files,
                                                             const OpenOptions& opts = {});
absl::StatusOr<std::unique_ptr<SliceSource>> OpenTiffSequence(
    const std::string& dir, const std::vector<std::string>& files);

enum class DicomSyntax : uint8_t {
  kExplicitLittle,  // 1.2.840.10008.1.2.1
  kImplicitLittle,  // 1.2.840.10008.1.2
  kJpegLossless,    // 1.2.840.10008.1.2.4.70 (process 14, selection value 1)
  kJpegLs,          // 1.2.840.10008.1.2.4.80 (lossless)
  kJpeg2000,        // 1.2.840.10008.1.2.4.90 (lossless)
  kRle,             // 1.2.840.10008.1.2.5
};
// "explicit", "implicit", "jpeg-lossless", "jpeg-ls", "jpeg2000", "rle".
absl::StatusOr<DicomSyntax> ParseDicomSyntax(const std::string& name);

struct DicomWriteOptions {
  DicomSyntax syntax = DicomSyntax::kExplicitLittle;
  std::string modality = "CT";  // CT is written as CT Image Storage, anything else as MR
  std::string series_description = "written by tandem";
  // Series and study UIDs: "" = generated (one per writer).
  std::string series_uid, study_uid;
  // uint8 / uint16 / int16 volumes are stored as they are, with these in RescaleSlope /
  // RescaleIntercept (readers deliver stored * slope + intercept). float32 volumes are
  // quantized to int16 over [float_min, float_max] (slope and intercept are then chosen):
  // lossy; WriteDicomSeries finds the range itself.
  double rescale_slope = 1.0, rescale_intercept = 0.0;
  float float_min = 0.0f, float_max = 0.0f;
  // BitsStored for integer volumes (0 = all allocated bits); CT scanners write 12.
  int bits_stored = 0;
  // ImageType, values separated by a backslash (ORIGINAL\PRIMARY\LOCALIZER for a scout);
  // "" = GDCM's default.
  std::string image_type;
};

// Writes DICOM slices one at a time (a scanner simulator writes them in any order): slice z
// of info goes to `path` with its position origin + z * spacing_z * normal and
// InstanceNumber z + 1 (a RAS grid turned into DICOM's LPS first). info.nz need not be known.
class DicomSliceWriter {
 public:
  static absl::StatusOr<DicomSliceWriter> Create(const VolumeInfo& info,
                                                 const DicomWriteOptions& opts);
  absl::Status Write(const std::string& path, int64_t z, const std::vector<uint8_t>& bytes) const;
  // The same with InstanceNumber `instance` (kNoInstanceNumber: none), as anonymizers and
  // reconstructions number slices.
  absl::Status Write(const std::string& path, int64_t z, const std::vector<uint8_t>& bytes,
                     int64_t instance) const;
  static constexpr int64_t kNoInstanceNumber = -1;

 private:
  DicomSliceWriter() = default;
  VolumeInfo info_;
  DicomWriteOptions opts_;
};

// The grid of a localizer image across info's volume, as a CT takes one before its stack:
// image 0 a front view (columns along x, rows down z, head up), 1 a side view (columns along
// y), through the middle of the other axis; nz = 0.
VolumeInfo LocalizerGrid(const VolumeInfo& info, int image);

// Writes the whole volume into dir (created if missing) as IM00001.dcm, IM00002.dcm, ...
absl::Status WriteDicomSeries(const std::string& dir, const VolumeInfo& info,
                              const SliceFn& slice_fn, const DicomWriteOptions& opts = {});

// Writes one page (slice z) as a single-page TIFF with an ImageJ description carrying the
// spacing and origin, as WriteVolume does for stacks.
absl::Status WriteTiffSlice(const std::string& path, const VolumeInfo& info, int64_t z,
                            const std::vector<uint8_t>& bytes);

// Writes the whole volume into dir (created if missing) as slice_00000.tif, ...
absl::Status WriteTiffSequence(const std::string& dir, const VolumeInfo& info,
                               const SliceFn& slice_fn);

}  // namespace tandem::io

#endif  // TANDEM_SERIES_H_
