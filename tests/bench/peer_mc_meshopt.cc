// Peer "mc+meshopt": our marching cubes (tandem_core, no simplification) followed by
// meshoptimizer's meshopt_simplify (0.18) down to a target triangle count.
//   peer_mc_meshopt --input V.json --iso C0 --target-triangles N --out M.ply
// Prints one JSON result line (bench_common.h). The error bound is left open (1.0 = the
// mesh's whole extent) so that the target count alone stops the simplifier, as for the
// other peers; meshopt may stop above the target when its topology rules block it.
#include <meshoptimizer.h>

#include "bench_common.h"
#include "core_extract.h"

int main(int argc, char** argv) {
  bench::Result r;
  r.pipeline = "mc+meshopt";
  bench::Clock clock;
  bench::PeerInput in = bench::ExtractPeerInput(argc, argv, &r, &clock);
  const long long target = in.target;
  const std::string& out = in.out;
  std::vector<float>& xyz = in.xyz;
  std::vector<uint32_t>& indices = in.indices;

  std::vector<uint32_t> simplified(indices.size());
  float result_error = 0;
  const size_t n = meshopt_simplify(simplified.data(), indices.data(), indices.size(), xyz.data(),
                                    xyz.size() / 3, 3 * sizeof(float), 3 * size_t(target),
                                    /*target_error=*/1.0f, /*options=*/0, &result_error);
  simplified.resize(n);
  std::vector<uint32_t>().swap(indices);
  r.vertices_final = static_cast<int64_t>(bench::CompactVertices(&xyz, &simplified));
  r.simplify_s = clock.Lap();
  r.triangles_final = static_cast<int64_t>(n / 3);

  bench::WritePly(out, xyz.data(), xyz.size() / 3, simplified.data(), simplified.size());
  r.write_s = clock.Lap();
  bench::PrintResult(r);
  return 0;
}
