// Neuroglancer's precomputed multi-resolution meshes: quantization into octree nodes, the
// per-segment manifest, the info files and the shards (tandem/io/neuroglancer.h).
#include "tandem/io/neuroglancer.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>

#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"

namespace tandem::io {
namespace {

void PutU32(std::string* out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
void PutF32(std::string* out, float f) { PutU32(out, std::bit_cast<uint32_t>(f)); }

absl::Status WriteFile(const std::filesystem::path& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (out) out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (out) out.close();
  if (!out) return absl::UnavailableError(absl::StrCat(path.string(), ": cannot write"));
  return absl::OkStatus();
}

nlohmann::json ShardingJson(const NeuroglancerSharding& s) {
  return {{"@type", "neuroglancer_uint64_sharded_v1"},
          {"preshift_bits", s.preshift_bits},
          {"hash", s.murmurhash ? "murmurhash3_x86_128" : "identity"},
          {"minishard_bits", s.minishard_bits},
          {"shard_bits", s.shard_bits},
          {"minishard_index_encoding", s.gzip_minishard_index ? "gzip" : "raw"},
          {"data_encoding", s.gzip_data ? "gzip" : "raw"}};
}

// The segmentation's own info: a volume Neuroglancer places in nanometres, whose "mesh" is
// the folder beside it. It has no voxel chunks: the export is meshes only.
nlohmann::json VolumeInfoJson(const VolumeInfo& grid, double nm) {
  nlohmann::json resolution = nlohmann::json::array(), offset = nlohmann::json::array(),
                 chunk = nlohmann::json::array();
  const int64_t size[3] = {std::max<int64_t>(grid.nx, 1), std::max<int64_t>(grid.ny, 1),
                           std::max<int64_t>(grid.nz, 1)};
  for (int j = 0; j < 3; ++j) {
    resolution.push_back(grid.spacing[j] * nm);
    offset.push_back(std::llround(grid.origin[j] / grid.spacing[j]));
    chunk.push_back(std::min<int64_t>(size[j], 64));
  }
  return {{"@type", "neuroglancer_multiscale_volume"},
          {"type", "segmentation"},
          {"data_type", "uint64"},
          {"num_channels", 1},
          {"mesh", "mesh"},
          {"scales",
           {{{"key", "data"},
             {"size", {size[0], size[1], size[2]}},
             {"resolution", resolution},
             {"voxel_offset", offset},
             {"chunk_sizes", {chunk}},
             {"encoding", "raw"}}}}};
}

absl::Status CheckSegment(const NeuroglancerSegment& s, size_t lods) {
  if (s.lods.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("segment ", s.id, ": no level of detail"));
  }
  if (lods != 0 && s.lods.size() != lods) {
    return absl::InvalidArgumentError(absl::StrCat(
        "segment ", s.id, ": ", s.lods.size(), " levels of detail, the first segment has ", lods));
  }
  for (size_t k = 0; k < s.lods.size(); ++k) {
    const IndexedMesh& m = s.lods[k];
    if (m.indices.size() % 3 != 0) {
      return absl::InvalidArgumentError(
          absl::StrCat("segment ", s.id, " level ", k, ": index count not a multiple of 3"));
    }
    for (uint32_t i : m.indices) {
      if (i >= m.positions.size()) {
        return absl::InvalidArgumentError(
            absl::StrCat("segment ", s.id, " level ", k, ": index ", i, " out of range"));
      }
    }
    for (const Vec3& p : m.positions) {
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
        return absl::InvalidArgumentError(
            absl::StrCat("segment ", s.id, " level ", k, ": a position is not finite"));
      }
    }
  }
  return absl::OkStatus();
}

}  // namespace

std::vector<std::pair<LabelId, std::vector<IndexedMesh>>> JoinLevels(
    std::vector<std::vector<std::pair<LabelId, IndexedMesh>>> levels) {
  std::map<LabelId, std::vector<IndexedMesh>> by_label;
  for (size_t k = 0; k < levels.size(); ++k) {
    for (auto& [id, mesh] : levels[k]) {
      std::vector<IndexedMesh>& lods = by_label[id];
      lods.resize(levels.size());
      lods[k] = std::move(mesh);
    }
    levels[k].clear();
  }
  return {std::make_move_iterator(by_label.begin()), std::make_move_iterator(by_label.end())};
}

