// Zarr v2 / v3 and OME-Zarr reader (see tandem/zarr.h for what is supported).
//
// Streaming: chunks are usually several planes deep and tiled in y and x, so the reader
// decodes one chunk-z layer at a time (every y/x chunk of that chunk row, for the chosen
// t/c indices), hands its planes out one per ReadSlice, then moves to the next layer. It
// holds one layer (chunk depth x ny x nx voxels) and one decoded chunk.
//
// The writer (ZarrAppender, WriteZarr; at the end of this file) works the other way round:
// it gathers one chunk-z layer of planes, then writes every chunk of that row.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "nlohmann/json.hpp"
#include "tandem/zarr.h"
#include "volume_io_internal.h"
#include "zarr_internal.h"

namespace tandem {
namespace internal {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;
using zarr::Compression;

constexpr uint64_t kMaxMetadataBytes = 16 << 20;
// One decoded chunk, and one chunk-z layer, must fit in memory comfortably.
constexpr uint64_t kMaxChunkBytes = uint64_t{512} << 20;
constexpr uint64_t kMaxLayerBytes = uint64_t{1} << 30;
// Every chunk costs a file to open (or a range of a shard to read), a few microseconds: a
// store of tiny chunks takes hours, and metadata alone can claim billions of them. Arrays
// read in at most kFreeChunks chunks, or in chunks of kMinChunkVoxels voxels on average
// (the chosen t/c), per chunk row and in all.
constexpr uint64_t kFreeChunks = 1 << 16;
constexpr uint64_t kMinChunkVoxels = 4096;
// Shape values beyond this are refused before any arithmetic on them.
constexpr int64_t kMaxShape = int64_t{1} << 40;
// nlohmann's dump and comparisons recurse: metadata nested deeper is refused unread.
constexpr int kMaxJsonDepth = 64;

absl::Status MetaError(const std::string& file, absl::string_view what) {
  return absl::InvalidArgumentError(absl::StrCat(file, ": ", what));
}

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
  if (absl::Status st = zarr::ReadWholeFile(file, kMaxMetadataBytes, &text); !st.ok()) return st;
  if (JsonDepth(text) > kMaxJsonDepth) {
    return MetaError(file, absl::StrCat("JSON nested more than ", kMaxJsonDepth,
                                        " levels deep (Zarr metadata nests a few)"));
  }
  json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return MetaError(file, "invalid JSON");
  if (!j.is_object()) return MetaError(file, "expected a JSON object");
  return j;
}

// The metadata of one array, whichever version described it.
struct ArrayMeta {
  std::string dir;        // the array's directory
  std::string meta_file;  // .zarray or zarr.json (named in metadata errors)
  int version = 2;
  std::vector<int64_t> shape, chunks;
  DType dtype = DType::kUInt8;
  bool big_endian = false;
  bool has_compression = false;
  Compression compression;
  std::array<uint8_t, 4> fill{};  // one element in stored byte order
  bool v3_default_key = false;    // "c/0/1/2" (v3 default) vs "0.1.2" (v2)
  char separator = '.';
  std::vector<double> isovalues;  // the array's "suggested_isovalues" attribute (tandem's)
  // v3 sharding_indexed: `chunks` is then the inner chunk (the unit decoded), each shard
  // file holds shard[d] / chunks[d] of them along every axis and an index of
  // (offset, nbytes) pairs, little-endian uint64, at its start or end.
  bool sharded = false;
  std::vector<int64_t> shard;
  bool index_at_start = false;
  uint64_t index_tail = 0;  // bytes after the index entries (4 with a crc32c codec)
};

struct Node {
  bool is_array = false;
  ArrayMeta array;
  json attrs = json::object();  // .zattrs (v2) or attributes (v3)
  std::string attrs_file;
};

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

bool FileExists(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

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

// v2 "<u2" / ">f4" / "|u1"; v3 "uint16" (byte order from the bytes codec).
absl::Status ParseV2DType(const std::string& file, const json& v, ArrayMeta* m) {
  const std::string s = v.is_string() ? v.get<std::string>() : v.dump();
  const auto bad = [&] {
    return MetaError(file, absl::StrCat("unsupported dtype '", s,
                                        "' (supported: |u1, <u2, >u2, <i2, >i2, <f4, >f4)"));
  };
  if (!v.is_string() || s.size() != 3) return bad();
  const std::string kind = s.substr(1);
  if (kind == "u1") {
    m->dtype = DType::kUInt8;
  } else if (kind == "u2") {
    m->dtype = DType::kUInt16;
  } else if (kind == "i2") {
    m->dtype = DType::kInt16;
  } else if (kind == "f4") {
    m->dtype = DType::kFloat32;
  } else {
    return bad();
  }
  if (s[0] == '>') {
    m->big_endian = true;
  } else if (s[0] == '<' || (s[0] == '|' && m->dtype == DType::kUInt8)) {
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
  const auto range = [&](double lo, double hi) -> absl::Status {
    if (!(d >= lo && d <= hi) || d != std::floor(d)) {
      return MetaError(file, absl::StrCat("fill_value ", v.dump(), " does not fit dtype ",
                                          Sv(DTypeName(m->dtype))));
    }
    return absl::OkStatus();
  };
  uint8_t host[4] = {};
  switch (m->dtype) {
    case DType::kUInt8:
      if (absl::Status st = range(0, 255); !st.ok()) return st;
      host[0] = static_cast<uint8_t>(d);
      break;
    case DType::kUInt16: {
      if (absl::Status st = range(0, 65535); !st.ok()) return st;
      const uint16_t x = static_cast<uint16_t>(d);
      std::memcpy(host, &x, 2);
      break;
    }
    case DType::kInt16: {
      if (absl::Status st = range(-32768, 32767); !st.ok()) return st;
      const int16_t x = static_cast<int16_t>(d);
      std::memcpy(host, &x, 2);
      break;
    }
    case DType::kFloat32: {
      if (have_bits) {
        std::memcpy(host, &bits, 4);
      } else {
        const float x = static_cast<float>(d);
        std::memcpy(host, &x, 4);
      }
      break;
    }
  }
  const size_t es = DTypeSize(m->dtype);
  if (m->big_endian == kHostIsLittleEndian) SwapBytesInPlace(host, 1, es);
  std::memcpy(m->fill.data(), host, es);
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
  absl::StatusOr<std::vector<int64_t>> shape = IntList(file, j["shape"], "shape");
  if (!shape.ok()) return shape.status();
  absl::StatusOr<std::vector<int64_t>> chunks = IntList(file, j["chunks"], "chunks");
  if (!chunks.ok()) return chunks.status();
  m.shape = *std::move(shape);
  m.chunks = *std::move(chunks);
  if (absl::Status st = ParseV2DType(file, j["dtype"], &m); !st.ok()) return st;
  if (j.contains("order") && j["order"] != "C") {
    return MetaError(file, absl::StrCat("order ", j["order"].dump(),
                                        " is not supported (only C order: x fastest)"));
  }
  if (j.contains("filters") && !j["filters"].is_null() &&
      !(j["filters"].is_array() && j["filters"].empty())) {
    return MetaError(file, absl::StrCat("filters are not supported: ", j["filters"].dump()));
  }
  if (absl::Status st = ParseV2Compressor(file, j.value("compressor", json()), &m); !st.ok()) {
    return st;
  }
  if (absl::Status st = ParseFill(file, j.value("fill_value", json()), &m); !st.ok()) return st;
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
  absl::StatusOr<std::vector<int64_t>> inner = IntList(file, cfg["chunk_shape"], "chunk_shape");
  if (!inner.ok()) return inner.status();
  m->sharded = true;
  m->shard = std::move(m->chunks);
  m->chunks = *std::move(inner);
  if (absl::Status st = ParseV3Codecs(file, cfg["codecs"], m); !st.ok()) return st;
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
  absl::StatusOr<std::vector<int64_t>> shape = IntList(file, j["shape"], "shape");
  if (!shape.ok()) return shape.status();
  m.shape = *std::move(shape);
  const json& grid = j["chunk_grid"];
  if (!grid.is_object() || grid.value("name", json()) != "regular" ||
      !grid.contains("configuration") || !grid["configuration"].is_object() ||
      !grid["configuration"].contains("chunk_shape")) {
    return MetaError(file, absl::StrCat("unsupported chunk_grid ", grid.dump(),
                                        " (only \"regular\" with a chunk_shape)"));
  }
  absl::StatusOr<std::vector<int64_t>> chunks =
      IntList(file, grid["configuration"]["chunk_shape"], "chunk_shape");
  if (!chunks.ok()) return chunks.status();
  m.chunks = *std::move(chunks);
  const json& dt = j["data_type"];
  const std::string dts = dt.is_string() ? dt.get<std::string>() : dt.dump();
  absl::StatusOr<DType> t = ParseDType(dts);
  if (!dt.is_string() || !t.ok()) {
    return MetaError(file, absl::StrCat("unsupported data_type '", dts,
                                        "' (supported: uint8, uint16, int16, float32)"));
  }
  m.dtype = *t;
  if (absl::Status st = ParseV3Codecs(file, j["codecs"], &m); !st.ok()) return st;
  if (j.contains("storage_transformers") && !j["storage_transformers"].empty()) {
    return MetaError(file, "storage_transformers are not supported");
  }
  if (absl::Status st = ParseFill(file, j.value("fill_value", json()), &m); !st.ok()) return st;
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

absl::StatusOr<Node> LoadNode(const std::string& dir) {
  Node node;
  const fs::path d(dir);
  if (FileExists(d / "zarr.json")) {
    const std::string file = (d / "zarr.json").string();
    absl::StatusOr<json> j = ReadJsonFile(file);
    if (!j.ok()) return j.status();
    if (j->value("zarr_format", json()) != 3) return MetaError(file, "expected \"zarr_format\": 3");
    const json type = j->value("node_type", json());
    if (j->contains("attributes") && (*j)["attributes"].is_object()) {
      node.attrs = (*j)["attributes"];
    }
    node.attrs_file = file;
    if (type == "array") {
      absl::StatusOr<ArrayMeta> m = ParseV3Array(dir, file, *j);
      if (!m.ok()) return m.status();
      node.is_array = true;
      node.array = *std::move(m);
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
    absl::StatusOr<json> a = ReadJsonFile(node.attrs_file);
    if (!a.ok()) return a.status();
    node.attrs = *std::move(a);
  }
  if (array) {
    const std::string file = (d / ".zarray").string();
    absl::StatusOr<json> j = ReadJsonFile(file);
    if (!j.ok()) return j.status();
    absl::StatusOr<ArrayMeta> m = ParseV2Array(dir, file, *j);
    if (!m.ok()) return m.status();
    node.is_array = true;
    node.array = *std::move(m);
    node.array.isovalues = SuggestedIsovalues(node.attrs);
  }
  return node;
}

// The OME multiscales list of a group's attributes (v0.5 nests it under "ome").
const json* Multiscales(const json& attrs) {
  if (attrs.contains("multiscales") && attrs["multiscales"].is_array() &&
      !attrs["multiscales"].empty()) {
    return &attrs["multiscales"];
  }
  if (attrs.contains("ome") && attrs["ome"].is_object()) return Multiscales(attrs["ome"]);
  return nullptr;
}

// What the chosen array is, and how its indices map to the world.
struct Resolved {
  ArrayMeta array;
  std::vector<std::string> axis_names;  // empty: the last three are z, y, x
  std::vector<std::string> axis_types;
  std::vector<std::string> axis_units;
  std::vector<double> scale, translation;  // per array dim; empty = identity
  std::string what;                        // for the description
};

// Applies a list of OME coordinateTransformations (scale, translation) after *s, *t.
absl::Status ApplyTransforms(const std::string& file, const json& list, size_t ndim,
                             std::vector<double>* s, std::vector<double>* t) {
  if (!list.is_array()) return absl::OkStatus();
  for (const json& tr : list) {
    if (!tr.is_object()) continue;
    const json type = tr.value("type", json());
    const char* key = type == "scale" ? "scale" : type == "translation" ? "translation" : nullptr;
    if (key == nullptr || !tr.contains(key)) continue;  // "identity", or by "path": ignored
    const json& v = tr[key];
    if (!v.is_array() || v.size() != ndim) {
      return MetaError(file, absl::StrCat("coordinateTransformations ", key, " ", v.dump(),
                                          " does not have one number per axis (", ndim, ")"));
    }
    for (size_t i = 0; i < ndim; ++i) {
      if (!v[i].is_number()) return MetaError(file, absl::StrCat(key, " must hold numbers"));
      const double x = v[i].get<double>();
      if (type == "scale") {
        (*s)[i] *= x;
        (*t)[i] *= x;
      } else {
        (*t)[i] += x;
      }
    }
  }
  return absl::OkStatus();
}

// `rel` (an array selector, or a multiscales dataset's path, named `what` in the error) as
// a path inside the group at `root`: relative, without "..", and inside it still once
// symlinks are resolved, so that metadata cannot send the reader elsewhere on the disk.
absl::StatusOr<std::string> InsideStore(const std::string& root, const std::string& rel,
                                        const std::string& what) {
  const fs::path p(rel);
  bool up = false;
  for (const fs::path& part : p) up = up || part == "..";
  const auto refuse = [&](absl::string_view why) {
    return absl::InvalidArgumentError(absl::StrCat(what, " '", rel, "' ", why, " (", root,
                                                   "); paths must stay inside the store"));
  };
  if (rel.empty() || p.is_absolute() || up) {
    return refuse(rel.empty() ? "is empty" : p.is_absolute() ? "is absolute" : "goes up with ..");
  }
  const fs::path joined = fs::path(root) / p;
  std::error_code ec_root, ec;
  const fs::path real_root = fs::weakly_canonical(root, ec_root);
  const fs::path real = fs::weakly_canonical(joined, ec);
  if (!ec_root && !ec) {
    auto [r, j] = std::mismatch(real_root.begin(), real_root.end(), real.begin(), real.end());
    if (r != real_root.end())
      return refuse(absl::StrCat("leads outside the group, to ", real.string()));
  }
  return joined.string();
}

bool AllDigits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

absl::StatusOr<Resolved> ResolveMultiscale(const std::string& root, const Node& group,
                                           const std::string& level_sel,
                                           const std::string& path_sel);

absl::StatusOr<Resolved> Resolve(const std::string& root, const std::string& selector) {
  absl::StatusOr<Node> node = LoadNode(root);
  if (!node.ok()) return node.status();
  if (node->is_array) {
    if (!selector.empty()) {
      return absl::InvalidArgumentError(absl::StrCat(
          root, ": is a Zarr array, not a group: the selector '", selector, "' does not apply"));
    }
    Resolved r;
    r.array = std::move(node->array);
    r.what = absl::StrCat("Zarr v", r.array.version, " array");
    return r;
  }
  const json* ms = Multiscales(node->attrs);
  // A number is a level of the multiscale image (in a plain group, an array's name).
  if (selector.empty() || (AllDigits(selector) && ms != nullptr)) {
    if (ms == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrCat(root,
                       ": is a Zarr group without OME-Zarr multiscales metadata; name an array "
                       "inside it as ",
                       root, "#PATH (tandem info/extract --zarr-array PATH)"));
    }
    return ResolveMultiscale(root, *node, selector.empty() ? "0" : selector, "");
  }
  absl::StatusOr<std::string> inside = InsideStore(root, selector, "array path");
  if (!inside.ok()) return inside.status();
  const std::string sub = *inside;
  absl::StatusOr<Node> inner = LoadNode(sub);
  if (!inner.ok()) return inner.status();
  if (!inner->is_array) return Resolve(sub, "");
  // An array that is one of this group's levels keeps the level's scale and translation.
  if (ms != nullptr) {
    for (const json& ds : (*ms)[0].value("datasets", json::array())) {
      if (ds.is_object() && ds.value("path", json()) == selector) {
        return ResolveMultiscale(root, *node, "", selector);
      }
    }
  }
  Resolved r;
  r.array = std::move(inner->array);
  r.what = absl::StrCat("Zarr v", r.array.version, " array '", selector, "'");
  return r;
}

absl::StatusOr<Resolved> ResolveMultiscale(const std::string& root, const Node& group,
                                           const std::string& level_sel,
                                           const std::string& path_sel) {
  const std::string& file = group.attrs_file;
  const json& m = (*Multiscales(group.attrs))[0];
  if (!m.is_object() || !m.contains("datasets") || !m["datasets"].is_array() ||
      m["datasets"].empty()) {
    return MetaError(file, "multiscales[0] has no datasets");
  }
  const json& datasets = m["datasets"];
  size_t level = 0;
  if (path_sel.empty()) {
    uint64_t n = 0;
    if (!absl::SimpleAtoi(level_sel, &n) || n >= datasets.size()) {
      return absl::InvalidArgumentError(
          absl::StrCat(root, ": level ", level_sel, " does not exist (the image has ",
                       datasets.size(), " levels, 0..", datasets.size() - 1, ")"));
    }
    level = static_cast<size_t>(n);
  } else {
    level = datasets.size();
    for (size_t i = 0; i < datasets.size(); ++i) {
      if (datasets[i].is_object() && datasets[i].value("path", json()) == path_sel) level = i;
    }
  }
  Resolved r;
  std::string path;
  if (level < datasets.size()) {
    const json& ds = datasets[level];
    if (!ds.is_object() || !ds.contains("path") || !ds["path"].is_string()) {
      return MetaError(file, absl::StrCat("multiscales dataset ", level, " has no 'path'"));
    }
    path = ds["path"].get<std::string>();
  } else {
    path = path_sel;  // an array of the group that is not a level: no transforms
  }
  absl::StatusOr<std::string> inside =
      InsideStore(root, path, absl::StrCat(file, ": multiscales dataset path"));
  if (!inside.ok()) return inside.status();
  absl::StatusOr<Node> arr = LoadNode(*inside);
  if (!arr.ok()) return arr.status();
  if (!arr->is_array) {
    return absl::InvalidArgumentError(
        absl::StrCat(root, ": multiscale dataset '", path, "' is not an array"));
  }
  r.array = std::move(arr->array);
  const size_t ndim = r.array.shape.size();
  if (m.contains("axes") && m["axes"].is_array()) {
    const json& axes = m["axes"];
    if (axes.size() != ndim) {
      return MetaError(file, absl::StrCat("multiscales axes list ", axes.size(),
                                          " axes but array '", path, "' has ", ndim));
    }
    for (const json& a : axes) {
      std::string name, type, unit;
      if (a.is_string()) {
        name = a.get<std::string>();  // v0.3: names only
      } else if (a.is_object()) {
        if (a.contains("name") && a["name"].is_string()) name = a["name"].get<std::string>();
        if (a.contains("type") && a["type"].is_string()) type = a["type"].get<std::string>();
        if (a.contains("unit") && a["unit"].is_string()) unit = a["unit"].get<std::string>();
      }
      r.axis_names.push_back(absl::AsciiStrToLower(name));
      r.axis_types.push_back(type);
      r.axis_units.push_back(unit);
    }
  }
  if (level < datasets.size()) {
    r.scale.assign(ndim, 1.0);
    r.translation.assign(ndim, 0.0);
    const json& ds = datasets[level];
    for (const json* list :
         {ds.contains("coordinateTransformations") ? &ds["coordinateTransformations"] : nullptr,
          m.contains("coordinateTransformations") ? &m["coordinateTransformations"] : nullptr}) {
      if (list == nullptr) continue;
      if (absl::Status st = ApplyTransforms(file, *list, ndim, &r.scale, &r.translation);
          !st.ok()) {
        return st;
      }
    }
  }
  std::string name;
  if (m.contains("name") && m["name"].is_string()) name = m["name"].get<std::string>();
  r.what = absl::StrCat("OME-Zarr image", name.empty() ? "" : " '", name, name.empty() ? "" : "'",
                        level < datasets.size() ? absl::StrCat(", level ", level) : "", " (array '",
                        path, "', Zarr v", r.array.version, ")");
  return r;
}

class ZarrSliceSource final : public CountedSliceSource {
 public:
  ~ZarrSliceSource() override {
    if (shard_fd_ >= 0) ::close(shard_fd_);
  }
  ZarrSliceSource(std::string path, Resolved r, VolumeInfo info, std::vector<int64_t> lead,
                  int64_t first_plane)
      : CountedSliceSource(std::move(path), std::move(info), OnFailure::kKeep, first_plane),
        r_(std::move(r)),
        lead_(std::move(lead)) {
    const ArrayMeta& a = r_.array;
    es_ = DTypeSize(a.dtype);
    const size_t nd = a.shape.size();
    stride_.assign(nd, 1);
    for (size_t d = nd - 1; d-- > 0;) stride_[d] = stride_[d + 1] * a.chunks[d + 1];
    chunk_elems_ = static_cast<size_t>(stride_[0] * a.chunks[0]);
    swap_ = a.big_endian == kHostIsLittleEndian && es_ > 1;
  }

  // Planes 0..n-1 whose chunk rows have every chunk file on disk, capped at the shape; rows
  // below `known` planes are taken as complete without looking.
  int64_t CompletePlanes(int64_t known) const {
    const size_t nd = r_.array.shape.size();
    const int64_t cdz = r_.array.chunks[nd - 3], cdy = r_.array.chunks[nd - 2],
                  cdx = r_.array.chunks[nd - 1];
    int64_t cz = std::clamp<int64_t>(known, 0, info_.nz) / cdz;
    for (; cz * cdz < info_.nz; ++cz) {
      std::vector<int64_t> idx = ChunkIndex(cz, nullptr);
      bool all = true;
      for (int64_t cy = 0; all && cy * cdy < info_.ny; ++cy) {
        for (int64_t cx = 0; all && cx * cdx < info_.nx; ++cx) {
          idx[nd - 2] = cy;
          idx[nd - 1] = cx;
          all = FileExists(ChunkPath(idx));
        }
      }
      if (!all) break;
    }
    return std::max(std::min(cz * cdz, info_.nz), std::clamp<int64_t>(known, 0, info_.nz));
  }

 private:
  absl::Status ReadNext(std::vector<uint8_t>* bytes) override {
    const int64_t depth = r_.array.chunks[r_.array.chunks.size() - 3];
    const int64_t cz = next_slice() / depth;
    if (cz != layer_cz_) {
      if (absl::Status st = LoadLayer(cz); !st.ok()) return st;
    }
    const size_t plane = info_.slice_bytes();
    const uint8_t* src = layer_.data() + static_cast<size_t>(next_slice() - cz * depth) * plane;
    bytes->assign(src, src + plane);
    return absl::OkStatus();
  }

  // The index of chunk (lead..., cz, 0, 0); *lead_offset (if set) gets the element offset of
  // the chosen t/c inside such a chunk.
  std::vector<int64_t> ChunkIndex(int64_t cz, size_t* lead_offset) const {
    const ArrayMeta& a = r_.array;
    const size_t nd = a.shape.size();
    std::vector<int64_t> idx(nd, 0);
    size_t offset = 0;
    for (size_t d = 0; d + 3 < nd; ++d) {
      idx[d] = lead_[d] / a.chunks[d];
      offset += static_cast<size_t>((lead_[d] % a.chunks[d]) * stride_[d]);
    }
    idx[nd - 3] = cz;
    if (lead_offset != nullptr) *lead_offset = offset;
    return idx;
  }

  // The file holding chunk idx (its shard's, for sharded arrays).
  std::string ChunkPath(const std::vector<int64_t>& idx) const {
    const std::string sep(1, r_.array.separator);
    std::vector<int64_t> key_idx = idx;
    if (r_.array.sharded) {
      for (size_t d = 0; d < idx.size(); ++d) {
        key_idx[d] = idx[d] / (r_.array.shard[d] / r_.array.chunks[d]);
      }
    }
    std::string key = absl::StrJoin(key_idx, sep);
    if (r_.array.v3_default_key) key = absl::StrCat("c", sep, key);
    return (fs::path(r_.array.dir) / key).string();
  }

  // The stored bytes of chunk idx into raw_: the whole chunk file, or the inner chunk's
  // range of its shard. NotFound when the chunk (or its shard) does not exist.
  absl::Status ReadChunk(const std::vector<int64_t>& idx, const std::string& file,
                         uint64_t max_bytes) {
    const ArrayMeta& a = r_.array;
    if (!a.sharded) return zarr::ReadWholeFile(file, max_bytes, &raw_);
    if (file != shard_file_) {  // open the shard and read its index once for its inner chunks
      shard_file_.clear();
      if (shard_fd_ >= 0) ::close(shard_fd_);
      shard_fd_ = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
      if (shard_fd_ < 0) return ErrnoError(file, "cannot open");  // NotFound: all fill_value
      size_t n = 1;
      for (size_t d = 0; d < idx.size(); ++d) n *= static_cast<size_t>(a.shard[d] / a.chunks[d]);
      const uint64_t index_bytes = 16 * uint64_t{n} + a.index_tail;
      struct stat file_info;
      if (::fstat(shard_fd_, &file_info) != 0) return ErrnoError(file, "cannot stat");
      const uint64_t size = static_cast<uint64_t>(file_info.st_size);
      if (size < index_bytes) {
        return absl::DataLossError(absl::StrCat(file, ": truncated shard: ", size,
                                                " bytes, its index alone needs ", index_bytes));
      }
      shard_size_ = size;
      const uint64_t at = a.index_at_start ? 0 : size - index_bytes;
      if (absl::Status st = zarr::ReadRangeAt(shard_fd_, file, at, 16 * n, &raw_); !st.ok()) {
        return st;
      }
      shard_index_.resize(2 * n);
      for (size_t i = 0; i < 2 * n; ++i) {
        shard_index_[i] = LoadScalar<uint64_t>(
            reinterpret_cast<const uint8_t*>(raw_.data()) + 8 * i, !kHostIsLittleEndian);
      }
      shard_file_ = file;
    }
    uint64_t inner = 0;  // C-order position of the inner chunk within its shard
    for (size_t d = 0; d < idx.size(); ++d) {
      const int64_t per = a.shard[d] / a.chunks[d];
      inner = inner * static_cast<uint64_t>(per) + static_cast<uint64_t>(idx[d] % per);
    }
    const uint64_t offset = shard_index_[2 * inner], nbytes = shard_index_[2 * inner + 1];
    if (offset == ~uint64_t{0} && nbytes == ~uint64_t{0}) {
      return absl::NotFoundError(absl::StrCat(file, ": inner chunk ", inner, " is empty"));
    }
    if (nbytes > max_bytes || offset > shard_size_ || nbytes > shard_size_ - offset) {
      return absl::DataLossError(
          absl::StrCat(file, ": shard index entry ", inner, " (offset ", offset, ", ", nbytes,
                       " bytes) lies outside the shard's ", shard_size_, " bytes"));
    }
    return zarr::ReadRangeAt(shard_fd_, file, offset, nbytes, &raw_);
  }

  // Decodes every chunk of chunk row cz into layer_ (host byte order).
  absl::Status LoadLayer(int64_t cz) {
    const ArrayMeta& a = r_.array;
    const size_t nd = a.shape.size();
    const int64_t cdz = a.chunks[nd - 3], cdy = a.chunks[nd - 2], cdx = a.chunks[nd - 1];
    const int64_t nx = info_.nx, ny = info_.ny;
    const int64_t depth = std::min(cdz, info_.nz - cz * cdz);
    layer_.resize(static_cast<size_t>(depth) * info_.slice_bytes());
    size_t lead_offset = 0;  // element offset of the chosen t/c inside a chunk
    std::vector<int64_t> idx = ChunkIndex(cz, &lead_offset);
    const size_t chunk_bytes = chunk_elems_ * es_;
    for (int64_t cy = 0; cy * cdy < ny; ++cy) {
      for (int64_t cx = 0; cx * cdx < nx; ++cx) {
        idx[nd - 2] = cy;
        idx[nd - 1] = cx;
        const std::string file = ChunkPath(idx);
        const int64_t rows = std::min(cdy, ny - cy * cdy), cols = std::min(cdx, nx - cx * cdx);
        const uint8_t* chunk = nullptr;
        absl::Status st =
            ReadChunk(idx, file, a.has_compression ? 2 * chunk_bytes + (1 << 20) : chunk_bytes);
        if (absl::IsNotFound(st)) {
          FillBlock(depth, cy * cdy, cx * cdx, rows, cols);
          continue;
        }
        if (!st.ok()) return st;
        const std::string where = absl::StrCat(file, ": chunk (", absl::StrJoin(idx, ", "), ")");
        if (a.has_compression) {
          const uint8_t* encoded = reinterpret_cast<const uint8_t*>(raw_.data());
          st = zarr::CheckDecodedSize(a.compression, encoded, raw_.size(), chunk_bytes);
          if (!st.ok()) return absl::DataLossError(absl::StrCat(where, ": ", st.message()));
          // Uninitialised: a damaged chunk fails before its declared size is touched.
          if (decoded_size_ < chunk_bytes) {
            decoded_.reset(new uint8_t[chunk_bytes]);
            decoded_size_ = chunk_bytes;
          }
          st = zarr::Decode(a.compression, reinterpret_cast<const uint8_t*>(raw_.data()),
                            raw_.size(), decoded_.get(), chunk_bytes);
          if (!st.ok()) return absl::DataLossError(absl::StrCat(where, ": ", st.message()));
          chunk = decoded_.get();
        } else {
          if (raw_.size() != chunk_bytes) {
            return absl::DataLossError(absl::StrCat(
                where, ": ", raw_.size() < chunk_bytes ? "truncated" : "size mismatch",
                ": uncompressed chunk has ", raw_.size(), " bytes, expected ", chunk_bytes));
          }
          chunk = reinterpret_cast<const uint8_t*>(raw_.data());
        }
        for (int64_t z = 0; z < depth; ++z) {
          for (int64_t y = 0; y < rows; ++y) {
            const size_t from =
                (lead_offset + static_cast<size_t>(z * stride_[nd - 3] + y * stride_[nd - 2])) *
                es_;
            const size_t to = static_cast<size_t>((z * ny + cy * cdy + y) * nx + cx * cdx) * es_;
            std::memcpy(layer_.data() + to, chunk + from, static_cast<size_t>(cols) * es_);
          }
        }
      }
    }
    if (swap_) SwapBytesInPlace(layer_.data(), layer_.size() / es_, es_);
    layer_cz_ = cz;
    return absl::OkStatus();
  }

  // A missing chunk: its part of the layer holds fill_value (one row built, then copied).
  void FillBlock(int64_t depth, int64_t y0, int64_t x0, int64_t rows, int64_t cols) {
    fill_row_.resize(static_cast<size_t>(cols) * es_);
    for (int64_t x = 0; x < cols; ++x) {
      std::memcpy(fill_row_.data() + x * es_, r_.array.fill.data(), es_);
    }
    for (int64_t z = 0; z < depth; ++z) {
      for (int64_t y = 0; y < rows; ++y) {
        uint8_t* dst =
            layer_.data() + static_cast<size_t>((z * info_.ny + y0 + y) * info_.nx + x0) * es_;
        std::memcpy(dst, fill_row_.data(), fill_row_.size());
      }
    }
  }

  Resolved r_;
  std::vector<int64_t> lead_;    // indices on the leading (t, c, ...) axes
  std::vector<int64_t> stride_;  // element strides inside a chunk
  size_t chunk_elems_ = 0;
  size_t es_ = 1;
  bool swap_ = false;
  int64_t layer_cz_ = -1;
  std::vector<uint8_t> layer_;  // one chunk-z layer: depth x ny x nx
  std::string raw_;             // one chunk file
  std::string shard_file_;      // the shard whose index is in shard_index_
  int shard_fd_ = -1;           // that shard, open
  uint64_t shard_size_ = 0;
  std::vector<uint64_t> shard_index_;
  std::vector<uint8_t> fill_row_;
  std::unique_ptr<uint8_t[]> decoded_;  // one decoded chunk
  size_t decoded_size_ = 0;
};

uint64_t CeilDiv(uint64_t a, uint64_t b) { return (a + b - 1) / b; }

// See kFreeChunks. info's extents are validated (at most 2^20 on each axis).
absl::Status CheckChunkCount(const std::string& file, const ArrayMeta& a, const VolumeInfo& info) {
  const size_t nd = a.chunks.size();
  const uint64_t cz = static_cast<uint64_t>(a.chunks[nd - 3]),
                 cy = static_cast<uint64_t>(a.chunks[nd - 2]),
                 cx = static_cast<uint64_t>(a.chunks[nd - 1]);
  const uint64_t nx = static_cast<uint64_t>(info.nx), ny = static_cast<uint64_t>(info.ny),
                 nz = static_cast<uint64_t>(std::max<int64_t>(info.nz, 1));
  const uint64_t per_row = CeilDiv(ny, cy) * CeilDiv(nx, cx);
  const uint64_t total = per_row * CeilDiv(nz, cz);
  const uint64_t row_voxels = nx * ny * std::min(cz, nz), voxels = nx * ny * nz;
  const bool row_ok = per_row <= std::max(kFreeChunks, row_voxels / kMinChunkVoxels);
  if (row_ok && total <= std::max(kFreeChunks, voxels / kMinChunkVoxels)) return absl::OkStatus();
  return MetaError(
      file, absl::StrCat("chunks of ", cz, "x", cy, "x", cx, " voxels: its ", nz, "x", ny, "x", nx,
                         " voxels lie in ", row_ok ? total : per_row,
                         row_ok ? " chunks" : " chunks per chunk row",
                         ", each a file or shard range to read; tandem reads arrays of at most ",
                         kFreeChunks, " chunks, or whose chunks hold ", kMinChunkVoxels,
                         " voxels or more on average (1x64x64, 16x16x16 or larger): rechunk it"));
}

// growing: an array with fewer than 2 planes (so far) is not an error (follow mode counts
// its planes).
absl::StatusOr<std::unique_ptr<ZarrSliceSource>> OpenResolved(const std::string& path, Resolved r,
                                                              const ZarrReadOptions& opts,
                                                              bool growing) {
  const ArrayMeta& a = r.array;
  const std::string& file = a.meta_file;
  const size_t nd = a.shape.size();
  if (a.chunks.size() != nd) {
    return MetaError(file, absl::StrCat("inconsistent metadata: shape has ", nd,
                                        " dimensions but chunks has ", a.chunks.size()));
  }
  if (nd < 3) {
    return MetaError(file,
                     absl::StrCat("array has ", nd, " dimensions; a volume needs 3 (z, y, x)"));
  }
  uint64_t chunk_elems = 1;
  for (size_t d = 0; d < nd; ++d) {
    if (a.shape[d] < 0) return MetaError(file, "negative shape");
    if (a.shape[d] > kMaxShape) {
      return MetaError(file, absl::StrCat("shape ", a.shape[d], " on axis ", d,
                                          " is beyond any volume (at most 2^40)"));
    }
    if (a.chunks[d] < 1 || a.chunks[d] > (int64_t{1} << 31)) {
      return MetaError(file, absl::StrCat("inconsistent metadata: chunk size ", a.chunks[d],
                                          " on axis ", d, " (must be at least 1)"));
    }
    chunk_elems *= static_cast<uint64_t>(a.chunks[d]);
    if (chunk_elems * DTypeSize(a.dtype) > kMaxChunkBytes) {
      return MetaError(file, absl::StrCat("chunks of ", absl::StrJoin(a.chunks, "x"),
                                          " elements are too large (at most 512 MiB a chunk)"));
    }
  }
  uint64_t inner_per_shard = 1;
  if (a.sharded) {
    for (size_t d = 0; d < nd; ++d) {
      if (a.shard.size() != nd || a.shard[d] < 1 || a.shard[d] > kMaxShape ||
          a.shard[d] % a.chunks[d] != 0) {
        return MetaError(
            file, absl::StrCat("inconsistent metadata: shard shape ", absl::StrJoin(a.shard, "x"),
                               " is not a multiple of the inner chunk shape ",
                               absl::StrJoin(a.chunks, "x")));
      }
      // Both factors at most 2^40 and 2^24 before the check: no overflow.
      inner_per_shard *= static_cast<uint64_t>(a.shard[d] / a.chunks[d]);
      if (inner_per_shard > (uint64_t{1} << 24)) {
        return MetaError(file, "sharding: more than 2^24 inner chunks per shard");
      }
    }
  }
  // Axis roles: the last three must be z, y, x (when named).
  if (!r.axis_names.empty()) {
    const std::string order =
        absl::StrCat(r.axis_names[nd - 3], r.axis_names[nd - 2], r.axis_names[nd - 1]);
    if (order != "zyx") {
      return MetaError(file, absl::StrCat("axes ", absl::StrJoin(r.axis_names, ","),
                                          ": the last three must be z, y, x"));
    }
  }
  std::vector<int64_t> lead(nd - 3, 0);
  std::string lead_text;
  for (size_t d = 0; d + 3 < nd; ++d) {
    const std::string name = r.axis_names.empty() ? "" : r.axis_names[d];
    const std::string type = r.axis_types.empty() ? "" : r.axis_types[d];
    if (type == "time" || name == "t") lead[d] = opts.t;
    if (type == "channel" || name == "c") lead[d] = opts.c;
    if (lead[d] < 0 || lead[d] >= a.shape[d]) {
      return absl::InvalidArgumentError(absl::StrCat(path, ": index ", lead[d], " on axis ",
                                                     name.empty() ? absl::StrCat(d) : name,
                                                     " is outside its ", a.shape[d], " entries"));
    }
    absl::StrAppend(&lead_text, lead_text.empty() ? "" : ", ",
                    name.empty() ? absl::StrCat("axis ", d) : name, "=", lead[d]);
  }
  VolumeInfo info;
  info.nz = a.shape[nd - 3];
  info.ny = a.shape[nd - 2];
  info.nx = a.shape[nd - 1];
  info.dtype = a.dtype;
  info.spacing_known = !r.scale.empty();
  if (!r.scale.empty()) {
    for (int k = 0; k < 3; ++k) {
      info.spacing[k] = r.scale[nd - 1 - k];
      info.origin[k] = r.translation[nd - 1 - k];
    }
  }
  if (info.nz == 0 && !growing) {
    return MetaError(file, "the array has no planes yet (shape 0 along z)");
  }
  VolumeInfo checked = info;
  if (growing && checked.nz < 2) checked.nz = 0;
  if (absl::Status st = ValidateVolumeInfo(checked); !st.ok()) {
    return absl::Status(st.code(), absl::StrCat(file, ": ", st.message()));
  }
  if (static_cast<uint64_t>(std::min(a.chunks[nd - 3], info.nz)) * info.slice_bytes() >
      kMaxLayerBytes) {
    return MetaError(file, absl::StrCat("a layer of chunks ", a.chunks[nd - 3],
                                        " planes deep is too large to hold (at most 1 GiB)"));
  }
  if (absl::Status st = CheckChunkCount(file, a, info); !st.ok()) return st;
  info.suggested_isovalues = a.isovalues;
  info.description = r.what;
  if (!lead_text.empty()) absl::StrAppend(&info.description, ", ", lead_text);
  if (!r.axis_units.empty() && !r.axis_units[nd - 1].empty()) {
    absl::StrAppend(&info.description, "; units z ", r.axis_units[nd - 3], ", y ",
                    r.axis_units[nd - 2], ", x ", r.axis_units[nd - 1]);
  }
  if (opts.first_plane < 0 || opts.first_plane > info.nz) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": first plane ", opts.first_plane,
                                                   " is outside the array's ", info.nz, " planes"));
  }
  return std::make_unique<ZarrSliceSource>(path, std::move(r), std::move(info), std::move(lead),
                                           opts.first_plane);
}

absl::StatusOr<std::unique_ptr<ZarrSliceSource>> OpenZarrSource(const std::string& path,
                                                                const ZarrReadOptions& opts,
                                                                bool growing) {
  std::string root = path;
  while (root.size() > 1 && root.back() == '/') root.pop_back();
  try {  // the checks should make json access safe; never let an exception escape
    absl::StatusOr<Resolved> r = Resolve(root, opts.array);
    if (!r.ok()) return r.status();
    return OpenResolved(path, *std::move(r), opts, growing);
  } catch (const json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": bad Zarr metadata: ", e.what()));
  }
}

}  // namespace

