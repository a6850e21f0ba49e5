// The segmentation benchmark's own parts (labels_bench.cc, labels_lib_test.cc): label volumes
// (an EM-like Voronoi volume, bands of a CT scan split into connected components), their raw +
// JSON sidecar files, and the two measures of a method's per-label surfaces:
//   - the reference surface of a label: marching cubes (tandem_core, full resolution) of the
//     label's indicator at 0.5, on the label's bounding box grown by one voxel;
//   - the gap between two touching labels A and B at an interface sample p (the midpoint of
//     two 6-adjacent voxels, one of A and one of B, whose neighbourhood holds no third label):
//     q = the point of A's surface closest to p, gap = the distance from q to B's surface, and
//     the same with A and B swapped; the larger of the two. Zero wherever the two surfaces
//     share the triangles near p. A sample farther than the margin's reach from either surface
//     is not counted (GapWithin): there the nearest point may lie on another interface.
// Voxel (i, j, k) sits at (i sx, j sy, k sz) (origin 0), x fastest, as the sidecar says.
#ifndef TANDEM_BENCH_LABELS_LIB_H_
#define TANDEM_BENCH_LABELS_LIB_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "tandem/eval/distance.h"
#include "tandem/mesh.h"
#include "tandem/options.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace labels {

struct LabelVolume {
  int64_t nx = 0, ny = 0, nz = 0;
  std::array<double, 3> spacing{1, 1, 1};
  std::vector<uint32_t> ids;  // x fastest, then y, then z; 0 = background

  size_t Index(int64_t i, int64_t j, int64_t k) const {
    return static_cast<size_t>((k * ny + j) * nx + i);
  }
  uint32_t At(int64_t i, int64_t j, int64_t k) const { return ids[Index(i, j, k)]; }
  tandem::Vec3 Position(int64_t i, int64_t j, int64_t k) const {
    return {double(i) * spacing[0], double(j) * spacing[1], double(k) * spacing[2]};
  }
};

[[noreturn]] inline void Fail(const std::string& msg) {
  std::fprintf(stderr, "%s\n", msg.c_str());
  std::exit(1);
}

inline size_t DTypeBytes(const std::string& dtype) {
  if (dtype == "uint8") return 1;
  if (dtype == "uint16") return 2;
  if (dtype == "uint32") return 4;
  return 0;
}

// Writes NAME.raw and its sidecar NAME.json; every id must fit the dtype.
inline void WriteLabelVolume(const std::string& json_path, const LabelVolume& v,
                             const std::string& dtype, const nlohmann::json& extra = {}) {
  const size_t bytes = DTypeBytes(dtype);
  if (bytes == 0) Fail("label dtype must be uint8, uint16 or uint32, not " + dtype);
  const uint64_t max_id = bytes == 4 ? UINT32_MAX : (uint64_t{1} << (8 * bytes)) - 1;
  std::filesystem::path raw = std::filesystem::path(json_path).replace_extension(".raw");
  std::vector<uint8_t> buf(v.ids.size() * bytes);
  for (size_t n = 0; n < v.ids.size(); ++n) {
    const uint32_t id = v.ids[n];
    if (id > max_id) Fail("label " + std::to_string(id) + " does not fit " + dtype);
    for (size_t b = 0; b < bytes; ++b) buf[n * bytes + b] = uint8_t(id >> (8 * b));  // little
  }
  std::ofstream out(raw, std::ios::binary);
  out.write(reinterpret_cast<const char*>(buf.data()), std::streamsize(buf.size()));
  if (!out) Fail(raw.string() + ": write error");
  nlohmann::json j = extra.is_object() ? extra : nlohmann::json::object();
  j["dims"] = {v.nx, v.ny, v.nz};
  j["dtype"] = dtype;
  j["spacing"] = {v.spacing[0], v.spacing[1], v.spacing[2]};
  j["byte_order"] = "little";
  j["raw_file"] = raw.filename().string();
  j["raw_bytes"] = buf.size();
  std::ofstream js(json_path);
  js << j.dump(1) << "\n";
  if (!js) Fail(json_path + ": write error");
}

