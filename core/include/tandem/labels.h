// Label volumes (segmentations): every label's surface from one sweep, touching labels
// sharing their interface triangles. The session extracts the interface complex (each
// triangle separates two labels) and simplifies it as one mesh, so where two labels touch
// their surfaces are the same triangles; SplitByLabel cuts it into one surface per label.
#ifndef TANDEM_LABELS_H_
#define TANDEM_LABELS_H_

#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "tandem/mesh.h"

namespace tandem {

// SessionOptions::labels: whether the volume is a label map, and which labels count.
struct LabelOptions {
  bool enabled = false;
  LabelId background = 0;     // has no surface of its own
  std::vector<LabelId> only;  // not empty: every other label counts as background
  bool close = false;         // close the surfaces at the grid's box (else open there)
};

// The interface complex: `patch[t]` indexes `pairs` for triangle t.
struct LabeledMesh {
  IndexedMesh mesh;
  std::vector<uint32_t> patch;
  std::vector<LabelPair> pairs;
};

// One side of an interface triangle: in `label`'s surface as it is (the label inside) or
// reversed (outside).
struct LabelSide {
  LabelId label;
  uint32_t tri;
  bool reversed;
};

// Each of the first `num_triangles` triangles once per side that is not `background`, sorted
// by label (triangle order within one), so a split by label is one pass however many labels.
// A triangle whose patch indexes no pair belongs to no label. `kept`, when not empty, holds
// per pair which of its sides count (bit 0: inside, bit 1: outside), so that a caller can cut
// the surfaces of some labels only (a shard's) without a pass per label.
std::vector<LabelSide> LabelSides(std::span<const uint32_t> patch, std::span<const LabelPair> pairs,
                                  size_t num_triangles, LabelId background,
                                  std::span<const uint8_t> kept = {});

// One surface per label other than the background, in increasing label: the triangles with
// that label inside as they are, those with it outside reversed, the vertices compacted
// (a vertex two labels share has the same position in both). `kept`: as for LabelSides.
std::vector<std::pair<LabelId, IndexedMesh>> SplitByLabel(const LabeledMesh& mesh,
                                                          LabelId background = 0,
                                                          std::span<const uint8_t> kept = {});

// A label session's sealed chunk (with `patch` and `pairs`) cut into one chunk per label
// other than `background` that it touches, in increasing label: that label's triangles as
// SplitByLabel takes them (in chunk order), their vertices with their ids in order of first
// use; index and slices as the chunk's. Welding one label's cuts by id gives the
// label's surface (WeldChunks).
std::vector<std::pair<LabelId, SealedChunk>> SplitLabeledChunk(const SealedChunk& chunk,
                                                               LabelId background);

// The interface complex a label session's sealed chunks make together (WeldChunks with each
// triangle's pair): its pairs in increasing (inside, outside), each once.
LabeledMesh WeldLabeledChunks(std::span<const SealedChunk> chunks);

}  // namespace tandem

#endif  // TANDEM_LABELS_H_