std::string EncodeManifest(const NeuroglancerManifest& m) {
  std::string out;
  for (float f : m.chunk_shape) PutF32(&out, f);
  for (float f : m.grid_origin) PutF32(&out, f);
  const size_t lods = m.lod_scales.size();
  PutU32(&out, static_cast<uint32_t>(lods));
  for (float f : m.lod_scales) PutF32(&out, f);
  for (size_t k = 0; k < lods; ++k) {
    for (int j = 0; j < 3; ++j)
      PutF32(&out, k < m.vertex_offsets.size() ? m.vertex_offsets[k][j] : 0);
  }
  for (size_t k = 0; k < lods; ++k) {
    PutU32(&out, static_cast<uint32_t>(k < m.positions.size() ? m.positions[k].size() : 0));
  }
  for (size_t k = 0; k < lods && k < m.positions.size(); ++k) {
    // [3, n]: all x, then all y, then all z; then the n sizes.
    for (int j = 0; j < 3; ++j) {
      for (const auto& p : m.positions[k]) PutU32(&out, p[j]);
    }
    for (size_t i = 0; i < m.positions[k].size(); ++i) {
      PutU32(&out, i < m.sizes[k].size() ? m.sizes[k][i] : 0);
    }
  }
  return out;
}

absl::StatusOr<QuantizedSegment> QuantizeSegment(const NeuroglancerSegment& segment, int bits) {
  if (bits != 10 && bits != 16) {
    return absl::InvalidArgumentError(
        absl::StrCat("vertex_quantization_bits must be 10 or 16, got ", bits));
  }
  if (absl::Status st = CheckSegment(segment, 0); !st.ok()) return st;
  double lo[3], hi[3];
  for (int j = 0; j < 3; ++j) {
    lo[j] = std::numeric_limits<double>::infinity();
    hi[j] = -lo[j];
  }
  for (const IndexedMesh& m : segment.lods) {
    for (const Vec3& p : m.positions) {
      const double v[3] = {p.x, p.y, p.z};
      for (int j = 0; j < 3; ++j) lo[j] = std::min(lo[j], v[j]), hi[j] = std::max(hi[j], v[j]);
    }
  }
  QuantizedSegment q;
  if (lo[0] > hi[0]) {  // no vertex at any level
    q.lods.resize(segment.lods.size());
    return q;
  }
  double extent = 0;
  for (int j = 0; j < 3; ++j) extent = std::max(extent, hi[j] - lo[j]);
  // A flat axis still needs a box; a tiny share of the largest one keeps steps meaningful.
  const double floor_extent = extent > 0 ? extent * 1e-3 : 1e-3;
  for (int j = 0; j < 3; ++j) {
    // float32 corner at or below lo and float32 size whose sum (as Neuroglancer adds them)
    // reaches hi: every vertex lies inside the finest node.
    float g = static_cast<float>(lo[j]);
    if (g > lo[j]) g = std::nextafter(g, -std::numeric_limits<float>::infinity());
    float c = static_cast<float>(std::max(hi[j] - double{g}, floor_extent));
    while (static_cast<float>(g + c) < hi[j] || double{g} + double{c} < hi[j]) {
      c = std::nextafter(c, std::numeric_limits<float>::infinity());
    }
    q.grid_origin[j] = g;
    q.chunk_shape[j] = c;
  }
  const double top = std::ldexp(1.0, bits) - 1;
  for (size_t k = 0; k < segment.lods.size(); ++k) {
    const IndexedMesh& m = segment.lods[k];
    NeuroglancerFragment f;
    f.indices = m.indices;
    f.positions.reserve(m.positions.size());
    // Level k's node is 2^k finest nodes wide; the segment fills its low octant, so its
    // 2x2x2 split (which Neuroglancer makes at 2^(bits-1)) never cuts a triangle.
    const double limit = k == 0 ? top : std::ldexp(1.0, bits - 1);
    for (const Vec3& p : m.positions) {
      const double v[3] = {p.x, p.y, p.z};
      std::array<uint32_t, 3> u;
      for (int j = 0; j < 3; ++j) {
        const double size = std::ldexp(double{q.chunk_shape[j]}, static_cast<int>(k));
        const double x = std::nearbyint((v[j] - q.grid_origin[j]) / size * top);
        u[j] = static_cast<uint32_t>(std::clamp(x, 0.0, limit));
      }
      f.positions.push_back(u);
    }
    q.lods.push_back(std::move(f));
  }
  return q;
}

Vec3 DequantizePosition(const QuantizedSegment& s, int lod, const std::array<uint32_t, 3>& q,
                        int bits) {
  const float top = static_cast<float>(std::ldexp(1.0, bits) - 1);
  float v[3];
  for (int j = 0; j < 3; ++j) {
    const float size = s.chunk_shape[j] * static_cast<float>(1 << lod);
    v[j] = s.grid_origin[j] + size * (static_cast<float>(q[j]) / top);
  }
  return {v[0], v[1], v[2]};
}