// Reads a raw + sidecar volume of unsigned integers (uint8/16/32) or, for the CT bands,
// int16 (negative values read as 0).
inline LabelVolume ReadLabelVolume(const std::string& json_path,
                                   nlohmann::json* sidecar = nullptr) {
  std::ifstream in(json_path);
  if (!in) Fail(json_path + ": cannot open");
  const nlohmann::json j = nlohmann::json::parse(in, nullptr, false);
  if (j.is_discarded() || !j.contains("dims") || !j.contains("dtype")) {
    Fail(json_path + ": not a sidecar with dims and dtype");
  }
  LabelVolume v;
  v.nx = j["dims"][0];
  v.ny = j["dims"][1];
  v.nz = j["dims"][2];
  if (j.contains("spacing")) {
    for (int a = 0; a < 3; ++a) v.spacing[a] = j["spacing"][a];
  }
  const std::string dtype = j["dtype"];
  const bool int16 = dtype == "int16";
  const size_t bytes = int16 ? 2 : DTypeBytes(dtype);
  if (bytes == 0) Fail(json_path + ": dtype " + dtype + " is not an integer type read here");
  std::filesystem::path raw =
      j.value("raw_file", std::filesystem::path(json_path).stem().string() + ".raw");
  raw = std::filesystem::path(json_path).parent_path() / raw;
  const size_t n = size_t(v.nx) * size_t(v.ny) * size_t(v.nz);
  std::vector<uint8_t> buf(n * bytes);
  std::ifstream r(raw, std::ios::binary);
  r.read(reinterpret_cast<char*>(buf.data()), std::streamsize(buf.size()));
  if (!r) Fail(raw.string() + ": shorter than dims x dtype");
  v.ids.resize(n);
  for (size_t k = 0; k < n; ++k) {
    uint32_t x = 0;
    for (size_t b = 0; b < bytes; ++b) x |= uint32_t(buf[k * bytes + b]) << (8 * b);
    if (int16 && (x & 0x8000u)) x = 0;
    v.ids[k] = x;
  }
  if (sidecar != nullptr) *sidecar = j;
  return v;
}

// `count` distinct ids drawn uniformly from [1, max_id] (scattered, not 1..N).
inline std::vector<uint32_t> ScatteredIds(size_t count, uint32_t max_id, std::mt19937_64& rng) {
  if (count > max_id) Fail("more labels than ids of the dtype");
  std::uniform_int_distribution<uint32_t> pick(1, max_id);
  std::unordered_set<uint32_t> seen;
  std::vector<uint32_t> ids;
  ids.reserve(count);
  while (ids.size() < count) {
    const uint32_t id = pick(rng);
    if (seen.insert(id).second) ids.push_back(id);
  }
  return ids;
}

struct VoronoiOptions {
  int64_t nx = 256, ny = 256, nz = 64;
  std::array<double, 3> spacing{4, 4, 40};
  int cells = 400;
  double background_fraction = 0.1;  // share of the cells that are background
  double wobble = 0.3;               // boundary displacement, in mean cell diameters
  double elongation = 1;             // cells this many times longer along z (neurites)
  uint64_t seed = 1;
  uint32_t max_id = UINT32_MAX;
};

// The cells behind a Voronoi volume: seed positions and their ids (0: a background cell).
struct VoronoiCells {
  std::vector<tandem::Vec3> seeds;
  std::vector<uint32_t> ids;
};

