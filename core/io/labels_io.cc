// Label names (CSV, 3D Slicer colour tables) and the per-label outputs: one mesh file per
// label and one GLB with a node per label (tandem/io/labels_io.h).
#include "tandem/io/labels_io.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>

#include "absl/functional/function_ref.h"
#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "mesh_io_internal.h"
#include "nlohmann/json.hpp"
#include "tandem/status_macros.h"

namespace tandem::io {
namespace {

using internal::meshio::AppendGlbBinHeader;
using internal::meshio::AppendGlbHeader;
using internal::meshio::AppendVec3;
using internal::meshio::BufferedWriter;

// Fields of one CSV line (RFC 4180 quoting: "a, b" is one field, "" a quote in it).
std::vector<std::string> CsvFields(absl::string_view line) {
  std::vector<std::string> fields(1);
  bool quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        fields.back().push_back('"');
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        fields.back().push_back(c);
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      fields.emplace_back();
    } else {
      fields.back().push_back(c);
    }
  }
  for (std::string& f : fields) f = std::string(absl::StripAsciiWhitespace(f));
  return fields;
}

bool ParseId(absl::string_view text, LabelId* id) {
  return !text.empty() && absl::ascii_isdigit(static_cast<unsigned char>(text[0])) &&
         absl::SimpleAtoi(text, id);
}

// Reads the line's colour from fields[first..first+3) (alpha from first+3 if present).
absl::Status ParseColor(const std::vector<std::string>& fields, size_t first, LabelName* out,
                        const std::string& where) {
  for (size_t c = 0; c < 4 && first + c < fields.size(); ++c) {
    int v = 0;
    if (!absl::SimpleAtoi(fields[first + c], &v) || v < 0 || v > 255) {
      return absl::InvalidArgumentError(absl::StrCat(
          where, ": colour component '", fields[first + c], "' is not a whole number in 0..255"));
    }
    out->rgba[c] = static_cast<uint8_t>(v);
  }
  out->has_color = true;
  return absl::OkStatus();
}

// The label's name in the table, else its id.
std::string DisplayName(LabelId id, const LabelNames* names) {
  if (names != nullptr) {
    if (auto it = names->find(id); it != names->end()) return it->second.name;
  }
  return absl::StrCat(id);
}

}  // namespace

absl::StatusOr<LabelNames> ReadLabelNames(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::NotFoundError(
        absl::StrCat(path, ": cannot open the label names: ", std::strerror(errno)));
  }
  const std::string ext = absl::AsciiStrToLower(std::filesystem::path(path).extension().string());
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  if (in.bad()) return absl::DataLossError(absl::StrCat(path, ": read error"));
  // CSV by name, or when the first line that is not a comment holds a comma.
  bool csv = ext == ".csv";
  if (ext != ".csv" && ext != ".ctbl" && ext != ".txt") {
    for (const std::string& line : lines) {
      const absl::string_view s = absl::StripAsciiWhitespace(line);
      if (s.empty() || s[0] == '#') continue;
      csv = absl::StrContains(s, ',');
      break;
    }
  }
  LabelNames names;
  std::map<LabelId, size_t> line_of;
  // CSV columns (a header may name them: Slicer's LabelValue, Name, Color_R ...).
  size_t id_col = 0, name_col = 1, color_col = 2;
  bool colors_by_header = false, first_data = true;
  for (size_t n = 0; n < lines.size(); ++n) {
    const std::string where = absl::StrCat(path, ":", n + 1);
    absl::string_view s = absl::StripAsciiWhitespace(lines[n]);
    if (n == 0) absl::ConsumePrefix(&s, "\xEF\xBB\xBF");  // a UTF-8 byte-order mark
    if (s.empty() || (!csv && s[0] == '#')) continue;
    std::vector<std::string> fields;
    if (csv) {
      fields = CsvFields(s);
    } else {
      for (absl::string_view f : absl::StrSplit(s, absl::ByAnyChar(" \t"), absl::SkipEmpty())) {
        fields.emplace_back(f);
      }
    }
    LabelId id = 0;
    if (csv && first_data && !ParseId(fields[0], &id)) {  // a header
      first_data = false;
      for (size_t c = 0; c < fields.size(); ++c) {
        const std::string h = absl::AsciiStrToLower(fields[c]);
        if (h == "labelvalue" || h == "id" || h == "label" || h == "value") id_col = c;
        if (h == "name" || h == "labelname") name_col = c;
        if (h == "color_r") {
          color_col = c;
          colors_by_header = true;
        }
      }
      continue;
    }
    first_data = false;
    if (fields.size() <= std::max(id_col, name_col) || fields[name_col].empty()) {
      return absl::InvalidArgumentError(absl::StrCat(
          where, ": expected ", csv ? "\"id,name\"" : "\"id name r g b a\"", ", got \"", s, "\""));
    }
    if (!ParseId(fields[id_col], &id)) {
      return absl::InvalidArgumentError(absl::StrCat(
          where, ": '", fields[id_col], "' is not a label id (a whole number in [0, 2^64))"));
    }
    LabelName entry;
    entry.name = fields[name_col];
    // Slicer tables: r g b a after the name; a CSV: with a header naming them, or 3-4
    // numbers after id,name.
    const bool colors =
        csv ? (colors_by_header ? fields.size() >= color_col + 3
                                : fields.size() >= 5 && id_col == 0 && name_col == 1)
            : fields.size() >= 5;
    if (!csv && fields.size() > 2 && fields.size() < 5) {
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": expected \"id name r g b a\", got \"", s, "\""));
    }
    if (colors) {
      if (absl::Status st = ParseColor(fields, csv ? color_col : 2, &entry, where); !st.ok()) {
        return st;
      }
    }
    if (auto [at, fresh] = line_of.emplace(id, n + 1); !fresh) {
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": label ", id, " is named already (line ", at->second, ")"));
    }
    names.emplace(id, std::move(entry));
  }
  return names;
}

