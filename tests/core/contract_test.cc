// The contract (tandem.h) stands alone: it pulls in no thread machinery, and with it alone a
// caller can supply the threads (an Executor of its own) and get the mesh the built-in pool
// gives.
#include "tandem/tandem.h"

// Checked before anything else is included: what tandem.h brings, and only that.
#if defined(_GLIBCXX_THREAD) || defined(_GLIBCXX_MUTEX) || \
    defined(_GLIBCXX_CONDITION_VARIABLE) || defined(_GLIBCXX_DEQUE)
#error "tandem/tandem.h pulls in <thread>, <mutex>, <condition_variable> or <deque>"
#endif

#include <cmath>
#include <functional>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "testutil/inline_executor.h"

namespace tandem {
namespace {

IndexedMesh Torus(Executor* executor) {
  VolumeInfo grid;
  grid.nx = grid.ny = 64;
  grid.nz = 32;
  SessionOptions options;
  options.error = 0.3;
  options.parts = 2;
  options.pipeline = true;
  auto session = TandemSession::Create(grid, options, executor);
  EXPECT_TRUE(session.ok()) << session.status();
  if (!session.ok()) return {};
  std::vector<float> slice(static_cast<size_t>(grid.nx * grid.ny));
  for (int k = 0; k < grid.nz; ++k) {
    for (int j = 0; j < grid.ny; ++j) {
      for (int i = 0; i < grid.nx; ++i) {
        const double ring = std::hypot(i - 31.5, j - 31.5) - 20.0;
        slice[static_cast<size_t>(j * grid.nx + i)] =
            static_cast<float>(std::hypot(ring, k - 15.5) - 8.0);
      }
    }
    EXPECT_TRUE((*session)->AddSlice(slice.data()).ok());
  }
  EXPECT_TRUE((*session)->Finish().ok());
  return (*session)->Snapshot();
}

TEST(Contract, ACallersExecutorGivesTheMeshOfTheBuiltInPool) {
  const IndexedMesh pooled = Torus(&Executor::Shared());
  ASSERT_GT(pooled.num_triangles(), 200u);
  InlineExecutor serial;
  const IndexedMesh mesh = Torus(&serial);
  EXPECT_EQ(mesh.positions, pooled.positions);
  EXPECT_EQ(mesh.indices, pooled.indices);
  EXPECT_GE(serial.tasks, 2 * 32) << "the session did not run its slab steps on the executor";
  const std::unique_ptr<Executor> none = NewThreadPool(0);  // the caller's thread does it all
  const IndexedMesh sequential = Torus(none.get());
  EXPECT_EQ(sequential.positions, pooled.positions);
  EXPECT_EQ(sequential.indices, pooled.indices);
}

}  // namespace
}  // namespace tandem
