// Neuroglancer's precomputed segmentation meshes: the multi-resolution format
// (neuroglancer_multilod_draco, src/datasource/precomputed/meshes.md in Neuroglancer) stored
// in shards (neuroglancer_uint64_sharded_v1, sharded.md), and the segmentation `info` that
// points at it, so that `precomputed://URL` opens the export as a segmentation layer.
// The Draco fragments come from the caller's encoder (tandem/codec/neuroglancer_draco.h:
// EncodeNeuroglancerFragment): io holds no Draco, as for the GLB writer.
#ifndef TANDEM_IO_NEUROGLANCER_H_
#define TANDEM_IO_NEUROGLANCER_H_

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"
#include "tandem/volume.h"

namespace tandem::io {

// One segment: its surface at each level of detail, finest first (level k is drawn when a
// pixel covers about lod_scales[k]).
struct NeuroglancerSegment {
  LabelId id = 0;
  std::vector<IndexedMesh> lods;
};

// One octree node's mesh as Neuroglancer decodes it: integer positions in
// [0, 2^vertex_quantization_bits) across the node's box, and triangles.
struct NeuroglancerFragment {
  std::vector<std::array<uint32_t, 3>> positions;
  std::vector<uint32_t> indices;
};
// A fragment as Draco bytes: a mesh whose POSITION attribute is 3 x int32, without Draco's
// own quantization (Neuroglancer refuses it), vertex and triangle counts kept.
using NeuroglancerFragmentEncoder =
    std::function<absl::StatusOr<std::string>(const NeuroglancerFragment& fragment)>;

// sharded.md's sharding specification.
struct NeuroglancerSharding {
  int preshift_bits = 0;
  bool murmurhash = true;  // murmurhash3_x86_128 of the shifted id; false: identity
  int minishard_bits = 0, shard_bits = 0;
  bool gzip_minishard_index = true;
  bool gzip_data = false;  // the manifests (the fragments are never compressed)
};

struct NeuroglancerOptions {
  int vertex_quantization_bits = 16;  // 10 or 16 (the format allows no other)
  // Nanometres per unit of the mesh positions (the grid's spacing unit): Neuroglancer's
  // precomputed coordinates are nanometres.
  double nm_per_unit = 1.0;
  // Per level (finest first), in mesh units; empty: 2^k times the grid's finest spacing.
  std::vector<double> lod_scales;
  // The finest octree node's edge in voxels; level k's nodes are 2^k times larger.
  int chunk_voxels = 32;
  // Skirt depth (BuildOctree) in mesh units; negative: the finest spacing (one voxel).
  double skirt = -1;
  // Shards and minishards; all bits 0 and murmurhash: chosen from the segment count
  // (ChooseSharding).
  NeuroglancerSharding sharding;
  bool choose_sharding = true;
  NeuroglancerFragmentEncoder encode;  // required
};

// Writes DIR/info (a uint64 segmentation whose "mesh" is "mesh", the grid's size,
// resolution and offset in nanometres, no voxel data) and DIR/mesh/ (info and the shard
// files). Each segment is an octree of fragments per level (BuildOctree), skirted where
// there is more than one level (docs/decisions.md). InvalidArgument for no encoder, bad
// bits or chunk size, an empty level list, unequal level counts, non-finite positions, an
// index out of range or two segments with one id; a failed write names the file.
absl::Status WriteNeuroglancer(const std::string& dir, const VolumeInfo& grid,
                               std::span<const NeuroglancerSegment> segments,
                               const NeuroglancerOptions& options);

// The segments handed over a shard at a time, so that an export of many labels holds one
// shard's surfaces and fragments, not every level of every label: `ids` every segment's id,
// `lods` their number of levels, `lowest` the least coordinate (per axis) of any level of any
// segment, and `fetch(ids, out)` the segments of those ids (a subset of `ids`, in that order).
struct NeuroglancerSource {
  std::vector<LabelId> ids;
  size_t lods = 0;
  Vec3 lowest{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
              std::numeric_limits<double>::infinity()};
  std::function<absl::Status(std::span<const LabelId> ids, std::vector<NeuroglancerSegment>* out)>
      fetch;
};
// WriteNeuroglancer with the segments from `source`; the same files and checks.
absl::Status WriteNeuroglancerFrom(const std::string& dir, const VolumeInfo& grid,
                                   const NeuroglancerSource& source,
                                   const NeuroglancerOptions& options);

// Per label, its surface at every level, from one SplitByLabel result per level (finest
// first): labels in increasing id, a label missing at a level gets an empty mesh there (its
// node is then empty, which Neuroglancer skips).
std::vector<std::pair<LabelId, std::vector<IndexedMesh>>> JoinLevels(
    std::vector<std::vector<std::pair<LabelId, IndexedMesh>>> levels);

// --- The format's pieces, for tests and readers. ---

// MurmurHash3_x86_128 (Austin Appleby's algorithm): h1..h4.
std::array<uint32_t, 4> MurmurHash3X86_128(std::span<const uint8_t> key, uint32_t seed);
// The hashed chunk id: hash(id >> preshift_bits), murmur over the 8 little-endian bytes
// with seed 0, its low 64 bits.
uint64_t HashChunkId(uint64_t id, const NeuroglancerSharding& sharding);
struct ShardLocation {
  uint64_t shard = 0, minishard = 0;
};
ShardLocation LocateChunk(uint64_t id, const NeuroglancerSharding& sharding);
// Up to about 2^14 segments per shard and 2^5 per minishard, murmurhash, gzip indices.
NeuroglancerSharding ChooseSharding(size_t segments);
// The shard file's name: lowercase hex, ceil(shard_bits / 4) digits, ".shard".
std::string ShardFileName(uint64_t shard, const NeuroglancerSharding& sharding);

// One chunk of a shard: `prefix` is written just before `data` (a segment's fragments before
// its manifest); the minishard index points at `data`.
struct ShardChunk {
  uint64_t id = 0;
  std::string prefix, data;
};
// A whole shard file: the shard index, the chunks (by minishard, then by id), the minishard
// indices. The chunks must all map to this shard; data is encoded as the spec says.
absl::StatusOr<std::string> BuildShard(std::vector<ShardChunk> chunks,
                                       const NeuroglancerSharding& sharding);

// The manifest (meshes.md: "Multi-resolution mesh manifest file format").
struct NeuroglancerManifest {
  std::array<float, 3> chunk_shape{1, 1, 1}, grid_origin{0, 0, 0};
  std::vector<float> lod_scales;
  std::vector<std::array<float, 3>> vertex_offsets;  // one per level
  // Per level: each fragment's node position and its byte size, in z-order.
  std::vector<std::vector<std::array<uint32_t, 3>>> positions;
  std::vector<std::vector<uint32_t>> sizes;
};
std::string EncodeManifest(const NeuroglancerManifest& manifest);

// The octree every segment shares: the finest node's shape and the grid's corner, so that
// touching segments cut and quantize their common triangles alike. Level k's node (x, y, z)
// is the box grid_origin + (x, y, z) * chunk_shape * 2^k, of size chunk_shape * 2^k.
struct NeuroglancerGrid {
  std::array<float, 3> chunk_shape{1, 1, 1}, grid_origin{0, 0, 0};
};
// Nodes of `chunk_voxels` voxels a side, the corner half a voxel below the volume and below
// every vertex (so an open border at the volume's faces never lies on a node face).
NeuroglancerGrid ChooseOctreeGrid(const VolumeInfo& grid,
                                  std::span<const NeuroglancerSegment> segments, int chunk_voxels);
// The same from the least coordinate of the segments' vertices (per axis).
NeuroglancerGrid ChooseOctreeGrid(const VolumeInfo& grid, const Vec3& lowest, int chunk_voxels);

// One octree node of one level: its grid position and its fragment (empty: a node kept only
// as the parent of finer ones).
struct NeuroglancerNode {
  std::array<uint32_t, 3> position{0, 0, 0};
  NeuroglancerFragment fragment;
};
// A segment's octree: per level (finest first) its nodes in z-order. Level k's mesh is cut
// exactly along the faces of its cells (the nodes for k = 0, their octants for k > 0, as the
// format's 2x2x2 partition asks), each cell's piece quantized inside the cell, octants
// meeting on the step 2^(bits-1) that Neuroglancer's partition lets either side hold. With
// skirt > 0 every cut edge hangs a strip of at least that depth (mesh units) inside the cut
// face, away from the surface's outer side, so that two levels meeting on a face overlap
// instead of leaving the crack between their cuts: down to another level's cut of that face
// (up to 4 skirts) where it lies further, down a cell edge where the cut reaches one, on into
// the neighbouring cells of its level where it leaves its own, and never past the surface's
// other side in the face (a thin wall keeps it inside); 0: none.
absl::StatusOr<std::vector<std::vector<NeuroglancerNode>>> BuildOctree(
    const NeuroglancerSegment& segment, const NeuroglancerGrid& grid, int bits, double skirt);
// Where quantized position q of level `lod`'s node `node` lands (meshes.md's formula).
Vec3 DequantizePosition(const NeuroglancerGrid& grid, int lod, const std::array<uint32_t, 3>& node,
                        const std::array<uint32_t, 3>& q, int bits);

// gzip (RFC 1952) of `bytes`, as sharded.md's "gzip" encoding.
absl::StatusOr<std::string> GzipBytes(std::string_view bytes);

}  // namespace tandem::io

#endif  // TANDEM_IO_NEUROGLANCER_H_
