// The Neuroglancer export's glue: io's format with the codec's Draco fragments.
#include "neuroglancer_export.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <span>
#include <utility>

#include "absl/strings/str_cat.h"
#include "tandem/codec/neuroglancer_draco.h"
#include "tandem/io/neuroglancer.h"
#include "tandem/labels.h"

namespace tandem::app {

double DefaultNmPerUnit(const VolumeInfo& info) {
  return info.space == Space::kLPS || info.space == Space::kRAS ? 1e6 : 1.0;
}

namespace {

io::NeuroglancerOptions ExportOptions(const VolumeInfo& info, double nm_per_unit,
                                      int compression_level, const NeuroglancerOctree& octree) {
  io::NeuroglancerOptions options;
  options.nm_per_unit = nm_per_unit;
  options.chunk_voxels = octree.chunk_voxels;
  const double finest = std::min({info.spacing[0], info.spacing[1], info.spacing[2]});
  options.skirt = octree.skirt_voxels < 0 ? -1.0 : octree.skirt_voxels * finest;
  options.encode = [compression_level](const io::NeuroglancerFragment& f) {
    return codec::EncodeNeuroglancerFragment(f.positions, f.indices, compression_level);
  };
  return options;
}

}  // namespace

absl::Status WriteNeuroglancerExport(
    const std::string& dir, const VolumeInfo& info,
    std::vector<std::pair<LabelId, std::vector<IndexedMesh>>> segments, double nm_per_unit,
    int compression_level, const NeuroglancerOctree& octree) {
  std::vector<io::NeuroglancerSegment> list;
  list.reserve(segments.size());
  for (auto& [id, lods] : segments) list.push_back({id, std::move(lods)});
  return io::WriteNeuroglancer(dir, info, list,
                               ExportOptions(info, nm_per_unit, compression_level, octree));
}

absl::Status WriteNeuroglancerLabels(const std::string& dir, const VolumeInfo& info,
                                     const std::vector<const LabeledMesh*>& levels,
                                     LabelId background, double nm_per_unit, int compression_level,
                                     const NeuroglancerOctree& octree) {
  // Every label with a triangle at some level, and the least corner of their vertices.
  io::NeuroglancerSource source;
  source.lods = levels.size();
  for (const LabeledMesh* level : levels) {
    const size_t n = std::min(level->mesh.num_triangles(), level->patch.size());
    std::vector<uint8_t> used(level->pairs.size(), 0);
    for (size_t t = 0; t < n; ++t) {
      const uint32_t p = level->patch[t];
      if (p >= level->pairs.size()) continue;
      const LabelPair& pair = level->pairs[p];
      if (pair.inside == background && pair.outside == background) continue;
      used[p] = 1;
      for (int c = 0; c < 3; ++c) {
        const uint32_t v = level->mesh.indices[3 * t + c];
        if (v >= level->mesh.positions.size()) continue;
        for (int j = 0; j < 3; ++j) {
          source.lowest[j] = std::min(source.lowest[j], level->mesh.positions[v][j]);
        }
      }
    }
    for (size_t p = 0; p < used.size(); ++p) {
      if (!used[p]) continue;
      for (LabelId id : {level->pairs[p].inside, level->pairs[p].outside}) {
        if (id != background) source.ids.push_back(id);
      }
    }
  }
  std::sort(source.ids.begin(), source.ids.end());
  source.ids.erase(std::unique(source.ids.begin(), source.ids.end()), source.ids.end());

  io::NeuroglancerOptions options = ExportOptions(info, nm_per_unit, compression_level, octree);
  options.choose_sharding = false;
  options.sharding = io::ChooseSharding(source.ids.size());
  // Per level and pair, the shards of its two labels: a shard's surfaces are then one pass
  // over each complex, whatever the number of labels.
  std::vector<std::vector<std::array<uint64_t, 2>>> pair_shards(levels.size());
  for (size_t k = 0; k < levels.size(); ++k) {
    pair_shards[k].reserve(levels[k]->pairs.size());
    for (const LabelPair& pair : levels[k]->pairs) {
      pair_shards[k].push_back({io::LocateChunk(pair.inside, options.sharding).shard,
                                io::LocateChunk(pair.outside, options.sharding).shard});
    }
  }
  source.fetch = [&](std::span<const LabelId> ids, std::vector<io::NeuroglancerSegment>* out) {
    if (ids.empty()) return absl::OkStatus();
    const uint64_t shard = io::LocateChunk(ids[0], options.sharding).shard;
    for (LabelId id : ids) out->push_back({id, std::vector<IndexedMesh>(levels.size())});
    std::vector<uint8_t> kept;
    for (size_t k = 0; k < levels.size(); ++k) {
      kept.resize(pair_shards[k].size());
      for (size_t p = 0; p < kept.size(); ++p) {
        kept[p] = static_cast<uint8_t>((pair_shards[k][p][0] == shard ? 1 : 0) |
                                       (pair_shards[k][p][1] == shard ? 2 : 0));
      }
      // Both lists are in increasing id: a merge puts each surface at its segment.
      size_t at = 0;
      for (auto& [id, mesh] : SplitByLabel(*levels[k], background, kept)) {
        while (at < ids.size() && ids[at] < id) ++at;
        if (at == ids.size() || ids[at] != id) {
          return absl::InternalError(
              absl::StrCat("neuroglancer export: label ", id, " is not in its shard's list"));
        }
        (*out)[at].lods[k] = std::move(mesh);
      }
    }
    return absl::OkStatus();
  };
  return io::WriteNeuroglancerFrom(dir, info, source, options);
}

}  // namespace tandem::app
