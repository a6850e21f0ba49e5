// PLY and OBJ mesh I/O. See tandem/mesh_io.h for the contracts.
//
// Reading loads the whole file (meshes of millions of triangles are tens of MB) and parses
// it in place with std::from_chars (locale-independent, no allocation per number); writing
// streams through one fixed buffer.
#include "tandem/mesh_io.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <optional>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "nlohmann/json.hpp"
#include "tandem/metrics.h"

namespace tandem {
namespace {

absl::Status Error(absl::StatusCode code, const std::string& path, absl::string_view what) {
  return absl::Status(code, absl::StrCat(path, ": ", what));
}

enum class Format { kPly, kObj, kStl, kGlb };

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

// ---------------------------------------------------------------------------------------
// Writing

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

void AppendVec3(BufferedWriter& out, const Vec3& v) {
  for (int k = 0; k < 3; ++k) out.AppendLe32(std::bit_cast<uint32_t>(static_cast<float>(v[k])));
}

// The frame of the positions as 3D Slicer looks for it in a model file's header ("SPACE=RAS"
// or "SPACE=LPS" anywhere in a PLY comment, OBJ's first comment or binary STL's header; LPS
// assumed without it); the frames Slicer does not know are named without "SPACE=".
std::string FrameTag(Space space) {
  if (space == Space::kLPS || space == Space::kRAS) {
    return absl::StrCat("SPACE=", SpaceName(space));
  }
  return absl::StrCat("frame ", SpaceName(space), " (not a patient frame)");
}

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

// "tag x y z\n", each coordinate rounded to float32 first, like the PLY output: both formats
// store the same values.
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

// GLB (binary glTF 2.0): one mesh, one triangle primitive with POSITION, NORMAL (unit
// length, as glTF requires: a vertex whose triangles have no area gets +z) and 32-bit
// indices, in one buffer. glTF's unit is the metre; positions keep the mesh's units.
// With `draco`, the primitive is that Draco buffer (KHR_draco_mesh_compression): the
// accessors say what it decodes to and have no buffer view of their own.
void WriteGlb(const IndexedMesh& mesh, const std::vector<Vec3>& normals,
              const GlbDracoPrimitive* draco, Space space, BufferedWriter& out) {
  const size_t nv = draco ? draco->vertices : mesh.num_vertices();
  const size_t ni = draco ? draco->indices : mesh.indices.size();
  std::array<double, 3> lo{0, 0, 0}, hi{0, 0, 0};
  for (size_t v = 0; v < nv; ++v) {
    for (int k = 0; k < 3; ++k) {
      const double x = static_cast<float>(mesh.positions[v][k]);  // the stored value
      lo[k] = v == 0 ? x : std::min(lo[k], x);
      hi[k] = v == 0 ? x : std::max(hi[k], x);
    }
  }
  const size_t pos_bytes = 12 * nv, nrm_bytes = 12 * nv, idx_bytes = 4 * ni;
  const size_t bin_bytes = pos_bytes + nrm_bytes + idx_bytes;  // multiples of 4 already
  nlohmann::json j;
  // glTF's own frame (metres, +y up) is not the volume's: positions stay in the volume's
  // frame and units, named here for programs that care.
  j["asset"] = {{"version", "2.0"},
                {"generator", "tandem"},
                {"extras", {{"frame", std::string(SpaceName(space))}}}};
  j["scene"] = 0;
  j["scenes"] = nlohmann::json::array({{{"nodes", {0}}}});
  j["nodes"] = nlohmann::json::array({{{"mesh", 0}}});
  nlohmann::json primitive = {{"attributes", {{"POSITION", 0}, {"NORMAL", 1}}}, {"mode", 4}};
  if (ni > 0) primitive["indices"] = 2;
  j["meshes"] = nlohmann::json::array({{{"primitives", {primitive}}}});
  j["buffers"] = nlohmann::json::array({{{"byteLength", bin_bytes}}});
  j["bufferViews"] = nlohmann::json::array(
      {{{"buffer", 0}, {"byteOffset", 0}, {"byteLength", pos_bytes}, {"target", 34962}},
       {{"buffer", 0}, {"byteOffset", pos_bytes}, {"byteLength", nrm_bytes}, {"target", 34962}},
       {{"buffer", 0},
        {"byteOffset", pos_bytes + nrm_bytes},
        {"byteLength", idx_bytes},
        {"target", 34963}}});
  nlohmann::json accessors = nlohmann::json::array(
      {{{"bufferView", 0}, {"componentType", 5126}, {"count", nv}, {"type", "VEC3"},
        {"min", lo}, {"max", hi}},
       {{"bufferView", 1}, {"componentType", 5126}, {"count", nv}, {"type", "VEC3"}}});
  if (ni > 0) {
    accessors.push_back({{"bufferView", 2}, {"componentType", 5125}, {"count", ni},
                         {"type", "SCALAR"}});
  }
  j["accessors"] = accessors;
  size_t draco_bytes = 0;
  if (draco != nullptr && nv > 0) {
    draco_bytes = draco->bytes.size();
    const size_t padded = (draco_bytes + 3) / 4 * 4;
    j["extensionsUsed"] = {"KHR_draco_mesh_compression"};
    j["extensionsRequired"] = {"KHR_draco_mesh_compression"};
    j["buffers"] = nlohmann::json::array({{{"byteLength", padded}}});
    j["bufferViews"] =
        nlohmann::json::array({{{"buffer", 0}, {"byteOffset", 0}, {"byteLength", draco_bytes}}});
    for (auto& a : j["accessors"]) a.erase("bufferView");
    j["accessors"][0]["min"] = draco->lo;
    j["accessors"][0]["max"] = draco->hi;
    j["meshes"][0]["primitives"][0]["extensions"] = {
        {"KHR_draco_mesh_compression",
         {{"bufferView", 0},
          {"attributes", {{"POSITION", draco->position_id}, {"NORMAL", draco->normal_id}}}}}};
  }
  if (nv == 0) {  // glTF forbids empty buffers and accessors: an empty scene instead
    j.erase("meshes");
    j.erase("buffers");
    j.erase("bufferViews");
    j.erase("accessors");
    j["nodes"] = nlohmann::json::array({nlohmann::json::object()});
  }
  std::string text = j.dump();
  text.append((4 - text.size() % 4) % 4, ' ');
  const size_t bin_payload = draco_bytes > 0 ? (draco_bytes + 3) / 4 * 4 : bin_bytes;
  const size_t bin_chunk = nv == 0 ? 0 : 8 + bin_payload;
  out.AppendLe32(0x46546C67u);  // "glTF"
  out.AppendLe32(2);
  out.AppendLe32(static_cast<uint32_t>(12 + 8 + text.size() + bin_chunk));
  out.AppendLe32(static_cast<uint32_t>(text.size()));
  out.AppendLe32(0x4E4F534Au);  // "JSON"
  out.Append(text);
  if (nv == 0) return;
  out.AppendLe32(static_cast<uint32_t>(bin_payload));
  out.AppendLe32(0x004E4942u);  // "BIN\0"
  if (draco_bytes > 0) {
    out.Append(draco->bytes);
    out.Append(std::string(bin_payload - draco_bytes, '\0'));
    return;
  }
  for (const Vec3& p : mesh.positions) AppendVec3(out, p);
  for (const Vec3& n : normals) AppendVec3(out, Dot(n, n) > 0 ? n : Vec3{0, 0, 1});
  for (uint32_t i : mesh.indices) out.AppendLe32(i);
}

// ---------------------------------------------------------------------------------------
// Reading: common helpers

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

// Parses a number in full; accepts a leading '+', which from_chars does not.
template <typename T>
bool ParseNumber(absl::string_view s, T& value) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  const auto res = std::from_chars(s.data(), s.data() + s.size(), value);
  return res.ec == std::errc() && res.ptr == s.data() + s.size();
}

bool IsSpace(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v';
}

// ---------------------------------------------------------------------------------------
// PLY

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

absl::StatusOr<IndexedMesh> ReadPly(const std::string& path, absl::string_view data) {
  absl::StatusOr<PlyHeader> header = ParsePlyHeader(path, data);
  if (!header.ok()) return header.status();
  const absl::string_view body = data.substr(header->body_offset);
  if (header->encoding == PlyEncoding::kAscii) {
    const size_t header_lines =
        static_cast<size_t>(std::count(data.begin(), data.begin() + header->body_offset, '\n'));
    PlyAsciiCursor in(body, header_lines + 1);
    return ReadPlyBody(path, *header, in);
  }
  PlyBinaryCursor in(body, header->encoding == PlyEncoding::kBinaryBig);
  return ReadPlyBody(path, *header, in);
}

// ---------------------------------------------------------------------------------------
// OBJ

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
  const absl::StatusOr<Format> format = FormatOf(path);
  if (!format.ok()) return format.status();
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
  const bool with_normals = *format == Format::kGlb || (options.normals && *format != Format::kStl);
  const std::vector<Vec3> normals = with_normals ? VertexNormals(mesh) : std::vector<Vec3>{};
  // The Draco primitive before the file is created: a failure leaves nothing behind.
  std::optional<GlbDracoPrimitive> draco;
  if (*format == Format::kGlb && options.glb_draco) {
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
  switch (*format) {
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

// ---------------------------------------------------------------------------------------
// ChunkedMeshWriter

bool ChunkedMeshWriter::Supports(const std::string& path) {
  const absl::StatusOr<Format> f = FormatOf(path);
  return f.ok() && (*f == Format::kPly || *f == Format::kObj);
}

absl::StatusOr<std::unique_ptr<ChunkedMeshWriter>> ChunkedMeshWriter::Open(
    const std::string& path, const MeshWriteOptions& options) {
  if (!Supports(path)) {
    return Error(absl::StatusCode::kInvalidArgument, path,
                 "sealed chunks are written as they come to .ply or .obj only");
  }
  std::FILE* verts = std::tmpfile();
  std::FILE* tris = std::tmpfile();
  if (verts == nullptr || tris == nullptr) {
    const int err = errno;
    if (verts != nullptr) std::fclose(verts);
    if (tris != nullptr) std::fclose(tris);
    return Error(absl::StatusCode::kUnavailable, path,
                 absl::StrCat("cannot create a scratch file: ", std::strerror(err)));
  }
  return std::unique_ptr<ChunkedMeshWriter>(new ChunkedMeshWriter(path, options, verts, tris));
}

ChunkedMeshWriter::~ChunkedMeshWriter() {
  std::fclose(verts_);
  std::fclose(tris_);
}

absl::Status ChunkedMeshWriter::Failed(const char* what) const {
  return Error(absl::StatusCode::kUnavailable, path_,
               absl::StrCat(what, ": ", std::strerror(errno != 0 ? errno : EIO)));
}

absl::Status ChunkedMeshWriter::Add(const SealedChunk& chunk) {
  const size_t nt = chunk.num_triangles();
  for (size_t t = 0; t < nt; ++t) {
    const uint32_t* tri = &chunk.indices[3 * t];
    const Vec3 w = TriangleAreaVector(chunk.positions[tri[0]], chunk.positions[tri[1]],
                                      chunk.positions[tri[2]]);
    uint32_t slot;
    if (free_.empty()) {
      slot = static_cast<uint32_t>(waiting_.size());
      waiting_.emplace_back();
    } else {
      slot = free_.back();
      free_.pop_back();
    }
    WaitingTriangle& waiting = waiting_[slot];
    waiting.place = triangles_ + static_cast<int64_t>(t);
    waiting.open = 3;
    for (int k = 0; k < 3; ++k) {
      const uint32_t id = chunk.ids[tri[k]];
      auto [it, fresh] = open_.try_emplace(id, OpenVertex{chunk.positions[tri[k]], Vec3{0, 0, 0}});
      it->second.normal = it->second.normal + w;
      waiting.corners[k] = id;
      waiting.next[k] = it->second.waiting;
      it->second.waiting = 3 * slot + static_cast<uint32_t>(k);
    }
  }
  triangles_ += static_cast<int64_t>(nt);
  done_.clear();
  for (uint32_t id : chunk.retired) {
    auto it = open_.find(id);
    if (it == open_.end()) continue;  // retired before any of its triangles: none it had
    const double len = Norm(it->second.normal);
    const Vec3 n = len > 0 ? it->second.normal * (1.0 / len) : Vec3{0, 0, 0};
    const float record[6] = {static_cast<float>(it->second.pos.x), static_cast<float>(it->second.pos.y),
                             static_cast<float>(it->second.pos.z), static_cast<float>(n.x),
                             static_cast<float>(n.y), static_cast<float>(n.z)};
    if (std::fwrite(record, sizeof record, 1, verts_) != 1) {
      return Failed("writing the scratch file of vertices");
    }
    const uint32_t index = static_cast<uint32_t>(vertices_++);
    for (uint32_t c = it->second.waiting; c != kNoCorner;) {
      WaitingTriangle& waiting = waiting_[c / 3];
      waiting.corners[c % 3] = index;
      const uint32_t next = waiting.next[c % 3];
      if (--waiting.open == 0) {
        done_.push_back(waiting);
        free_.push_back(c / 3);
      }
      c = next;
    }
    open_.erase(it);
  }
  // The triangles whose last vertex this chunk retired go to their places; those of one
  // chunk mostly follow each other there, written as runs.
  std::sort(done_.begin(), done_.end(),
            [](const WaitingTriangle& x, const WaitingTriangle& y) { return x.place < y.place; });
  for (size_t i = 0; i < done_.size();) {
    const int64_t place = done_[i].place;
    run_.clear();
    for (; i < done_.size() && done_[i].place == place + static_cast<int64_t>(run_.size() / 3); ++i) {
      run_.insert(run_.end(), done_[i].corners, done_[i].corners + 3);
    }
    if (place != tris_at_ &&
        std::fseek(tris_, static_cast<long>(place * 3 * sizeof(uint32_t)), SEEK_SET) != 0) {
      return Failed("writing the scratch file of triangles");
    }
    if (std::fwrite(run_.data(), sizeof(uint32_t), run_.size(), tris_) != run_.size()) {
      return Failed("writing the scratch file of triangles");
    }
    tris_at_ = place + static_cast<int64_t>(run_.size() / 3);
  }
  return absl::OkStatus();
}

size_t ChunkedMeshWriter::MemoryBytes() const {
  // A flat_hash_map slot holds its pair plus one control byte.
  return open_.capacity() * (sizeof(std::pair<const uint32_t, OpenVertex>) + 1) +
         (waiting_.capacity() + done_.capacity()) * sizeof(WaitingTriangle) +
         (free_.capacity() + run_.capacity()) * sizeof(uint32_t);
}

absl::Status ChunkedMeshWriter::Finish() {
  if (!open_.empty()) {
    return Error(absl::StatusCode::kInternal, path_,
                 absl::StrCat(open_.size(), " vertices were never retired: chunks are missing"));
  }
  const bool ply = *FormatOf(path_) == Format::kPly;
  std::FILE* file = std::fopen(path_.c_str(), "wb");
  if (file == nullptr) return Failed("cannot open for writing");
  BufferedWriter out(file);
  const size_t nv = static_cast<size_t>(vertices_), nt = static_cast<size_t>(triangles_);
  const bool normals = options_.normals;
  if (ply) {
    AppendPlyHeader(out, nv, nt, normals, options_.space);
  } else {
    AppendObjHeader(out, nv, nt, options_.space);
  }
  // Vertices: PLY one record each; OBJ the "v" lines, then the "vn" lines.
  std::vector<float> block(6 * 4096);
  for (int pass = 0; pass < (ply || !normals ? 1 : 2); ++pass) {
    std::rewind(verts_);
    for (size_t done = 0; done < nv;) {
      const size_t n = std::min<size_t>(4096, nv - done);
      if (std::fread(block.data(), 6 * sizeof(float), n, verts_) != n) {
        return Failed("reading back the scratch file of vertices");
      }
      for (size_t i = 0; i < n; ++i) {
        const float* r = &block[6 * i];
        const Vec3 p{r[0], r[1], r[2]}, q{r[3], r[4], r[5]};
        if (ply) {
          AppendVec3(out, p);
          if (normals) AppendVec3(out, q);
        } else {
          AppendObjVec3(out, pass == 0 ? "v" : "vn", pass == 0 ? p : q);
        }
      }
      done += n;
    }
  }
  std::rewind(tris_);
  std::vector<uint32_t> tris(3 * 4096);
  for (size_t done = 0; done < nt;) {
    const size_t n = std::min<size_t>(4096, nt - done);
    if (std::fread(tris.data(), 3 * sizeof(uint32_t), n, tris_) != n) {
      return Failed("reading back the scratch file of triangles");
    }
    for (size_t i = 0; i < n; ++i) {
      if (ply) {
        AppendPlyFace(out, &tris[3 * i]);
      } else {
        AppendObjFace(out, &tris[3 * i], normals);
      }
    }
    done += n;
  }
  if (const int err = out.Close(); err != 0) {
    return Error(absl::StatusCode::kUnavailable, path_,
                 absl::StrCat("write failed: ", std::strerror(err)));
  }
  return absl::OkStatus();
}

// Binary STL; corners with the same float32 position become one vertex, in order of first
// appearance, so a mesh written by WriteStl reads back with its vertex count.
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

absl::StatusOr<IndexedMesh> ReadMesh(const std::string& path) {
  const absl::StatusOr<Format> format = FormatOf(path);
  if (!format.ok()) return format.status();
  const absl::StatusOr<std::string> data = ReadWholeFile(path);
  if (!data.ok()) return data.status();
  switch (*format) {
    case Format::kPly: return ReadPly(path, *data);
    case Format::kObj: return ReadObj(path, *data);
    case Format::kStl: return ReadStl(path, *data);
    case Format::kGlb: break;
  }
  return Error(absl::StatusCode::kInvalidArgument, path,
               "reading .glb is not supported (tandem writes it for viewers; read .ply, .obj "
               "or .stl)");
}

}  // namespace tandem