absl::Status WriteNeuroglancer(const std::string& dir, const VolumeInfo& grid,
                               std::span<const NeuroglancerSegment> segments,
                               const NeuroglancerOptions& options) {
  if (!options.encode) {
    return absl::InvalidArgumentError("neuroglancer export: no fragment encoder");
  }
  const int bits = options.vertex_quantization_bits;
  if (bits != 10 && bits != 16) {
    return absl::InvalidArgumentError(
        absl::StrCat("vertex_quantization_bits must be 10 or 16, got ", bits));
  }
  if (!(options.nm_per_unit > 0) || !std::isfinite(options.nm_per_unit)) {
    return absl::InvalidArgumentError(
        absl::StrCat("nm_per_unit must be positive, got ", options.nm_per_unit));
  }
  const size_t lods = segments.empty() ? options.lod_scales.size() : segments[0].lods.size();
  std::map<LabelId, size_t> ids;
  for (size_t i = 0; i < segments.size(); ++i) {
    if (absl::Status st = CheckSegment(segments[i], lods); !st.ok()) return st;
    if (!ids.emplace(segments[i].id, i).second) {
      return absl::InvalidArgumentError(absl::StrCat("two segments with id ", segments[i].id));
    }
  }
  std::vector<float> scales;
  const double finest = std::min({grid.spacing[0], grid.spacing[1], grid.spacing[2]});
  for (size_t k = 0; k < lods; ++k) {
    scales.push_back(static_cast<float>(
        k < options.lod_scales.size() ? options.lod_scales[k] : std::ldexp(finest, int(k))));
  }
  const NeuroglancerSharding sharding =
      options.choose_sharding ? ChooseSharding(segments.size()) : options.sharding;
  if (sharding.shard_bits < 0 || sharding.minishard_bits < 0 || sharding.preshift_bits < 0 ||
      sharding.shard_bits + sharding.minishard_bits > 64 || sharding.shard_bits > 32) {
    return absl::InvalidArgumentError("sharding: bits out of range");
  }

  std::error_code ec;
  const std::filesystem::path root(dir), mesh_dir = root / "mesh";
  std::filesystem::create_directories(mesh_dir, ec);
  if (ec) return absl::UnavailableError(absl::StrCat(mesh_dir.string(), ": ", ec.message()));
  const double nm = options.nm_per_unit;
  const nlohmann::json mesh_info = {{"@type", "neuroglancer_multilod_draco"},
                                    {"vertex_quantization_bits", bits},
                                    {"transform", {nm, 0, 0, 0, 0, nm, 0, 0, 0, 0, nm, 0}},
                                    {"lod_scale_multiplier", 1.0},
                                    {"sharding", ShardingJson(sharding)}};
  if (absl::Status st = WriteFile(mesh_dir / "info", mesh_info.dump(2) + "\n"); !st.ok()) {
    return st;
  }
  if (absl::Status st = WriteFile(root / "info", VolumeInfoJson(grid, nm).dump(2) + "\n");
      !st.ok()) {
    return st;
  }

  // One shard at a time: only its segments' fragments are held.
  std::map<uint64_t, std::vector<size_t>> by_shard;
  for (size_t i = 0; i < segments.size(); ++i) {
    by_shard[LocateChunk(segments[i].id, sharding).shard].push_back(i);
  }
  for (const auto& [shard, members] : by_shard) {
    std::vector<ShardChunk> chunks;
    chunks.reserve(members.size());
    for (size_t i : members) {
      const NeuroglancerSegment& s = segments[i];
      absl::StatusOr<QuantizedSegment> q = QuantizeSegment(s, bits);
      if (!q.ok()) return q.status();
      NeuroglancerManifest m;
      m.chunk_shape = q->chunk_shape;
      m.grid_origin = q->grid_origin;
      m.lod_scales = scales;
      m.vertex_offsets.assign(lods, {0, 0, 0});
      ShardChunk c;
      c.id = s.id;
      for (size_t k = 0; k < q->lods.size(); ++k) {
        std::string bytes;
        if (!q->lods[k].indices.empty()) {  // an empty node: size 0, never requested
          absl::StatusOr<std::string> e = options.encode(q->lods[k]);
          if (!e.ok()) {
            return absl::Status(e.status().code(), absl::StrCat("segment ", s.id, " level ", k,
                                                                ": ", e.status().message()));
          }
          bytes = *std::move(e);
        }
        m.positions.push_back({{0, 0, 0}});
        m.sizes.push_back({static_cast<uint32_t>(bytes.size())});
        c.prefix += bytes;
      }
      c.data = EncodeManifest(m);
      chunks.push_back(std::move(c));
    }
    absl::StatusOr<std::string> file = BuildShard(std::move(chunks), sharding);
    if (!file.ok()) return file.status();
    if (absl::Status st = WriteFile(mesh_dir / ShardFileName(shard, sharding), *file); !st.ok()) {
      return st;
    }
  }
  return absl::OkStatus();
}

}  // namespace tandem::io
