// The Neuroglancer export's glue: io's format with the codec's Draco fragments.
#include "neuroglancer_export.h"

#include <algorithm>
#include <utility>

#include "tandem/codec/neuroglancer_draco.h"
#include "tandem/io/neuroglancer.h"

namespace tandem::app {

double DefaultNmPerUnit(const VolumeInfo& info) {
  return info.space == Space::kLPS || info.space == Space::kRAS ? 1e6 : 1.0;
}

absl::Status WriteNeuroglancerExport(
    const std::string& dir, const VolumeInfo& info,
    std::vector<std::pair<LabelId, std::vector<IndexedMesh>>> segments, double nm_per_unit,
    int compression_level, const NeuroglancerOctree& octree) {
  std::vector<io::NeuroglancerSegment> list;
  list.reserve(segments.size());
  for (auto& [id, lods] : segments) list.push_back({id, std::move(lods)});
  io::NeuroglancerOptions options;
  options.nm_per_unit = nm_per_unit;
  options.chunk_voxels = octree.chunk_voxels;
  const double finest = std::min({info.spacing[0], info.spacing[1], info.spacing[2]});
  options.skirt = octree.skirt_voxels < 0 ? -1.0 : octree.skirt_voxels * finest;
  options.encode = [compression_level](const io::NeuroglancerFragment& f) {
    return codec::EncodeNeuroglancerFragment(f.positions, f.indices, compression_level);
  };
  return io::WriteNeuroglancer(dir, info, list, options);
}

absl::Status WriteNeuroglancerLabels(
    const std::string& dir, const VolumeInfo& info,
    std::vector<std::vector<std::pair<LabelId, IndexedMesh>>> levels, double nm_per_unit,
    int compression_level, const NeuroglancerOctree& octree) {
  return WriteNeuroglancerExport(dir, info, io::JoinLevels(std::move(levels)), nm_per_unit,
                                 compression_level, octree);
}

}  // namespace tandem::app
