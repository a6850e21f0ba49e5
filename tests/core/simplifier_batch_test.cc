// DELAY's batched evaluation (simplifier_batch.cc): every edge queued once, and the half of a
// large batch that runs on the executor hands its CPU time to the phase that asked.
#include <functional>
#include <thread>
#include <utility>

#include <gtest/gtest.h>

#include "engine_testutil.h"
#include "mesh_store.h"
#include "quadric.h"
#include "simplifier.h"
#include "simplifier_access.h"
#include "tandem/eval/synthetic.h"
#include "tandem/executor.h"

namespace tandem {
namespace {

TEST(Simplifier, DelayQueuesEveryEdgeOfTheLayersOnce) {
  for (bool closed : {true, false}) {
    for (ReleaseRule rule : {ReleaseRule::kReach, ReleaseRule::kLayer}) {
      auto src = closed ? eval::MakeSyntheticSource(eval::Shape::kSphere, 29, 26, 23)
                        : BoxCutGyroid(29, 26, 23);
      MeshStore store;
      SimplifierOptions so;
      so.error = 0.1;
      so.release = rule;
      Simplifier simplifier(&store, so);
      ExtractLayers(src.get(), &store, &simplifier, /*delay_each_layer=*/true);
      const EdgeTriangles edges = CountEdgeTriangles(store);
      uint8_t faces = 0;  // box faces holding a boundary edge
      for (const auto& [e, count] : edges) {
        if (count == 1) faces |= store.box_mask(e.first) & store.box_mask(e.second);
      }
      EXPECT_EQ(faces, closed ? 0 : kBoxXMin | kBoxXMax | kBoxYMin | kBoxYMax | kBoxZMin | kBoxZMax);
      ASSERT_GT(edges.size(), 1000u);
      EXPECT_EQ(SimplifierProbe::queue_sizes(simplifier), edges.size())
          << (closed ? "sphere" : "box-cut gyroid")
          << (rule == ReleaseRule::kReach ? " reach" : " layer");
    }
  }
}

// An executor that runs every task at once on a thread of its own: a pool's thread may start
// too late on a loaded machine, and the waiting caller then runs the half itself.
class OtherThreadAtOnce final : public Executor {
 public:
  void Enqueue(std::function<void()> task) override { std::thread(std::move(task)).join(); }
  int threads() const override { return 1; }
};

// Half of a large DELAY batch's evaluations runs on the executor: the CPU time it takes
// there is handed to the phase that asked (TakeHelperSeconds), which times only its own
// thread (core/src/schedule.cc).
TEST(Simplifier, BatchHalvesOnOtherThreadsReportTheirCpuTime) {
  OtherThreadAtOnce one;
  auto src = BoxCutGyroid(96, 96, 16);  // thousands of edges a layer: batches of 1024 or more
  MeshStore store;
  SimplifierOptions so;
  so.error = 0.1;
  so.parallel = &one;
  Simplifier simplifier(&store, so);
  ExtractLayers(src.get(), &store, &simplifier, /*delay_each_layer=*/true);
  EXPECT_GT(simplifier.TakeHelperSeconds(), 0.0);
  EXPECT_EQ(simplifier.TakeHelperSeconds(), 0.0) << "taken once";
  // Without an executor everything runs on the calling thread: nothing to hand over.
  MeshStore store0;
  so.parallel = nullptr;
  Simplifier alone(&store0, so);
  src = BoxCutGyroid(96, 96, 16);
  ExtractLayers(src.get(), &store0, &alone, /*delay_each_layer=*/true);
  EXPECT_EQ(alone.TakeHelperSeconds(), 0.0);
}

// An edge's evaluation, called from another file as the batch evaluation calls it, is the
// scalar evaluation bit for bit: H_a + H_b, the full solve's placement at the midpoint, ε0
// there. (A compiler that reached a CPU-dispatched Evaluate through its resolver from another
// file got no evaluation at all: every edge read as refused or at cost 0.)
TEST(Simplifier, AnEvaluationFromAnotherFileIsTheScalarOne) {
  auto src = eval::MakeSyntheticSource(eval::Shape::kSphere, 29, 26, 23);
  MeshStore store;
  SimplifierOptions so;
  so.error = 0.1;
  Simplifier simplifier(&store, so);
  ExtractLayers(src.get(), &store, &simplifier, /*delay_each_layer=*/false);
  const EdgeTriangles edges = CountEdgeTriangles(store);
  ASSERT_GT(edges.size(), 1000u);
  int solved = 0;
  for (const auto& [e, count] : edges) {
    const auto [a, b] = e;
    ASSERT_EQ(store.box_mask(a) | store.box_mask(b), 0);  // a closed sphere: nothing fixed
    Quadric h = SimplifierProbe::quadric(simplifier, a);
    h += SimplifierProbe::quadric(simplifier, b);
    const Vec3 ref = (store.position(a) + store.position(b)) * 0.5;
    const Vec3 want = MinimizeQuadricSolve(h, ref, 0);
    Vec3 pos{-1, -1, -1};
    double cost = -1, eps0 = -1;
    ASSERT_TRUE(SimplifierProbe::Evaluate(simplifier, a, b, &pos, &cost, &eps0)) << a << " " << b;
    EXPECT_EQ(pos, want) << a << " " << b;
    EXPECT_EQ(eps0, ShapeError(h, want)) << a << " " << b;
    EXPECT_EQ(cost, eps0) << a << " " << b;  // α = 0
    solved += eps0 > 0;
  }
  EXPECT_GT(solved, 1000);  // curved: the edges cost something
}

}  // namespace
}  // namespace tandem