// Voronoi cells of random seeds in the physical box (so cells are round in nanometres and
// flat in voxels), stretched along z by `elongation` (z distances count 1 / elongation), their
// boundaries bent by a smooth displacement of the query point (cells of an EM volume are not
// polyhedra); a share of the cells is background.
inline LabelVolume MakeVoronoi(const VoronoiOptions& o, VoronoiCells* cells_out = nullptr) {
  LabelVolume v;
  v.nx = o.nx;
  v.ny = o.ny;
  v.nz = o.nz;
  v.spacing = o.spacing;
  const std::array<double, 3> extent{double(o.nx - 1) * o.spacing[0],
                                     double(o.ny - 1) * o.spacing[1],
                                     double(o.nz - 1) * o.spacing[2]};
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> unit(0, 1);
  const int cells = std::max(1, o.cells);
  std::vector<tandem::Vec3> seeds(static_cast<size_t>(cells));
  // Seeds and buckets live where z is divided by the elongation.
  const double elongation = std::max(1e-6, o.elongation);
  const std::array<double, 3> box{extent[0], extent[1], extent[2] / elongation};
  for (auto& s : seeds) s = {unit(rng) * box[0], unit(rng) * box[1], unit(rng) * box[2]};
  const double diameter = std::cbrt(std::max(1e-30, box[0] * box[1] * box[2]) / cells);

  std::vector<uint32_t> id_of_cell = ScatteredIds(size_t(cells), o.max_id, rng);
  for (auto& id : id_of_cell) {
    if (unit(rng) < o.background_fraction) id = 0;
  }

  // Buckets of side `diameter` hold the seeds; a query looks at rings of buckets until the
  // next ring cannot hold a nearer seed.
  std::array<int64_t, 3> g;
  for (int a = 0; a < 3; ++a) g[a] = std::max<int64_t>(1, int64_t(std::ceil(box[a] / diameter)));
  auto bucket_of = [&](double x, int a) {
    return std::clamp<int64_t>(int64_t(x / diameter), 0, g[a] - 1);
  };
  std::vector<std::vector<uint32_t>> buckets(size_t(g[0] * g[1] * g[2]));
  for (size_t s = 0; s < seeds.size(); ++s) {
    buckets[size_t((bucket_of(seeds[s].z, 2) * g[1] + bucket_of(seeds[s].y, 1)) * g[0] +
                   bucket_of(seeds[s].x, 0))]
        .push_back(uint32_t(s));
  }

  // The displacement: three plane waves per axis, wavelength about a cell.
  struct Wave {
    tandem::Vec3 k;
    double phase;
  };
  std::array<std::array<Wave, 3>, 3> waves;
  for (auto& axis : waves) {
    for (auto& w : axis) {
      tandem::Vec3 d{unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5};
      const double len = std::max(1e-9, tandem::Norm(d));
      const double wavelength = diameter * (0.7 + 0.6 * unit(rng));
      w.k = (2 * M_PI / wavelength / len) * d;
      w.phase = 2 * M_PI * unit(rng);
    }
  }
  const double amplitude = o.wobble * diameter / 3;

  v.ids.resize(size_t(o.nx) * size_t(o.ny) * size_t(o.nz));
  for (int64_t k = 0; k < o.nz; ++k) {
    for (int64_t j = 0; j < o.ny; ++j) {
      for (int64_t i = 0; i < o.nx; ++i) {
        tandem::Vec3 p = v.Position(i, j, k);
        tandem::Vec3 q = p;
        for (int a = 0; a < 3; ++a) {
          double s = 0;
          for (const Wave& w : waves[a]) s += std::sin(tandem::Dot(w.k, p) + w.phase);
          q[a] = std::clamp(p[a] + amplitude * s, 0.0, extent[a]);
        }
        q.z /= elongation;
        const int64_t b[3] = {bucket_of(q.x, 0), bucket_of(q.y, 1), bucket_of(q.z, 2)};
        double best = INFINITY;
        uint32_t best_seed = 0;
        for (int64_t r = 0;; ++r) {
          for (int64_t bz = std::max<int64_t>(0, b[2] - r); bz <= std::min(g[2] - 1, b[2] + r);
               ++bz) {
            for (int64_t by = std::max<int64_t>(0, b[1] - r); by <= std::min(g[1] - 1, b[1] + r);
                 ++by) {
              for (int64_t bx = std::max<int64_t>(0, b[0] - r); bx <= std::min(g[0] - 1, b[0] + r);
                   ++bx) {
                const int64_t ring =
                    std::max({std::abs(bx - b[0]), std::abs(by - b[1]), std::abs(bz - b[2])});
                if (ring != r) continue;
                for (uint32_t s : buckets[size_t((bz * g[1] + by) * g[0] + bx)]) {
                  const tandem::Vec3 d = seeds[s] - q;
                  const double d2 = tandem::Dot(d, d);
                  if (d2 < best || (d2 == best && s < best_seed)) {
                    best = d2;
                    best_seed = s;
                  }
                }
              }
            }
          }
          // q lies in its bucket, so any seed beyond ring r is at least r buckets away.
          const bool covered = r >= std::max({g[0], g[1], g[2]});
          if (covered || (best < INFINITY && std::sqrt(best) <= double(r) * diameter)) break;
        }
        v.ids[v.Index(i, j, k)] = id_of_cell[best_seed];
      }
    }
  }
  if (cells_out != nullptr) {
    *cells_out = {seeds, id_of_cell};
    for (tandem::Vec3& s : cells_out->seeds) s.z *= elongation;
  }
  return v;
}

