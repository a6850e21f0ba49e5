// Reading and writing triangle meshes as PLY, Wavefront OBJ, binary STL and GLB files.
//
// The format is chosen by the file's extension, case-insensitively: ".ply", ".obj", ".stl"
// or ".glb" (GLB is written, not read).
// Positions keep the mesh's units (tandem writes physical units); no transform is applied.
// Errors are absl::Status values whose message starts with the path and names the problem:
//   NotFound          the file cannot be opened for reading
//   InvalidArgument   unknown extension, bad header, malformed number or face, index out of
//                     range (also for WriteMesh given an invalid mesh)
//   DataLoss          the file ends before the data its header announces (truncated)
//   Unavailable       an operating-system write error (disk full, permission)
#ifndef TANDEM_MESH_IO_H_
#define TANDEM_MESH_IO_H_

#include <array>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/mesh.h"
#include "tandem/volume.h"

namespace tandem::io {

// Writes `mesh` to `path` (overwriting it), streamed through a fixed buffer, so memory does
// not grow with the mesh.
//   .ply  binary_little_endian 1.0: "element vertex" with float32 x y z (positions are
//         rounded to float), "element face" with "property list uchar int vertex_indices".
//   .obj  text: "v x y z" with each coordinate rounded to float32 and printed as the
//         shortest decimal that reads back as that float (≤ 9 significant digits, the
//         precision of %.9g), then "f i j k" with 1-based indices. Reading it back and
//         rounding to float gives the written float32 values exactly.
// Fails with InvalidArgument, before creating the file, if indices.size() is not a multiple
// of 3 or an index is ≥ num_vertices(), or if the mesh has ≥ 2^31 vertices (PLY int).
//   .stl  binary: per triangle its unit normal and three float32 corners (no shared
//         vertices; 50 bytes a triangle).
//   .glb  binary glTF 2.0: POSITION, NORMAL and uint32 indices in one buffer (glTF's unit is
//         the metre: positions keep the mesh's units, usually millimetres for CT); with
//         MeshWriteOptions::glb_draco, the primitive is one Draco buffer instead
//         (KHR_draco_mesh_compression).
// Normals (MeshWriteOptions::normals, default on) are the area-weighted vertex normals of
// VertexNormals: PLY gets float nx ny nz vertex properties, OBJ "vn" lines and "f i//i"
// corners; GLB always has them; STL has its facet normals.
// GLB with KHR_draco_mesh_compression: the caller's compressor (tandem/mesh.h:
// GlbDracoCompressor) makes the primitive.

struct MeshWriteOptions {
  bool normals = true;
  // The frame of the positions, written where 3D Slicer reads it: "SPACE=LPS" or
  // "SPACE=RAS" in a PLY comment, the OBJ's first comment and the binary STL header (other
  // frames are named without "SPACE=", which Slicer then takes as LPS); a GLB names it in
  // asset.extras.frame ("LPS", "RAS", "grid", "voxel"), its positions left in that frame.
  Space space = Space::kGrid;
  GlbDracoCompressor glb_draco;  // .glb: set = Draco-compressed primitive
};
absl::Status WriteMesh(const std::string& path, const IndexedMesh& mesh,
                       const MeshWriteOptions& options = {});
inline constexpr const char* kMeshExtensions = ".ply, .obj, .stl or .glb";
// Whether WriteMesh writes files with this path's extension.
bool IsMeshOutputPath(const std::string& path);

// Writes a mesh that arrives in sealed chunks (sealer.h) to a .ply or .obj file (as WriteMesh
// writes them) while it comes, so that memory holds only the vertices still open and the
// triangles that touch them, whatever the depth: a vertex is written once a chunk retires
// its id, with the area-weighted normal of all its triangles, and gets its index then; a
// triangle goes to its place in a scratch file once its last vertex is retired, and Finish
// writes the header, the vertices and the triangles. The mesh is WeldChunks's, its vertices
// in the order they were retired. Errors as WriteMesh's; Finish fails with Internal when a
// vertex was never retired (chunks missing).
class ChunkedMeshWriter {
 public:
  static bool Supports(const std::string& path);  // .ply and .obj
  static absl::StatusOr<std::unique_ptr<ChunkedMeshWriter>> Open(
      const std::string& path, const MeshWriteOptions& options = {});
  ~ChunkedMeshWriter();
  absl::Status Add(const SealedChunk& chunk);
  absl::Status Finish();
  int64_t vertices() const { return vertices_; }
  int64_t triangles() const { return triangles_; }
  // What the writer holds in memory: the open vertices, the triangles waiting for them and
  // the free slots among them (tables at their capacity).
  size_t MemoryBytes() const;

 private:
  static constexpr uint32_t kNoCorner = 0xffffffffu;
  struct OpenVertex {
    Vec3 pos;
    Vec3 normal;  // sum of the area vectors of its triangles so far
    uint32_t waiting = kNoCorner;  // its first corner in waiting_ (3 * slot + k), a list
  };
  struct WaitingTriangle {
    int64_t place : 62;   // in the order the triangles came
    uint64_t open : 2;    // corners still a global id
    uint32_t corners[3];  // an output index once retired, else a global id
    uint32_t next[3];     // the next waiting corner of the same vertex
  };
  ChunkedMeshWriter(std::string path, MeshWriteOptions options, std::FILE* verts, std::FILE* tris)
      : path_(std::move(path)), options_(options), verts_(verts), tris_(tris) {}
  absl::Status Failed(const char* what) const;
  std::string path_;
  MeshWriteOptions options_;
  std::FILE* verts_;  // scratch: float32 x y z nx ny nz per written vertex
  std::FILE* tris_;   // scratch: 3 output indices per triangle, in the order they came
  int64_t tris_at_ = 0;  // the triangle tris_'s position is at
  absl::flat_hash_map<uint32_t, OpenVertex> open_;
  std::vector<WaitingTriangle> waiting_;  // slots, reused
  std::vector<uint32_t> free_;           // free slots of waiting_
  std::vector<WaitingTriangle> done_;    // the last chunk's complete triangles, by place
  std::vector<uint32_t> run_;  // triangles of consecutive places, written at once
  int64_t vertices_ = 0, triangles_ = 0;
};

// Unit area-weighted vertex normals (the sum of the incident triangles' area vectors,
// normalised); (0, 0, 0) for a vertex whose triangles have no area or that has none.
std::vector<Vec3> VertexNormals(const IndexedMesh& mesh);

// Reads a mesh. Polygons with more than 3 corners are fan-triangulated (v0 vi vi+1); faces
// with fewer than 3 corners are dropped. Vertex order and count are kept as in the file.
//   .ply  ascii, binary_little_endian or binary_big_endian 1.0. The vertex element must have
//         x, y, z (any scalar type, usually float or double); other vertex properties and
//         other elements are skipped. Faces: a list property named "vertex_indices" (or
//         "vertex_index") with any integer count and index types; other face properties are
//         skipped. A file without a face element reads as a point set (no indices).
//   .obj  "v x y z [w]" and "f" lines; face corners may be "i", "i/t", "i//n" or "i/t/n",
//         1-based, or negative (relative to the vertices read so far). Other lines (vn, vt,
//         g, o, s, usemtl, comments, ...) are ignored.
absl::StatusOr<IndexedMesh> ReadMesh(const std::string& path);

}  // namespace tandem::io

#endif  // TANDEM_MESH_IO_H_
