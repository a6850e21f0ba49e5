// A key for an oriented triangle by its corner positions, whatever its vertex indices: tests
// that compare two meshes' triangles (a label's surface against its neighbour's, a streamed
// file against a local one).
#ifndef TANDEM_TESTS_TESTUTIL_TRIANGLE_KEY_H_
#define TANDEM_TESTS_TESTUTIL_TRIANGLE_KEY_H_

#include <algorithm>
#include <array>
#include <cstddef>

#include "tandem/mesh.h"

namespace tandem::testing {

using TriangleKey = std::array<std::array<double, 3>, 3>;

// Triangle t's corners rotated to start at the least, in reverse order when `reversed`.
inline TriangleKey KeyOfTriangle(const IndexedMesh& m, size_t t, bool reversed) {
  TriangleKey k;
  for (int c = 0; c < 3; ++c) {
    const int corner = reversed ? (3 - c) % 3 : c;
    const Vec3& p = m.positions[m.indices[3 * t + static_cast<size_t>(corner)]];
    k[static_cast<size_t>(c)] = {p.x, p.y, p.z};
  }
  std::rotate(k.begin(), std::min_element(k.begin(), k.end()), k.end());
  return k;
}

}  // namespace tandem::testing

#endif  // TANDEM_TESTS_TESTUTIL_TRIANGLE_KEY_H_