// A CT scan's bands (value >= thresholds[0] is band 1, >= thresholds[1] band 2, ...), each
// split into 6-connected components; components below min_voxels become background, the
// rest get scattered ids, largest first while max_labels allows.
inline LabelVolume BandComponents(const LabelVolume& ct, const std::vector<double>& thresholds,
                                  int64_t min_voxels, size_t max_labels, uint32_t max_id,
                                  uint64_t seed) {
  LabelVolume v = ct;
  const size_t n = ct.ids.size();
  std::vector<uint8_t> band(n);
  for (size_t k = 0; k < n; ++k) {
    uint8_t b = 0;
    for (double t : thresholds) b += double(ct.ids[k]) >= t;
    band[k] = b;
  }
  constexpr uint32_t kNone = UINT32_MAX;
  std::vector<uint32_t> comp(n, kNone);
  std::vector<int64_t> sizes;
  std::vector<size_t> stack;
  const int64_t strides[3] = {1, ct.nx, ct.nx * ct.ny};
  for (size_t start = 0; start < n; ++start) {
    if (band[start] == 0 || comp[start] != kNone) continue;
    const uint32_t c = uint32_t(sizes.size());
    sizes.push_back(0);
    comp[start] = c;
    stack.push_back(start);
    while (!stack.empty()) {
      const size_t at = stack.back();
      stack.pop_back();
      ++sizes[c];
      const int64_t xyz[3] = {int64_t(at) % ct.nx, (int64_t(at) / ct.nx) % ct.ny,
                              int64_t(at) / (ct.nx * ct.ny)};
      const int64_t dims[3] = {ct.nx, ct.ny, ct.nz};
      for (int a = 0; a < 3; ++a) {
        for (int s : {-1, 1}) {
          if (xyz[a] + s < 0 || xyz[a] + s >= dims[a]) continue;
          const size_t nb = size_t(int64_t(at) + s * strides[a]);
          if (band[nb] == band[at] && comp[nb] == kNone) {
            comp[nb] = c;
            stack.push_back(nb);
          }
        }
      }
    }
  }
  std::vector<uint32_t> order(sizes.size());
  for (uint32_t c = 0; c < order.size(); ++c) order[c] = c;
  std::stable_sort(order.begin(), order.end(),
                   [&](uint32_t a, uint32_t b) { return sizes[a] > sizes[b]; });
  size_t kept = 0;
  while (kept < order.size() && kept < max_labels && sizes[order[kept]] >= min_voxels) ++kept;
  std::mt19937_64 rng(seed);
  const std::vector<uint32_t> ids = ScatteredIds(kept, max_id, rng);
  std::vector<uint32_t> id_of(sizes.size(), 0);
  for (size_t r = 0; r < kept; ++r) id_of[order[r]] = ids[r];
  for (size_t k = 0; k < n; ++k) v.ids[k] = comp[k] == kNone ? 0 : id_of[comp[k]];
  return v;
}

struct LabelBox {
  uint32_t id = 0;
  int64_t voxels = 0;
  std::array<int64_t, 3> lo{INT64_MAX, INT64_MAX, INT64_MAX}, hi{-1, -1, -1};
};

// The labels other than `background`, in increasing id, with their voxel counts and boxes.
inline std::vector<LabelBox> LabelBoxes(const LabelVolume& v, uint32_t background = 0) {
  std::unordered_map<uint32_t, size_t> slot;
  std::vector<LabelBox> boxes;
  for (int64_t k = 0; k < v.nz; ++k) {
    for (int64_t j = 0; j < v.ny; ++j) {
      for (int64_t i = 0; i < v.nx; ++i) {
        const uint32_t id = v.At(i, j, k);
        if (id == background) continue;
        auto [it, added] = slot.try_emplace(id, boxes.size());
        if (added) {
          boxes.emplace_back();
          boxes.back().id = id;
        }
        LabelBox& b = boxes[it->second];
        ++b.voxels;
        const int64_t c[3] = {i, j, k};
        for (int a = 0; a < 3; ++a) {
          b.lo[a] = std::min(b.lo[a], c[a]);
          b.hi[a] = std::max(b.hi[a], c[a]);
        }
      }
    }
  }
  std::sort(boxes.begin(), boxes.end(),
            [](const LabelBox& a, const LabelBox& b) { return a.id < b.id; });
  return boxes;
}