std::string LabelFileStem(LabelId id, const LabelNames* names) {
  std::string stem;
  if (names != nullptr) {
    if (auto it = names->find(id); it != names->end()) {
      for (char c : it->second.name) {
        const bool keep =
            absl::ascii_isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '_';
        if (keep) {
          stem.push_back(c);
        } else if (stem.empty() || stem.back() != '_') {
          stem.push_back('_');
        }
        if (stem.size() >= 80) break;
      }
      while (!stem.empty() && stem.front() == '.') stem.erase(stem.begin());
      while (!stem.empty() && stem.back() == '.') stem.pop_back();  // Windows drops them
      if (std::none_of(stem.begin(), stem.end(),
                       [](char c) { return absl::ascii_isalnum(static_cast<unsigned char>(c)); })) {
        stem.clear();
      }
    }
  }
  return stem.empty() ? absl::StrCat(id) : stem;
}

std::array<uint8_t, 4> LabelColor(LabelId id, size_t order, const LabelNames* names) {
  if (names != nullptr) {
    if (auto it = names->find(id); it != names->end() && it->second.has_color) {
      return it->second.rgba;
    }
  }
  // HSV (h, 0.6, 0.9): the golden angle apart, so no two of the first labels look alike.
  const double h = std::fmod(static_cast<double>(order) * 0.6180339887498949, 1.0) * 6.0;
  const double v = 0.9, s = 0.6, c = v * s, x = c * (1 - std::abs(std::fmod(h, 2.0) - 1)),
               m = v - c;
  double r = 0, g = 0, b = 0;
  switch (static_cast<int>(h)) {
    case 0:
      r = c, g = x;
      break;
    case 1:
      r = x, g = c;
      break;
    case 2:
      g = c, b = x;
      break;
    case 3:
      g = x, b = c;
      break;
    case 4:
      r = x, b = c;
      break;
    default:
      r = c, b = x;
      break;
  }
  auto byte = [m](double u) { return static_cast<uint8_t>(std::lround((u + m) * 255.0)); };
  return {byte(r), byte(g), byte(b), 255};
}

absl::StatusOr<std::vector<LabelFile>> WriteLabelMeshes(
    const std::string& dir, const std::string& extension,
    const std::vector<std::pair<LabelId, IndexedMesh>>& surfaces, const LabelNames* names,
    const MeshWriteOptions& options) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::UnavailableError(absl::StrCat(dir, ": cannot create: ", ec.message()));
  const std::filesystem::path folder(dir);
  // Case-insensitive, as macOS and Windows file systems compare names.
  std::set<std::string> taken = {"labels"};
  std::vector<LabelFile> files;
  for (const auto& [id, mesh] : surfaces) {
    std::string stem = LabelFileStem(id, names);
    if (!taken.insert(absl::AsciiStrToLower(stem)).second) {
      stem = absl::StrCat(stem, "_", id);
      for (int k = 2; !taken.insert(absl::AsciiStrToLower(stem)).second; ++k) {
        stem = absl::StrCat(LabelFileStem(id, names), "_", id, "_", k);
      }
    }
    LabelFile f;
    f.id = id;
    f.path = (folder / (stem + extension)).string();
    f.name = DisplayName(id, names);
    TANDEM_RETURN_IF_ERROR(WriteMesh(f.path, mesh, options));
    files.push_back(std::move(f));
  }
  if (absl::Status st =
          WriteLabelsGlb((folder / "labels.glb").string(), surfaces, names, options.space);
      !st.ok()) {
    return st;
  }
  return files;
}

