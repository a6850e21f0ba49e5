// IndexedMesh: a compact, immutable-by-convention triangle mesh (the "snapshot" form).
// Positions are in physical units; triangles are counter-clockwise seen from outside
// (outside = where the field is below the iso-value).
#ifndef TANDEM_MESH_H_
#define TANDEM_MESH_H_

#include <cstdint>
#include <vector>

#include "tandem/types.h"

namespace tandem {

struct IndexedMesh {
  std::vector<Vec3> positions;     // one per vertex
  std::vector<uint32_t> indices;   // 3 per triangle, into positions

  size_t num_vertices() const { return positions.size(); }
  size_t num_triangles() const { return indices.size() / 3; }
};

}  // namespace tandem

#endif  // TANDEM_MESH_H_
