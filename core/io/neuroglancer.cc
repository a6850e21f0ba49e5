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
#include <tuple>
#include <unordered_map>

#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"
#include "tandem/status_macros.h"

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

NeuroglancerGrid ChooseOctreeGrid(const VolumeInfo& grid,
                                  std::span<const NeuroglancerSegment> segments, int chunk_voxels) {
  NeuroglancerGrid g;
  for (int j = 0; j < 3; ++j) {
    const double sp = grid.spacing[j] > 0 ? grid.spacing[j] : 1.0;
    double lo = grid.origin[j];
    for (const NeuroglancerSegment& s : segments) {
      for (const IndexedMesh& m : s.lods) {
        for (const Vec3& p : m.positions) lo = std::min(lo, p[j]);
      }
    }
    // float32 corner at or below: every vertex sits at or above it as Neuroglancer adds.
    float o = static_cast<float>(lo - 0.5 * sp);
    if (o > lo - 0.5 * sp) o = std::nextafter(o, -std::numeric_limits<float>::infinity());
    g.grid_origin[j] = o;
    g.chunk_shape[j] = static_cast<float>(sp * chunk_voxels);
  }
  return g;
}

namespace {

// A convex polygon of a triangle cut by a cell box; at most 3 + 6 corners.
struct Polygon {
  std::array<Vec3, 12> v;
  int n = 0;
};

// The corner on the plane x_j = t along edge (a, b), computed from the edge's endpoints in
// one fixed order, so that the two segments sharing a triangle get the same bits.
Vec3 CutEdge(Vec3 a, Vec3 b, int j, double t) {
  if (std::tie(b.x, b.y, b.z) < std::tie(a.x, a.y, a.z)) std::swap(a, b);
  const double f = (t - a[j]) / (b[j] - a[j]);
  Vec3 p{a.x + (b.x - a.x) * f, a.y + (b.y - a.y) * f, a.z + (b.z - a.z) * f};
  p[j] = t;
  return p;
}

// Sutherland-Hodgman against x_j >= t (keep_above) or x_j <= t.
void ClipPlane(Polygon* poly, int j, double t, bool keep_above) {
  Polygon out;
  auto inside = [&](const Vec3& p) { return keep_above ? p[j] >= t : p[j] <= t; };
  for (int i = 0; i < poly->n; ++i) {
    const Vec3& a = poly->v[i];
    const Vec3& b = poly->v[(i + 1) % poly->n];
    const bool ia = inside(a), ib = inside(b);
    if (ia) out.v[out.n++] = a;
    if (ia != ib && out.n < 12) out.v[out.n++] = CutEdge(a, b, j, t);
  }
  *poly = out;
}

uint64_t CellKey(const std::array<int64_t, 3>& c) {
  return static_cast<uint64_t>(c[0]) | static_cast<uint64_t>(c[1]) << 21 |
         static_cast<uint64_t>(c[2]) << 42;
}
std::array<uint32_t, 3> KeyCell(uint64_t key) {
  const uint64_t m = (uint64_t{1} << 21) - 1;
  return {static_cast<uint32_t>(key & m), static_cast<uint32_t>(key >> 21 & m),
          static_cast<uint32_t>(key >> 42 & m)};
}
// Z-curve order, x the fastest bit (Neuroglancer's zorder3LessThan).
uint64_t Morton(const std::array<uint32_t, 3>& p) {
  uint64_t code = 0;
  for (int b = 0; b < 21; ++b) {
    for (int j = 0; j < 3; ++j) code |= static_cast<uint64_t>(p[j] >> b & 1) << (3 * b + j);
  }
  return code;
}

// One node's fragment being built: welded quantized corners and triangles.
class NodeBuilder {
 public:
  uint32_t Vertex(const std::array<uint32_t, 3>& q) {
    const uint64_t key = uint64_t{q[0]} | uint64_t{q[1]} << 21 | uint64_t{q[2]} << 42;
    auto [it, fresh] = index_.emplace(key, static_cast<uint32_t>(f_.positions.size()));
    if (fresh) f_.positions.push_back(q);
    return it->second;
  }
  // A corner of its own (a skirt's far corner): welded to nothing, so no strip pinches the
  // surface into a non-manifold vertex, which Draco's Edgebreaker cannot code.
  uint32_t Fresh(const std::array<uint32_t, 3>& q) {
    f_.positions.push_back(q);
    return static_cast<uint32_t>(f_.positions.size() - 1);
  }
  void Triangle(uint32_t a, uint32_t b, uint32_t c) {
    if (a == b || b == c || a == c) return;  // collapsed by quantization: no area left
    f_.indices.insert(f_.indices.end(), {a, b, c});
  }
  NeuroglancerFragment& fragment() { return f_; }