bool LooksLikeZarr(const std::string& path) {
  std::string p = path;
  while (p.size() > 1 && p.back() == '/') p.pop_back();
  if (absl::AsciiStrToLower(p).ends_with(".zarr")) return true;
  std::error_code ec;
  if (!fs::is_directory(p, ec)) return false;
  for (const char* f : {".zarray", ".zgroup", ".zattrs", "zarr.json"}) {
    if (FileExists(fs::path(p) / f)) return true;
  }
  return false;
}

}  // namespace internal

std::pair<std::string, std::string> SplitZarrSelector(const std::string& path) {
  std::error_code ec;
  const size_t hash = path.rfind('#');
  if (hash == std::string::npos || std::filesystem::exists(path, ec)) return {path, ""};
  return {path.substr(0, hash), path.substr(hash + 1)};
}

absl::StatusOr<std::unique_ptr<SliceSource>> OpenZarrVolume(const std::string& path,
                                                            const ZarrReadOptions& opts) {
  absl::StatusOr<std::unique_ptr<internal::ZarrSliceSource>> src =
      internal::OpenZarrSource(path, opts, /*growing=*/false);
  if (!src.ok()) return src.status();
  return std::unique_ptr<SliceSource>(std::move(*src));
}

absl::StatusOr<int64_t> CountCompleteZarrPlanes(const std::string& path,
                                                const ZarrReadOptions& opts, int64_t known) {
  ZarrReadOptions o = opts;
  o.first_plane = 0;
  absl::StatusOr<std::unique_ptr<internal::ZarrSliceSource>> src =
      internal::OpenZarrSource(path, o, /*growing=*/true);
  if (!src.ok()) return src.status();
  return (*src)->CompletePlanes(known);
}

