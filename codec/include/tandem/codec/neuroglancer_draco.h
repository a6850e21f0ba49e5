// Draco fragments as Neuroglancer's multi-resolution meshes take them (meshes.md: a mesh with
// a 3-component integer POSITION, no Draco quantization), for the io writer's
// NeuroglancerFragmentEncoder (tandem/io/neuroglancer.h; the programs join the two).
#ifndef TANDEM_CODEC_NEUROGLANCER_DRACO_H_
#define TANDEM_CODEC_NEUROGLANCER_DRACO_H_

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"

namespace tandem::codec {

// Positions as int32 values (each below 2^31), triangles by index. Edgebreaker at
// `compression_level` (1..10; 0 = sequential); when Edgebreaker would change the vertex or
// triangle count (degenerate or non-manifold pieces), sequential coding instead, so every
// triangle arrives. InvalidArgument for an index out of range, a value of 2^31 or more, no
// triangle (Neuroglancer's decoder takes meshes only) or a vertex in no triangle (Draco would
// drop it, or code bytes no Draco decoder reads); Internal if Draco fails.
absl::StatusOr<std::string> EncodeNeuroglancerFragment(
    std::span<const std::array<uint32_t, 3>> positions, std::span<const uint32_t> indices,
    int compression_level = 7);

// Decodes such a fragment back (for tests and readers): integer positions and triangles.
struct IntegerMesh {
  std::vector<std::array<uint32_t, 3>> positions;
  std::vector<uint32_t> indices;
};
absl::StatusOr<IntegerMesh> DecodeNeuroglancerFragment(std::string_view bytes);

}  // namespace tandem::codec

#endif  // TANDEM_CODEC_NEUROGLANCER_DRACO_H_
