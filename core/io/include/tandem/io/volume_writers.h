// Volume output, the mirror of OpenVolume: writes a volume slice by slice (never the whole
// volume in memory) in the format named by the file extension. Used by `tandem generate`
// (the .json form) and by the reader tests (all forms).
#ifndef TANDEM_VOLUME_WRITERS_H_
#define TANDEM_VOLUME_WRITERS_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "tandem/volume.h"

namespace tandem::io {

struct VolumeWriteOptions {
  // .nrrd / .nhdr: gzip encoding; .tif / .tiff: deflate compression. (.nii.gz is chosen by
  // the extension alone.)
  bool gzip = false;
  // Store voxels big-endian (.json, .nrrd, .nhdr, .nii, .nii.gz, .tif, .mha, .mhd); default
  // little.
  bool big_endian = false;
  // .tif / .tiff: 0 writes strips, otherwise square tiles of this size (a multiple of 16).
  int tiff_tile_size = 0;
  // .nii / .nii.gz: stored as-is in the header (voxels are written unchanged; readers then
  // deliver value * slope + inter). 0 means "no scaling" as in the NIfTI standard.
  float nifti_scl_slope = 0.0f;
  float nifti_scl_inter = 0.0f;
  // .json sidecar provenance fields (the shared sidecars carry the same keys).
  std::string source = "written by tandem";
  std::string license;
  std::string modality;
};

// Produces slice z (0 <= z < info.nz, called in order) as info.slice_bytes() bytes of voxels
// in host byte order into *bytes (the writer reuses the vector between calls).
using SliceFn = std::function<absl::Status(int64_t z, std::vector<uint8_t>* bytes)>;

// Writes a volume by extension:
//   .json         raw voxels in STEM.raw beside it + a JSON sidecar with the keys of the
//                 shared sidecars (dims, dtype, spacing, origin, byte_order, layout, source,
//                 license, suggested_isovalues, description, modality, value_range, raw_file,
//                 raw_bytes, sha256)
//   .nrrd         attached NRRD (opts.gzip selects gzip encoding)
//   .nhdr         detached NRRD header + STEM.raw (or STEM.raw.gz with opts.gzip)
//   .nii/.nii.gz  NIfTI-1 single file (qform and sform both carry spacing and origin)
//   .tif/.tiff    multi-page TIFF, one page per z-slice, ImageJ description for spacing/origin
//   .mha / .mhd   ITK MetaImage, uncompressed: header and data in one file, or header +
//                 STEM.raw (spacing, origin and directions)
//   .zarr         OME-Zarr v2 image, blosc-lz4, chunks 1x256x256 (WriteZarr in tandem/zarr.h
//                 for other versions, codecs and chunks)
// info.nz must be known. Errors name the file and the problem.
absl::Status WriteVolume(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                         const VolumeWriteOptions& opts = {});

}  // namespace tandem::io

#endif  // TANDEM_VOLUME_WRITERS_H_
