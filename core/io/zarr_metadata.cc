// Zarr metadata: one array's or group's .zarray, .zgroup and .zattrs (v2) or zarr.json (v3),
// parsed and checked into a Node (zarr_metadata.h).
#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"
#include "zarr_metadata.h"

namespace tandem::io::internal::zarr {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

constexpr uint64_t kMaxMetadataBytes = 16 << 20;
// nlohmann's dump and comparisons recurse: metadata nested deeper is refused unread.
constexpr int kMaxJsonDepth = 64;

}  // namespace

absl::Status MetaError(const std::string& file, absl::string_view what) {
  return absl::InvalidArgumentError(absl::StrCat(file, ": ", what));
}

namespace {

// The deepest nesting of arrays and objects in JSON text (strings skipped).
int JsonDepth(const std::string& text) {
  int depth = 0, deepest = 0;
  bool in_string = false, escaped = false;
  for (const char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      deepest = std::max(deepest, ++depth);
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
  return deepest;
}

absl::StatusOr<json> ReadJsonFile(const std::string& file) {
  std::string text;
  TANDEM_RETURN_IF_ERROR(zarr::ReadWholeFile(file, kMaxMetadataBytes, &text));
  if (JsonDepth(text) > kMaxJsonDepth) {
    return MetaError(file, absl::StrCat("JSON nested more than ", kMaxJsonDepth,
                                        " levels deep (Zarr metadata nests a few)"));
  }
  json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return MetaError(file, "invalid JSON");
  if (!j.is_object()) return MetaError(file, "expected a JSON object");
  return j;
}

// tandem's writer stores the volume's suggested iso-values in the array's attributes.
std::vector<double> SuggestedIsovalues(const json& attrs) {
  std::vector<double> out;
  if (!attrs.contains("suggested_isovalues") || !attrs["suggested_isovalues"].is_array())
    return out;
  for (const json& v : attrs["suggested_isovalues"]) {
    if (v.is_number() && std::isfinite(v.get<double>())) out.push_back(v.get<double>());
  }
  return out;
}

}  // namespace

bool FileExists(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

namespace {

absl::StatusOr<std::vector<int64_t>> IntList(const std::string& file, const json& v,
                                             const char* key) {
  if (!v.is_array()) return MetaError(file, absl::StrCat("'", key, "' must be a list of integers"));
  std::vector<int64_t> out;
  for (const json& e : v) {
    if (!e.is_number_integer()) {
      return MetaError(file, absl::StrCat("'", key, "' must be a list of integers"));
    }
    out.push_back(e.get<int64_t>());
  }
  return out;
}

// v2 "<u2" / ">f4" / "|u1" (numpy's typestr: byte order, kind, size); v3 "uint16" (byte
// order from the bytes codec).
absl::Status ParseV2DType(const std::string& file, const json& v, ArrayMeta* m) {
  const std::string s = v.is_string() ? v.get<std::string>() : v.dump();
  const auto bad = [&] {
    return MetaError(file, absl::StrCat("unsupported dtype '", s,
                                        "' (supported: |u1, |i1, <u2, <i2, <u4, <i4, <u8, "
                                        "<i8, <f4, or > for big-endian)"));
  };
  if (!v.is_string() || s.size() != 3) return bad();
  bool found = false;
  for (DType t : kAllDTypes) {
    const char kind = t == DType::kFloat32 ? 'f' : IsSignedDType(t) ? 'i' : 'u';
    if (s[1] == kind && s[2] == static_cast<char>('0' + DTypeSize(t))) {
      m->dtype = t;
      found = true;
    }
  }
  if (!found) return bad();
  if (s[0] == '>') {
    m->big_endian = true;
  } else if (s[0] == '<' || (s[0] == '|' && DTypeSize(m->dtype) == 1)) {
    m->big_endian = false;
  } else {
    return bad();
  }
  return absl::OkStatus();
}

// fill_value: null (0), a number, "NaN" / "Infinity" / "-Infinity", or (v3, float) a
// "0x7fc00000" bit pattern. Stored in the array's byte order.
absl::Status ParseFill(const std::string& file, const json& v, ArrayMeta* m) {
  double d = 0.0;
  bool have_bits = false;
  uint32_t bits = 0;
  if (v.is_null()) {
    d = 0.0;
  } else if (v.is_number()) {
    d = v.get<double>();
  } else if (v.is_string()) {
    const std::string s = v.get<std::string>();
    if (s == "NaN") {
      d = std::numeric_limits<double>::quiet_NaN();
    } else if (s == "Infinity") {
      d = std::numeric_limits<double>::infinity();
    } else if (s == "-Infinity") {
      d = -std::numeric_limits<double>::infinity();
    } else if (s.size() == 10 && s.starts_with("0x") && m->dtype == DType::kFloat32 &&
               absl::SimpleHexAtoi(s.substr(2), &bits)) {
      have_bits = true;
    } else {
      return MetaError(file, absl::StrCat("unsupported fill_value '", s, "'"));
    }
  } else {
    return MetaError(file, absl::StrCat("unsupported fill_value ", v.dump()));
  }
  const auto misfit = [&] {
    return MetaError(file, absl::StrCat("fill_value ", v.dump(), " does not fit dtype ",
                                        Sv(DTypeName(m->dtype))));
  };
  // An integer fill, exactly: JSON integers as they are (a uint64 id is beyond a double's
  // 53 bits), any other number only if it is a whole one.
  const auto integer = [&](auto* x) -> absl::Status {
    using T = std::remove_pointer_t<decltype(x)>;
    if (v.is_number_unsigned()) {
      const uint64_t u = v.get<uint64_t>();
      if (u > static_cast<uint64_t>(std::numeric_limits<T>::max())) return misfit();
      *x = static_cast<T>(u);
    } else if (v.is_number_integer()) {
      const int64_t i = v.get<int64_t>();
      if (!std::in_range<T>(i)) return misfit();
      *x = static_cast<T>(i);
    } else {
      // 2^63 and 2^64 are exact doubles: below them every whole double converts.
      if (!(d >= static_cast<double>(std::numeric_limits<T>::lowest()) &&
            d < std::ldexp(1.0, std::numeric_limits<T>::digits)) ||
          d != std::floor(d)) {
        return misfit();
      }
      *x = static_cast<T>(d);
    }
    return absl::OkStatus();
  };
  const auto store = [&](auto x) -> absl::Status {
    TANDEM_RETURN_IF_ERROR(integer(&x));
    std::memcpy(m->fill.data(), &x, sizeof x);
    return absl::OkStatus();
  };
  m->fill = {};
  switch (m->dtype) {
    case DType::kUInt8:
      TANDEM_RETURN_IF_ERROR(store(uint8_t{}));
      break;
    case DType::kInt8:
      TANDEM_RETURN_IF_ERROR(store(int8_t{}));
      break;
    case DType::kUInt16:
      TANDEM_RETURN_IF_ERROR(store(uint16_t{}));
      break;
    case DType::kInt16:
      TANDEM_RETURN_IF_ERROR(store(int16_t{}));
      break;
    case DType::kUInt32:
      TANDEM_RETURN_IF_ERROR(store(uint32_t{}));
      break;
    case DType::kInt32:
      TANDEM_RETURN_IF_ERROR(store(int32_t{}));
      break;
    case DType::kUInt64:
      TANDEM_RETURN_IF_ERROR(store(uint64_t{}));
      break;
    case DType::kInt64:
      TANDEM_RETURN_IF_ERROR(store(int64_t{}));
      break;
    case DType::kFloat32: {
      if (have_bits) {
        std::memcpy(m->fill.data(), &bits, 4);
      } else {
        const float x = static_cast<float>(d);
        std::memcpy(m->fill.data(), &x, 4);
      }
      break;
    }
  }
  // In the host's order now: into the array's.
  if (m->big_endian == kHostIsLittleEndian)
    SwapBytesInPlace(m->fill.data(), 1, DTypeSize(m->dtype));
  return absl::OkStatus();
}

int ShuffleCode(const json& v) {
  if (v.is_number_integer()) return v.get<int>();
  if (v.is_string()) {
    const std::string s = v.get<std::string>();
    if (s == "noshuffle") return 0;
    if (s == "shuffle") return 1;
    if (s == "bitshuffle") return 2;
  }
  return 1;
}

absl::Status ParseV2Compressor(const std::string& file, const json& c, ArrayMeta* m) {
  if (c.is_null()) return absl::OkStatus();
  if (!c.is_object() || !c.contains("id") || !c["id"].is_string()) {
    return MetaError(file, "'compressor' must be null or an object with an 'id'");
  }
  const std::string id = c["id"].get<std::string>();
  m->has_compression = true;
  if (id == "blosc") {
    m->compression.kind = Compression::kBlosc;
    if (c.contains("cname") && c["cname"].is_string()) {
      m->compression.blosc_cname = c["cname"].get<std::string>();
    }
    if (c.contains("shuffle")) m->compression.blosc_shuffle = ShuffleCode(c["shuffle"]);
  } else if (id == "zstd") {
    m->compression.kind = Compression::kZstd;
  } else if (id == "gzip") {
    m->compression.kind = Compression::kGzip;
  } else if (id == "zlib") {
    m->compression.kind = Compression::kZlib;
  } else {
    return MetaError(file, absl::StrCat("unsupported compressor '", id,
                                        "' (supported: blosc, zstd, gzip, zlib, null)"));
  }
  return absl::OkStatus();
}

absl::StatusOr<ArrayMeta> ParseV2Array(const std::string& dir, const std::string& file,
                                       const json& j) {
  ArrayMeta m;
  m.dir = dir;
  m.meta_file = file;
  m.version = 2;
  if (!j.contains("zarr_format") || j["zarr_format"] != 2) {
    return MetaError(file, "expected \"zarr_format\": 2");
  }
  for (const char* key : {"shape", "chunks", "dtype"}) {
    if (!j.contains(key)) return MetaError(file, absl::StrCat("missing '", key, "'"));
  }
  TANDEM_ASSIGN_OR_RETURN(std::vector<int64_t> shape, IntList(file, j["shape"], "shape"));
  TANDEM_ASSIGN_OR_RETURN(std::vector<int64_t> chunks, IntList(file, j["chunks"], "chunks"));
  m.shape = std::move(shape);
  m.chunks = std::move(chunks);
  TANDEM_RETURN_IF_ERROR(ParseV2DType(file, j["dtype"], &m));
  if (j.contains("order") && j["order"] != "C") {
    return MetaError(file, absl::StrCat("order ", j["order"].dump(),
                                        " is not supported (only C order: x fastest)"));
  }
  if (j.contains("filters") && !j["filters"].is_null() &&
      !(j["filters"].is_array() && j["filters"].empty())) {
    return MetaError(file, absl::StrCat("filters are not supported: ", j["filters"].dump()));
  }
  TANDEM_RETURN_IF_ERROR(ParseV2Compressor(file, j.value("compressor", json()), &m));
  TANDEM_RETURN_IF_ERROR(ParseFill(file, j.value("fill_value", json()), &m));
  if (j.contains("dimension_separator")) {
    const json& s = j["dimension_separator"];
    if (s == ".") {
      m.separator = '.';
    } else if (s == "/") {
      m.separator = '/';
    } else {
      return MetaError(file, absl::StrCat("dimension_separator ", s.dump(),
                                          " is not supported (\".\" or \"/\")"));
    }
  }
  return m;
}

absl::Status ParseV3Codecs(const std::string& file, const json& codecs, ArrayMeta* m);

// The sharding codec (the array's only array-to-bytes codec): its inner chunk shape and
// codecs describe each inner chunk; the index must be little-endian uint64 pairs, with an
// optional crc32c (skipped, not verified).
absl::Status ParseSharding(const std::string& file, const json& cfg, ArrayMeta* m) {
  if (!cfg.contains("chunk_shape") || !cfg.contains("codecs")) {
    return MetaError(file, "sharding_indexed needs chunk_shape and codecs");
  }
  TANDEM_ASSIGN_OR_RETURN(std::vector<int64_t> inner,
                          IntList(file, cfg["chunk_shape"], "chunk_shape"));
  m->sharded = true;
  m->shard = std::move(m->chunks);
  m->chunks = std::move(inner);
  TANDEM_RETURN_IF_ERROR(ParseV3Codecs(file, cfg["codecs"], m));
  const json loc = cfg.value("index_location", json("end"));
  if (loc != "end" && loc != "start") {
    return MetaError(file, absl::StrCat("sharding: unsupported index_location ", loc.dump()));
  }
  m->index_at_start = loc == "start";
  const json index = cfg.value("index_codecs", json::array());
  bool little = false;
  for (const json& c : index) {
    const json name = c.is_object() ? c.value("name", json()) : json();
    const json ccfg = c.is_object() ? c.value("configuration", json::object()) : json();
    if (name == "bytes" && ccfg.is_object() && ccfg.value("endian", json("little")) == "little") {
      little = true;
    } else if (name == "crc32c" && little) {
      m->index_tail = 4;
    } else {
      return MetaError(file, absl::StrCat("sharding: unsupported index_codecs ", index.dump(),
                                          " (little-endian bytes, then optionally crc32c)"));
    }
  }
  if (!little) return MetaError(file, "sharding: index_codecs must start with bytes (little)");
  return absl::OkStatus();
}

absl::Status ParseV3Codecs(const std::string& file, const json& codecs, ArrayMeta* m) {
  if (!codecs.is_array()) return MetaError(file, "'codecs' must be a list");
  bool have_bytes = false;
  for (const json& c : codecs) {
    if (!c.is_object() || !c.contains("name") || !c["name"].is_string()) {
      return MetaError(file, "every codec needs a 'name'");
    }
    const std::string name = c["name"].get<std::string>();
    const json cfg = c.value("configuration", json::object());
    if (!cfg.is_object())
      return MetaError(file, absl::StrCat("codec '", name, "': bad configuration"));
    if (name == "sharding_indexed" && !have_bytes && codecs.size() == 1 && !m->sharded) {
      return ParseSharding(file, cfg, m);
    }
    if (name == "sharding_indexed") {
      return MetaError(file,
                       "codec 'sharding_indexed' must be the only codec (nested or "
                       "combined sharding is not supported)");
    }
    if (name == "bytes") {
      have_bytes = true;
      const json endian = cfg.value("endian", json("little"));
      if (endian == "big") {
        m->big_endian = true;
      } else if (endian == "little") {
        m->big_endian = false;
      } else {
        return MetaError(file, absl::StrCat("bytes codec: unsupported endian ", endian.dump()));
      }
      continue;
    }
    if (!have_bytes) {
      return MetaError(file, absl::StrCat("unsupported codec '", name,
                                          "' before the bytes codec (supported: bytes, then "
                                          "blosc, zstd or gzip)"));
    }
    if (m->has_compression) {
      return MetaError(file, "more than one compression codec is not supported");
    }
    m->has_compression = true;
    if (name == "blosc") {
      m->compression.kind = Compression::kBlosc;
      if (cfg.contains("cname") && cfg["cname"].is_string()) {
        m->compression.blosc_cname = cfg["cname"].get<std::string>();
      }
      if (cfg.contains("shuffle")) m->compression.blosc_shuffle = ShuffleCode(cfg["shuffle"]);
    } else if (name == "zstd") {
      m->compression.kind = Compression::kZstd;
    } else if (name == "gzip") {
      m->compression.kind = Compression::kGzip;
    } else {
      return MetaError(file, absl::StrCat("unsupported codec '", name,
                                          "' (supported: bytes, blosc, zstd, gzip)"));
    }
  }
  if (!have_bytes) return MetaError(file, "no 'bytes' codec in 'codecs'");
  return absl::OkStatus();
}

absl::StatusOr<ArrayMeta> ParseV3Array(const std::string& dir, const std::string& file,
                                       const json& j) {
  ArrayMeta m;
  m.dir = dir;
  m.meta_file = file;
  m.version = 3;
  for (const char* key : {"shape", "data_type", "chunk_grid", "codecs"}) {
    if (!j.contains(key)) return MetaError(file, absl::StrCat("missing '", key, "'"));
  }
  TANDEM_ASSIGN_OR_RETURN(std::vector<int64_t> shape, IntList(file, j["shape"], "shape"));
  m.shape = std::move(shape);
  const json& grid = j["chunk_grid"];
  if (!grid.is_object() || grid.value("name", json()) != "regular" ||
      !grid.contains("configuration") || !grid["configuration"].is_object() ||
      !grid["configuration"].contains("chunk_shape")) {
    return MetaError(file, absl::StrCat("unsupported chunk_grid ", grid.dump(),
                                        " (only \"regular\" with a chunk_shape)"));
  }
  TANDEM_ASSIGN_OR_RETURN(std::vector<int64_t> chunks,
                          IntList(file, grid["configuration"]["chunk_shape"], "chunk_shape"));
  m.chunks = std::move(chunks);
  const json& dt = j["data_type"];
  const std::string dts = dt.is_string() ? dt.get<std::string>() : dt.dump();
  absl::StatusOr<DType> t = ParseDType(dts);
  if (!dt.is_string() || !t.ok()) {
    return MetaError(
        file, absl::StrCat("unsupported data_type '", dts, "' (supported: ", DTypeNames(), ")"));
  }
  m.dtype = *t;
  TANDEM_RETURN_IF_ERROR(ParseV3Codecs(file, j["codecs"], &m));
  if (j.contains("storage_transformers") && !j["storage_transformers"].empty()) {
    return MetaError(file, "storage_transformers are not supported");
  }
  TANDEM_RETURN_IF_ERROR(ParseFill(file, j.value("fill_value", json()), &m));
  m.v3_default_key = true;
  m.separator = '/';
  if (j.contains("chunk_key_encoding")) {
    const json& e = j["chunk_key_encoding"];
    const json name = e.is_object() ? e.value("name", json()) : json();
    const json cfg = e.is_object() ? e.value("configuration", json::object()) : json();
    if (name == "default") {
      m.v3_default_key = true;
      m.separator = '/';
    } else if (name == "v2") {
      m.v3_default_key = false;
      m.separator = '.';
    } else {
      return MetaError(file, absl::StrCat("unsupported chunk_key_encoding ", e.dump()));
    }
    if (cfg.is_object() && cfg.contains("separator")) {
      if (cfg["separator"] == "/") {
        m.separator = '/';
      } else if (cfg["separator"] == ".") {
        m.separator = '.';
      } else {
        return MetaError(file,
                         absl::StrCat("unsupported chunk key separator ", cfg["separator"].dump()));
      }
    }
  }
  return m;
}

}  // namespace

absl::StatusOr<Node> LoadNode(const std::string& dir) {
  Node node;
  const fs::path d(dir);
  if (FileExists(d / "zarr.json")) {
    const std::string file = (d / "zarr.json").string();
    TANDEM_ASSIGN_OR_RETURN(json j, ReadJsonFile(file));
    if (j.value("zarr_format", json()) != 3) return MetaError(file, "expected \"zarr_format\": 3");
    const json type = j.value("node_type", json());
    if (j.contains("attributes") && j["attributes"].is_object()) {
      node.attrs = j["attributes"];
    }
    node.attrs_file = file;
    if (type == "array") {
      TANDEM_ASSIGN_OR_RETURN(ArrayMeta m, ParseV3Array(dir, file, j));
      node.is_array = true;
      node.array = std::move(m);
      node.array.isovalues = SuggestedIsovalues(node.attrs);
    } else if (type != "group") {
      return MetaError(file, "node_type must be \"array\" or \"group\"");
    }
    return node;
  }
  const bool array = FileExists(d / ".zarray");
  if (!array && !FileExists(d / ".zgroup") && !FileExists(d / ".zattrs")) {
    std::error_code ec;
    if (!fs::exists(d, ec))
      return absl::NotFoundError(absl::StrCat(dir, ": no such file or directory"));
    return absl::InvalidArgumentError(absl::StrCat(
        dir, ": not a Zarr array or group (no .zarray, .zgroup, .zattrs or zarr.json)"));
  }
  if (FileExists(d / ".zattrs")) {
    node.attrs_file = (d / ".zattrs").string();
    TANDEM_ASSIGN_OR_RETURN(json a, ReadJsonFile(node.attrs_file));
    node.attrs = std::move(a);
  }
  if (array) {
    const std::string file = (d / ".zarray").string();
    TANDEM_ASSIGN_OR_RETURN(json j, ReadJsonFile(file));
    TANDEM_ASSIGN_OR_RETURN(ArrayMeta m, ParseV2Array(dir, file, j));
    node.is_array = true;
    node.array = std::move(m);
    node.array.isovalues = SuggestedIsovalues(node.attrs);
  }
  return node;
}

}  // namespace tandem::io::internal::zarr
