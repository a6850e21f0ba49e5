// ChunkedRelease: a release enters whole or a chunk at a time, every live edge exactly once,
// an edge with an end not ready yet waiting for that end's chunk, chunks ordered in tiles.
#include "chunked_release.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <utility>
#include <vector>

#include "edge_queues.h"
#include "mesh_store.h"
#include "pod_array.h"

namespace tandem {
namespace {

using Edge = std::pair<VertexId, VertexId>;

struct Fixture {
  MeshStore store;
  PodArray<uint32_t> version;
  WaitingQueue w;
  // n vertices along x (x = 10 i), edges i -> i + 1 queued in W at key 1.
  explicit Fixture(int n) {
    for (int i = 0; i < n; ++i) store.AddVertex({10.0 * i, 0, 0}, 0, 0, 0);
    version.resize(static_cast<size_t>(n));
    for (VertexId i = 0; i + 1 < static_cast<VertexId>(n); ++i) {
      w.Push(WEntry{1.0, i, i + 1, 0, 0});
    }
  }
};

std::vector<Edge> Chunk(ChunkedRelease& r, size_t g) {
  std::vector<Edge> out;
  r.ForEachIn(g, [&](const WEdge& e) { out.emplace_back(e.a, e.b); });
  return out;
}

TEST(ChunkedRelease, SmallReleaseEntersWholeInWOrderWithoutStaleEdges) {
  Fixture f(6);
  ChunkedRelease r(&f.store, &f.version, /*chunk=*/16, 0, 0);
  ++f.version[0];                    // edge 0-1 is stale
  EXPECT_EQ(r.Take(&f.w, 0.5), 0u);  // nothing released below its key
  EXPECT_EQ(r.Take(&f.w, 1.0), 1u);
  EXPECT_EQ(r.size(), 4u);
  EXPECT_EQ(Chunk(r, 0), (std::vector<Edge>{{1, 2}, {2, 3}, {3, 4}, {4, 5}}));
  EXPECT_FALSE(r.Defer(1, 2));  // whole: every vertex is ready
  r.Done();
  EXPECT_EQ(r.MemoryBytes(), 0u);
  EXPECT_EQ(f.w.size(), 0u);
}

TEST(ChunkedRelease, ChunksBringEveryEdgeOnceAfterBothEndsAreReady) {
  Fixture f(9);  // 8 edges
  ChunkedRelease r(&f.store, &f.version, /*chunk=*/3, 0, 0);
  ASSERT_EQ(r.Take(&f.w, 1.0), 3u);
  EXPECT_EQ(r.chunk(), 3u);
  // Vertex 3 ends edge 2-3 (chunk 0) and starts 3-4 (chunk 1): ready with chunk 1, so edge
  // 2-3 waits for chunk 1.
  const std::vector<Edge> first = Chunk(r, 0);
  EXPECT_EQ(first, (std::vector<Edge>{{0, 1}, {1, 2}}));
  // A contraction's edge during chunk 0 to a vertex of chunk 2 waits there.
  EXPECT_TRUE(r.Defer(1, 7));
  EXPECT_FALSE(r.Defer(0, 1));
  const std::vector<Edge> second = Chunk(r, 1);
  EXPECT_EQ(second, (std::vector<Edge>{{2, 3}, {3, 4}, {4, 5}}));
  const std::vector<Edge> third = Chunk(r, 2);
  EXPECT_EQ(third, (std::vector<Edge>{{1, 7}, {5, 6}, {6, 7}, {7, 8}}));
  EXPECT_EQ(r.deferred(), 3);  // 2-3, 5-6 (vertex 6 is chunk 2's), and 1-7
  r.Done();
  EXPECT_EQ(r.MemoryBytes(), 0u);
}

TEST(ChunkedRelease, DeferredEdgesGoneStaleAreNotBroughtIn) {
  Fixture f(9);
  ChunkedRelease r(&f.store, &f.version, 3, 0, 0);
  ASSERT_EQ(r.Take(&f.w, 1.0), 3u);
  (void)Chunk(r, 0);
  ++f.version[3];  // 2-3 waits for chunk 1 and goes stale
  const std::vector<Edge> second = Chunk(r, 1);
  EXPECT_EQ(second, (std::vector<Edge>{{4, 5}}));  // 3-4 is stale too
  r.Done();
}

TEST(ChunkedRelease, TilesMakeEachChunkACompactPatch) {
  // Edges alternate between two far apart patches in W's order; in tiles each chunk holds
  // one patch.
  MeshStore store;
  PodArray<uint32_t> version;
  WaitingQueue w;
  for (int i = 0; i < 8; ++i) {
    store.AddVertex({i % 2 == 0 ? 1.0 * i : 1000.0 + i, 0, 0}, 0, 0, 0);
  }
  version.resize(8);
  // Even vertices near x = 0, odd ones near x = 1000: edges (0,2) (1,3) (4,6) (5,7) ...
  const std::vector<Edge> edges = {{0, 2}, {1, 3}, {4, 6}, {5, 7}};
  for (const auto& [a, b] : edges) w.Push(WEntry{1.0, a, b, 0, 0});
  // Tiles of 4: 256 of them span x < 1024, and a release this small is sorted by the
  // curve's top bits alone (x below or above 512).
  ChunkedRelease r(&store, &version, /*chunk=*/2, /*tile_x=*/4, /*tile_y=*/4);
  ASSERT_EQ(r.Take(&w, 1.0), 2u);
  std::vector<Edge> first = Chunk(r, 0), second = Chunk(r, 1);
  std::sort(first.begin(), first.end());
  std::sort(second.begin(), second.end());
  EXPECT_EQ(first, (std::vector<Edge>{{0, 2}, {4, 6}}));
  EXPECT_EQ(second, (std::vector<Edge>{{1, 3}, {5, 7}}));
  r.Done();
}

TEST(ChunkedRelease, SweepDropsStaleWaitingEdgesOnceWGrew) {
  Fixture f(9);
  ChunkedRelease r(&f.store, &f.version, 3, 0, 0);
  ASSERT_EQ(r.Take(&f.w, 1.0), 3u);
  (void)Chunk(r, 0);
  // Contractions push edges for later fronts into W, and most go stale.
  for (VertexId i = 0; i < 8; ++i) f.w.Push(WEntry{5.0, i, i + 1, 0, 0});
  r.Sweep(&f.w);
  EXPECT_EQ(f.w.size(), 8u);                                               // live: kept
  for (VertexId i = 0; i < 2; ++i) f.w.Push(WEntry{5.0, i, i + 1, 1, 0});  // stale
  r.Sweep(&f.w);
  EXPECT_EQ(f.w.size(), 10u);  // grown by less than half and a chunk: not swept yet
  for (VertexId i = 2; i < 8; ++i) f.w.Push(WEntry{5.0, i, i + 1, 1, 0});
  r.Sweep(&f.w);
  EXPECT_EQ(f.w.size(), 8u);  // swept: the live ones stay
  r.Done();
}

}  // namespace
}  // namespace tandem
