// Wavefront OBJ mesh files: the writer ("v", "vn" and "f" lines) and the reader of "v" and
// "f" lines (tandem/mesh_io.h).
#include <cstdint>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "mesh_io_internal.h"

namespace tandem::io::internal::meshio {

void AppendObjVec3(BufferedWriter& out, absl::string_view tag, const Vec3& v) {
  out.Append(tag);
  for (int k = 0; k < 3; ++k) {
    out.Append(" ");
    out.AppendFloat(static_cast<float>(v[k]));
  }
  out.Append("\n");
}

void AppendObjHeader(BufferedWriter& out, size_t vertices, size_t triangles, Space space) {
  out.Append(absl::StrCat("# written by tandem: ", vertices, " vertices, ", triangles,
                          " triangles\n# ", FrameTag(space), "\n"));
}

void AppendObjFace(BufferedWriter& out, const uint32_t* tri, bool normals) {
  out.Append("f");
  for (int k = 0; k < 3; ++k) {
    const uint64_t i = uint64_t{tri[k]} + 1;
    out.Append(" ");
    out.AppendUint(i);
    if (normals) {  // "i//i": vertex i with normal i
      out.Append("//");
      out.AppendUint(i);
    }
  }
  out.Append("\n");
}

void WriteObj(const IndexedMesh& mesh, const std::vector<Vec3>& normals, Space space,
              BufferedWriter& out) {
  AppendObjHeader(out, mesh.num_vertices(), mesh.num_triangles(), space);
  for (const Vec3& p : mesh.positions) AppendObjVec3(out, "v", p);
  for (const Vec3& n : normals) AppendObjVec3(out, "vn", n);
  for (size_t t = 0; t < mesh.num_triangles(); ++t) {
    AppendObjFace(out, &mesh.indices[3 * t], !normals.empty());
  }
}

absl::StatusOr<IndexedMesh> ReadObj(const std::string& path, absl::string_view data) {
  IndexedMesh mesh;
  // Positive (absolute) indices may refer to vertices defined later, so they are checked at
  // the end; negative ones are resolved against the vertices read so far.
  std::vector<int64_t> corners;
  size_t max_line_of_face = 0;
  int64_t max_index = -1;
  size_t pos = 0;
  for (size_t line_no = 1; pos < data.size(); ++line_no) {
    size_t eol = data.find('\n', pos);
    if (eol == absl::string_view::npos) eol = data.size();
    absl::string_view line = data.substr(pos, eol - pos);
    pos = eol + 1;
    auto bad = [&](absl::string_view why) {
      return Error(absl::StatusCode::kInvalidArgument, path,
                   absl::StrCat("line ", line_no, ": ", why));
    };
    for (char ch : line) {
      const auto u = static_cast<unsigned char>(ch);
      if (u < 0x20 && !IsSpace(ch)) {
        return bad(absl::StrCat("not a text OBJ file (control byte 0x",
                                absl::Hex(u, absl::kZeroPad2), ")"));
      }
    }
    const size_t hash = line.find('#');
    if (hash != absl::string_view::npos) line = line.substr(0, hash);
    const std::vector<absl::string_view> tok =
        absl::StrSplit(line, absl::ByAnyChar(" \t\r\f\v"), absl::SkipEmpty());
    if (tok.empty()) continue;
    if (tok[0] == "v") {
      Vec3 p;
      if (tok.size() < 4 || !ParseNumber(tok[1], p.x) || !ParseNumber(tok[2], p.y) ||
          !ParseNumber(tok[3], p.z)) {
        return bad("expected 'v x y z'");
      }
      mesh.positions.push_back(p);
    } else if (tok[0] == "f") {
      corners.clear();
      for (size_t k = 1; k < tok.size(); ++k) {
        const absl::string_view corner = tok[k].substr(0, tok[k].find('/'));
        int64_t index;
        if (!ParseNumber(corner, index) || index == 0) {
          return bad(absl::StrCat("bad face corner '", tok[k], "'"));
        }
        if (index < 0) {
          index += static_cast<int64_t>(mesh.positions.size());
          if (index < 0) {
            return bad(absl::StrCat("relative index ", corner, " out of range (",
                                    mesh.positions.size(), " vertices so far)"));
          }
        } else {
          index -= 1;
        }
        if (index > max_index) {
          max_index = index;
          max_line_of_face = line_no;
        }
        corners.push_back(index);
      }
      for (size_t k = 1; k + 1 < corners.size(); ++k) {
        mesh.indices.push_back(static_cast<uint32_t>(corners[0]));
        mesh.indices.push_back(static_cast<uint32_t>(corners[k]));
        mesh.indices.push_back(static_cast<uint32_t>(corners[k + 1]));
      }
    }
  }
  if (max_index >= static_cast<int64_t>(mesh.positions.size())) {
    return Error(absl::StatusCode::kInvalidArgument, path,
                 absl::StrCat("line ", max_line_of_face, ": vertex index ", max_index + 1,
                              " out of range (", mesh.positions.size(), " vertices)"));
  }
  return mesh;
}

}  // namespace tandem::io::internal::meshio
