// Our full-resolution extraction for the peers that pair it with another simplifier:
// tandem_core's streaming marching cubes (Schedule::kNone), reading the volume file one slice
// at a time. Returns float positions and a 32-bit index buffer.
#ifndef TANDEM_BENCH_CORE_EXTRACT_H_
#define TANDEM_BENCH_CORE_EXTRACT_H_

#include <string>
#include <vector>

#include "bench_common.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/run_session.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace bench {

inline void ExtractWithCore(const std::string& input, double iso, std::vector<float>* xyz,
                            std::vector<uint32_t>* indices) {
  auto source = tandem::io::OpenVolume(input);
  if (!source.ok()) Die(std::string(source.status().message()));
  tandem::SessionOptions opt;
  opt.iso = iso;
  opt.schedule = tandem::Schedule::kNone;
  auto session = tandem::io::RunSession(**source, opt);
  if (!session.ok()) Die(input + ": " + std::string(session.status().message()));
  tandem::IndexedMesh mesh = (*session)->Snapshot();
  session->reset();  // free the session's store before the simplifier allocates
  xyz->resize(3 * mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    (*xyz)[3 * i] = static_cast<float>(mesh.positions[i].x);
    (*xyz)[3 * i + 1] = static_cast<float>(mesh.positions[i].y);
    (*xyz)[3 * i + 2] = static_cast<float>(mesh.positions[i].z);
  }
  *indices = std::move(mesh.indices);
}

// The start shared by the "our extraction + another simplifier" programs: their flags
// (--input, --iso, --target-triangles, --out) and the full-resolution surface, with the
// extraction's time (reading included, interleaved) and triangle count recorded in *r.
// *clock is lapped after the extraction, so the caller's next Lap() times its simplifier.
struct PeerInput {
  std::string out;
  long long target = 0;
  std::vector<float> xyz;
  std::vector<uint32_t> indices;
};

inline PeerInput ExtractPeerInput(int argc, char** argv, Result* r, Clock* clock) {
  auto flags = ParseFlags(argc, argv);
  const std::string input = Require(flags, "input");
  const double iso = std::stod(Require(flags, "iso"));
  PeerInput in;
  in.target = std::stoll(Require(flags, "target-triangles"));
  in.out = Require(flags, "out");
  clock->Lap();
  ExtractWithCore(input, iso, &in.xyz, &in.indices);
  r->extract_s = clock->Lap();
  r->triangles_extracted = static_cast<int64_t>(in.indices.size() / 3);
  return in;
}

}  // namespace bench

#endif  // TANDEM_BENCH_CORE_EXTRACT_H_