// ---------------------------------------------------------------------------------------
// Writer: Zarr v2 / v3, optionally an OME-Zarr image, written one chunk-z layer at a time.

namespace internal {
namespace {

using ojson = nlohmann::ordered_json;

ojson ZarrCompressorJson(const ZarrWriteOptions& o, size_t typesize) {
  const bool v3 = o.version == 3;
  switch (o.compressor) {
    case ZarrCompressor::kNone:
      return nullptr;
    case ZarrCompressor::kGzip:
      return v3 ? ojson{{"name", "gzip"}, {"configuration", {{"level", o.level}}}}
                : ojson{{"id", "gzip"}, {"level", o.level}};
    case ZarrCompressor::kZstd:
      return v3 ? ojson{{"name", "zstd"},
                        {"configuration", {{"level", o.level}, {"checksum", false}}}}
                : ojson{{"id", "zstd"}, {"level", o.level}};
    case ZarrCompressor::kBloscLz4:
    case ZarrCompressor::kBloscZstd: {
      const char* cname = o.compressor == ZarrCompressor::kBloscLz4 ? "lz4" : "zstd";
      if (v3) {
        return ojson{{"name", "blosc"},
                     {"configuration",
                      {{"cname", cname},
                       {"clevel", o.level},
                       {"shuffle", typesize > 1 ? "shuffle" : "noshuffle"},
                       {"typesize", typesize},
                       {"blocksize", 0}}}};
      }
      return ojson{{"id", "blosc"},
                   {"cname", cname},
                   {"clevel", o.level},
                   {"shuffle", typesize > 1 ? 1 : 0},
                   {"blocksize", 0}};
    }
  }
  return nullptr;
}

class ZarrAppenderImpl final : public ZarrAppender {
 public:
  ZarrAppenderImpl(std::string path, const VolumeInfo& info, const ZarrWriteOptions& opts)
      : path_(std::move(path)), info_(info), opts_(opts) {
    array_path_ = opts_.ome ? (std::filesystem::path(path_) / "0").string() : path_;
    es_ = DTypeSize(info_.dtype);
    swap_ = opts_.big_endian == kHostIsLittleEndian && es_ > 1;
    // y and x chunks no larger than the plane (0: the whole plane); z as asked.
    chunks_[0] = opts_.chunks[0];
    chunks_[1] = opts_.chunks[1] > 0 ? std::min(opts_.chunks[1], info_.ny) : info_.ny;
    chunks_[2] = opts_.chunks[2] > 0 ? std::min(opts_.chunks[2], info_.nx) : info_.nx;
    layer_.assign(static_cast<size_t>(chunks_[0]) * info_.slice_bytes(), 0);
    if (opts_.compressor != ZarrCompressor::kNone) {
      compression_.level = opts_.level;
      switch (opts_.compressor) {
        case ZarrCompressor::kGzip:
          compression_.kind = zarr::Compression::kGzip;
          break;
        case ZarrCompressor::kZstd:
          compression_.kind = zarr::Compression::kZstd;
          break;
        default:
          compression_.kind = zarr::Compression::kBlosc;
          compression_.blosc_cname = opts_.compressor == ZarrCompressor::kBloscLz4 ? "lz4" : "zstd";
          compression_.blosc_shuffle = es_ > 1 ? 1 : 0;
          break;
      }
    }
  }

