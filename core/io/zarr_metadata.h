// Zarr metadata, internal to the reader: one array's or group's metadata parsed and checked
// (zarr_metadata.cc), and a store path and selector resolved to one array (zarr_resolve.cc).
#ifndef TANDEM_IO_ZARR_METADATA_H_
#define TANDEM_IO_ZARR_METADATA_H_

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "nlohmann/json.hpp"
#include "tandem/volume.h"
#include "zarr_internal.h"

namespace tandem::io::internal::zarr {

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
  std::array<uint8_t, 8> fill{};  // one element in stored byte order
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
  nlohmann::json attrs = nlohmann::json::object();  // .zattrs (v2) or attributes (v3)
  std::string attrs_file;
};

// A node's directory: an array (with its metadata) or a group; NotFound when the directory
// does not exist, InvalidArgument naming the file for bad metadata.
absl::StatusOr<Node> LoadNode(const std::string& dir);

// What the chosen array is, and how its indices map to the world.
struct Resolved {
  ArrayMeta array;
  std::vector<std::string> axis_names;  // empty: the last three are z, y, x
  std::vector<std::string> axis_types;
  std::vector<std::string> axis_units;
  std::vector<double> scale, translation;  // per array dim; empty = identity
  std::string what;                        // for the description
};

// The array a store path and its selector (an array path, or a multiscale level) name.
absl::StatusOr<Resolved> Resolve(const std::string& root, const std::string& selector);

// InvalidArgument "file: what".
absl::Status MetaError(const std::string& file, absl::string_view what);
bool FileExists(const std::filesystem::path& p);

}  // namespace tandem::io::internal::zarr

#endif  // TANDEM_IO_ZARR_METADATA_H_
