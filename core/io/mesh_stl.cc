// Binary STL mesh files: the writer (one facet normal and three corners a triangle) and the
// reader, which welds corners of the same position (tandem/mesh_io.h).
#include <array>
#include <bit>
#include <cstring>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/str_cat.h"
#include "mesh_io_internal.h"
#include "tandem/geometry.h"

namespace tandem::io::internal::meshio {

// Binary STL: an 80-byte header, the triangle count, then per triangle its unit normal, its
// three corners (float32) and a zero attribute word. STL has no shared vertices.
void WriteStl(const IndexedMesh& mesh, Space space, BufferedWriter& out) {
  char header[80] = {};
  // Never "solid" first: that would be an ASCII STL.
  const std::string text = absl::StrCat("binary STL written by tandem ", FrameTag(space));
  std::memcpy(header, text.data(), std::min(text.size(), sizeof header));
  out.Append(header, sizeof header);
  out.AppendLe32(static_cast<uint32_t>(mesh.num_triangles()));
  for (size_t t = 0; t < mesh.num_triangles(); ++t) {
    const Vec3 a = mesh.positions[mesh.indices[3 * t]], b = mesh.positions[mesh.indices[3 * t + 1]],
               c = mesh.positions[mesh.indices[3 * t + 2]];
    const Vec3 n = TriangleAreaVector(a, b, c);
    const double len = Norm(n);
    AppendVec3(out, len > 0 ? n * (1.0 / len) : Vec3{0, 0, 0});
    for (const Vec3& p : {a, b, c}) AppendVec3(out, p);
    const char attribute[2] = {0, 0};
    out.Append(attribute, 2);
  }
}

absl::StatusOr<IndexedMesh> ReadStl(const std::string& path, const std::string& data) {
  uint32_t count = 0;
  if (data.size() >= 84) std::memcpy(&count, data.data() + 80, 4);
  if (data.size() < 84 || data.size() != 84 + uint64_t{50} * count) {
    if (data.compare(0, 5, "solid") == 0) {  // and not a binary file of the right size
      return Error(absl::StatusCode::kInvalidArgument, path,
                   "ASCII STL is not supported (binary STL only)");
    }
    if (data.size() < 84) {
      return Error(absl::StatusCode::kDataLoss, path,
                   "shorter than a binary STL header (84 bytes)");
    }
    return Error(absl::StatusCode::kDataLoss, path,
                 absl::StrCat("binary STL of ", count, " triangles needs ", 84 + uint64_t{50} * count,
                              " bytes, the file has ", data.size()));
  }
  IndexedMesh mesh;
  absl::flat_hash_map<std::array<uint32_t, 3>, uint32_t> ids;
  mesh.indices.reserve(3 * size_t{count});
  for (uint32_t t = 0; t < count; ++t) {
    const char* rec = data.data() + 84 + size_t{50} * t + 12;  // past the facet normal
    for (int c = 0; c < 3; ++c) {
      std::array<uint32_t, 3> bits;
      std::memcpy(bits.data(), rec + 12 * c, 12);
      auto [it, added] = ids.try_emplace(bits, static_cast<uint32_t>(mesh.positions.size()));
      if (added) {
        mesh.positions.push_back(Vec3{std::bit_cast<float>(bits[0]), std::bit_cast<float>(bits[1]),
                                      std::bit_cast<float>(bits[2])});
      }
      mesh.indices.push_back(it->second);
    }
  }
  return mesh;
}

}  // namespace tandem::io::internal::meshio
