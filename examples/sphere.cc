// A sphere delivered slice by slice, meshed and simplified while it arrives: the library's
// whole contract in one program (the README quotes it).
#include <cmath>
#include <cstdio>
#include <vector>

#include "tandem/tandem.h"

static int Fail(const absl::Status& st) {
  std::fprintf(stderr, "%s\n", st.ToString().c_str());
  return 1;
}

int main() {
  tandem::VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 96;
  grid.spacing = {0.5, 0.5, 0.5};  // millimetres per voxel step

  tandem::SessionOptions options;
  options.iso = 0;      // the surface where the field crosses 0: a sphere of radius 20 mm
  options.error = 0.1;  // E0: no simplified triangle strays more than 0.1 mm from it

  auto session = tandem::TandemSession::Create(grid, options);
  if (!session.ok()) return Fail(session.status());
  std::vector<float> slice(grid.nx * grid.ny);
  for (int k = 0; k < grid.nz; ++k) {  // one slice at a time, as a scanner delivers them
    for (int j = 0; j < grid.ny; ++j) {
      for (int i = 0; i < grid.nx; ++i) {
        slice[j * grid.nx + i] = 20.0f - 0.5f * std::hypot(i - 47.5f, j - 47.5f, k - 47.5f);
      }
    }
    if (absl::Status st = (*session)->AddSlice(slice.data()); !st.ok()) return Fail(st);
  }
  if (absl::Status st = (*session)->Finish(); !st.ok()) return Fail(st);
  tandem::IndexedMesh mesh = (*session)->Snapshot();  // positions in mm, 3 indices a triangle
  std::printf("%zu vertices, %zu triangles, Error(K) = %.3f mm\n", mesh.num_vertices(),
              mesh.num_triangles(), (*session)->MaxShapeError());
  return 0;
}