  absl::Status Start() {
    std::error_code ec;
    for (const char* f : {".zarray", ".zgroup", ".zattrs", "zarr.json"}) {
      if (std::filesystem::exists(std::filesystem::path(path_) / f, ec)) {
        return absl::AlreadyExistsError(
            absl::StrCat(path_, ": already holds a Zarr store (remove it first)"));
      }
    }
    std::filesystem::create_directories(array_path_, ec);
    if (ec) {
      return absl::InternalError(absl::StrCat(array_path_, ": cannot create: ", ec.message()));
    }
    if (opts_.ome) {
      if (absl::Status st = WriteGroup(); !st.ok()) return st;
    }
    if (opts_.version == 2 && !info_.suggested_isovalues.empty()) {
      const std::string attrs = (std::filesystem::path(array_path_) / ".zattrs").string();
      if (absl::Status st = WriteJson(attrs, ArrayAttributes()); !st.ok()) return st;
    }
    return WriteArrayMeta();
  }

  absl::Status Append(const uint8_t* plane) override {
    if (finished_) return absl::FailedPreconditionError(absl::StrCat(path_, ": already finished"));
    const size_t bytes = info_.slice_bytes();
    uint8_t* dst = layer_.data() + static_cast<size_t>(planes_ - visible_) * bytes;
    std::memcpy(dst, plane, bytes);
    if (swap_) SwapBytesInPlace(dst, info_.slice_voxels(), es_);
    ++planes_;
    if (planes_ - visible_ == chunks_[0]) return FlushLayer(planes_);
    return absl::OkStatus();
  }