namespace {

using Json = nlohmann::json;

bool HasMesh(const IndexedMesh& mesh) { return mesh.num_vertices() > 0 && !mesh.indices.empty(); }
// A surface's part of the binary payload: positions, normals, indices.
size_t PayloadBytes(const IndexedMesh& mesh) {
  return HasMesh(mesh) ? 24 * mesh.num_vertices() + 4 * mesh.indices.size() : 0;
}

// labels.glb's JSON document, emitted a part at a time into `out`, each part dumped as it
// is inside the whole document (compact, keys sorted): as one tree, a million labels' JSON
// held gigabytes. Returns the binary payload's bytes.
size_t EmitLabelsGltf(const std::vector<std::pair<LabelId, IndexedMesh>>& surfaces,
                      const LabelNames* names, Space space,
                      absl::FunctionRef<void(absl::string_view)> out) {
  const auto dump = [&](const Json& j) {
    out(j.dump(-1, ' ', false, Json::error_handler_t::replace));
  };
  // part(order, m, byte) per surface with a mesh: m counts those before it, byte their payload.
  const auto each_mesh = [&](auto&& part) {
    size_t m = 0, byte = 0;
    for (size_t order = 0; order < surfaces.size(); ++order) {
      const IndexedMesh& mesh = surfaces[order].second;
      if (!HasMesh(mesh)) continue;
      part(order, m, byte);
      ++m;
      byte += PayloadBytes(mesh);
    }
    return byte;
  };
  const auto array = [&](absl::string_view key, auto&& items) {
    out(absl::StrCat("\"", key, "\":["));
    bool first = true;
    items([&](const Json& item) {
      if (!first) out(",");
      first = false;
      dump(item);
    });
    out("]");
  };
  const size_t bytes = each_mesh([](size_t, size_t, size_t) {});
  out("{");
  if (bytes > 0) {  // glTF forbids empty arrays and buffers
    array("accessors", [&](auto item) {
      each_mesh([&](size_t order, size_t m, size_t) {
        const IndexedMesh& mesh = surfaces[order].second;
        const size_t nv = mesh.num_vertices();
        std::array<double, 3> lo{}, hi{};
        for (size_t v = 0; v < nv; ++v) {
          for (int k = 0; k < 3; ++k) {
            const double x = static_cast<float>(mesh.positions[v][k]);  // as stored
            lo[k] = v == 0 ? x : std::min(lo[k], x);
            hi[k] = v == 0 ? x : std::max(hi[k], x);
          }
        }
        item({{"bufferView", 3 * m},
              {"componentType", 5126},
              {"count", nv},
              {"type", "VEC3"},
              {"min", lo},
              {"max", hi}});
        item({{"bufferView", 3 * m + 1}, {"componentType", 5126}, {"count", nv}, {"type", "VEC3"}});
        item({{"bufferView", 3 * m + 2},
              {"componentType", 5125},
              {"count", mesh.indices.size()},
              {"type", "SCALAR"}});
      });
    });
    out(",");
  }
  out("\"asset\":");
  dump({{"version", "2.0"},
        {"generator", "tandem"},
        {"extras", {{"frame", std::string(SpaceName(space))}}}});
  if (bytes > 0) {
    out(",");
    array("bufferViews", [&](auto item) {
      each_mesh([&](size_t order, size_t, size_t byte) {
        const IndexedMesh& mesh = surfaces[order].second;
        const size_t nv = mesh.num_vertices();
        item({{"buffer", 0}, {"byteOffset", byte}, {"byteLength", 12 * nv}, {"target", 34962}});
        item({{"buffer", 0},
              {"byteOffset", byte + 12 * nv},
              {"byteLength", 12 * nv},
              {"target", 34962}});
        item({{"buffer", 0},
              {"byteOffset", byte + 24 * nv},
              {"byteLength", 4 * mesh.indices.size()},
              {"target", 34963}});
      });
    });
    out(",\"buffers\":[");
    dump({{"byteLength", bytes}});
    out("],");
    array("materials", [&](auto item) {
      each_mesh([&](size_t order, size_t, size_t) {
        const LabelId id = surfaces[order].first;
        const std::array<uint8_t, 4> rgba = LabelColor(id, order, names);
        // glTF's baseColorFactor is linear; the tables' colours are sRGB.
        auto linear = [](uint8_t c) {
          const double u = c / 255.0;
          return u <= 0.04045 ? u / 12.92 : std::pow((u + 0.055) / 1.055, 2.4);
        };
        Json material = {{"name", DisplayName(id, names)},
                         {"pbrMetallicRoughness",
                          {{"baseColorFactor",
                            {linear(rgba[0]), linear(rgba[1]), linear(rgba[2]), rgba[3] / 255.0}},
                           {"metallicFactor", 0.0},
                           {"roughnessFactor", 0.8}}},
                         {"doubleSided", true}};
        if (rgba[3] < 255) material["alphaMode"] = "BLEND";
        item(material);
      });
    });
    out(",");
    array("meshes", [&](auto item) {
      each_mesh([&](size_t order, size_t m, size_t) {
        item({{"name", DisplayName(surfaces[order].first, names)},
              {"primitives",
               {{{"attributes", {{"POSITION", 3 * m}, {"NORMAL", 3 * m + 1}}},
                 {"indices", 3 * m + 2},
                 {"material", m},
                 {"mode", 4}}}}});
      });
    });
  }
  out(",");
  array("nodes", [&](auto item) {
    size_t m = 0;
    for (const auto& [id, mesh] : surfaces) {
      Json node = {{"name", DisplayName(id, names)}, {"extras", {{"label", absl::StrCat(id)}}}};
      if (HasMesh(mesh)) node["mesh"] = m++;
      item(node);
    }
  });
  out(",\"scene\":0,\"scenes\":[{\"nodes\":[");
  for (size_t i = 0; i < surfaces.size(); ++i) out(absl::StrCat(i == 0 ? "" : ",", i));
  out("]}]}");
  return bytes;
}

}  // namespace

