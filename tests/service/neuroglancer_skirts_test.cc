// The Neuroglancer export's skirts (io::BuildOctree) closing every crack where two levels of
// detail meet: wherever Neuroglancer may draw one level on one side of a cell face and a
// finer one on the other, the part of the face inside one level's solid but not the other's
// must be covered by triangles lying in the face (the strips, or a surface lying in it).
#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"
#include "service/neuroglancer_sheet.h"
#include "tandem/io/neuroglancer.h"
#include "tandem/labels.h"
#include "tandem/tandem.h"

namespace tandem::io {
namespace {

using Tree = std::vector<std::vector<NeuroglancerNode>>;
using Triangle = std::array<Vec3, 3>;
using CellIndex = std::array<int64_t, 3>;

// A level's triangles by the unit column (x, y) of the plane they overlap: the z of a
// vertical line's crossings with the level.
class Columns {
 public:
  explicit Columns(const IndexedMesh& m) : m_(m) {
    for (uint32_t t = 0; t + 2 < m.indices.size(); t += 3) {
      double lo[2] = {1e300, 1e300}, hi[2] = {-1e300, -1e300};
      for (int c = 0; c < 3; ++c) {
        for (int j = 0; j < 2; ++j) {
          lo[j] = std::min(lo[j], m.positions[m.indices[t + c]][j]);
          hi[j] = std::max(hi[j], m.positions[m.indices[t + c]][j]);
        }
      }
      for (int64_t x = Floor(lo[0]); x <= Floor(hi[0]); ++x) {
        for (int64_t y = Floor(lo[1]); y <= Floor(hi[1]); ++y) cells_[{x, y}].push_back(t);
      }
    }
  }
  std::vector<double> Crossings(double x, double y) const {
    std::vector<double> out;
    auto it = cells_.find({Floor(x), Floor(y)});
    if (it == cells_.end()) return out;
    for (uint32_t t : it->second) {
      const Vec3 &a = m_.positions[m_.indices[t]], &b = m_.positions[m_.indices[t + 1]],
                 &c = m_.positions[m_.indices[t + 2]];
      auto edge = [&](const Vec3& p, const Vec3& q) {
        return (q.x - p.x) * (y - p.y) - (q.y - p.y) * (x - p.x);
      };
      const double wa = edge(b, c), wb = edge(c, a), wc = edge(a, b), sum = wa + wb + wc;
      const bool in = (wa > 0 && wb > 0 && wc > 0) || (wa < 0 && wb < 0 && wc < 0);
      if (in && sum != 0) out.push_back((wa * a.z + wb * b.z + wc * c.z) / sum);
    }
    std::sort(out.begin(), out.end());
    return out;
  }

