// Label volumes' files: the names (and colours) of the labels, read from a CSV or a 3D Slicer
// colour table, and the meshes of a label session written one per label plus one GLB that
// holds every label as a node of its own (SplitByLabel's surfaces, tandem/labels.h).
#ifndef TANDEM_IO_LABELS_IO_H_
#define TANDEM_IO_LABELS_IO_H_

#include <array>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/io/mesh_io.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"

namespace tandem::io {

struct LabelName {
  std::string name;
  bool has_color = false;
  std::array<uint8_t, 4> rgba{0, 0, 0, 255};  // sRGB, 0..255
};
using LabelNames = std::map<LabelId, LabelName>;

// Reads a table of label names:
//   CSV (.csv, or any file whose first data line holds a comma): "id,name" lines, more
//     columns ignored unless they are colours; a first line that does not start with a
//     number is a header. 3D Slicer's CSV colour tables ("LabelValue,Name,Color_R,Color_G,
//     Color_B,Color_A" header) give colours; so do "id,name,r,g,b[,a]" lines without a header.
//     A name may be quoted ("a, b"; "" for a quote).
//   3D Slicer colour table (.ctbl, .txt): "id name r g b a" lines separated by spaces or tabs,
//     '#' comments.
// Empty lines are skipped. A line the table cannot use (an id that is not a whole number in
// [0, 2^64), no name, a colour outside 0..255, an id named twice) is refused with
// "FILE:LINE: what is wrong".
absl::StatusOr<LabelNames> ReadLabelNames(const std::string& path);

// The stem of label id's files: its name made safe for every file system (letters, digits,
// '.', '-' and '_' kept, runs of anything else one '_', at most 80 characters, no leading or
// trailing '.'; the id when no letter or digit is left or no name is given).
std::string LabelFileStem(LabelId id, const LabelNames* names);

// A label's colour in labels.glb: the table's when it has one, else a hue of its own (the
// golden-angle sequence over the labels' order, so neighbours in id differ).
std::array<uint8_t, 4> LabelColor(LabelId id, size_t order, const LabelNames* names);

struct LabelFile {
  LabelId id = 0;
  std::string path;  // the file written
  std::string name;  // the label's name, or its id
};

// Writes `surfaces` (one per label, increasing id) into the folder `dir` (created if
// missing): DIR/<stem><extension> per label (LabelFileStem; a stem that two labels share,
// case-insensitively, or "labels", which labels.glb has, gets "_<id>" appended), written by
// WriteMesh with `options`, and DIR/labels.glb (WriteLabelsGlb). Returns the per-label
// files in the order of `surfaces`. `extension`: ".ply", ".obj", ".stl" or ".glb".
absl::StatusOr<std::vector<LabelFile>> WriteLabelMeshes(
    const std::string& dir, const std::string& extension,
    const std::vector<std::pair<LabelId, IndexedMesh>>& surfaces, const LabelNames* names,
    const MeshWriteOptions& options = {});

// One GLB (binary glTF 2.0) holding every surface: a node per label, named by its name (or
// id), with a mesh of its own (POSITION, NORMAL, uint32 indices) and a material of its own
// (LabelColor, as glTF's linear baseColorFactor; alpha below 255 blends), "extras": {"label":
// id}. Positions in the mesh's units and `space`'s frame, as WriteMesh's GLB.
absl::Status WriteLabelsGlb(const std::string& path,
                            const std::vector<std::pair<LabelId, IndexedMesh>>& surfaces,
                            const LabelNames* names, Space space = Space::kGrid);

}  // namespace tandem::io

#endif  // TANDEM_IO_LABELS_IO_H_
