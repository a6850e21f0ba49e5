// Helpers shared by the engine's tests (simplifier, contraction checks, sag correction):
// volumes from formulas, layer-by-layer extraction into a store, edge tallies, the full-
// resolution surface of a source.
#ifndef TANDEM_TESTS_CORE_ENGINE_TESTUTIL_H_
#define TANDEM_TESTS_CORE_ENGINE_TESTUTIL_H_

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "layer_extractor.h"
#include "mesh_store.h"
#include "simplifier.h"
#include "tandem/geometry.h"
#include "tandem/io/run_session.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"
#include "testutil/embedded.h"
#include "testutil/testutil.h"

namespace tandem {

using EdgeTriangles = std::map<std::pair<VertexId, VertexId>, int>;  // edge -> its triangles
inline EdgeTriangles CountEdgeTriangles(const MeshStore& store) {
  EdgeTriangles edge_triangles;
  for (TriId t = 0; t < store.triangle_capacity(); ++t) {
    if (!store.triangle_alive(t)) continue;
    const auto& tri = store.triangle(t);
    for (int i = 0; i < 3; ++i) ++edge_triangles[std::minmax(tri[i], tri[(i + 1) % 3])];
  }
  return edge_triangles;
}


// A float32 volume from a formula (testutil.h).
using ::tandem::testing::FieldSource;

using ::tandem::testing::BoxCutGyroid;

// Extracts the whole volume into `store` layer by layer, adding each layer's triangles to the
// simplifier (and delaying them, as the tandem schedules do, if asked), then calling
// after_layer(k) if given; returns them all.
inline std::vector<TriId> ExtractLayers(SliceSource* src, MeshStore* store, Simplifier* simplifier,
                                 bool delay_each_layer,
                                 const std::function<void(int64_t)>& after_layer = nullptr) {
  const VolumeInfo& info = src->info();
  LayerExtractor ex(ExtractorConfig{info.nx, info.ny, info.nz, info.spacing, info.origin, 0},
                    store);
  std::vector<uint8_t> bytes;
  std::vector<TriId> tris, all;
  std::vector<VertexId> verts;
  for (int64_t k = 0; k < info.nz; ++k) {
    EXPECT_TRUE(src->ReadSlice(&bytes).ok());
    tris.clear();
    verts.clear();
    EXPECT_TRUE(ex.AddSlice(reinterpret_cast<const float*>(bytes.data()), &tris, &verts).ok());
    simplifier->AddTriangles(tris, verts);
    if (delay_each_layer) simplifier->Delay(tris);
    all.insert(all.end(), tris.begin(), tris.end());
    if (after_layer) after_layer(k);
  }
  return all;
}

// The unsimplified surface of a source, to measure distances to.
inline IndexedMesh FullSurface(SliceSource& src) {
  SessionOptions o;
  o.schedule = Schedule::kNone;
  auto full = io::RunSession(src, o);
  EXPECT_TRUE(full.ok()) << full.status();
  return full.ok() ? (*full)->Snapshot() : IndexedMesh{};
}

// A finished session over the n³ float grid v (x fastest, z slowest); null after a failure
// (reported).
inline std::unique_ptr<TandemSession> RunCube(const std::vector<float>& v, int n,
                                              const SessionOptions& options) {
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = n;
  grid.dtype = DType::kFloat32;
  auto session = TandemSession::Create(grid, options);
  EXPECT_TRUE(session.ok()) << session.status();
  if (!session.ok()) return nullptr;
  for (int k = 0; k < n; ++k) {
    const absl::Status st = (*session)->AddSlice(v.data() + static_cast<size_t>(k) * n * n);
    EXPECT_TRUE(st.ok()) << st;
    if (!st.ok()) return nullptr;
  }
  const absl::Status st = (*session)->Finish();
  EXPECT_TRUE(st.ok()) << st;
  return st.ok() ? std::move(*session) : nullptr;
}

// A quantised tangle at grid point (i, j, k): six fixed plane waves (directions and phases
// from the seed) summed and rounded to the integers 0..8. At iso-value 4, grid values equal to
// it put edge points on grid points, which leaves zero-area triangles (issue 24).
inline double QuantisedTangle(int seed, double i, double j, double k) {
  double f = 0;
  for (int w = 0; w < 6; ++w) {
    const double a = 0.37 * (w + 1) + 1.3 * seed, b = 0.91 * (w + 2) + 0.7 * seed;
    f += std::cos(0.35 * (std::cos(a) * i + std::sin(a) * std::cos(b) * j + std::sin(b) * k) +
                  1.7 * w + seed);
  }
  return std::clamp(std::round(1.5 * f + 4), 0.0, 8.0);
}

// Triangles of zero area (IsDegenerateTriangle).
inline int64_t CountDegenerate(const IndexedMesh& m) {
  return testing::CountTrianglesWhere(m, IsDegenerateTriangle);
}

}  // namespace tandem

#endif  // TANDEM_TESTS_CORE_ENGINE_TESTUTIL_H_
