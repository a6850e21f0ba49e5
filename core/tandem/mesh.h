// IndexedMesh: a compact, immutable-by-convention triangle mesh (the "snapshot" form).
// Positions are in physical units; triangles are counter-clockwise seen from outside
// (outside = where the field is below the iso-value).
#ifndef TANDEM_MESH_H_
#define TANDEM_MESH_H_

#include <cstdint>
#include <span>
#include <vector>

#include "tandem/types.h"

namespace tandem {

struct IndexedMesh {
  std::vector<Vec3> positions;     // one per vertex
  std::vector<uint32_t> indices;   // 3 per triangle, into positions

  size_t num_vertices() const { return positions.size(); }
  size_t num_triangles() const { return indices.size() / 3; }
};

// A sealed chunk (TandemSession::TakeSealed): a piece of the final mesh that never changes
// once handed out.
struct SealedChunk {
  int64_t index = 0;                // 0, 1, ... in the order the chunks were taken
  int64_t first_slice = 0, last_slice = 0;  // slices its vertices span (floor/ceil of heights)
  std::vector<Vec3> positions;      // one per vertex
  std::vector<uint32_t> ids;        // global id of each vertex
  std::vector<uint32_t> indices;    // 3 per triangle, into positions
  // Ids no later chunk has: every triangle of these vertices is in this chunk or an earlier
  // one (a writer can put them out now, normals complete). Not sent on the wire.
  std::vector<uint32_t> retired;
  size_t num_triangles() const { return indices.size() / 3; }
};

// The mesh the chunks make together: one vertex per global id (in increasing id), the
// triangles in chunk order.
IndexedMesh WeldChunks(std::span<const SealedChunk> chunks);

}  // namespace tandem

#endif  // TANDEM_MESH_H_
