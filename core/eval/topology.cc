#include "tandem/eval/topology.h"

#include <algorithm>
#include <numeric>
#include <tuple>

namespace tandem::eval {
namespace {

struct DisjointSets {
  std::vector<uint32_t> parent;
  explicit DisjointSets(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0u); }
  uint32_t Find(uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void Union(uint32_t a, uint32_t b) {
    a = Find(a);
    b = Find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

struct HalfEdge {
  uint32_t lo, hi;  // sorted endpoints
  uint32_t tri;
  bool forward;     // traversed lo -> hi
  bool operator<(const HalfEdge& o) const {
    return std::tie(lo, hi, tri) < std::tie(o.lo, o.hi, o.tri);
  }
};

}  // namespace

TopologyReport AnalyzeTopology(const IndexedMesh& mesh) {
  TopologyReport r;
  const size_t nt = mesh.num_triangles();
  const size_t nv = mesh.num_vertices();
  r.triangles = nt;
  std::vector<uint8_t> used(nv, 0);
  std::vector<HalfEdge> he;
  he.reserve(nt * 3);
  for (uint32_t t = 0; t < nt; ++t) {
    const uint32_t* v = &mesh.indices[3 * t];
    if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0]) ++r.repeated_index_triangles;
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = v[k], b = v[(k + 1) % 3];
      used[a] = 1;
      if (a == b) continue;
      he.push_back({std::min(a, b), std::max(a, b), t, a < b});
    }
  }
  r.vertices = static_cast<size_t>(std::count(used.begin(), used.end(), 1));
  std::sort(he.begin(), he.end());

  // Edges; triangles sharing an edge are joined in a per-vertex fan structure below.
  DisjointSets tri_sets(nt);
  std::vector<std::pair<uint32_t, uint32_t>> boundary;  // boundary edges
  // Corner fans: for each vertex, its incident triangles united when they share an edge at
  // that vertex. Keyed by (vertex, triangle) -> index into `corner_of`.
  std::vector<std::pair<uint32_t, uint32_t>> corners;  // (vertex, tri)
  corners.reserve(nt * 3);
  for (uint32_t t = 0; t < nt; ++t) {
    for (int k = 0; k < 3; ++k) corners.emplace_back(mesh.indices[3 * t + k], t);
  }
  std::sort(corners.begin(), corners.end());
  corners.erase(std::unique(corners.begin(), corners.end()), corners.end());
  auto corner_index = [&corners](uint32_t v, uint32_t t) {
    return static_cast<uint32_t>(
        std::lower_bound(corners.begin(), corners.end(), std::make_pair(v, t)) - corners.begin());
  };
  DisjointSets fans(corners.size());

  for (size_t i = 0; i < he.size();) {
    size_t j = i;
    while (j < he.size() && he[j].lo == he[i].lo && he[j].hi == he[i].hi) ++j;
    const size_t count = j - i;
    ++r.edges;
    if (count == 1) {
      ++r.boundary_edges;
      boundary.emplace_back(he[i].lo, he[i].hi);
    } else if (count == 2) {
      if (he[i].forward == he[i + 1].forward) ++r.misoriented_edges;
    } else {
      ++r.nonmanifold_edges;
    }
    for (size_t k = i + 1; k < j; ++k) {
      tri_sets.Union(he[i].tri, he[k].tri);
      fans.Union(corner_index(he[i].lo, he[i].tri), corner_index(he[i].lo, he[k].tri));
      fans.Union(corner_index(he[i].hi, he[i].tri), corner_index(he[i].hi, he[k].tri));
    }
    i = j;
  }
  r.euler = static_cast<int64_t>(r.vertices) - static_cast<int64_t>(r.edges) +
            static_cast<int64_t>(nt);

  // Non-manifold vertices: more than one fan of triangles around the vertex.
  for (size_t i = 0; i < corners.size();) {
    size_t j = i;
    size_t roots = 0;
    while (j < corners.size() && corners[j].first == corners[i].first) {
      if (fans.Find(static_cast<uint32_t>(j)) == j) ++roots;
      ++j;
    }
    if (roots > 1) ++r.nonmanifold_vertices;
    i = j;
  }

