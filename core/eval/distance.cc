// Metro-style mesh distances: a BVH for exact closest-point queries and chunked, seeded,
// area-uniform sampling. See tandem/distance.h for the contracts.
#include "tandem/eval/distance.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cassert>
#include <cmath>
#include <limits>
#include <random>
#include <thread>

#include "tandem/eval/metrics.h"

namespace tandem::eval {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr uint32_t kLeafSize = 4;
// Work unit of the sampler. Fixed (not derived from the thread count) so that the RNG
// streams and the order of the partial sums, hence the result, do not depend on threads.
constexpr size_t kChunk = 4096;
constexpr size_t kAutoMinSamples = 100'000;
constexpr size_t kAutoMaxSamples = 10'000'000;

Vec3 Lerp(Vec3 a, Vec3 b, double t) { return a + t * (b - a); }
double Distance2(Vec3 a, Vec3 b) { return Dot(a - b, a - b); }

Vec3 ClosestPointOnSegment(Vec3 p, Vec3 a, Vec3 b) {
  const Vec3 ab = b - a;
  const double len2 = Dot(ab, ab);
  if (!(len2 > 0.0)) return a;
  return Lerp(a, b, std::clamp(Dot(p - a, ab) / len2, 0.0, 1.0));
}

// splitmix64 finaliser: decorrelates (seed, chunk) into a well-mixed 64-bit stream seed.
uint64_t Mix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

double BoxDistance2(Vec3 p, Vec3 lo, Vec3 hi) {
  double d2 = 0.0;
  for (int k = 0; k < 3; ++k) {
    const double d = std::max({lo[k] - p[k], 0.0, p[k] - hi[k]});
    d2 += d * d;
  }
  return d2;
}

}  // namespace

Vec3 ClosestPointOnTriangle(Vec3 p, Vec3 a, Vec3 b, Vec3 c) {
  // Ericson §5.1.5: test the Voronoi regions of the vertices, then of the edges, then the
  // face, using only dot products of the edge vectors with the query offsets.
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = Dot(ab, ap), d2 = Dot(ac, ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;

  const Vec3 bp = p - b;
  const double d3 = Dot(ab, bp), d4 = Dot(ac, bp);
  if (d3 >= 0.0 && d4 <= d3) return b;

  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + (d1 / (d1 - d3)) * ab;

  const Vec3 cp = p - c;
  const double d5 = Dot(ab, cp), d6 = Dot(ac, cp);
  if (d6 >= 0.0 && d5 <= d6) return c;

  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + (d2 / (d2 - d6)) * ac;

  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0) {
    return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  }

  // Face region. va + vb + vc = |ab × ac|²: for a (near-)degenerate triangle the barycentric
  // division is meaningless, and the closest point lies on an edge anyway.
  const double denom = va + vb + vc;
  if (!(denom > 1e-24 * Dot(ab, ab) * Dot(ac, ac))) {
    const Vec3 q[3] = {ClosestPointOnSegment(p, a, b), ClosestPointOnSegment(p, b, c),
                       ClosestPointOnSegment(p, c, a)};
    int best = 0;
    for (int k = 1; k < 3; ++k)
      if (Distance2(p, q[k]) < Distance2(p, q[best])) best = k;
    return q[best];
  }
  // Clamped so that round-off can never place the answer outside the triangle.
  const double v = std::clamp(vb / denom, 0.0, 1.0);
  const double w = std::clamp(vc / denom, 0.0, 1.0 - v);
  return a + v * ab + w * ac;
}

// ---------------------------------------------------------------------------------------
// TriangleBvh

