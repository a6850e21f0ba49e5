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
//   - every regular, non-hidden, non-empty file must be a DICOM image of one series (DICOMDIR
//     files and empty marker files are skipped); a second SeriesInstanceUID, a file that is not DICOM, multi-frame or colour
//     images are errors that name the files;
//   - slices are ordered by ImagePositionPatient projected on the slice normal (the cross
//     product of the ImageOrientationPatient row and column directions), not by file name or
//     InstanceNumber; two slices at the same position, or a step between neighbours that
//     differs from the series' mean step by more than 10% (a missing slice), are errors that
//     name the two files; so are positions that drift sideways (gantry tilt);
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
#include "tandem/volume.h"
#include "tandem/volume_writers.h"

namespace tandem {

// The regular, non-hidden files of dir in natural order of their names (digit runs compare as
// numbers: "s2" < "s10"). NotFound / InvalidArgument errors name dir.
absl::StatusOr<std::vector<std::string>> ListSliceFiles(const std::string& dir);

// The names that end in .tif or .tiff (case-insensitive), in the given order.
std::vector<std::string> TiffNames(const std::vector<std::string>& files);

// Readers over an explicit list of files (full paths), e.g. what a follower has seen so far.
// The DICOM list is sorted by position; the TIFF list is read in the given order.
absl::StatusOr<std::unique_ptr<SliceSource>> OpenDicomSeries(const std::string& dir,
                                                             const std::vector<std::string>& files);
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
};

// Writes DICOM slices one at a time (a scanner simulator writes them in any order): slice z
// of info goes to `path` with its position origin + z * spacing_z * normal and
// InstanceNumber z + 1. info.nz need not be known.
class DicomSliceWriter {
 public:
  static absl::StatusOr<DicomSliceWriter> Create(const VolumeInfo& info,
                                                 const DicomWriteOptions& opts);
  absl::Status Write(const std::string& path, int64_t z, const std::vector<uint8_t>& bytes) const;

 private:
  DicomSliceWriter() = default;
  VolumeInfo info_;
  DicomWriteOptions opts_;
};

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

}  // namespace tandem

#endif  // TANDEM_SERIES_H_