  // Components (triangles joined through shared vertices) and their Euler characteristics.
  for (size_t i = 0; i < corners.size();) {
    size_t j = i + 1;
    while (j < corners.size() && corners[j].first == corners[i].first) {
      tri_sets.Union(corners[i].second, corners[j].second);
      ++j;
    }
    i = j;
  }
  std::vector<int64_t> comp_of_root(nt, -1);
  for (uint32_t t = 0; t < nt; ++t) {
    const uint32_t root = tri_sets.Find(t);
    if (comp_of_root[root] < 0) {
      comp_of_root[root] = static_cast<int64_t>(r.component_euler.size());
      r.component_euler.push_back(0);
    }
    r.component_euler[comp_of_root[root]] += 1;  // F
  }
  r.components = r.component_euler.size();
  for (size_t i = 0; i < he.size();) {
    size_t j = i;
    while (j < he.size() && he[j].lo == he[i].lo && he[j].hi == he[i].hi) ++j;
    r.component_euler[comp_of_root[tri_sets.Find(he[i].tri)]] -= 1;  // E
    i = j;
  }
  for (size_t i = 0; i < corners.size();) {
    size_t j = i;
    while (j < corners.size() && corners[j].first == corners[i].first) ++j;
    r.component_euler[comp_of_root[tri_sets.Find(corners[i].second)]] += 1;  // V
    i = j;
  }

  // Boundary loops: connected components of the boundary-edge graph.
  if (!boundary.empty()) {
    DisjointSets bsets(nv);
    std::vector<uint8_t> on_boundary(nv, 0);
    for (auto [a, b] : boundary) {
      bsets.Union(a, b);
      on_boundary[a] = on_boundary[b] = 1;
    }
    for (uint32_t v = 0; v < nv; ++v) {
      if (on_boundary[v] && bsets.Find(v) == v) ++r.boundary_loops;
    }
  }
  return r;
}

namespace {

// The vertices sorted by position (x, then y, then z; ties by id).
std::vector<uint32_t> ByPosition(const IndexedMesh& mesh) {
  std::vector<uint32_t> order(mesh.num_vertices());
  std::iota(order.begin(), order.end(), 0u);
  auto key = [&mesh](uint32_t v) {
    const Vec3& p = mesh.positions[v];
    return std::make_tuple(p.x, p.y, p.z, v);
  };
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key(a) < key(b); });
  return order;
}

}  // namespace

size_t CountDuplicatePositions(const IndexedMesh& mesh) {
  const std::vector<uint32_t> order = ByPosition(mesh);
  size_t dup = 0;
  for (size_t i = 1; i < order.size(); ++i) {
    dup += mesh.positions[order[i]] == mesh.positions[order[i - 1]];
  }
  return dup;
}

IndexedMesh WeldByPosition(const IndexedMesh& mesh) {
  const std::vector<uint32_t> order = ByPosition(mesh);
  // Each vertex goes to the least id at its position; ids are renumbered in ascending order.
  std::vector<uint32_t> first(mesh.num_vertices());
  for (size_t i = 0; i < order.size(); ++i) {
    const bool same = i > 0 && mesh.positions[order[i]] == mesh.positions[order[i - 1]];
    first[order[i]] = same ? first[order[i - 1]] : order[i];
  }
  IndexedMesh out;
  std::vector<uint32_t> id(mesh.num_vertices());
  for (uint32_t v = 0; v < mesh.num_vertices(); ++v) {
    if (first[v] == v) {
      id[v] = static_cast<uint32_t>(out.positions.size());
      out.positions.push_back(mesh.positions[v]);
    }
  }
  out.indices.reserve(mesh.indices.size());
  for (uint32_t v : mesh.indices) out.indices.push_back(id[first[v]]);
  return out;
}

}  // namespace tandem::eval

