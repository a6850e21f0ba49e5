// distance_quantiles A.ply B.ply [SAMPLES]: quantiles of the per-sample distances from
// area-uniform samples of A to B ("fwd") and of B to A ("bwd"), one line each:
//   fwd  p50  p90  p99  p99.9  max-of-samples
// A high quantile is a robust stand-in for the Hausdorff distance (a maximum, which one
// contraction moves by tens of percent): tests/bench/SEALING.md uses it to compare sealed
// and plain runs. Samples: SAMPLES per direction (default 1,000,000), seed 1, jittered along
// the cumulative area as core/eval/distance.cc does; vertices are not added.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <vector>

#include "tandem/eval/distance.h"
#include "tandem/io/mesh_io.h"

namespace {

using tandem::IndexedMesh;
using tandem::Vec3;
using tandem::eval::TriangleBvh;

std::vector<double> SampleDistances(const IndexedMesh& from, const TriangleBvh& to, size_t n) {
  const size_t num_tris = from.num_triangles();
  auto corner = [&](size_t t, int k) { return from.positions[from.indices[3 * t + k]]; };
  std::vector<double> cumulative(num_tris);
  double total = 0;
  for (size_t t = 0; t < num_tris; ++t) {
    total += 0.5 * tandem::Norm(tandem::Cross(corner(t, 1) - corner(t, 0),
                                              corner(t, 2) - corner(t, 0)));
    cumulative[t] = total;
  }
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> uniform(0, 1);
  std::vector<double> out(n);
  uint32_t hint = tandem::kInvalid;
  size_t t = 0;
  for (size_t i = 0; i < n; ++i) {
    const double u = (static_cast<double>(i) + uniform(rng)) * total / static_cast<double>(n);
    while (t + 1 < num_tris && cumulative[t] <= u) ++t;
    const double s = std::sqrt(uniform(rng)), r = uniform(rng);
    const Vec3 q = (1 - s) * corner(t, 0) + (s * (1 - r)) * corner(t, 1) + (s * r) * corner(t, 2);
    const TriangleBvh::Hit hit = to.Closest(q, hint);
    hint = hit.triangle;
    out[i] = hit.distance;
  }
  return out;
}

void PrintQuantiles(const char* direction, std::vector<double> d) {
  std::sort(d.begin(), d.end());
  std::printf("%s", direction);
  for (double q : {0.5, 0.9, 0.99, 0.999})
    std::printf("\t%.4f", d[static_cast<size_t>(q * static_cast<double>(d.size() - 1))]);
  std::printf("\t%.4f\n", d.back());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: distance_quantiles A.ply B.ply [SAMPLES]\n");
    return 2;
  }
  const auto a = tandem::io::ReadMesh(argv[1]);
  const auto b = tandem::io::ReadMesh(argv[2]);
  if (!a.ok() || !b.ok() || a->num_triangles() == 0 || b->num_triangles() == 0) {
    std::fprintf(stderr, "distance_quantiles: cannot read two non-empty meshes\n");
    return 1;
  }
  const size_t n = argc > 3 ? std::strtoull(argv[3], nullptr, 10) : 1000000;
  {
    const TriangleBvh to_b(*b);
    PrintQuantiles("fwd", SampleDistances(*a, to_b, n));
  }
  const TriangleBvh to_a(*a);
  PrintQuantiles("bwd", SampleDistances(*b, to_a, n));
  return 0;
}
