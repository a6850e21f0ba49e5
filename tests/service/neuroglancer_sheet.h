// What neuroglancer_test and neuroglancer_skirts_test both build: the label sheet of the browser
// test (tests/neuroglancer), and a labels session's complex of a volume at one E0.
#ifndef TANDEM_TESTS_SERVICE_NEUROGLANCER_SHEET_H_
#define TANDEM_TESTS_SERVICE_NEUROGLANCER_SHEET_H_

#include <cmath>
#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "tandem/tandem.h"

namespace tandem::testing {

// Label 1 below a wavy surface in 128 x 128 x 40 voxels, open at the volume's border.
struct LabelSheet {
  VolumeInfo grid;
  std::vector<uint8_t> voxels;  // x fastest, then y, then z
};

inline LabelSheet WavyLabelSheet() {
  LabelSheet s;
  s.grid.nx = s.grid.ny = 128;
  s.grid.nz = 40;
  s.grid.dtype = DType::kUInt8;
  s.voxels.resize(s.grid.nx * s.grid.ny * s.grid.nz);
  for (int64_t z = 0; z < s.grid.nz; ++z) {
    for (int64_t y = 0; y < s.grid.ny; ++y) {
      for (int64_t x = 0; x < s.grid.nx; ++x) {
        const double h = 20 + 5 * std::sin(x / 7.0) * std::cos(y / 9.0) +
                         3 * std::sin(static_cast<double>(x + y) / 13);
        s.voxels[(z * s.grid.ny + y) * s.grid.nx + x] = static_cast<double>(z) < h ? 1 : 0;
      }
    }
  }
  return s;
}

// The label complex a labels session at E0 makes of `voxels` (grid.dtype, slice after slice).
inline absl::StatusOr<LabeledMesh> MeshLabels(const VolumeInfo& grid, const uint8_t* voxels,
                                              double e0) {
  SessionOptions o;
  o.labels.enabled = true;
  o.error = e0;
  auto session = TandemSession::Create(grid, o);
  if (!session.ok()) return session.status();
  for (int64_t z = 0; z < grid.nz; ++z) {
    absl::Status added = (*session)->AddSliceBytes(grid.dtype, voxels + z * grid.slice_bytes());
    if (!added.ok()) return added;
  }
  absl::Status finished = (*session)->Finish();
  if (!finished.ok()) return finished;
  return (*session)->SnapshotLabeled();
}

}  // namespace tandem::testing

#endif  // TANDEM_TESTS_SERVICE_NEUROGLANCER_SHEET_H_