  absl::Status Finish() override {
    if (finished_) return absl::OkStatus();
    finished_ = true;
    if (planes_ > visible_) {
      // Planes past the end of the array in the last chunk row hold the fill value (0).
      const size_t used = static_cast<size_t>(planes_ - visible_) * info_.slice_bytes();
      std::fill(layer_.begin() + static_cast<std::ptrdiff_t>(used), layer_.end(), 0);
      return FlushLayer(planes_);
    }
    return absl::OkStatus();
  }

  int64_t planes() const override { return planes_; }
  int64_t planes_visible() const override { return visible_; }
  const std::string& array_path() const override { return array_path_; }

 private:
  absl::Status WriteJson(const std::string& file, const ojson& j) {
    const std::string text = j.dump(2, ' ', false, ojson::error_handler_t::replace);
    return zarr::WriteFileAtomic(file, text.data(), text.size());
  }

  // The volume's suggested iso-values, which OpenVolume reads back (tandem's own key).
  ojson ArrayAttributes() const {
    ojson a = ojson::object();
    if (!info_.suggested_isovalues.empty()) a["suggested_isovalues"] = info_.suggested_isovalues;
    return a;
  }

  absl::Status WriteGroup() {
    const auto& s = info_.spacing;
    const auto& o = info_.origin;
    ojson axes = ojson::array();
    for (const char* name : {"z", "y", "x"}) {
      axes.push_back({{"name", name}, {"type", "space"}, {"unit", opts_.unit}});
    }
    ojson ms = {{"name", info_.description.empty() ? std::string("tandem") : info_.description},
                {"axes", axes},
                {"datasets",
                 {{{"path", "0"},
                   {"coordinateTransformations",
                    {{{"type", "scale"}, {"scale", {s[2], s[1], s[0]}}},
                     {{"type", "translation"}, {"translation", {o[2], o[1], o[0]}}}}}}}}};
    const std::filesystem::path root(path_);
    if (opts_.version == 3) {
      ojson ome = {{"version", "0.5"}, {"multiscales", {ms}}};
      return WriteJson(
          (root / "zarr.json").string(),
          {{"zarr_format", 3}, {"node_type", "group"}, {"attributes", {{"ome", ome}}}});
    }
    ms["version"] = "0.4";
    if (absl::Status st = WriteJson((root / ".zgroup").string(), {{"zarr_format", 2}}); !st.ok()) {
      return st;
    }
    return WriteJson((root / ".zattrs").string(), {{"multiscales", {ms}}});
  }

