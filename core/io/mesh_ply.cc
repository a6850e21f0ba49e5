// PLY mesh files: the binary little-endian writer and the reader of ascii and binary PLY
// of either byte order (tandem/mesh_io.h states what is read and written).
#include <algorithm>
#include <bit>
#include <cstring>
#include <optional>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "mesh_io_internal.h"
#include "tandem/status_macros.h"

namespace tandem::io::internal::meshio {

void AppendPlyHeader(BufferedWriter& out, size_t vertices, size_t triangles, bool normals,
                     Space space) {
  out.Append(absl::StrCat("ply\nformat binary_little_endian 1.0\ncomment written by tandem\n",
                          "comment ", FrameTag(space), "\n",
                          "element vertex ", vertices,
                          "\nproperty float x\nproperty float y\nproperty float z\n",
                          normals ? "property float nx\nproperty float ny\nproperty float nz\n" : "",
                          "element face ", triangles,
                          "\nproperty list uchar int vertex_indices\nend_header\n"));
}

void AppendPlyFace(BufferedWriter& out, const uint32_t* tri) {
  const char count = 3;
  out.Append(&count, 1);
  for (int k = 0; k < 3; ++k) out.AppendLe32(tri[k]);
}

void WritePly(const IndexedMesh& mesh, const std::vector<Vec3>& normals, Space space,
              BufferedWriter& out) {
  AppendPlyHeader(out, mesh.num_vertices(), mesh.num_triangles(), !normals.empty(), space);
  for (size_t v = 0; v < mesh.positions.size(); ++v) {
    AppendVec3(out, mesh.positions[v]);
    if (!normals.empty()) AppendVec3(out, normals[v]);
  }
  for (size_t t = 0; t < mesh.num_triangles(); ++t) AppendPlyFace(out, &mesh.indices[3 * t]);
}

namespace {

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

std::optional<PlyType> ParsePlyType(absl::string_view name) {
  if (name == "char" || name == "int8") return PlyType::kInt8;
  if (name == "uchar" || name == "uint8") return PlyType::kUint8;
  if (name == "short" || name == "int16") return PlyType::kInt16;
  if (name == "ushort" || name == "uint16") return PlyType::kUint16;
  if (name == "int" || name == "int32") return PlyType::kInt32;
  if (name == "uint" || name == "uint32") return PlyType::kUint32;
  if (name == "float" || name == "float32") return PlyType::kFloat32;
  if (name == "double" || name == "float64") return PlyType::kFloat64;
  return std::nullopt;
}

size_t PlyTypeSize(PlyType t) {
  switch (t) {
    case PlyType::kInt8:
    case PlyType::kUint8:
      return 1;
    case PlyType::kInt16:
    case PlyType::kUint16:
      return 2;
    case PlyType::kInt32:
    case PlyType::kUint32:
    case PlyType::kFloat32:
      return 4;
    case PlyType::kFloat64:
      return 8;
  }
  return 0;
}

struct PlyProperty {
  std::string name;
  bool is_list = false;
  PlyType count_type = PlyType::kUint8;  // lists only
  PlyType type = PlyType::kFloat32;      // the value (or list item) type
};

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  std::vector<PlyProperty> properties;
};

enum class PlyEncoding { kAscii, kBinaryLittle, kBinaryBig };

struct PlyHeader {
  PlyEncoding encoding = PlyEncoding::kAscii;
  std::vector<PlyElement> elements;
  size_t body_offset = 0;  // first byte after the "end_header" line
};

absl::StatusOr<PlyHeader> ParsePlyHeader(const std::string& path, absl::string_view data) {
  auto bad = [&](size_t line_no, absl::string_view why) {
    return Error(absl::StatusCode::kInvalidArgument, path,
                 absl::StrCat("bad PLY header, line ", line_no, ": ", why));
  };
  PlyHeader header;
  bool have_format = false;
  size_t pos = 0;
  for (size_t line_no = 1;; ++line_no) {
    const size_t eol = data.find('\n', pos);
    if (eol == absl::string_view::npos) {
      if (line_no == 1) break;  // reported below as a missing magic line
      return Error(absl::StatusCode::kInvalidArgument, path,
                   "bad PLY header: no 'end_header' line");
    }
    absl::string_view line = data.substr(pos, eol - pos);
    pos = eol + 1;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (line_no == 1) {
      if (line != "ply") break;
      continue;
    }
    const std::vector<absl::string_view> tok =
        absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (tok.empty()) continue;
    const absl::string_view key = tok[0];
    if (key == "comment" || key == "obj_info") continue;
    if (key == "end_header") {
      if (!have_format) return bad(line_no, "no 'format' line");
      header.body_offset = pos;
      return header;
    }
    if (key == "format") {
      if (tok.size() != 3 || tok[2] != "1.0")
        return bad(line_no, "expected 'format <encoding> 1.0'");
      if (tok[1] == "ascii") {
        header.encoding = PlyEncoding::kAscii;
      } else if (tok[1] == "binary_little_endian") {
        header.encoding = PlyEncoding::kBinaryLittle;
      } else if (tok[1] == "binary_big_endian") {
        header.encoding = PlyEncoding::kBinaryBig;
      } else {
        return bad(line_no, absl::StrCat("unknown format '", tok[1], "'"));
      }
      have_format = true;
    } else if (key == "element") {
      PlyElement element;
      if (tok.size() != 3 || !ParseNumber(tok[2], element.count)) {
        return bad(line_no, "expected 'element <name> <count>'");
      }
      element.name = std::string(tok[1]);
      header.elements.push_back(std::move(element));
    } else if (key == "property") {
      if (header.elements.empty()) return bad(line_no, "property before any element");
      PlyProperty prop;
      std::optional<PlyType> type, count_type;
      if (tok.size() == 5 && tok[1] == "list") {
        count_type = ParsePlyType(tok[2]);
        type = ParsePlyType(tok[3]);
        if (!count_type || !type) return bad(line_no, "unknown list type");
        if (*count_type == PlyType::kFloat32 || *count_type == PlyType::kFloat64) {
          return bad(line_no, "list count must have an integer type");
        }
        prop.is_list = true;
        prop.count_type = *count_type;
        prop.type = *type;
        prop.name = std::string(tok[4]);
      } else if (tok.size() == 3) {
        type = ParsePlyType(tok[1]);
        if (!type) return bad(line_no, absl::StrCat("unknown property type '", tok[1], "'"));
        prop.type = *type;
        prop.name = std::string(tok[2]);
      } else {
        return bad(line_no, "expected 'property <type> <name>' or 'property list ...'");
      }
      header.elements.back().properties.push_back(std::move(prop));
    } else {
      return bad(line_no, absl::StrCat("unknown keyword '", key, "'"));
    }
  }
  return Error(absl::StatusCode::kInvalidArgument, path,
               "not a PLY file (the first line is not 'ply')");
}

// Reads scalars from a binary body, in either byte order.
class PlyBinaryCursor {
 public:
  PlyBinaryCursor(absl::string_view data, bool big_endian) : data_(data), big_(big_endian) {}

