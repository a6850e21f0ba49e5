// Mesh files: the choice of format by extension, WriteMesh and ReadMesh, and vertex normals.
// See tandem/mesh_io.h for the contracts; each format has a file of its own (mesh_io_internal.h).
//
// Reading loads the whole file (meshes of millions of triangles are tens of MB) and parses
// it in place with std::from_chars (locale-independent, no allocation per number); writing
// streams through one fixed buffer.
#include "tandem/io/mesh_io.h"

#include <bit>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <optional>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "mesh_io_internal.h"
#include "tandem/geometry.h"
#include "tandem/status_macros.h"

namespace tandem::io {
namespace internal::meshio {

absl::Status Error(absl::StatusCode code, const std::string& path, absl::string_view what) {
  return absl::Status(code, absl::StrCat(path, ": ", what));
}

absl::StatusOr<Format> FormatOf(const std::string& path) {
  const std::string ext = absl::AsciiStrToLower(std::filesystem::path(path).extension().string());
  if (ext == ".ply") return Format::kPly;
  if (ext == ".obj") return Format::kObj;
  if (ext == ".stl") return Format::kStl;
  if (ext == ".glb") return Format::kGlb;
  return Error(absl::StatusCode::kInvalidArgument, path,
               absl::StrCat("unsupported mesh extension '", ext, "' (expected ",
                            kMeshExtensions, ")"));
}

void AppendVec3(BufferedWriter& out, const Vec3& v) {
  for (int k = 0; k < 3; ++k) out.AppendLe32(std::bit_cast<uint32_t>(static_cast<float>(v[k])));
}

std::string FrameTag(Space space) {
  if (space == Space::kLPS || space == Space::kRAS) {
    return absl::StrCat("SPACE=", SpaceName(space));
  }
  return absl::StrCat("frame ", SpaceName(space), " (not a patient frame)");
}

}  // namespace internal::meshio

namespace {

using internal::meshio::BufferedWriter;
using internal::meshio::Error;
using internal::meshio::Format;
using internal::meshio::FormatOf;
using internal::meshio::ReadObj;
using internal::meshio::ReadPly;
using internal::meshio::ReadStl;
using internal::meshio::WriteGlb;
using internal::meshio::WriteObj;
using internal::meshio::WritePly;
using internal::meshio::WriteStl;

absl::StatusOr<std::string> ReadWholeFile(const std::string& path) {
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) {
    return Error(absl::StatusCode::kNotFound, path,
                 absl::StrCat("cannot open for reading: ", std::strerror(errno)));
  }
  std::string data;
  char chunk[1 << 16];
  size_t n;
  while ((n = std::fread(chunk, 1, sizeof chunk, file)) > 0) data.append(chunk, n);
  const bool failed = std::ferror(file) != 0;
  std::fclose(file);
  if (failed) return Error(absl::StatusCode::kDataLoss, path, "read error");
  return data;
}

}  // namespace

bool IsMeshOutputPath(const std::string& path) { return FormatOf(path).ok(); }

std::vector<Vec3> VertexNormals(const IndexedMesh& mesh) {
  std::vector<Vec3> n(mesh.num_vertices(), Vec3{0, 0, 0});
  for (size_t t = 0; t < mesh.num_triangles(); ++t) {
    const uint32_t* tri = &mesh.indices[3 * t];
    const Vec3 w = TriangleAreaVector(mesh.positions[tri[0]], mesh.positions[tri[1]],
                                      mesh.positions[tri[2]]);
    for (int k = 0; k < 3; ++k) n[tri[k]] = n[tri[k]] + w;
  }
  for (Vec3& v : n) {
    const double len = Norm(v);
    v = len > 0 ? v * (1.0 / len) : Vec3{0, 0, 0};
  }
  return n;
}

absl::Status WriteMesh(const std::string& path, const IndexedMesh& mesh,
                       const MeshWriteOptions& options) {
  TANDEM_ASSIGN_OR_RETURN(const Format format, FormatOf(path));
  if (mesh.indices.size() % 3 != 0) {
    return Error(absl::StatusCode::kInvalidArgument, path,
                 absl::StrCat("mesh has ", mesh.indices.size(), " indices, not a multiple of 3"));
  }
  if (mesh.positions.size() >= (size_t{1} << 31)) {
    return Error(absl::StatusCode::kInvalidArgument, path, "mesh has 2^31 or more vertices");
  }
  for (size_t i = 0; i < mesh.indices.size(); ++i) {
    if (mesh.indices[i] >= mesh.positions.size()) {
      return Error(absl::StatusCode::kInvalidArgument, path,
                   absl::StrCat("triangle ", i / 3, ": vertex index ", mesh.indices[i],
                                " out of range (", mesh.positions.size(), " vertices)"));
    }
  }
  const bool with_normals = format == Format::kGlb || (options.normals && format != Format::kStl);
  const std::vector<Vec3> normals = with_normals ? VertexNormals(mesh) : std::vector<Vec3>{};
  // The Draco primitive before the file is created: a failure leaves nothing behind.
  std::optional<GlbDracoPrimitive> draco;
  if (format == Format::kGlb && options.glb_draco) {
    auto primitive = options.glb_draco(mesh, normals);
    if (!primitive.ok()) {
      return Error(primitive.status().code(), path, std::string(primitive.status().message()));
    }
    draco = *std::move(primitive);
  }
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) {
    return Error(absl::StatusCode::kUnavailable, path,
                 absl::StrCat("cannot open for writing: ", std::strerror(errno)));
  }
  BufferedWriter out(file);
  switch (format) {
    case Format::kPly: WritePly(mesh, normals, options.space, out); break;
    case Format::kObj: WriteObj(mesh, normals, options.space, out); break;
    case Format::kStl: WriteStl(mesh, options.space, out); break;
    case Format::kGlb: WriteGlb(mesh, normals, draco ? &*draco : nullptr, options.space, out); break;
  }
  if (const int err = out.Close(); err != 0) {
    return Error(absl::StatusCode::kUnavailable, path,
                 absl::StrCat("write failed: ", std::strerror(err)));
  }
  return absl::OkStatus();
}

absl::StatusOr<IndexedMesh> ReadMesh(const std::string& path) {
  TANDEM_ASSIGN_OR_RETURN(const Format format, FormatOf(path));
  TANDEM_ASSIGN_OR_RETURN(const std::string data, ReadWholeFile(path));
  switch (format) {
    case Format::kPly: return ReadPly(path, data);
    case Format::kObj: return ReadObj(path, data);
    case Format::kStl: return ReadStl(path, data);
    case Format::kGlb: break;
  }
  return Error(absl::StatusCode::kInvalidArgument, path,
               "reading .glb is not supported (tandem writes it for viewers; read .ply, .obj "
               "or .stl)");
}

}  // namespace tandem::io