 private:
  NeuroglancerFragment f_;
  std::unordered_map<uint64_t, uint32_t> index_;
};

constexpr size_t kMaxCells = size_t{1} << 21;

}  // namespace

Vec3 DequantizePosition(const NeuroglancerGrid& g, int lod, const std::array<uint32_t, 3>& node,
                        const std::array<uint32_t, 3>& q, int bits) {
  const float top = static_cast<float>(std::ldexp(1.0, bits) - 1);
  float v[3];
  for (int j = 0; j < 3; ++j) {
    const float size = g.chunk_shape[j] * static_cast<float>(1 << lod);
    v[j] = g.grid_origin[j] + size * (static_cast<float>(node[j]) + static_cast<float>(q[j]) / top);
  }
  return {v[0], v[1], v[2]};
}

absl::StatusOr<std::vector<std::vector<NeuroglancerNode>>> BuildOctree(
    const NeuroglancerSegment& segment, const NeuroglancerGrid& g, int bits, double skirt) {
  if (bits != 10 && bits != 16) {
    return absl::InvalidArgumentError(
        absl::StrCat("vertex_quantization_bits must be 10 or 16, got ", bits));
  }
  TANDEM_RETURN_IF_ERROR(CheckSegment(segment, 0));
  const uint32_t top = (uint32_t{1} << bits) - 1, mid = uint32_t{1} << (bits - 1);
  std::vector<std::vector<NeuroglancerNode>> out(segment.lods.size());
  for (size_t k = 0; k < segment.lods.size(); ++k) {
    const IndexedMesh& m = segment.lods[k];
    const int lod = static_cast<int>(k);
    // Level k is cut at its nodes' faces and, above 0, their middle planes: cells of
    // half a node, which Neuroglancer's 2x2x2 partition never splits.
    const int shift = lod > 0 ? lod - 1 : 0;
    double cell[3], origin[3];
    for (int j = 0; j < 3; ++j) {
      cell[j] = std::ldexp(double{g.chunk_shape[j]}, shift);
      origin[j] = g.grid_origin[j];
    }
    std::map<uint64_t, std::vector<Vec3>> pieces;  // cell -> its triangles' corners
    for (size_t t = 0; t + 2 < m.indices.size(); t += 3) {
      const Vec3 tri[3] = {m.positions[m.indices[t]], m.positions[m.indices[t + 1]],
                           m.positions[m.indices[t + 2]]};
      std::array<int64_t, 3> lo, hi;
      for (int j = 0; j < 3; ++j) {
        double a = std::min({tri[0][j], tri[1][j], tri[2][j]});
        double b = std::max({tri[0][j], tri[1][j], tri[2][j]});
        lo[j] = std::max<int64_t>(0, static_cast<int64_t>(std::floor((a - origin[j]) / cell[j])));
        hi[j] = std::max<int64_t>(0, static_cast<int64_t>(std::floor((b - origin[j]) / cell[j])));
        if (static_cast<size_t>(hi[j]) >= kMaxCells) {
          return absl::InvalidArgumentError(absl::StrCat("segment ", segment.id, " level ", k,
                                                         ": a vertex lies 2^21 octree cells away"));
        }
      }
      std::array<int64_t, 3> c;
      for (c[2] = lo[2]; c[2] <= hi[2]; ++c[2]) {
        for (c[1] = lo[1]; c[1] <= hi[1]; ++c[1]) {
          for (c[0] = lo[0]; c[0] <= hi[0]; ++c[0]) {
            Polygon poly;
            poly.n = 3;
            std::copy(tri, tri + 3, poly.v.begin());
            const bool whole = lo == hi;  // in one cell: no cut
            for (int j = 0; j < 3 && !whole && poly.n >= 3; ++j) {
              const double a = origin[j] + cell[j] * static_cast<double>(c[j]);
              ClipPlane(&poly, j, a, true);
              if (poly.n >= 3) ClipPlane(&poly, j, origin[j] + cell[j] * double(c[j] + 1), false);
            }
            if (poly.n < 3) continue;
            // Fan from the least corner: the same triangles for both sides of an interface.
            int first = 0;
            for (int i = 1; i < poly.n; ++i) {
              const Vec3& p = poly.v[i];
              const Vec3& f = poly.v[first];
              if (std::tie(p.x, p.y, p.z) < std::tie(f.x, f.y, f.z)) first = i;
            }
            std::vector<Vec3>& piece = pieces[CellKey(c)];
            for (int i = 1; i + 1 < poly.n; ++i) {
              piece.push_back(poly.v[first]);
              piece.push_back(poly.v[(first + i) % poly.n]);
              piece.push_back(poly.v[(first + i + 1) % poly.n]);
            }
          }
        }
      }
    }
    // Cells into nodes (z-order of the node, then of the octant).
    std::map<uint64_t, std::vector<uint64_t>> nodes;  // Morton(node) -> cells
    for (const auto& [key, piece] : pieces) {
      std::array<uint32_t, 3> n = KeyCell(key);
      if (lod > 0) n = {n[0] >> 1, n[1] >> 1, n[2] >> 1};
      nodes[Morton(n)].push_back(key);
    }
    for (const auto& [code, cells] : nodes) {
      NodeBuilder node;
      std::array<uint32_t, 3> position = KeyCell(cells[0]);
      if (lod > 0) position = {position[0] >> 1, position[1] >> 1, position[2] >> 1};
      for (uint64_t key : cells) {
        const std::array<uint32_t, 3> c = KeyCell(key);
        // The cell's quantized range per axis.
        uint32_t qlo[3], qhi[3];
        for (int j = 0; j < 3; ++j) {
          const bool high = lod > 0 && (c[j] & 1);
          // Octants meet at `mid`, which Neuroglancer's partition lets either side use.
          qlo[j] = lod == 0 ? 0 : (high ? mid : 0);
          qhi[j] = lod == 0 ? top : (high ? top : mid);
        }
        const double size[3] = {std::ldexp(double{g.chunk_shape[0]}, lod),
                                std::ldexp(double{g.chunk_shape[1]}, lod),
                                std::ldexp(double{g.chunk_shape[2]}, lod)};
        auto quantize = [&](const Vec3& p) {
          std::array<uint32_t, 3> q;
          for (int j = 0; j < 3; ++j) {
            const double corner = origin[j] + size[j] * position[j];
            const double x = std::nearbyint((p[j] - corner) / size[j] * top);
            q[j] = static_cast<uint32_t>(
                std::clamp(x, static_cast<double>(qlo[j]), static_cast<double>(qhi[j])));
          }
          return q;
        };
        auto real = [&](const std::array<uint32_t, 3>& q) {
          Vec3 p;
          for (int j = 0; j < 3; ++j) {
            p[j] = origin[j] + size[j] * (position[j] + static_cast<double>(q[j]) / top);
          }
          return p;
        };
        const std::vector<Vec3>& piece = pieces[key];
        const size_t first_index = node.fragment().indices.size();
        for (size_t i = 0; i < piece.size(); i += 3) {
          node.Triangle(node.Vertex(quantize(piece[i])), node.Vertex(quantize(piece[i + 1])),
                        node.Vertex(quantize(piece[i + 2])));
        }
        if (!(skirt > 0)) continue;
        // The cut edges: used by one triangle of this cell, both ends on one face.
        NeuroglancerFragment& f = node.fragment();
        const size_t last_index = f.indices.size();
        std::map<std::pair<uint32_t, uint32_t>, int> uses;
        for (size_t i = first_index; i < last_index; i += 3) {
          for (int e = 0; e < 3; ++e) {
            const uint32_t a = f.indices[i + e], b = f.indices[i + (e + 1) % 3];
            ++uses[{std::min(a, b), std::max(a, b)}];
          }
        }
        struct Hang {
          uint32_t a, b;
          int face;  // 2 * axis + (high side)
        };
        std::vector<Hang> hangs;
        std::map<std::pair<uint32_t, int>, Vec3> dir;  // (vertex, face) -> summed direction
        for (size_t i = first_index; i < last_index; i += 3) {
          for (int e = 0; e < 3; ++e) {
            const uint32_t a = f.indices[i + e], b = f.indices[i + (e + 1) % 3],
                           c3 = f.indices[i + (e + 2) % 3];
            if (uses[{std::min(a, b), std::max(a, b)}] != 1) continue;
            for (int j = 0; j < 3; ++j) {
              for (int side = 0; side < 2; ++side) {
                const uint32_t plane = side ? qhi[j] : qlo[j];
                if (f.positions[a][j] != plane || f.positions[b][j] != plane) continue;
                const Vec3 pa = real(f.positions[a]), pb = real(f.positions[b]),
                           pc = real(f.positions[c3]);
                const Vec3 u = pb - pa, v = pc - pa;
                const Vec3 n = Cross(u, v);
                Vec3 axis{0, 0, 0};
                axis[j] = 1;
                Vec3 w = Cross(u, axis);  // in the face, across the edge
                const double s = Dot(w, n);
                const double len = std::sqrt(Dot(w, w));
                if (s == 0 || len == 0) continue;  // the triangle lies in the face
                w = w * ((s > 0 ? -1.0 : 1.0) / len);
                hangs.push_back({a, b, 2 * j + side});
                for (uint32_t x : {a, b}) {
                  Vec3& d = dir[{x, 2 * j + side}];
                  d = d + w;
                }
              }
            }
          }
        }
        std::map<std::pair<uint32_t, int>, uint32_t> lower;  // the strip's far corners
        for (auto& [key2, d] : dir) {
          const double len = std::sqrt(Dot(d, d));
          const Vec3 p = real(f.positions[key2.first]);
          const Vec3 far = len > 0 ? p + d * (skirt / len) : p;
          std::array<uint32_t, 3> q = quantize(far);
          const int j = key2.second / 2;
          q[j] = f.positions[key2.first][j];  // stays in the face
          // A strip wholly on `mid` would go to the low octant: a high one tilts it a step.
          for (int i = 0; i < 3; ++i) {
            if (lod > 0 && (c[i] & 1) && q[i] == mid) q[i] = mid + 1;
          }
          lower[key2] = node.Fresh(q);
        }
        for (const Hang& h : hangs) {
          const uint32_t la = lower[{h.a, h.face}], lb = lower[{h.b, h.face}];
          node.Triangle(h.b, h.a, la);
          node.Triangle(h.b, la, lb);
        }
      }
      // Slivers that quantization collapsed leave nothing to draw.
      if (!node.fragment().indices.empty())
        out[k].push_back({position, std::move(node.fragment())});
    }
  }
  // Every non-empty node needs its parent at the next level, else Neuroglancer never
  // reaches it: an empty parent (size 0) where that level has nothing.
  for (size_t k = 0; k + 1 < out.size(); ++k) {
    std::map<uint64_t, NeuroglancerNode> up;
    for (NeuroglancerNode& n : out[k + 1]) up.emplace(Morton(n.position), std::move(n));
    for (const NeuroglancerNode& n : out[k]) {
      const std::array<uint32_t, 3> p = {n.position[0] >> 1, n.position[1] >> 1,
                                         n.position[2] >> 1};
      up.try_emplace(Morton(p), NeuroglancerNode{p, {}});
    }
    out[k + 1].clear();
    for (auto& [code, n] : up) out[k + 1].push_back(std::move(n));
  }
  return out;
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
    TANDEM_RETURN_IF_ERROR(CheckSegment(segments[i], lods));
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
  if (options.chunk_voxels < 1 || options.chunk_voxels > 4096) {
    return absl::InvalidArgumentError(
        absl::StrCat("chunk_voxels must be in [1, 4096], got ", options.chunk_voxels));
  }
  // One level has nothing to refine: one node over the whole grid, as few fragments as can be.
  const int chunk = lods < 2 ? static_cast<int>(std::min<int64_t>(
                                   4096, std::max({grid.nx, grid.ny, grid.nz, int64_t{1}}) + 1))
                             : options.chunk_voxels;
  const NeuroglancerGrid octree = ChooseOctreeGrid(grid, segments, chunk);
  // One level draws everywhere alike: no face where two levels meet, nothing to skirt.
  const double skirt = lods < 2 ? 0.0 : (options.skirt >= 0 ? options.skirt : finest);
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
      TANDEM_ASSIGN_OR_RETURN(std::vector<std::vector<NeuroglancerNode>> tree,
                              BuildOctree(s, octree, bits, skirt));
      NeuroglancerManifest m;
      m.chunk_shape = octree.chunk_shape;
      m.grid_origin = octree.grid_origin;
      m.lod_scales = scales;
      m.vertex_offsets.assign(lods, {0, 0, 0});
      m.positions.resize(lods);
      m.sizes.resize(lods);
      ShardChunk c;
      c.id = s.id;
      for (size_t k = 0; k < tree.size(); ++k) {
        for (const NeuroglancerNode& node : tree[k]) {
          std::string bytes;
          if (!node.fragment.indices.empty()) {  // an empty node: size 0, never requested
            absl::StatusOr<std::string> e = options.encode(node.fragment);
            if (!e.ok()) {
              return absl::Status(e.status().code(), absl::StrCat("segment ", s.id, " level ", k,
                                                                  ": ", e.status().message()));
            }
            bytes = *std::move(e);
          }
          m.positions[k].push_back(node.position);
          m.sizes[k].push_back(static_cast<uint32_t>(bytes.size()));
          c.prefix += bytes;
        }
      }
      c.data = EncodeManifest(m);
      chunks.push_back(std::move(c));
    }
    TANDEM_ASSIGN_OR_RETURN(std::string file, BuildShard(std::move(chunks), sharding));
    if (absl::Status st = WriteFile(mesh_dir / ShardFileName(shard, sharding), file); !st.ok()) {
      return st;
    }
  }
  return absl::OkStatus();
}

}  // namespace tandem::io