  absl::Status WriteArrayMeta() {
    const ojson shape = {visible_, info_.ny, info_.nx};
    const ojson chunks = {chunks_[0], chunks_[1], chunks_[2]};
    const ojson fill = info_.dtype == DType::kFloat32 ? ojson(0.0) : ojson(0);
    const std::filesystem::path dir(array_path_);
    if (opts_.version == 3) {
      ojson codecs = {{{"name", "bytes"},
                       {"configuration", {{"endian", opts_.big_endian ? "big" : "little"}}}}};
      if (opts_.compressor != ZarrCompressor::kNone)
        codecs.push_back(ZarrCompressorJson(opts_, es_));
      return WriteJson(
          (dir / "zarr.json").string(),
          {{"zarr_format", 3},
           {"node_type", "array"},
           {"shape", shape},
           {"data_type", std::string(DTypeName(info_.dtype))},
           {"chunk_grid", {{"name", "regular"}, {"configuration", {{"chunk_shape", chunks}}}}},
           {"chunk_key_encoding", {{"name", "default"}, {"configuration", {{"separator", "/"}}}}},
           {"fill_value", fill},
           {"codecs", codecs},
           {"attributes", ArrayAttributes()},
           {"dimension_names", {"z", "y", "x"}}});
    }
    const char kind = info_.dtype == DType::kFloat32 ? 'f'
                      : info_.dtype == DType::kInt16 ? 'i'
                                                     : 'u';
    const std::string dtype =
        es_ == 1 ? "|u1" : absl::StrCat(opts_.big_endian ? ">" : "<", std::string(1, kind), es_);
    return WriteJson((dir / ".zarray").string(),
                     {{"zarr_format", 2},
                      {"shape", shape},
                      {"chunks", chunks},
                      {"dtype", dtype},
                      {"compressor", ZarrCompressorJson(opts_, es_)},
                      {"fill_value", fill},
                      {"order", "C"},
                      {"filters", nullptr},
                      {"dimension_separator", std::string(1, opts_.dimension_separator)}});
  }