// The full-resolution surface of one label: marching cubes of its indicator at 0.5 over its
// box grown by one voxel (clipped to the volume, where the surface stays open), in the
// volume's physical frame.
inline tandem::IndexedMesh ReferenceSurface(const LabelVolume& v, const LabelBox& box) {
  std::array<int64_t, 3> lo, hi;
  const int64_t dims[3] = {v.nx, v.ny, v.nz};
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::max<int64_t>(0, box.lo[a] - 1);
    hi[a] = std::min<int64_t>(dims[a] - 1, box.hi[a] + 1);
    if (hi[a] == lo[a]) (lo[a] > 0 ? --lo[a] : ++hi[a]);  // a session needs 2 samples an axis
  }
  tandem::VolumeInfo grid;
  grid.nx = hi[0] - lo[0] + 1;
  grid.ny = hi[1] - lo[1] + 1;
  grid.nz = hi[2] - lo[2] + 1;
  grid.dtype = tandem::DType::kFloat32;
  grid.spacing = v.spacing;
  grid.origin = {double(lo[0]) * v.spacing[0], double(lo[1]) * v.spacing[1],
                 double(lo[2]) * v.spacing[2]};
  tandem::SessionOptions opt;
  opt.iso = 0.5;
  opt.schedule = tandem::Schedule::kNone;
  opt.parts = 1;
  auto session = tandem::TandemSession::Create(grid, opt);
  if (!session.ok())
    Fail("reference of label " + std::to_string(box.id) + ": " +
         std::string(session.status().message()));
  std::vector<float> slice(size_t(grid.nx * grid.ny));
  for (int64_t k = lo[2]; k <= hi[2]; ++k) {
    for (int64_t j = lo[1]; j <= hi[1]; ++j) {
      for (int64_t i = lo[0]; i <= hi[0]; ++i) {
        slice[size_t((j - lo[1]) * grid.nx + (i - lo[0]))] = v.At(i, j, k) == box.id ? 1.f : 0.f;
      }
    }
    if (auto st = (*session)->AddSlice(slice.data()); !st.ok()) Fail(std::string(st.message()));
  }
  if (auto st = (*session)->Finish(); !st.ok()) Fail(std::string(st.message()));
  return (*session)->Snapshot();
}

// Interface samples of two touching labels a < b: midpoints of 6-adjacent voxel pairs of a
// and b whose neighbourhood (margin[axis] voxels around both) holds no third label.
struct PairSamples {
  uint32_t a = 0, b = 0;
  int64_t faces = 0;  // every a-b voxel face, interior or not
  std::vector<tandem::Vec3> points;
};

using Margin = std::array<int, 3>;

inline bool OnlyTwoLabels(const LabelVolume& v, int64_t i, int64_t j, int64_t k, int axis,
                          const Margin& margin, uint32_t a, uint32_t b) {
  int64_t lo[3] = {i - margin[0], j - margin[1], k - margin[2]};
  int64_t hi[3] = {i + margin[0], j + margin[1], k + margin[2]};
  hi[axis] += 1;  // the face's second voxel
  const int64_t dims[3] = {v.nx, v.ny, v.nz};
  for (int d = 0; d < 3; ++d) {
    lo[d] = std::max<int64_t>(0, lo[d]);
    hi[d] = std::min<int64_t>(dims[d] - 1, hi[d]);
  }
  for (int64_t z = lo[2]; z <= hi[2]; ++z) {
    for (int64_t y = lo[1]; y <= hi[1]; ++y) {
      for (int64_t x = lo[0]; x <= hi[0]; ++x) {
        const uint32_t id = v.At(x, y, z);
        if (id != a && id != b) return false;
      }
    }
  }
  return true;
}

