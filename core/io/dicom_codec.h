// The GDCM side of the DICOM reader and writer (format_dicom.cc), as a module loaded on first
// use: libtandem_dicom.so (dicom_codec.cc), found next to the executable or in
// ../lib/tandem/. GDCM loads its dictionaries when its libraries are loaded (gdcm::Global),
// so only a program that reads or writes DICOM should pay that (docs/decisions.md 41).
//
// The module holds only what touches GDCM (one header, one slice's pixels, one slice
// written, a UID) and no other tandem code; the reading program tandem-dicom-worker
// (dicom_worker.cc) is built from the same source and reads files for tandem_io
// (dicom_worker_client.h), which loads the module only to write: ordering, checking and converting
// a series stay in tandem_io. Both sides are built together, with the same compiler and libraries,
// so the table passes C++ types (std::string, absl::Status); kDicomCodecAbi guards against a stale
// module.
#ifndef TANDEM_IO_DICOM_CODEC_H_
#define TANDEM_IO_DICOM_CODEC_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace tandem::io::dicom {

// What the header of one file says (only what ordering and checking need).
struct SliceHeader {
  std::string path;
  std::string series_uid;
  std::array<double, 3> position{0, 0, 0};
  std::array<double, 6> orientation{1, 0, 0, 0, 1, 0};
  int64_t rows = 0, cols = 0;
  double row_spacing = 1, col_spacing = 1;  // PixelSpacing[0], [1]
  bool has_spacing = false;
  int bits_allocated = 0, bits_stored = 0, pixel_representation = 0, samples = 1;
  int64_t frames = 1;
  double slope = 1, intercept = 0;
  std::string modality, description;
  std::string image_type;  // ImageType (0008,0008) as stored: ORIGINAL\PRIMARY\LOCALIZER
  double along = 0;  // position projected on the normal (set by the reader, not the codec)
  int64_t instance = -1;  // InstanceNumber (0020,0013), -1 when absent
};

// One slice to write: stored pixels (uint8, uint16 or int16 as `bits_allocated` and
// `is_signed` say) and what the file says about them.
struct SliceImage {
  std::string path;
  const uint8_t* pixels = nullptr;
  int64_t nx = 0, ny = 0;
  int bits_allocated = 8;
  bool is_signed = false;
  int bits_stored = 0;  // 0 = all allocated bits
  std::array<double, 3> spacing{1, 1, 1};
  std::array<double, 3> origin{0, 0, 0};
  std::array<double, 6> cosines{1, 0, 0, 0, 1, 0};
  double slope = 1, intercept = 0;
  int syntax = 0;  // tandem::DicomSyntax
  bool ct = true;  // CT Image Storage, else MR
  std::string modality, series_description, study_uid, series_uid;
  int64_t instance = 1;         // < 0: no InstanceNumber written
  std::string image_type;       // "" = GDCM's default
  std::string slice_thickness;  // (0018,0050), as written
};

inline constexpr int kDicomCodecAbi = 2;

struct Codec {
  int abi;
  // A slice, nothing for a file to skip (DICOMDIR), or an error naming the file (a corrupt
  // file is DataLoss, also when GDCM fails one of its own assertions on it; a whole DICOM
  // object that is no image slice, without Rows/Columns or ImagePositionPatient, such as a
  // dose report, is FailedPrecondition). Both reads check the file's structure first
  // (dicom_scan.h).
  absl::StatusOr<std::optional<SliceHeader>> (*read_header)(const std::string& path);
  // The stored pixels of one slice, decoded into `out`: exactly `stored_bytes` of them.
  absl::Status (*read_pixels)(const std::string& path, size_t stored_bytes, uint8_t* out);
  absl::Status (*write_slice)(const SliceImage& image);
  std::string (*generate_uid)();
  // Called by the executable's __assert_fail (dicom_worker.cc): when a guarded GDCM call is
  // in progress on this thread, jumps back to it; otherwise returns.
  void (*on_failed_assertion)(const char* assertion);
};

// The module's only symbol.
extern "C" using CodecEntry = const Codec* ();
inline constexpr const char kCodecEntryName[] = "tandem_dicom_codec";
inline constexpr const char kModuleName[] = "libtandem_dicom.so";

// The codec, loaded once (dicom_codec_loader.cc). FailedPrecondition naming the places
// searched when the module is missing or does not load.
absl::StatusOr<const Codec*> LoadCodec();

}  // namespace tandem::io::dicom

#endif  // TANDEM_IO_DICOM_CODEC_H_
