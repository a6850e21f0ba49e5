// SplitByLabel (tandem/labels.h): the interface complex cut into one surface per label; and
// the complex welded from a label session's sealed chunks.
#include "tandem/labels.h"

#include <algorithm>
#include <cstdint>
#include <tuple>

#include "sealer.h"
#include "tandem/types.h"

namespace tandem {

std::vector<LabelSide> LabelSides(std::span<const uint32_t> patch, std::span<const LabelPair> pairs,
                                  size_t num_triangles, LabelId background,
                                  std::span<const uint8_t> kept) {
  const size_t n = std::min(num_triangles, patch.size());
  std::vector<LabelSide> sides;
  sides.reserve(2 * n);
  for (size_t t = 0; t < n; ++t) {
    if (patch[t] >= pairs.size()) continue;
    const LabelPair& p = pairs[patch[t]];
    const auto id = static_cast<uint32_t>(t);
    const uint8_t sides_kept = kept.empty() ? 3 : patch[t] < kept.size() ? kept[patch[t]] : 0;
    if (p.inside != background && (sides_kept & 1)) sides.push_back({p.inside, id, false});
    if (p.outside != background && p.outside != p.inside && (sides_kept & 2)) {
      sides.push_back({p.outside, id, true});
    }
  }
  std::stable_sort(sides.begin(), sides.end(),
                   [](const LabelSide& a, const LabelSide& b) { return a.label < b.label; });
  return sides;
}

std::vector<std::pair<LabelId, IndexedMesh>> SplitByLabel(const LabeledMesh& mesh,
                                                          LabelId background,
                                                          std::span<const uint8_t> kept) {
  const std::vector<LabelSide> sides =
      LabelSides(mesh.patch, mesh.pairs, mesh.mesh.num_triangles(), background, kept);
  std::vector<std::pair<LabelId, IndexedMesh>> out;
  std::vector<uint32_t> map(mesh.mesh.num_vertices(), kInvalid);
  for (size_t begin = 0; begin < sides.size();) {
    size_t end = begin;
    while (end < sides.size() && sides[end].label == sides[begin].label) ++end;
    IndexedMesh m;
    m.indices.reserve(3 * (end - begin));
    for (size_t s = begin; s < end; ++s) {
      const uint32_t* tri = mesh.mesh.indices.data() + 3 * size_t{sides[s].tri};
      const uint32_t corners[3] = {tri[0], sides[s].reversed ? tri[2] : tri[1],
                                   sides[s].reversed ? tri[1] : tri[2]};
      for (uint32_t v : corners) {
        if (v >= map.size()) continue;
        if (map[v] == kInvalid) {
          map[v] = static_cast<uint32_t>(m.positions.size());
          m.positions.push_back(mesh.mesh.positions[v]);
        }
        m.indices.push_back(map[v]);
      }
      if (m.indices.size() % 3 != 0) m.indices.resize(m.indices.size() / 3 * 3);
    }
    for (size_t s = begin; s < end; ++s) {  // reset the map for the next label
      const uint32_t* tri = mesh.mesh.indices.data() + 3 * size_t{sides[s].tri};
      for (int k = 0; k < 3; ++k) {
        if (tri[k] < map.size()) map[tri[k]] = kInvalid;
      }
    }
    out.emplace_back(sides[begin].label, std::move(m));
    begin = end;
  }
  return out;
}

std::vector<std::pair<LabelId, SealedChunk>> SplitLabeledChunk(const SealedChunk& chunk,
                                                               LabelId background) {
  const std::vector<LabelSide> sides =
      LabelSides(chunk.patch, chunk.pairs, chunk.num_triangles(), background);
  std::vector<std::pair<LabelId, SealedChunk>> out;
  std::vector<uint32_t> local(chunk.positions.size(), kInvalid);
  for (size_t begin = 0; begin < sides.size();) {
    const LabelId label = sides[begin].label;
    size_t end = begin;
    while (end < sides.size() && sides[end].label == label) ++end;
    SealedChunk c;
    c.index = chunk.index;
    c.first_slice = chunk.first_slice;
    c.last_slice = chunk.last_slice;
    c.indices.reserve(3 * (end - begin));
    for (size_t s = begin; s < end; ++s) {
      const uint32_t* tri = chunk.indices.data() + 3 * size_t{sides[s].tri};
      const uint32_t corners[3] = {tri[0], sides[s].reversed ? tri[2] : tri[1],
                                   sides[s].reversed ? tri[1] : tri[2]};
      for (uint32_t v : corners) {
        if (local[v] == kInvalid) {
          local[v] = static_cast<uint32_t>(c.positions.size());
          c.positions.push_back(chunk.positions[v]);
          c.ids.push_back(chunk.ids[v]);
        }
        c.indices.push_back(local[v]);
      }
    }
    for (size_t s = begin; s < end; ++s) {  // reset for the next label
      const uint32_t* tri = chunk.indices.data() + 3 * size_t{sides[s].tri};
      for (int k = 0; k < 3; ++k) local[tri[k]] = kInvalid;
    }
    out.emplace_back(label, std::move(c));
    begin = end;
  }
  return out;
}

LabeledMesh WeldLabeledChunks(std::span<const SealedChunk> chunks) {
  LabeledMesh out;
  out.mesh = WeldChunks(chunks);
  JoinPairs(chunks, &out.patch, &out.pairs);
  return out;
}

}  // namespace tandem