  // Writes chunk row visible_ / chunks_[0] from layer_, then shows `shown` planes.
  absl::Status FlushLayer(int64_t shown) {
    const int64_t cz = visible_ / chunks_[0];
    const int64_t cdz = chunks_[0], cdy = chunks_[1], cdx = chunks_[2];
    chunk_.resize(static_cast<size_t>(cdz * cdy * cdx) * es_);
    for (int64_t cy = 0; cy * cdy < info_.ny; ++cy) {
      for (int64_t cx = 0; cx * cdx < info_.nx; ++cx) {
        std::fill(chunk_.begin(), chunk_.end(), 0);  // edge chunks: fill value past the edge
        const int64_t rows = std::min(cdy, info_.ny - cy * cdy);
        const int64_t cols = std::min(cdx, info_.nx - cx * cdx);
        for (int64_t z = 0; z < cdz; ++z) {
          for (int64_t y = 0; y < rows; ++y) {
            const size_t from =
                static_cast<size_t>((z * info_.ny + cy * cdy + y) * info_.nx + cx * cdx) * es_;
            std::memcpy(chunk_.data() + static_cast<size_t>((z * cdy + y) * cdx) * es_,
                        layer_.data() + from, static_cast<size_t>(cols) * es_);
          }
        }
        const std::string key =
            opts_.version == 3 ? absl::StrCat("c/", cz, "/", cy, "/", cx)
                               : absl::StrCat(cz, std::string(1, opts_.dimension_separator), cy,
                                              std::string(1, opts_.dimension_separator), cx);
        const std::filesystem::path file = std::filesystem::path(array_path_) / key;
        if (key.find('/') != std::string::npos) {
          std::error_code ec;
          std::filesystem::create_directories(file.parent_path(), ec);
        }
        const uint8_t* data = chunk_.data();
        size_t n = chunk_.size();
        if (opts_.compressor != ZarrCompressor::kNone) {
          if (absl::Status st =
                  zarr::Encode(compression_, chunk_.data(), chunk_.size(), es_, &encoded_);
              !st.ok()) {
            return absl::Status(st.code(), absl::StrCat(file.string(), ": ", st.message()));
          }
          data = encoded_.data();
          n = encoded_.size();
        }
        if (absl::Status st = zarr::WriteFileAtomic(file.string(), data, n); !st.ok()) return st;
      }
    }
    visible_ = shown;
    return WriteArrayMeta();
  }

