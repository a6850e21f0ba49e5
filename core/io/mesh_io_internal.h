// Mesh files, internal to io: the extension's format, the buffered writer and number parsing
// that the per-format files (mesh_ply.cc, mesh_obj.cc, mesh_stl.cc, mesh_glb.cc) share, and
// their entries for WriteMesh, ReadMesh (mesh_io.cc) and ChunkedMeshWriter.
#ifndef TANDEM_IO_MESH_IO_INTERNAL_H_
#define TANDEM_IO_MESH_IO_INTERNAL_H_

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <system_error>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "tandem/mesh.h"
#include "tandem/io/mesh_io.h"
#include "tandem/volume.h"

namespace tandem::io::internal::meshio {

// A status whose message starts with the path.
absl::Status Error(absl::StatusCode code, const std::string& path, absl::string_view what);

enum class Format { kPly, kObj, kStl, kGlb };
// The format of a path's extension; InvalidArgument naming the extension otherwise.
absl::StatusOr<Format> FormatOf(const std::string& path);

// Appends to a 1 MiB buffer and hands full buffers to stdio; remembers the first error.
class BufferedWriter {
 public:
  explicit BufferedWriter(std::FILE* file) : file_(file), buffer_(1 << 20) {}

  void Append(const char* data, size_t n) {
    while (n > 0) {
      if (used_ == buffer_.size()) Flush();
      const size_t take = std::min(n, buffer_.size() - used_);
      std::memcpy(buffer_.data() + used_, data, take);
      used_ += take;
      data += take;
      n -= take;
    }
  }
  void Append(absl::string_view s) { Append(s.data(), s.size()); }
  void AppendLe32(uint32_t v) {
    const char bytes[4] = {static_cast<char>(v & 0xff), static_cast<char>((v >> 8) & 0xff),
                           static_cast<char>((v >> 16) & 0xff),
                           static_cast<char>((v >> 24) & 0xff)};
    Append(bytes, 4);
  }
  // The shortest decimal that reads back as the same float32 (at most 9 significant
  // digits, like %.9g, but "0.1" rather than "0.100000001").
  void AppendFloat(float v) {
    char text[32];
    const auto res = std::to_chars(text, text + sizeof text, v);
    Append(text, static_cast<size_t>(res.ptr - text));
  }
  void AppendUint(uint64_t v) {
    char text[24];
    const auto res = std::to_chars(text, text + sizeof text, v);
    Append(text, static_cast<size_t>(res.ptr - text));
  }

  void Flush() {
    if (used_ > 0 && error_ == 0 && std::fwrite(buffer_.data(), 1, used_, file_) != used_) {
      error_ = errno != 0 ? errno : EIO;
    }
    used_ = 0;
  }
  // Flushes and closes; returns 0 or the first errno seen.
  int Close() {
    Flush();
    if (std::fclose(file_) != 0 && error_ == 0) error_ = errno != 0 ? errno : EIO;
    file_ = nullptr;
    return error_;
  }
  ~BufferedWriter() {
    if (file_ != nullptr) std::fclose(file_);
  }

 private:
  std::FILE* file_;
  std::vector<char> buffer_;
  size_t used_ = 0;
  int error_ = 0;
};

// Three little-endian float32.
void AppendVec3(BufferedWriter& out, const Vec3& v);
// The frame of the positions as 3D Slicer looks for it in a model file's header ("SPACE=RAS"
// or "SPACE=LPS" anywhere in a PLY comment, OBJ's first comment or binary STL's header; LPS
// assumed without it); the frames Slicer does not know are named without "SPACE=".
std::string FrameTag(Space space);

// Parses a number in full; accepts a leading '+', which from_chars does not.
template <typename T>
inline bool ParseNumber(absl::string_view s, T& value) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  const auto res = std::from_chars(s.data(), s.data() + s.size(), value);
  return res.ec == std::errc() && res.ptr == s.data() + s.size();
}

inline bool IsSpace(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v';
}

// PLY (mesh_ply.cc): binary little-endian, written; ascii or binary of either order, read.
void AppendPlyHeader(BufferedWriter& out, size_t vertices, size_t triangles, bool normals,
                     Space space);
void AppendPlyFace(BufferedWriter& out, const uint32_t* tri);
void WritePly(const IndexedMesh& mesh, const std::vector<Vec3>& normals, Space space,
              BufferedWriter& out);
absl::StatusOr<IndexedMesh> ReadPly(const std::string& path, absl::string_view data);

// Wavefront OBJ (mesh_obj.cc).
// "tag x y z\n", each coordinate rounded to float32 first, like the PLY output: both formats
// store the same values.
void AppendObjVec3(BufferedWriter& out, absl::string_view tag, const Vec3& v);
void AppendObjHeader(BufferedWriter& out, size_t vertices, size_t triangles, Space space);
void AppendObjFace(BufferedWriter& out, const uint32_t* tri, bool normals);
void WriteObj(const IndexedMesh& mesh, const std::vector<Vec3>& normals, Space space,
              BufferedWriter& out);
absl::StatusOr<IndexedMesh> ReadObj(const std::string& path, absl::string_view data);

// Binary STL (mesh_stl.cc).
void WriteStl(const IndexedMesh& mesh, Space space, BufferedWriter& out);
// Binary STL; corners with the same float32 position become one vertex, in order of first
// appearance, so a mesh written by WriteStl reads back with its vertex count.
absl::StatusOr<IndexedMesh> ReadStl(const std::string& path, const std::string& data);

// The GLB container up to its binary payload: the 12-byte header, the JSON chunk (`json`,
// padded here to 4 bytes with spaces) and, when bin_bytes > 0 (a multiple of 4), the BIN
// chunk's header; the caller appends the payload.
void AppendGlbContainer(BufferedWriter& out, std::string json, size_t bin_bytes);
// The parts of that container: the header with the JSON chunk's (`json_bytes`, padded)
// header; the BIN chunk's header (nothing when bin_bytes is 0).
void AppendGlbHeader(BufferedWriter& out, size_t json_bytes, size_t bin_bytes);
void AppendGlbBinHeader(BufferedWriter& out, size_t bin_bytes);
// GLB, binary glTF 2.0 (mesh_glb.cc); with `draco`, the primitive is that Draco buffer.
void WriteGlb(const IndexedMesh& mesh, const std::vector<Vec3>& normals,
              const GlbDracoPrimitive* draco, Space space, BufferedWriter& out);

}  // namespace tandem::io::internal::meshio

#endif  // TANDEM_IO_MESH_IO_INTERNAL_H_