TriangleBvh::TriangleBvh(const IndexedMesh& mesh) {
  assert(mesh.indices.size() % 3 == 0);
  const size_t n = mesh.num_triangles();
  if (n == 0) return;
  assert(n < kInvalid);

  // Per-triangle boxes, used only while building. The split key is the box centre (as good
  // as the centroid), kept as lo + hi to save memory and a multiplication.
  struct Prim {
    Vec3 lo, hi;
    double Key(int axis) const { return lo[axis] + hi[axis]; }
  };
  std::vector<Prim> prims(n);
  for (size_t t = 0; t < n; ++t) {
    Prim& pr = prims[t];
    pr.lo = pr.hi = mesh.positions[mesh.indices[3 * t]];
    for (int k = 1; k < 3; ++k) {
      const Vec3 v = mesh.positions[mesh.indices[3 * t + k]];
      for (int d = 0; d < 3; ++d) {
        pr.lo[d] = std::min(pr.lo[d], v[d]);
        pr.hi[d] = std::max(pr.hi[d], v[d]);
      }
    }
  }
  tri_ids_.resize(n);
  for (size_t t = 0; t < n; ++t) tri_ids_[t] = static_cast<uint32_t>(t);

  // A median split yields leaves of 2..4 triangles (for n ≥ 2), so fewer than n nodes.
  nodes_.reserve(n);
  nodes_.push_back({});
  struct Task {
    uint32_t node, begin, end;
  };
  std::vector<Task> stack = {{0, 0, static_cast<uint32_t>(n)}};
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    Vec3 lo{kInf, kInf, kInf}, hi{-kInf, -kInf, -kInf};
    Vec3 clo = lo, chi = hi;  // bounds of the split keys
    for (uint32_t i = task.begin; i < task.end; ++i) {
      const Prim& pr = prims[tri_ids_[i]];
      for (int d = 0; d < 3; ++d) {
        lo[d] = std::min(lo[d], pr.lo[d]);
        hi[d] = std::max(hi[d], pr.hi[d]);
        clo[d] = std::min(clo[d], pr.Key(d));
        chi[d] = std::max(chi[d], pr.Key(d));
      }
    }
    nodes_[task.node].lo = lo;
    nodes_[task.node].hi = hi;
    const uint32_t count = task.end - task.begin;
    if (count <= kLeafSize) {
      nodes_[task.node].first = task.begin;
      nodes_[task.node].count = count;
      continue;
    }
    int axis = 0;
    for (int d = 1; d < 3; ++d)
      if (chi[d] - clo[d] > chi[axis] - clo[axis]) axis = d;
    const uint32_t mid = task.begin + count / 2;
    std::nth_element(
        tri_ids_.begin() + task.begin, tri_ids_.begin() + mid, tri_ids_.begin() + task.end,
        [&](uint32_t x, uint32_t y) { return prims[x].Key(axis) < prims[y].Key(axis); });
    const uint32_t left = static_cast<uint32_t>(nodes_.size());
    nodes_[task.node].first = left;
    nodes_[task.node].count = 0;
    nodes_.push_back({});
    nodes_.push_back({});
    stack.push_back({left + 1, mid, task.end});
    stack.push_back({left, task.begin, mid});
  }

  corners_.resize(3 * n);
  slot_of_.resize(n);
  for (size_t slot = 0; slot < n; ++slot) {
    const uint32_t t = tri_ids_[slot];
    slot_of_[t] = static_cast<uint32_t>(slot);
    for (int k = 0; k < 3; ++k) corners_[3 * slot + k] = mesh.positions[mesh.indices[3 * t + k]];
  }
}