 private:
  static int64_t Floor(double v) { return static_cast<int64_t>(std::floor(v)); }
  const IndexedMesh& m_;
  std::map<std::pair<int64_t, int64_t>, std::vector<uint32_t>> cells_;
};

// Inside a level's solid at height z of a line with these crossings: an odd number above.
bool Inside(const std::vector<double>& crossings, double z) {
  return (crossings.end() - std::upper_bound(crossings.begin(), crossings.end(), z)) % 2 == 1;
}

// Level k's drawn triangles per cell (half a node above level 0), each triangle in the first
// octant whose closed box holds its three corners, as Neuroglancer partitions a fragment.
std::map<CellIndex, std::vector<Triangle>> DrawnCells(const Tree& tree,
                                                      const NeuroglancerGrid& grid, int k) {
  std::map<CellIndex, std::vector<Triangle>> out;
  constexpr uint32_t kMid = 1u << 15;
  for (const NeuroglancerNode& node : tree[k]) {
    const NeuroglancerFragment& f = node.fragment;
    for (size_t t = 0; t + 2 < f.indices.size(); t += 3) {
      int octant = 0;
      if (k > 0) {
        for (octant = 0; octant < 8; ++octant) {
          bool holds = true;
          for (int c = 0; c < 3 && holds; ++c) {
            for (int j = 0; j < 3; ++j) {
              const uint32_t q = f.positions[f.indices[t + c]][j];
              holds = holds && ((octant >> j & 1) ? q >= kMid : q <= kMid);
            }
          }
          if (holds) break;
        }
      }
      CellIndex cell;
      for (int j = 0; j < 3; ++j) {
        cell[j] = k > 0 ? 2 * int64_t{node.position[j]} + (octant >> j & 1) : node.position[j];
      }
      Triangle tri;
      for (int c = 0; c < 3; ++c) {
        tri[c] = DequantizePosition(grid, k, node.position, f.positions[f.indices[t + c]], 16);
      }
      out[cell].push_back(tri);
    }
  }
  return out;
}

// Where two levels meet with a crack left open: the length of vertical lines (every 1/16 of
// a unit across each face) inside one level's solid on its side of the face and outside the
// other's on the other side, not covered by a triangle in the face.
struct Cracks {
  double length = 0;  // summed over the lines
  double worst = 0;   // on one line
  std::string where;
};

// Every x and y face of level `coarse`'s cells inside `bounds` (the volume's box less a
// margin, where the surface is open), drawn at `coarse` on one side and at `fine` across.
Cracks OpenCracks(const NeuroglancerSegment& segment, const Tree& tree,
                  const NeuroglancerGrid& grid, int fine, int coarse, const Vec3& lo,
                  const Vec3& hi) {
  const Columns fine_columns(segment.lods[fine]), coarse_columns(segment.lods[coarse]);
  const auto fine_cells = DrawnCells(tree, grid, fine),
             coarse_cells = DrawnCells(tree, grid, coarse);
  auto cell_size = [&](int k, int j) {
    return std::ldexp(double{grid.chunk_shape[j]}, std::max(k - 1, 0));
  };
  Cracks cracks;
  constexpr double kStep = 1.0 / 16, kAcross = 1e-7, kMargin = 0.05;
  for (const auto& [cell, tris] : coarse_cells) {
    for (int j = 0; j < 2; ++j) {
      const int u = 1 - j;
      for (int side = 0; side < 2; ++side) {
        const double plane = grid.grid_origin[j] + cell_size(coarse, j) * double(cell[j] + side);
        if (plane <= lo[j] || plane >= hi[j]) continue;
        const double sigma = side ? 1 : -1;  // toward the fine side
        const double u0 = grid.grid_origin[u] + cell_size(coarse, u) * double(cell[u]);
        const double z0 = grid.grid_origin[2] + cell_size(coarse, 2) * double(cell[2]);
        const double u1 = u0 + cell_size(coarse, u), z1 = z0 + cell_size(coarse, 2);
        // The triangles in the face: the coarse cell's and its fine neighbours' across it.
        std::vector<Triangle> in_face;
        auto gather = [&](const std::vector<Triangle>& from) {
          for (const Triangle& t : from) {
            if (std::abs(t[0][j] - plane) < 1e-3 && std::abs(t[1][j] - plane) < 1e-3 &&
                std::abs(t[2][j] - plane) < 1e-3) {
              in_face.push_back(t);
            }
          }
        };
        gather(tris);
        CellIndex n;
        const double fine_j = cell_size(fine, j), fine_u = cell_size(fine, u),
                     fine_z = cell_size(fine, 2);
        n[j] = std::llround((plane - grid.grid_origin[j]) / fine_j) - (side ? 0 : 1);
        for (n[u] = std::llround((u0 - grid.grid_origin[u]) / fine_u);
             grid.grid_origin[u] + fine_u * double(n[u]) < u1 - 1e-9; ++n[u]) {
          for (n[2] = std::llround((z0 - grid.grid_origin[2]) / fine_z);
               grid.grid_origin[2] + fine_z * double(n[2]) < z1 - 1e-9; ++n[2]) {
            if (auto it = fine_cells.find(n); it != fine_cells.end()) gather(it->second);
          }
        }
        for (double at = u0 + kStep / 2; at < u1; at += kStep) {
          if (at <= lo[u] || at >= hi[u]) continue;
          Vec3 p{0, 0, 0};
          p[u] = at;
          p[j] = plane - sigma * kAcross;
          const std::vector<double> mine = coarse_columns.Crossings(p.x, p.y);
          p[j] = plane + sigma * kAcross;
          const std::vector<double> theirs = fine_columns.Crossings(p.x, p.y);
          // The face's triangles met by the line: z intervals.
          std::vector<std::pair<double, double>> covered;
          for (const Triangle& t : in_face) {
            double a = 1e300, b = -1e300;
            for (int e = 0; e < 3; ++e) {
              const Vec3 &p0 = t[e], &p1 = t[(e + 1) % 3];
              if ((p0[u] - at) * (p1[u] - at) > 0 || p0[u] == p1[u]) continue;
              const double z = p0.z + (p1.z - p0.z) * (at - p0[u]) / (p1[u] - p0[u]);
              a = std::min(a, z), b = std::max(b, z);
            }
            if (a <= b) covered.push_back({a, b});
          }
          std::vector<double> cuts = {z0 + kMargin, z1 - kMargin};
          for (double z : mine) cuts.push_back(z);
          for (double z : theirs) cuts.push_back(z);
          for (const auto& [a, b] : covered) cuts.push_back(a), cuts.push_back(b);
          std::sort(cuts.begin(), cuts.end());
          double open = 0, open_at = 0;
          for (size_t i = 0; i + 1 < cuts.size(); ++i) {
            const double a = std::max(cuts[i], z0 + kMargin),
                         b = std::min(cuts[i + 1], z1 - kMargin);
            if (b <= a) continue;
            const double z = 0.5 * (a + b);
            if (Inside(mine, z) == Inside(theirs, z)) continue;
            bool hit = false;
            for (const auto& [c0, c1] : covered) hit = hit || (c0 <= z && z <= c1);
            if (!hit) open += b - a, open_at = z;
          }
          cracks.length += open;
          if (open > cracks.worst) {
            cracks.worst = open;
            Vec3 w{0, 0, open_at};
            w[u] = at;
            w[j] = plane;
            cracks.where =
                absl::StrCat("levels ", fine, "/", coarse, " face ", j == 0 ? "x" : "y", " = ",
                             plane, " at (", w.x, ", ", w.y, ", ", w.z, "), ", open,
                             " open, coarse cell (", cell[0], ", ", cell[1], ", ", cell[2], ")");
          }
        }
      }
    }
  }
  return cracks;
}

// The browser test's label sheet: label 1 below a wavy surface in 128 x 128 x 40 voxels,
// meshed at E0 0.2, 0.4 and 0.8 voxels as `tandem extract --labels --neuroglancer` does.
TEST(NeuroglancerSkirts, TheLabelSheetsLevelsMeetWithoutACrack) {
  const testing::LabelSheet sheet = testing::WavyLabelSheet();
  const VolumeInfo& grid = sheet.grid;
  const std::vector<uint8_t>& voxels = sheet.voxels;
  NeuroglancerSegment segment{1, {}};
  for (double e0 : {0.2, 0.4, 0.8}) {
    absl::StatusOr<LabeledMesh> complex = testing::MeshLabels(grid, voxels.data(), e0);
    ASSERT_TRUE(complex.ok()) << complex.status();
    for (auto& [id, mesh] : SplitByLabel(*complex, 0)) {
      if (id == 1) segment.lods.push_back(std::move(mesh));
    }
  }
  ASSERT_EQ(segment.lods.size(), 3u);
  const NeuroglancerGrid g = ChooseOctreeGrid(grid, {&segment, 1}, 8);
  auto tree = BuildOctree(segment, g, 16, 1.0);
  ASSERT_TRUE(tree.ok()) << tree.status();
  // The surface is open at the volume's sides: their faces have nothing to close.
  const Vec3 lo{1, 1, -1}, hi{126, 126, 41};
  for (int coarse = 1; coarse < 3; ++coarse) {
    for (int fine = 0; fine < coarse; ++fine) {
      // Quantization (a 65536th of a node) leaves slivers far below a pixel.
      const Cracks c = OpenCracks(segment, *tree, g, fine, coarse, lo, hi);
      EXPECT_LT(c.worst, 0.05) << c.length << " open in all; worst " << c.where;
    }
  }
  // The check sees the cracks: cut without skirts, every pair of levels leaves them open.
  auto cut = BuildOctree(segment, g, 16, 0.0);
  ASSERT_TRUE(cut.ok()) << cut.status();
  for (const auto& [fine, coarse] : {std::pair{0, 1}, std::pair{0, 2}, std::pair{1, 2}}) {
    EXPECT_GT(OpenCracks(segment, *cut, g, fine, coarse, lo, hi).worst, 0.3)
        << fine << "/" << coarse;
  }
}

}  // namespace
}  // namespace tandem::io
