// DELAY's batched evaluation (simplifier_batch.cc): every edge queued once, and the half of a
// large batch that runs on the executor hands its CPU time to the phase that asked.
#include <gtest/gtest.h>

#include "engine_testutil.h"
#include "mesh_store.h"
#include "simplifier.h"
#include "simplifier_access.h"
#include "tandem/eval/synthetic.h"
#include "thread_pool.h"

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

// Half of a large DELAY batch's evaluations runs on the executor: the CPU time it takes
// there is handed to the phase that asked (TakeHelperSeconds), which times only its own
// thread (core/src/schedule.cc).
TEST(Simplifier, BatchHalvesOnOtherThreadsReportTheirCpuTime) {
  ThreadPool one(1);
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

}  // namespace
}  // namespace tandem
