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

// The least coordinate per axis of any level of any segment (infinite where there is none).
Vec3 Lowest(std::span<const NeuroglancerSegment> segments) {
  const double inf = std::numeric_limits<double>::infinity();
  Vec3 lowest{inf, inf, inf};
  for (const NeuroglancerSegment& s : segments) {
    for (const IndexedMesh& m : s.lods) {
      for (const Vec3& p : m.positions) {
        for (int j = 0; j < 3; ++j) lowest[j] = std::min(lowest[j], p[j]);
      }
    }
  }
  return lowest;
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
  return ChooseOctreeGrid(grid, Lowest(segments), chunk_voxels);
}

NeuroglancerGrid ChooseOctreeGrid(const VolumeInfo& grid, const Vec3& lowest, int chunk_voxels) {
  NeuroglancerGrid g;
  for (int j = 0; j < 3; ++j) {
    const double sp = grid.spacing[j] > 0 ? grid.spacing[j] : 1.0;
    const double lo = std::min(grid.origin[j], lowest[j]);
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
  // The fragment without the corners no triangle kept (a sliver or a strip that quantization
  // collapsed), in their order: Edgebreaker drops such corners and Draco's sequential coding
  // writes more of them than corners as a mesh no Draco decoder (Neuroglancer's) accepts.
  NeuroglancerFragment Take() {
    constexpr uint32_t kUnused = ~uint32_t{0};
    std::vector<uint32_t> at(f_.positions.size(), kUnused);
    for (uint32_t i : f_.indices) at[i] = 0;
    uint32_t kept = 0;
    for (size_t i = 0; i < at.size(); ++i) {
      if (at[i] == kUnused) continue;
      f_.positions[kept] = f_.positions[i];
      at[i] = kept++;
    }
    f_.positions.resize(kept);
    for (uint32_t& i : f_.indices) i = at[i];
    return std::move(f_);
  }

 private:
  NeuroglancerFragment f_;
  std::unordered_map<uint64_t, uint32_t> index_;
};

constexpr size_t kMaxCells = size_t{1} << 21;

// Every level's cut edges on every cut plane, bucketed by the finest cells along the plane,
// so that a strip can find how far another level's cut of its face lies. Each edge knows its
// inner side in the plane (where that level's solid, or its surface lying in the plane, is).
class CutCurves {
 public:
  void Add(int axis, int64_t plane, int side, const Vec3& a, const Vec3& b, const Vec3& inward,
           int lod, const double* origin, const std::array<float, 3>& cell) {
    const int u = (axis + 1) % 3, w = (axis + 2) % 3;
    const int64_t u0 = Cell(std::min(a[u], b[u]), origin[u], cell[u]),
                  u1 = Cell(std::max(a[u], b[u]), origin[u], cell[u]),
                  w0 = Cell(std::min(a[w], b[w]), origin[w], cell[w]),
                  w1 = Cell(std::max(a[w], b[w]), origin[w], cell[w]);
    for (int64_t cu = u0; cu <= u1; ++cu) {
      for (int64_t cw = w0; cw <= w1; ++cw)
        buckets_[{axis, plane, cu, cw}].push_back({a, b, inward, lod, side});
    }
  }
  // How far from p along the unit direction `dir` (in the plane) a strip must reach. Not
  // `own`: to the farthest cut edge of another level, from the plane's other side (`side` is
  // p's cell's), that the ray crosses into that level's solid: stretches of the ray outside it
  // lie before (a surface lying in the plane, or touching it, makes nearer edges that do not
  // end them). `own`: to the first edge of level `lod` from p's side, further than `least`,
  // that the ray crosses out of its own solid. `limit` if there is none.
  double Reach(int axis, int64_t plane, int side, const Vec3& p, const Vec3& dir, int lod,
               double limit, const double* origin, const std::array<float, 3>& cell,
               bool own = false, double least = 0) const {
    const int u = (axis + 1) % 3, w = (axis + 2) % 3;
    double best = limit, farthest = -1;
    for (int64_t cu = Cell(p[u] - limit, origin[u], cell[u]);
         cu <= Cell(p[u] + limit, origin[u], cell[u]); ++cu) {
      for (int64_t cw = Cell(p[w] - limit, origin[w], cell[w]);
           cw <= Cell(p[w] + limit, origin[w], cell[w]); ++cw) {
        auto it = buckets_.find({axis, plane, cu, cw});
        if (it == buckets_.end()) continue;
        for (const Edge& e : it->second) {
          if ((e.lod == lod) != own || (e.side == side) != own) continue;
          const double enters = Dot(dir, e.inward);
          if (enters == 0 || (own && enters > 0)) continue;
          // p + t dir = a + s (b - a), in the plane's two axes.
          const double eu = e.b[u] - e.a[u], ew = e.b[w] - e.a[w];
          const double ru = e.a[u] - p[u], rw = e.a[w] - p[w];
          const double det = eu * dir[w] - dir[u] * ew;
          if (det == 0) continue;
          const double t = (eu * rw - ru * ew) / det, s = (dir[u] * rw - dir[w] * ru) / det;
          // Own edges are met up to `least` past their ends: a strip from a corner of the
          // curve (quantized off it) must not slip past the other side's end there.
          const double slack = own ? least / std::sqrt(eu * eu + ew * ew) : 0;
          if (!(t > least && t < limit && s >= -slack && s <= 1 + slack)) continue;
          if (own) {
            best = std::min(best, t);
          } else if (enters > 0) {
            farthest = std::max(farthest, t);
          }
        }
      }
    }
    return own || farthest < 0 ? best : farthest;
  }

 private:
  struct Edge {
    Vec3 a, b, inward;
    int lod;
    int side;  // 0: from the cell above the plane, 1: below it
  };
  static int64_t Cell(double x, double origin, float cell) {
    return static_cast<int64_t>(std::floor((x - origin) / cell));
  }
  std::map<std::tuple<int, int64_t, int64_t, int64_t>, std::vector<Edge>> buckets_;
};

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
  const size_t levels = segment.lods.size();
  std::vector<std::vector<NeuroglancerNode>> out(levels);
  double origin[3];
  for (int j = 0; j < 3; ++j) origin[j] = g.grid_origin[j];
  // Level k is cut at its nodes' faces and, above 0, their middle planes: cells of half a
  // node, which Neuroglancer's 2x2x2 partition never splits.
  auto shift_of = [](int lod) { return lod > 0 ? lod - 1 : 0; };
  std::vector<std::map<uint64_t, std::vector<Vec3>>> level_pieces(levels);  // cell -> corners
  CutCurves curves;
  for (size_t k = 0; k < levels; ++k) {
    const IndexedMesh& m = segment.lods[k];
    const int lod = static_cast<int>(k);
    const int shift = shift_of(lod);
    double cell[3];
    for (int j = 0; j < 3; ++j) cell[j] = std::ldexp(double{g.chunk_shape[j]}, shift);
    std::map<uint64_t, std::vector<Vec3>>& pieces = level_pieces[k];
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
            if (skirt > 0 && levels > 1) {
              const Vec3 normal = Cross(tri[1] - tri[0], tri[2] - tri[0]);
              Vec3 middle{0, 0, 0};
              for (int i = 0; i < poly.n; ++i) middle = middle + poly.v[i] * (1.0 / poly.n);
              for (int i = 0; i < poly.n; ++i) {
                const Vec3 &a = poly.v[i], &b = poly.v[(i + 1) % poly.n];
                for (int j = 0; j < 3; ++j) {
                  for (int side = 0; side < 2; ++side) {
                    const double plane = origin[j] + cell[j] * double(c[j] + side);
                    if (a[j] != plane || b[j] != plane) continue;
                    // Inward: against the normal; for a piece lying in the plane, onto it.
                    Vec3 axis{0, 0, 0};
                    axis[j] = 1;
                    Vec3 w = Cross(b - a, axis);
                    const double s = Dot(w, normal), m = Dot(w, middle - a);
                    const double len = std::sqrt(Dot(w, w));
                    if (len == 0 || (s == 0 && m == 0)) continue;
                    w = w * ((s != 0 ? (s > 0 ? -1.0 : 1.0) : (m > 0 ? 1.0 : -1.0)) / len);
                    curves.Add(j, (c[j] + side) << shift, side, a, b, w, lod, origin,
                               g.chunk_shape);
                  }
                }
              }
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
  }
  // Where two levels' cuts of a face are further apart than the strip, it reaches the other
  // level's cut (and half a strip beyond), up to 4 strips deep (the third level's error).
  const double deepest = std::ldexp(skirt, static_cast<int>(std::min<size_t>(levels, 3)) - 1);
  for (size_t k = 0; k < levels; ++k) {
    const int lod = static_cast<int>(k);
    const int shift = shift_of(lod);
    std::map<uint64_t, std::vector<Vec3>>& pieces = level_pieces[k];
    double cell_size[3];
    for (int j = 0; j < 3; ++j) cell_size[j] = std::ldexp(double{g.chunk_shape[j]}, shift);
    // A strip that leaves its cell goes on in the neighbouring cells of its level (the format
    // keeps each cell's triangles inside it): cell -> those parts, as triangles.
    std::map<uint64_t, std::vector<Polygon>> spill;
    // A strip wholly on `mid` would go to the low octant: a high one tilts it a step.
    auto off_mid_of = [&](const std::array<uint32_t, 3>& c, std::array<uint32_t, 3> q) {
      for (int i = 0; i < 3; ++i) {
        if (lod > 0 && (c[i] & 1) && q[i] == mid) q[i] = mid + 1;
      }
      return q;
    };
    // Builds cell `key`'s piece and strips into `node`; with `spill_out`, only gathers the
    // strips' parts beyond the cell.
    auto build_cell = [&](NodeBuilder& node, uint64_t key,
                          std::map<uint64_t, std::vector<Polygon>>* spill_out) {
      const std::array<uint32_t, 3> c = KeyCell(key);
      std::array<uint32_t, 3> position = c;
      if (lod > 0) position = {c[0] >> 1, c[1] >> 1, c[2] >> 1};
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
      static const std::vector<Vec3> kNone;
      const auto found = pieces.find(key);
      const std::vector<Vec3>& piece = found != pieces.end() ? found->second : kNone;
      const size_t first_index = node.fragment().indices.size();
      for (size_t i = 0; i < piece.size(); i += 3) {
        node.Triangle(node.Vertex(quantize(piece[i])), node.Vertex(quantize(piece[i + 1])),
                      node.Vertex(quantize(piece[i + 2])));
      }
      // Strips from the neighbouring cells' cut edges that reach into this one.
      auto add_spill = [&]() {
        auto it = spill.find(key);
        if (spill_out != nullptr || it == spill.end()) return;
        for (const Polygon& part : it->second) {
          std::array<std::array<uint32_t, 3>, 12> q;
          int n = 0;
          for (int v = 0; v < part.n; ++v) {
            q[n] = off_mid_of(c, quantize(part.v[v]));
            if (n == 0 || q[n] != q[n - 1]) ++n;
          }
          while (n > 1 && q[n - 1] == q[0]) --n;
          if (n < 3) continue;
          std::array<uint32_t, 12> id;
          for (int v = 0; v < n; ++v) id[v] = node.Fresh(q[v]);
          for (int v = 1; v + 1 < n; ++v) {
            if (q[0] != q[v + 1] && q[v] != q[v + 1]) node.Triangle(id[0], id[v], id[v + 1]);
          }
        }
      };
      if (!(skirt > 0)) return;
      // The cut edges: used by one triangle of this cell, both ends on one face. A triangle
      // lying in that face does not count: it ends there, so the surface that leaves the cell
      // along the edge from the other triangle still needs its strip.
      NeuroglancerFragment& f = node.fragment();
      const size_t last_index = f.indices.size();
      std::map<std::pair<uint32_t, uint32_t>, int> uses;
      std::map<std::tuple<uint32_t, uint32_t, int>, int> flat_uses;  // (edge, face) -> uses
      for (size_t i = first_index; i < last_index; i += 3) {
        int flat = -1;
        for (int j = 0; j < 3; ++j) {
          const uint32_t x = f.positions[f.indices[i]][j];
          if ((x == qlo[j] || x == qhi[j]) && f.positions[f.indices[i + 1]][j] == x &&
              f.positions[f.indices[i + 2]][j] == x) {
            flat = 2 * j + (x == qhi[j] ? 1 : 0);
          }
        }
        for (int e = 0; e < 3; ++e) {
          const uint32_t a = f.indices[i + e], b = f.indices[i + (e + 1) % 3];
          ++uses[{std::min(a, b), std::max(a, b)}];
          if (flat >= 0) ++flat_uses[{std::min(a, b), std::max(a, b), flat}];
        }
      }
      struct Hang {
        uint32_t a, b;
        int face;     // 2 * axis + (high side)
        Vec3 inward;  // unit, in the face, across the edge
      };
      std::vector<Hang> hangs;
      std::map<std::pair<uint32_t, int>, Vec3> dir;  // (vertex, face) -> summed direction
      for (size_t i = first_index; i < last_index; i += 3) {
        for (int e = 0; e < 3; ++e) {
          const uint32_t a = f.indices[i + e], b = f.indices[i + (e + 1) % 3],
                         c3 = f.indices[i + (e + 2) % 3];
          const int used = uses[{std::min(a, b), std::max(a, b)}];
          for (int j = 0; j < 3; ++j) {
            for (int side = 0; side < 2; ++side) {
              const uint32_t plane = side ? qhi[j] : qlo[j];
              if (f.positions[a][j] != plane || f.positions[b][j] != plane) continue;
              const auto flat = flat_uses.find({std::min(a, b), std::max(a, b), 2 * j + side});
              if (used - (flat != flat_uses.end() ? flat->second : 0) != 1) continue;
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
              hangs.push_back({a, b, 2 * j + side, w});
              for (uint32_t x : {a, b}) {
                Vec3& d = dir[{x, 2 * j + side}];
                d = d + w;
              }
            }
          }
        }
      }
      auto off_mid = [&](const std::array<uint32_t, 3>& q) { return off_mid_of(c, q); };
      // How deep a strip from p on face `face` (2 * axis + high side) goes along `unit`.
      // `stretch`: a corner's strip goes that much further along its averaged direction, so
      // that it lies as deep below each of its edges (a miter).
      auto depth_at = [&](const Vec3& p, int face, const Vec3& unit, double stretch) {
        if (levels < 2) return skirt;
        const int j = face / 2, side = face % 2;
        const int64_t plane = (int64_t{c[j]} + side) << shift;
        const double reach =
            curves.Reach(j, plane, side, p, unit, lod, deepest, origin, g.chunk_shape);
        const double depth =
            stretch * (reach < deepest ? std::clamp(reach + 0.5 * skirt, skirt, deepest) : skirt);
        // No deeper than the surface's other side in the face: a thin wall keeps it inside.
        return curves.Reach(j, plane, side, p, unit, lod, depth, origin, g.chunk_shape, true,
                            0.01 * skirt);
      };
      std::map<std::pair<uint32_t, int>, uint32_t> lower;  // the strip's far corners
      std::map<std::pair<uint32_t, int>, Vec3> far_of;     // where they lie unclamped
      // Where a cut curve reaches a cell edge (its face meets another cut face there), the
      // strip must reach down that edge, or the strips of the two faces leave a notch
      // between them: a far corner that would leave the cell slides down the edge instead of
      // being clamped short, and one tilted away from the edge gets a wedge back to it.
      std::map<std::pair<uint32_t, int>, uint32_t> wedge;  // the corner down the edge
      // Per corner, the least cosine between its averaged direction and its edges' own.
      std::map<std::pair<uint32_t, int>, double> least_cos;
      for (const Hang& h : hangs) {
        for (uint32_t x : {h.a, h.b}) {
          const Vec3& d = dir[{x, h.face}];
          const double len = std::sqrt(Dot(d, d));
          auto [it, fresh] = least_cos.try_emplace({x, h.face}, 1.0);
          if (len > 0) it->second = std::min(it->second, Dot(d, h.inward) / len);
        }
      }
      for (auto& [key2, d] : dir) {
        const double len = std::sqrt(Dot(d, d));
        const std::array<uint32_t, 3>& at = f.positions[key2.first];
        const Vec3 p = real(at);
        const int j = key2.second / 2;
        const int face = key2.second;  // outside the lambda: clang 14 cannot capture a binding
        // Up to twice as far (edges turning by up to 120 degrees); sharper turns hang strips
        // of their own below.
        const double stretch = 1 / std::max(least_cos[key2], 0.5);
        auto depth_toward = [&](const Vec3& unit) { return depth_at(p, face, unit, 1.0); };
        const double depth = len > 0 ? depth_at(p, face, d * (1 / len), stretch) : skirt;
        const Vec3 far = len > 0 ? p + d * (depth / len) : p;
        std::array<uint32_t, 3> q = quantize(far);
        q[j] = at[j];  // stays in the face
        int other = -1, faces = 0;
        for (int i = 0; i < 3; ++i) {
          if (i != j && (at[i] == qlo[i] || at[i] == qhi[i])) other = i, ++faces;
        }
        const int along = 3 - j - other;
        if (faces == 1 && d[along] != 0) {
          Vec3 unit{0, 0, 0};
          unit[along] = d[along] > 0 ? 1 : -1;
          const Vec3 down = p + unit * depth_toward(unit);
          std::array<uint32_t, 3> e = quantize(down);
          e[j] = at[j];
          e[other] = at[other];
          const double edge_corner = origin[other] + size[other] * position[other];
          const double x = (far[other] - edge_corner) / size[other] * top;
          if (x < qlo[other] - 0.5 || x > qhi[other] + 0.5) {
            q = e;  // it would leave the cell: down the edge at full depth
          } else if (off_mid(e) != off_mid(q)) {
            wedge[key2] = node.Fresh(off_mid(e));
          }
        }
        lower[key2] = node.Fresh(off_mid(q));
        far_of[key2] = far;
      }
      // The wedge is turned like the strip beside it (in the face, normal along its axis).
      auto turn = [&](uint32_t a, uint32_t b, uint32_t c3, int j) {
        auto v = [&](uint32_t i, int k) { return static_cast<double>(f.positions[i][k]); };
        const int u = (j + 1) % 3, w = (j + 2) % 3;
        return (v(b, u) - v(a, u)) * (v(c3, w) - v(a, w)) -
               (v(b, w) - v(a, w)) * (v(c3, u) - v(a, u));
      };
      // Where the cut curve turns sharply, a corner's averaged direction runs nearly along an
      // edge and the strip under that edge thins out: the edge then hangs a strip of its own
      // as well, straight across it, each end as deep as a strip from there goes. (Every
      // point of the face within a strip's depth of an edge, on its inner side, is covered.)
      std::vector<std::array<Vec3, 2>> own_far;  // per hang; at its own ends: none needed
      for (const Hang& h : hangs) {
        const Vec3 pa = real(f.positions[h.a]), pb = real(f.positions[h.b]);
        const double da = depth_at(pa, h.face, h.inward, 1.0),
                     db = depth_at(pb, h.face, h.inward, 1.0);
        const bool thin = Dot(far_of[{h.a, h.face}] - pa, h.inward) < 0.99 * da ||
                          Dot(far_of[{h.b, h.face}] - pb, h.inward) < 0.99 * db;
        own_far.push_back(thin ? std::array<Vec3, 2>{pa + h.inward * da, pb + h.inward * db}
                               : std::array<Vec3, 2>{pa, pb});
      }
      std::map<std::pair<uint32_t, int>, double> wedge_turn;
      for (size_t i = 0; i < hangs.size(); ++i) {
        const Hang& h = hangs[i];
        const uint32_t la = lower[{h.a, h.face}], lb = lower[{h.b, h.face}];
        node.Triangle(h.b, h.a, la);
        node.Triangle(h.b, la, lb);
        const double t = turn(h.b, h.a, la, h.face / 2);
        if (t != 0) wedge_turn.try_emplace({h.a, h.face}, t);
        if (t != 0) wedge_turn.try_emplace({h.b, h.face}, t);
        const int j = h.face / 2;
        std::array<uint32_t, 3> qa = quantize(own_far[i][0]), qb = quantize(own_far[i][1]);
        qa[j] = f.positions[h.a][j];
        qb[j] = f.positions[h.b][j];
        if (qa == f.positions[h.a] && qb == f.positions[h.b]) continue;
        const uint32_t oa = node.Fresh(off_mid(qa)), ob = node.Fresh(off_mid(qb));
        node.Triangle(h.b, h.a, oa);
        node.Triangle(h.b, oa, ob);
      }
      for (const auto& [key2, e] : wedge) {
        const uint32_t v = key2.first, la = lower[key2];
        const double t = wedge_turn.contains(key2) ? wedge_turn[key2] : 0;
        if (t * turn(v, la, e, key2.second / 2) >= 0) {
          node.Triangle(v, la, e);
        } else {
          node.Triangle(v, e, la);
        }
      }
      add_spill();
      if (spill_out == nullptr) return;
      // Each strip unclamped (one quad if convex, else two triangles), cut by the
      // neighbouring cells in its face.
      for (size_t strip = 0; strip < 2 * hangs.size(); ++strip) {
        const Hang& h = hangs[strip / 2];
        const int j = h.face / 2, u = (j + 1) % 3, w = (j + 2) % 3;
        const bool own = strip % 2 == 1;
        const Vec3 quad[4] = {real(f.positions[h.b]), real(f.positions[h.a]),
                              own ? own_far[strip / 2][0] : far_of[{h.a, h.face}],
                              own ? own_far[strip / 2][1] : far_of[{h.b, h.face}]};
        if (own && quad[2] == quad[1] && quad[3] == quad[0]) continue;
        int turns[2] = {0, 0};
        for (int i = 0; i < 4; ++i) {
          const Vec3 &a = quad[i], &b = quad[(i + 1) % 4], &e = quad[(i + 2) % 4];
          const double t = (b[u] - a[u]) * (e[w] - b[w]) - (b[w] - a[w]) * (e[u] - b[u]);
          if (t != 0) ++turns[t > 0];
        }
        Polygon shapes[2];
        if (turns[0] == 0 || turns[1] == 0) {
          shapes[0].n = 4;
          std::copy(quad, quad + 4, shapes[0].v.begin());
        } else {
          shapes[0].n = shapes[1].n = 3;
          shapes[0].v[0] = shapes[1].v[0] = quad[0];
          shapes[0].v[1] = quad[1];
          shapes[0].v[2] = shapes[1].v[1] = quad[2];
          shapes[1].v[2] = quad[3];
        }
        for (const Polygon& shape : shapes) {
          if (shape.n < 3) continue;
          std::array<int64_t, 3> lo, hi;
          for (int i = 0; i < 3; ++i) {
            lo[i] = hi[i] = c[i];
            if (i == j) continue;
            double a = shape.v[0][i], b = a;
            for (int v = 1; v < shape.n; ++v) {
              a = std::min(a, shape.v[v][i]);
              b = std::max(b, shape.v[v][i]);
            }
            lo[i] = std::max<int64_t>(
                0, static_cast<int64_t>(std::floor((a - origin[i]) / cell_size[i])));
            hi[i] = std::min<int64_t>(
                kMaxCells - 1, static_cast<int64_t>(std::floor((b - origin[i]) / cell_size[i])));
          }
          std::array<int64_t, 3> n;
          for (n[2] = lo[2]; n[2] <= hi[2]; ++n[2]) {
            for (n[1] = lo[1]; n[1] <= hi[1]; ++n[1]) {
              for (n[0] = lo[0]; n[0] <= hi[0]; ++n[0]) {
                if (n[0] == c[0] && n[1] == c[1] && n[2] == c[2]) continue;
                Polygon poly = shape;
                for (int i = 0; i < 3 && poly.n >= 3; ++i) {
                  if (i == j) continue;
                  ClipPlane(&poly, i, origin[i] + cell_size[i] * double(n[i]), true);
                  if (poly.n >= 3) {
                    ClipPlane(&poly, i, origin[i] + cell_size[i] * double(n[i] + 1), false);
                  }
                }
                if (poly.n >= 3) (*spill_out)[CellKey(n)].push_back(poly);
              }
            }
          }
        }
      }
    };
    if (skirt > 0 && levels > 1) {
      for (const auto& [key, piece] : pieces) {
        NodeBuilder scratch;
        build_cell(scratch, key, &spill);
      }
    }
    // Cells into nodes (z-order of the node, then of the octant).
    std::map<uint64_t, std::vector<uint64_t>> nodes;  // Morton(node) -> cells
    auto node_of = [&](uint64_t key) {
      std::array<uint32_t, 3> n = KeyCell(key);
      if (lod > 0) n = {n[0] >> 1, n[1] >> 1, n[2] >> 1};
      return Morton(n);
    };
    for (const auto& [key, piece] : pieces) nodes[node_of(key)].push_back(key);
    for (const auto& [key, parts] : spill) {
      if (!pieces.contains(key) && !parts.empty()) nodes[node_of(key)].push_back(key);
    }
    for (auto& [code, cells] : nodes) {
      std::sort(cells.begin(), cells.end());
      NodeBuilder node;
      std::array<uint32_t, 3> position = KeyCell(cells[0]);
      if (lod > 0) position = {position[0] >> 1, position[1] >> 1, position[2] >> 1};
      for (uint64_t key : cells) build_cell(node, key, nullptr);
      // Slivers that quantization collapsed leave nothing to draw.
      if (!node.fragment().indices.empty()) out[k].push_back({position, node.Take()});
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
  NeuroglancerSource source;
  source.lods = segments.empty() ? options.lod_scales.size() : segments[0].lods.size();
  std::map<LabelId, size_t> at;
  for (size_t i = 0; i < segments.size(); ++i) {
    TANDEM_RETURN_IF_ERROR(CheckSegment(segments[i], source.lods));
    if (!at.emplace(segments[i].id, i).second) {
      return absl::InvalidArgumentError(absl::StrCat("two segments with id ", segments[i].id));
    }
    source.ids.push_back(segments[i].id);
  }
  source.lowest = Lowest(segments);
  source.fetch = [&](std::span<const LabelId> ids, std::vector<NeuroglancerSegment>* out) {
    for (LabelId id : ids) out->push_back(segments[at.at(id)]);
    return absl::OkStatus();
  };
  return WriteNeuroglancerFrom(dir, grid, source, options);
}

absl::Status WriteNeuroglancerFrom(const std::string& dir, const VolumeInfo& grid,
                                   const NeuroglancerSource& source,
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
  const size_t lods = source.lods;
  {
    std::vector<LabelId> sorted = source.ids;
    std::sort(sorted.begin(), sorted.end());
    if (auto twice = std::adjacent_find(sorted.begin(), sorted.end()); twice != sorted.end()) {
      return absl::InvalidArgumentError(absl::StrCat("two segments with id ", *twice));
    }
  }
  if (!source.ids.empty() && !source.fetch) {
    return absl::InvalidArgumentError("neuroglancer export: no segment source");
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
  const NeuroglancerGrid octree = ChooseOctreeGrid(grid, source.lowest, chunk);
  // One level draws everywhere alike: no face where two levels meet, nothing to skirt.
  const double skirt = lods < 2 ? 0.0 : (options.skirt >= 0 ? options.skirt : finest);
  const NeuroglancerSharding sharding =
      options.choose_sharding ? ChooseSharding(source.ids.size()) : options.sharding;
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

  // One shard at a time: only its segments' surfaces and fragments are held.
  std::map<uint64_t, std::vector<LabelId>> by_shard;
  for (LabelId id : source.ids) by_shard[LocateChunk(id, sharding).shard].push_back(id);
  for (const auto& [shard, members] : by_shard) {
    std::vector<NeuroglancerSegment> segments;
    segments.reserve(members.size());
    TANDEM_RETURN_IF_ERROR(source.fetch(members, &segments));
    if (segments.size() != members.size()) {
      return absl::InternalError(absl::StrCat("neuroglancer export: ", segments.size(),
                                              " segments for ", members.size(), " ids"));
    }
    std::vector<ShardChunk> chunks;
    chunks.reserve(members.size());
    for (size_t i = 0; i < segments.size(); ++i) {
      NeuroglancerSegment& s = segments[i];
      if (s.id != members[i]) {
        return absl::InternalError(
            absl::StrCat("neuroglancer export: segment ", s.id, " for id ", members[i]));
      }
      TANDEM_RETURN_IF_ERROR(CheckSegment(s, lods));
      TANDEM_ASSIGN_OR_RETURN(std::vector<std::vector<NeuroglancerNode>> tree,
                              BuildOctree(s, octree, bits, skirt));
      s.lods = {};  // its fragments hold it from here
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