absl::Status WriteLabelsGlb(const std::string& path,
                            const std::vector<std::pair<LabelId, IndexedMesh>>& surfaces,
                            const LabelNames* names, Space space) {
  for (const auto& [id, mesh] : surfaces) {
    for (uint32_t i : mesh.indices) {
      if (i >= mesh.num_vertices()) {
        return absl::InvalidArgumentError(absl::StrCat(path, ": label ", id, ": vertex index ", i,
                                                       " out of range (", mesh.num_vertices(),
                                                       " vertices)"));
      }
    }
  }
  // The JSON twice, counted and then written, rather than held.
  size_t json_bytes = 0;
  const size_t bin_bytes = EmitLabelsGltf(surfaces, names, space,
                                          [&](absl::string_view s) { json_bytes += s.size(); });
  if (12 + 8 + json_bytes + 3 + 8 + bin_bytes > UINT32_MAX) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": the surfaces need ", bin_bytes, " bytes, past GLB's 4 GiB"));
  }
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) {
    return absl::UnavailableError(
        absl::StrCat(path, ": cannot open for writing: ", std::strerror(errno)));
  }
  BufferedWriter out(file);
  const size_t padding = (4 - json_bytes % 4) % 4;  // every part a multiple of 4 bytes
  AppendGlbHeader(out, json_bytes + padding, bin_bytes);
  EmitLabelsGltf(surfaces, names, space, [&](absl::string_view s) { out.Append(s); });
  out.Append("   ", padding);
  AppendGlbBinHeader(out, bin_bytes);
  for (const auto& [id, mesh] : surfaces) {
    if (!HasMesh(mesh)) continue;
    for (const Vec3& p : mesh.positions) AppendVec3(out, p);
    for (const Vec3& n : VertexNormals(mesh)) AppendVec3(out, Dot(n, n) > 0 ? n : Vec3{0, 0, 1});
    for (uint32_t i : mesh.indices) out.AppendLe32(i);
  }
  if (const int err = out.Close(); err != 0) {
    return absl::UnavailableError(absl::StrCat(path, ": write failed: ", std::strerror(err)));
  }
  return absl::OkStatus();
}

}  // namespace tandem::io