TriangleBvh::Hit TriangleBvh::Closest(Vec3 p, uint32_t hint) const {
  Hit hit;
  hit.distance = kInf;
  if (nodes_.empty()) return hit;
  double best_d2 = kInf;
  uint32_t best_slot = kInvalid;
  auto test = [&](uint32_t slot) {
    const Vec3 q = ClosestPointOnTriangle(p, corners_[3 * slot], corners_[3 * slot + 1],
                                          corners_[3 * slot + 2]);
    const double d2 = Distance2(p, q);
    if (d2 < best_d2) {
      best_d2 = d2;
      best_slot = slot;
      hit.point = q;
    }
  };
  if (hint < slot_of_.size()) test(slot_of_[hint]);

  // Depth-first, nearer child first; a median split keeps the depth ≤ log2(n) + 1 < 64.
  struct Entry {
    uint32_t node;
    double d2;
  };
  std::array<Entry, 64> stack;
  int top = 0;
  stack[top++] = {0, BoxDistance2(p, nodes_[0].lo, nodes_[0].hi)};
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.d2 >= best_d2) continue;
    const Node& node = nodes_[e.node];
    if (node.count > 0) {
      for (uint32_t s = node.first; s < node.first + node.count; ++s) test(s);
      continue;
    }
    const uint32_t l = node.first, r = node.first + 1;
    const double dl = BoxDistance2(p, nodes_[l].lo, nodes_[l].hi);
    const double dr = BoxDistance2(p, nodes_[r].lo, nodes_[r].hi);
    // Push the farther one first so the nearer one is popped next.
    if (dl <= dr) {
      if (dr < best_d2) stack[top++] = {r, dr};
      if (dl < best_d2) stack[top++] = {l, dl};
    } else {
      if (dl < best_d2) stack[top++] = {l, dl};
      if (dr < best_d2) stack[top++] = {r, dr};
    }
  }
  if (best_slot == kInvalid) {  // only when p has a NaN coordinate
    hit.distance = kNaN;
    return hit;
  }
  hit.distance = std::sqrt(best_d2);
  hit.triangle = tri_ids_[best_slot];
  return hit;
}

// ---------------------------------------------------------------------------------------
// Sampling and measurement

namespace {

struct Partial {
  double sum = 0, sum2 = 0, max = 0;
  size_t count = 0;
};

// Runs fn(chunk) → Partial for chunk = 0 .. chunks−1 on `threads` threads and returns the
// partials in chunk order (so any later reduction is independent of scheduling).
template <typename Fn>
std::vector<Partial> RunChunks(size_t chunks, int threads, const Fn& fn) {
  std::vector<Partial> out(chunks);
  size_t workers = threads > 0 ? static_cast<size_t>(threads)
                               : std::max(1u, std::thread::hardware_concurrency());
  workers = std::min(workers, chunks);
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t c; (c = next.fetch_add(1, std::memory_order_relaxed)) < chunks;) out[c] = fn(c);
  };
  std::vector<std::thread> pool;
  for (size_t i = 1; i < workers; ++i) pool.emplace_back(work);
  work();
  for (std::thread& t : pool) t.join();
  return out;
}

}  // namespace

