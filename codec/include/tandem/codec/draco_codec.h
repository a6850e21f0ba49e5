// IndexedMesh <-> Draco bytes, for every mesh the service sends (previews, final mesh).
// Lives outside core so that core stays free of Draco.
//
// Contract of a round trip DecodeDraco(EncodeDraco(m, o)):
//   * exactly m.num_triangles() triangles and m.num_vertices() vertices, at every level
//     (degenerate triangles, unreferenced vertices and non-manifold vertices included);
//   * every coordinate within PositionTolerance(m, o.quantization_bits) of the original:
//     two quantization steps plus float32 rounding;
//   * no triangle that has an area as written (float32: twice the area above 2e-6 of its
//     squared edges) decodes to one without, or turned over, and no two vertices decode to
//     one position, where one grid step of a corner can prevent it (below);
//   * compression_level 0 also keeps vertex and triangle order (and corner order), so
//     decoded vertex i is original vertex i; levels >= 1 may reorder both.
// Encoding is deterministic: the same mesh and options give byte-identical output.
#ifndef TANDEM_PROTO_CODEC_DRACO_CODEC_H_
#define TANDEM_PROTO_CODEC_DRACO_CODEC_H_

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/mesh.h"

namespace tandem::codec {

// The ranges and defaults every front end (flags, the wire config) takes from here.
inline constexpr int kMinQuantizationBits = 1, kMaxQuantizationBits = 30;
inline constexpr int kMinCompressionLevel = 0, kMaxCompressionLevel = 10;
inline constexpr int kDefaultQuantizationBits = 16, kDefaultCompressionLevel = 7;

struct DracoOptions {
  int quantization_bits = kDefaultQuantizationBits;  // position quantization, 1..30
  // 0..10. 0 = sequential coding (fast, order kept, larger); 1..10 = Edgebreaker, where a
  // higher level means smaller output for more encoding time (Draco speed = 10 - level).
  int compression_level = kDefaultCompressionLevel;
  // Explicit quantization grid (grid_range > 0): every axis is quantized on
  // [grid_origin, grid_origin + grid_range] instead of the mesh's own bounding box, so that
  // meshes encoded on one grid decode a vertex they share to bit-identical coordinates
  // (sealed chunks). Positions outside are clamped onto the grid's faces.
  std::array<float, 3> grid_origin{0, 0, 0};
  float grid_range = 0;
};

// Checks the ranges above; InvalidArgument starts with the field's name
// ("quantization_bits must be in [1, 30], got 31"), for a front end to rename.
absl::Status ValidateDracoOptions(const DracoOptions& options);

// Encodes positions (as float32) and triangles. InvalidArgument for invalid options, an
// index out of range, more than 2^31 vertices or non-finite positions; Internal if Draco
// fails. A mesh without triangles (empty included) is sent as a Draco point cloud, since
// Draco's mesh decoders refuse zero faces; DecodeDraco reads it back as such a mesh.
// Edgebreaker cannot carry some connectivity (non-manifold vertices get split, degenerate
// faces and isolated vertices dropped); when the counts would change, the mesh is encoded
// sequentially instead, so the contract above always holds.
// `ids` (empty, or one per vertex) travel as a GENERIC uint32 attribute, losslessly. With
// ids, Edgebreaker may split a non-manifold vertex into copies that carry its id and its
// position: the decoded vertex count may then exceed the original (triangles are kept).
// Quantization snaps every corner to the nearest grid point, and a thin triangle can lose
// its area on the grid (its corners on one grid line) or turn over: a zero-area triangle in
// the output, which breaks normals, slicers and some viewers; and two vertices
// closer than a step can land on one grid point, which a reader welding by position joins
// (a non-manifold mesh). Where either would happen, a corner steps to a free neighbouring
// grid point where none of its triangles loses its area or turns over (so it lies up to 1.5
// steps from where it was). `fixed` (empty, or one flag per vertex) names the corners that
// may not move: a sealed chunk's vertices that an earlier chunk sent on the same grid.
// `moved` (if given) gets the corners that moved, each with the position it was encoded at
// (float32 values, exactly), for a later chunk on the same grid that sends that vertex
// again. `avoid`: positions other buffers on the same grid sent (an earlier chunk's
// vertices), whose grid points no vertex here may take unless it is fixed.
using MovedCorners = std::vector<std::pair<uint32_t, Vec3>>;  // (vertex, position sent)
absl::StatusOr<std::string> EncodeDraco(const IndexedMesh& mesh, const DracoOptions& options = {},
                                        std::span<const uint32_t> ids = {},
                                        std::span<const uint8_t> fixed = {},
                                        MovedCorners* moved = nullptr,
                                        std::span<const Vec3> avoid = {});

// Decodes a Draco mesh or point-cloud buffer (positions as 3 floats per point; a point
// cloud gives a mesh without triangles). InvalidArgument for what is not Draco, DataLoss
// for a buffer Draco cannot decode (e.g. truncated).
// With `ids`: the GENERIC uint32 attribute EncodeDraco wrote, one per vertex
// (InvalidArgument when the buffer has none).
absl::StatusOr<IndexedMesh> DecodeDraco(std::string_view bytes,
                                        std::vector<uint32_t>* ids = nullptr);

// glTF's KHR_draco_mesh_compression: the mesh with its unit normals (one per vertex; a zero
// one becomes +z) as one Draco buffer, positions quantized as `options` say and normals on
// 10 bits, with what it decodes to (tandem/mesh.h: GlbDracoPrimitive). InvalidArgument
// for a mesh with vertices but no triangle (Draco has no such mesh).
absl::StatusOr<GlbDracoPrimitive> EncodeGlbPrimitive(const IndexedMesh& mesh,
                                                     const std::vector<Vec3>& normals,
                                                     const DracoOptions& options = {});
// The compressor WriteMesh takes (MeshWriteOptions::glb_draco) for these options.
GlbDracoCompressor GlbCompressor(const DracoOptions& options = {});

// How far a decoded coordinate may lie from the original: Draco quantizes all three axes
// on the largest extent of the bounding box, step = extent / (2^bits - 1), to the nearest
// grid point, a corner moved to keep a triangle's area goes one step further (two steps in
// all, rounded up), and Draco works in float32, which adds a few roundings of the largest
// |coordinate|. 0 for no vertices.
double PositionTolerance(const IndexedMesh& mesh, int bits);

}  // namespace tandem::codec

#endif  // TANDEM_PROTO_CODEC_DRACO_CODEC_H_
