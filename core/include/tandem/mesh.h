// IndexedMesh: a compact, immutable-by-convention triangle mesh (the "snapshot" form).
// Positions are in physical units; triangles are counter-clockwise seen from outside
// (outside = where the field is below the iso-value).
#ifndef TANDEM_MESH_H_
#define TANDEM_MESH_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "tandem/types.h"

namespace tandem {

struct IndexedMesh {
  std::vector<Vec3> positions;     // one per vertex
  std::vector<uint32_t> indices;   // 3 per triangle, into positions

  size_t num_vertices() const { return positions.size(); }
  size_t num_triangles() const { return indices.size() / 3; }
};

// A label map's id (labels.h).
using LabelId = uint64_t;

// The two labels a triangle of a label session separates, one side each: `inside` is the
// label the triangle's normal points away from (the triangle is counter-clockwise seen from
// `outside`).
struct LabelPair {
  LabelId inside = 0, outside = 0;
  friend bool operator==(const LabelPair&, const LabelPair&) = default;
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
  // A label session's chunk (SessionOptions::labels): triangle t separates pairs[patch[t]];
  // `pairs` holds the pairs of this chunk's triangles, in increasing (inside, outside), each
  // once. Both empty for an iso-surface session.
  std::vector<uint32_t> patch;
  std::vector<LabelPair> pairs;
  size_t num_triangles() const { return indices.size() / 3; }
};

// The mesh the chunks make together: one vertex per global id (in increasing id), the
// triangles in chunk order.
IndexedMesh WeldChunks(std::span<const SealedChunk> chunks);

// A GLB file's primitive with KHR_draco_mesh_compression (tandem/mesh_io.h writes GLB):
// positions, normals and triangles as one Draco buffer, which neither core nor io can make
// (neither holds Draco). The caller's compressor (tandem/codec/draco_codec.h: GlbCompressor)
// makes it from the mesh and its normals, and tells what the buffer decodes to, for the glTF
// accessors: the counts (Draco may split a vertex), the positions' bounds, and the Draco
// attribute ids of POSITION and NORMAL.
struct GlbDracoPrimitive {
  std::string bytes;
  size_t vertices = 0, indices = 0;
  std::array<double, 3> lo{0, 0, 0}, hi{0, 0, 0};
  int position_id = 0, normal_id = 1;
};
using GlbDracoCompressor = std::function<absl::StatusOr<GlbDracoPrimitive>(
    const IndexedMesh& mesh, const std::vector<Vec3>& normals)>;

}  // namespace tandem

#endif  // TANDEM_MESH_H_