  // False when fewer than the value's bytes are left.
  bool Read(PlyType type, double& value) {
    const size_t n = PlyTypeSize(type);
    if (data_.size() - pos_ < n) return false;
    const auto* p = reinterpret_cast<const unsigned char*>(data_.data() + pos_);
    pos_ += n;
    uint64_t bits = 0;
    for (size_t i = 0; i < n; ++i) bits |= uint64_t{p[big_ ? n - 1 - i : i]} << (8 * i);
    switch (type) {
      case PlyType::kInt8:
        value = static_cast<int8_t>(bits);
        break;
      case PlyType::kUint8:
        value = static_cast<uint8_t>(bits);
        break;
      case PlyType::kInt16:
        value = static_cast<int16_t>(bits);
        break;
      case PlyType::kUint16:
        value = static_cast<uint16_t>(bits);
        break;
      case PlyType::kInt32:
        value = static_cast<int32_t>(bits);
        break;
      case PlyType::kUint32:
        value = static_cast<uint32_t>(bits);
        break;
      case PlyType::kFloat32:
        value = std::bit_cast<float>(static_cast<uint32_t>(bits));
        break;
      case PlyType::kFloat64:
        value = std::bit_cast<double>(bits);
        break;
    }
    return true;
  }
  std::string Where() const { return absl::StrCat("byte ", pos_); }
  bool bad_number() const { return false; }  // every bit pattern is a number
  absl::string_view token() const { return {}; }