// Up to `per_pair` samples of every touching pair (background excluded), pairs in increasing
// (a, b); faces are drawn in a fixed pseudo-random order, so the samples spread over the
// interface and repeat from run to run.
inline std::vector<PairSamples> InterfaceSamples(const LabelVolume& v, size_t per_pair,
                                                 const Margin& margin = {2, 2, 2},
                                                 uint32_t background = 0) {
  std::unordered_map<uint64_t, size_t> slot;
  std::vector<PairSamples> pairs;
  std::vector<std::vector<uint64_t>> faces;  // voxel index * 3 + axis
  for (int64_t k = 0; k < v.nz; ++k) {
    for (int64_t j = 0; j < v.ny; ++j) {
      for (int64_t i = 0; i < v.nx; ++i) {
        const uint32_t x = v.At(i, j, k);
        if (x == background) continue;
        for (int axis = 0; axis < 3; ++axis) {
          const int64_t c[3] = {i + (axis == 0), j + (axis == 1), k + (axis == 2)};
          if (c[0] >= v.nx || c[1] >= v.ny || c[2] >= v.nz) continue;
          const uint32_t y = v.At(c[0], c[1], c[2]);
          if (y == background || y == x) continue;
          const uint32_t a = std::min(x, y), b = std::max(x, y);
          auto [it, added] = slot.try_emplace(uint64_t(a) << 32 | b, pairs.size());
          if (added) {
            pairs.push_back(PairSamples{a, b, 0, {}});
            faces.emplace_back();
          }
          faces[it->second].push_back(uint64_t(v.Index(i, j, k)) * 3 + uint64_t(axis));
        }
      }
    }
  }
  for (size_t p = 0; p < pairs.size(); ++p) {
    std::vector<uint64_t>& f = faces[p];
    pairs[p].faces = int64_t(f.size());
    std::mt19937_64 rng(uint64_t(pairs[p].a) * 0x9E3779B97F4A7C15ull ^ pairs[p].b);
    std::shuffle(f.begin(), f.end(), rng);
    for (uint64_t code : f) {
      if (pairs[p].points.size() >= per_pair) break;
      const int axis = int(code % 3);
      const int64_t at = int64_t(code / 3);
      const int64_t i = at % v.nx, j = (at / v.nx) % v.ny, k = at / (v.nx * v.ny);
      if (!OnlyTwoLabels(v, i, j, k, axis, margin, pairs[p].a, pairs[p].b)) continue;
      tandem::Vec3 q = v.Position(i, j, k);
      q[axis] += 0.5 * v.spacing[axis];
      pairs[p].points.push_back(q);
    }
    std::vector<uint64_t>().swap(f);
  }
  std::sort(pairs.begin(), pairs.end(), [](const PairSamples& x, const PairSamples& y) {
    return std::pair(x.a, x.b) < std::pair(y.a, y.b);
  });
  return pairs;
}

// margin voxels on each axis, or more where `physical` (a length) needs more: a method whose
// surfaces move by up to E from the full-resolution ones needs about 3 E, so that the point
// of A's surface nearest a sample is on the A-B interface rather than on another one.
inline Margin MarginFor(const LabelVolume& v, int voxels, double physical) {
  Margin m;
  for (int a = 0; a < 3; ++a) {
    m[a] = std::max(voxels, int(std::ceil(physical / v.spacing[a] - 1e-9)));
  }
  return m;
}

// The gap at interface sample p between the surfaces of two labels (see the file comment).
inline double GapAt(const tandem::eval::TriangleBvh& a, const tandem::eval::TriangleBvh& b,
                    tandem::Vec3 p) {
  const double ab = b.Distance(a.Closest(p).point);
  const double ba = a.Distance(b.Closest(p).point);
  return std::max(ab, ba);
}

// GapAt where both surfaces pass within `reach` of p (half the smallest margin, as a length),
// so that the nearest points lie in p's neighbourhood, which holds A and B only; nullopt
// otherwise (a surface that moved farther from its voxels than that, as a coarse one may on
// anisotropic voxels, has its nearest point on another interface, and the gap would be that
// interface's distance, not a gap).
inline std::optional<double> GapWithin(const tandem::eval::TriangleBvh& a,
                                       const tandem::eval::TriangleBvh& b, tandem::Vec3 p,
                                       double reach) {
  if (a.Distance(p) > reach || b.Distance(p) > reach) return std::nullopt;
  return GapAt(a, b, p);
}

}  // namespace labels

#endif  // TANDEM_BENCH_LABELS_LIB_H_