DirectedDistance MeasureDirectedDistance(const IndexedMesh& from, const TriangleBvh& to,
                                         const DistanceOptions& options) {
  DirectedDistance result;
  if (to.empty() || from.positions.empty()) {
    result.l1 = result.l2 = result.linf = kNaN;
    return result;
  }

  // Cumulative area over triangles: the inverse CDF of area-uniform sampling.
  const size_t num_tris = from.num_triangles();
  std::vector<double> cumulative(num_tris);
  double total = 0.0;
  for (size_t t = 0; t < num_tris; ++t) {
    total +=
        TriangleArea(from.positions[from.indices[3 * t]], from.positions[from.indices[3 * t + 1]],
                     from.positions[from.indices[3 * t + 2]]);
    cumulative[t] = total;
  }
  size_t samples = 0;
  if (total > 0.0) {
    samples = options.samples > 0
                  ? options.samples
                  : std::min(kAutoMaxSamples, std::max(kAutoMinSamples, 2 * num_tris));
  }
  const size_t sample_chunks = (samples + kChunk - 1) / kChunk;
  const size_t num_vertices = from.num_vertices();
  const size_t vertex_chunks = (num_vertices + kChunk - 1) / kChunk;

  auto run_chunk = [&](size_t chunk) {
    Partial part;
    uint32_t hint = kInvalid;
    auto add = [&](Vec3 q) {
      const TriangleBvh::Hit hit = to.Closest(q, hint);
      hint = hit.triangle;
      part.sum += hit.distance;
      part.sum2 += hit.distance * hit.distance;
      part.max = std::max(part.max, hit.distance);
      ++part.count;
    };
    if (chunk >= sample_chunks) {  // a chunk of vertices
      const size_t begin = (chunk - sample_chunks) * kChunk;
      const size_t end = std::min(begin + kChunk, num_vertices);
      for (size_t v = begin; v < end; ++v) add(from.positions[v]);
      return part;
    }
    // Jittered stratification: sample i sits at cumulative area (i + U) / samples · total,
    // so the walk over `cumulative` is monotone within a chunk and successive samples are
    // neighbours on the surface (good BVH hints), and every triangle gets its area's share.
    std::mt19937_64 rng(Mix(options.seed ^ Mix(chunk)));
    std::uniform_real_distribution<double> uniform(0.0, 1.0);
    const size_t begin = chunk * kChunk;
    const size_t end = std::min(begin + kChunk, samples);
    const double step = total / static_cast<double>(samples);
    size_t t = 0;
    for (size_t i = begin; i < end; ++i) {
      const double u = (static_cast<double>(i) + uniform(rng)) * step;
      if (i == begin) {
        t = std::upper_bound(cumulative.begin(), cumulative.end(), u) - cumulative.begin();
      } else {
        while (t < num_tris && cumulative[t] <= u) ++t;
      }
      t = std::min(t, num_tris - 1);  // u may round up to total
      // Uniform point in the triangle (square-root warp of two uniforms).
      const double s = std::sqrt(uniform(rng)), r = uniform(rng);
      const Vec3 a = from.positions[from.indices[3 * t]];
      const Vec3 b = from.positions[from.indices[3 * t + 1]];
      const Vec3 c = from.positions[from.indices[3 * t + 2]];
      add((1.0 - s) * a + (s * (1.0 - r)) * b + (s * r) * c);
    }
    return part;
  };
  const std::vector<Partial> parts =
      RunChunks(sample_chunks + vertex_chunks, options.threads, run_chunk);

  // Means over the area samples; the vertices only join the maximum (they are not
  // area-uniform), unless there are no area samples at all.
  Partial area, all;
  for (size_t c = 0; c < parts.size(); ++c) {
    if (c < sample_chunks) {
      area.sum += parts[c].sum;
      area.sum2 += parts[c].sum2;
      area.count += parts[c].count;
    }
    all.sum += parts[c].sum;
    all.sum2 += parts[c].sum2;
    all.count += parts[c].count;
    all.max = std::max(all.max, parts[c].max);
  }
  const Partial& mean_over = area.count > 0 ? area : all;
  const double n = static_cast<double>(mean_over.count);
  result.l1 = mean_over.sum / n;
  result.l2 = std::sqrt(mean_over.sum2 / n);
  result.linf = all.max;
  result.samples = area.count;
  return result;
}

Distances MeasureDistances(const IndexedMesh& a, const IndexedMesh& b,
                           const DistanceOptions& options) {
  Distances d;
  {
    const TriangleBvh bvh_b(b);
    d.forward = MeasureDirectedDistance(a, bvh_b, options);
  }  // one hierarchy alive at a time: they can be large
  {
    const TriangleBvh bvh_a(a);
    d.backward = MeasureDirectedDistance(b, bvh_a, options);
  }
  // std::max would hide a NaN in its second argument; NaN in either direction wins here.
  auto max_nan = [](double x, double y) {
    return std::isnan(x) || std::isnan(y) ? kNaN : std::max(x, y);
  };
  d.l1_max = max_nan(d.forward.l1, d.backward.l1);
  d.l2_max = max_nan(d.forward.l2, d.backward.l2);
  d.linf_max = max_nan(d.forward.linf, d.backward.linf);
  return d;
}

}  // namespace tandem::eval