 private:
  absl::string_view data_;
  bool big_;
  size_t pos_ = 0;
};

// Reads whitespace-separated numbers from an ASCII body, tracking the line for messages.
class PlyAsciiCursor {
 public:
  PlyAsciiCursor(absl::string_view data, size_t first_line) : data_(data), line_(first_line) {}

  // False at the end of the data, or (with bad_number() set) on a malformed number.
  bool Read(PlyType, double& value) {
    while (pos_ < data_.size() && IsSpace(data_[pos_])) {
      if (data_[pos_] == '\n') ++line_;
      ++pos_;
    }
    if (pos_ == data_.size()) return false;
    const size_t start = pos_;
    while (pos_ < data_.size() && !IsSpace(data_[pos_])) ++pos_;
    token_ = data_.substr(start, pos_ - start);
    if (!ParseNumber(token_, value)) {
      bad_number_ = true;
      return false;
    }
    return true;
  }
  std::string Where() const { return absl::StrCat("line ", line_); }
  bool bad_number() const { return bad_number_; }
  absl::string_view token() const { return token_; }

 private:
  absl::string_view data_;
  size_t line_;
  size_t pos_ = 0;
  absl::string_view token_;
  bool bad_number_ = false;
};

// Upper bound of a polygon's corner count: guards against a garbage count reserving memory.
constexpr double kMaxPolygonCorners = 1 << 16;

template <typename Cursor>
absl::StatusOr<IndexedMesh> ReadPlyBody(const std::string& path, const PlyHeader& header,
                                        Cursor& in) {
  IndexedMesh mesh;
  // Corners as read. Indices that no mesh could hold fail at once; the check against the
  // vertex count waits until every element is read (a face element may come first).
  std::vector<uint32_t> face_indices;
  std::vector<uint32_t> face_sizes;
  bool have_vertices = false;
  for (const PlyElement& element : header.elements) {
    auto fail = [&](uint64_t instance) -> absl::Status {
      if (in.bad_number()) {
        return Error(absl::StatusCode::kInvalidArgument, path,
                     absl::StrCat("bad number '", in.token(), "' in element '", element.name, "' ",
                                  instance, " (", in.Where(), ")"));
      }
      return Error(absl::StatusCode::kDataLoss, path,
                   absl::StrCat("truncated: the data ends in element '", element.name, "' ",
                                instance, " of ", element.count));
    };
    const bool is_vertex = element.name == "vertex";
    const bool is_face = element.name == "face";
    std::vector<int> axis_of(element.properties.size(), -1);  // 0..2 for x, y, z
    int index_list = -1;
    int axes_found = 0;  // bit k set when axis k has a property
    for (size_t p = 0; p < element.properties.size(); ++p) {
      const PlyProperty& prop = element.properties[p];
      if (is_vertex && !prop.is_list) {
        if (prop.name == "x") axis_of[p] = 0;
        if (prop.name == "y") axis_of[p] = 1;
        if (prop.name == "z") axis_of[p] = 2;
        if (axis_of[p] >= 0) axes_found |= 1 << axis_of[p];
      }
      if (is_face && prop.is_list && index_list < 0 &&
          (prop.name == "vertex_indices" || prop.name == "vertex_index")) {
        index_list = static_cast<int>(p);
      }
    }
    if (is_vertex) {
      if (have_vertices) {
        return Error(absl::StatusCode::kInvalidArgument, path, "two 'vertex' elements");
      }
      if (axes_found != 7) {
        return Error(absl::StatusCode::kInvalidArgument, path,
                     "bad PLY header: the vertex element lacks scalar x, y and z properties");
      }
      have_vertices = true;
      // Bounded reserve: a garbage count must fail as truncated, not exhaust memory.
      mesh.positions.reserve(std::min<uint64_t>(element.count, 1u << 24));
    }
    if (is_face && index_list < 0) {
      return Error(absl::StatusCode::kInvalidArgument, path,
                   "bad PLY header: the face element has no 'vertex_indices' list");
    }
    if (is_face) {
      face_sizes.reserve(std::min<uint64_t>(element.count, 1u << 24));
      face_indices.reserve(3 * face_sizes.capacity());
    }

    // An element without properties has no bytes; skipping it also stops a garbage count
    // from spinning through an empty loop.
    if (element.properties.empty()) continue;
    for (uint64_t i = 0; i < element.count; ++i) {
      Vec3 position;
      for (size_t p = 0; p < element.properties.size(); ++p) {
        const PlyProperty& prop = element.properties[p];
        double value = 0;
        if (!prop.is_list) {
          if (!in.Read(prop.type, value)) return fail(i);
          if (axis_of[p] >= 0) position[axis_of[p]] = value;
          continue;
        }
        double count = 0;
        if (!in.Read(prop.count_type, count)) return fail(i);
        if (!(count >= 0 && count <= kMaxPolygonCorners) || count != std::floor(count)) {
          return Error(
              absl::StatusCode::kInvalidArgument, path,
              absl::StrCat("bad list length ", count, " in element '", element.name, "' ", i));
        }
        const bool keep = static_cast<int>(p) == index_list;
        for (uint32_t k = 0; k < static_cast<uint32_t>(count); ++k) {
          if (!in.Read(prop.type, value)) return fail(i);
          if (!keep) continue;
          if (!(value >= 0 && value < double{kInvalid}) || value != std::floor(value)) {
            return Error(absl::StatusCode::kInvalidArgument, path,
                         absl::StrCat("face ", i, ": invalid vertex index ", value));
          }
          face_indices.push_back(static_cast<uint32_t>(value));
        }
        if (keep) face_sizes.push_back(static_cast<uint32_t>(count));
      }
      if (is_vertex) mesh.positions.push_back(position);
    }
  }
  if (!have_vertices) {
    return Error(absl::StatusCode::kInvalidArgument, path, "bad PLY header: no 'vertex' element");
  }
  // Bytes after the declared elements are ignored (some writers pad): the mesh is complete.

  // Fan-triangulate and validate indices.
  size_t next = 0;
  for (size_t f = 0; f < face_sizes.size(); ++f) {
    const uint32_t n = face_sizes[f];
    for (uint32_t k = 0; k < n; ++k) {
      const uint32_t v = face_indices[next + k];
      if (v >= mesh.positions.size()) {
        return Error(absl::StatusCode::kInvalidArgument, path,
                     absl::StrCat("face ", f, ": vertex index ", v, " out of range (",
                                  mesh.positions.size(), " vertices)"));
      }
    }
    for (uint32_t k = 1; k + 1 < n; ++k) {
      mesh.indices.push_back(face_indices[next]);
      mesh.indices.push_back(face_indices[next + k]);
      mesh.indices.push_back(face_indices[next + k + 1]);
    }
    next += n;
  }
  return mesh;
}

}  // namespace

absl::StatusOr<IndexedMesh> ReadPly(const std::string& path, absl::string_view data) {
  TANDEM_ASSIGN_OR_RETURN(PlyHeader header, ParsePlyHeader(path, data));
  const absl::string_view body = data.substr(header.body_offset);
  if (header.encoding == PlyEncoding::kAscii) {
    const size_t header_lines =
        static_cast<size_t>(std::count(data.begin(), data.begin() + header.body_offset, '\n'));
    PlyAsciiCursor in(body, header_lines + 1);
    return ReadPlyBody(path, header, in);
  }
  PlyBinaryCursor in(body, header.encoding == PlyEncoding::kBinaryBig);
  return ReadPlyBody(path, header, in);
}

}  // namespace tandem::io::internal::meshio