  std::string path_, array_path_;
  VolumeInfo info_;
  ZarrWriteOptions opts_;
  std::array<int64_t, 3> chunks_{};
  size_t es_ = 1;
  bool swap_ = false;
  zarr::Compression compression_;
  int64_t planes_ = 0, visible_ = 0;
  bool finished_ = false;
  std::vector<uint8_t> layer_, chunk_, encoded_;
};

}  // namespace
}  // namespace internal

absl::StatusOr<ZarrCompressor> ParseZarrCompressor(const std::string& name) {
  if (name == "none") return ZarrCompressor::kNone;
  if (name == "gzip") return ZarrCompressor::kGzip;
  if (name == "zstd") return ZarrCompressor::kZstd;
  if (name == "blosc-lz4") return ZarrCompressor::kBloscLz4;
  if (name == "blosc-zstd") return ZarrCompressor::kBloscZstd;
  return absl::InvalidArgumentError(absl::StrCat("unknown Zarr compressor '", name,
                                                 "' (none, gzip, zstd, blosc-lz4, blosc-zstd)"));
}

absl::StatusOr<std::unique_ptr<ZarrAppender>> ZarrAppender::Create(const std::string& path,
                                                                   const VolumeInfo& info,
                                                                   const ZarrWriteOptions& opts) {
  VolumeInfo grid = info;
  grid.nz = 0;
  if (absl::Status st = ValidateVolumeInfo(grid); !st.ok()) {
    return absl::Status(st.code(), absl::StrCat(path, ": ", st.message()));
  }
  if (opts.version != 2 && opts.version != 3) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": Zarr version ", opts.version, " (2 or 3)"));
  }
  if (opts.chunks[0] < 1 || opts.chunks[1] < 0 || opts.chunks[2] < 0) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": chunk shape ", opts.chunks[0], ",", opts.chunks[1], ",", opts.chunks[2],
        " (z at least 1; y and x at least 1, or 0 for the whole extent)"));
  }
  if (opts.dimension_separator != '.' && opts.dimension_separator != '/') {
    return absl::InvalidArgumentError(absl::StrCat(path, ": dimension separator must be . or /"));
  }
  if (!info.axis_aligned()) {
    return absl::UnimplementedError(
        absl::StrCat(path, ": OME-Zarr stores scale and translation only, not rotated or "
                           "flipped grid directions"));
  }
  auto appender = std::make_unique<internal::ZarrAppenderImpl>(path, info, opts);
  if (absl::Status st = appender->Start(); !st.ok()) return st;
  return std::unique_ptr<ZarrAppender>(std::move(appender));
}

absl::Status WriteZarr(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                       const ZarrWriteOptions& opts) {
  if (info.nz < 1) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": nz must be known to write a volume"));
  }
  ZarrWriteOptions o = opts;
  if (o.chunks[0] == 0) o.chunks[0] = info.nz;
  absl::StatusOr<std::unique_ptr<ZarrAppender>> w = ZarrAppender::Create(path, info, o);
  if (!w.ok()) return w.status();
  std::vector<uint8_t> slice;
  for (int64_t z = 0; z < info.nz; ++z) {
    if (absl::Status st = internal::FetchSlice(path, info, slice_fn, z, &slice); !st.ok()) {
      return st;
    }
    if (absl::Status st = (*w)->Append(slice.data()); !st.ok()) return st;
  }
  return (*w)->Finish();
}

}  // namespace tandem
