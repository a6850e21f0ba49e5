// `tandem extract --neuroglancer DIR`: surfaces and their coarser sweeps as a Neuroglancer
// precomputed segmentation (tandem/io/neuroglancer.h), Draco fragments from the codec.
#ifndef TANDEM_APPS_TANDEM_NEUROGLANCER_EXPORT_H_
#define TANDEM_APPS_TANDEM_NEUROGLANCER_EXPORT_H_

#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"
#include "tandem/volume.h"

namespace tandem::app {

// Nanometres per unit of the grid's spacing when --neuroglancer-nm is not given: patient
// frames (DICOM LPS, NIfTI RAS) are millimetres; any other grid is taken as nanometres
// (electron microscopy's usual unit).
double DefaultNmPerUnit(const VolumeInfo& info);

// The octree's shape: finest node edge and skirt depth in voxels (negative: the default,
// one voxel; 0: none).
struct NeuroglancerOctree {
  int chunk_voxels = 32;
  double skirt_voxels = -1;
};

// One segment per (id, levels finest first); every segment has the same number of levels.
// The iso-surfaces come here as ids 1..N, the labels through WriteNeuroglancerLabels.
absl::Status WriteNeuroglancerExport(
    const std::string& dir, const VolumeInfo& info,
    std::vector<std::pair<LabelId, std::vector<IndexedMesh>>> segments, double nm_per_unit,
    int compression_level, const NeuroglancerOctree& octree = {});

// The label mode's export: `levels[k]` is each label's surface (SplitByLabel, background
// left out) from the sweep at E0 * 2^k, finest first; the meshes are moved into the export,
// so that the caller's finest surfaces are not held a second time.
absl::Status WriteNeuroglancerLabels(
    const std::string& dir, const VolumeInfo& info,
    std::vector<std::vector<std::pair<LabelId, IndexedMesh>>> levels, double nm_per_unit,
    int compression_level, const NeuroglancerOctree& octree = {});

}  // namespace tandem::app

#endif  // TANDEM_APPS_TANDEM_NEUROGLANCER_EXPORT_H_
