// RiseLists: what a rise of E0 offers again (listed edges within reach, link refusals whose
// stars changed), what it keeps, the next cost, stale sweeps and a merge's adoption.
#include "rise_lists.h"

#include <gtest/gtest.h>

#include <limits>
#include <vector>

#include "edge_queues.h"
#include "mesh_store.h"
#include "pod_array.h"

namespace tandem {
namespace {

struct Fixture {
  MeshStore store;
  PodArray<uint32_t> version;
  std::vector<VertexId> v;
  Fixture() {
    for (int i = 0; i < 6; ++i) v.push_back(store.AddVertex({double(i), 0, 0}, 0, 0, 0));
    version.resize(v.size());
    store.AddTriangle(v[0], v[1], v[2]);
    store.AddTriangle(v[3], v[4], v[5]);
  }
};

TEST(RiseLists, OffersListedEdgesWithinReachAndKeepsTheRest) {
  Fixture f;
  RiseLists r(&f.store, &f.version, /*listing=*/true);
  r.Dropped(f.v[0], f.v[1], 3.0);
  r.List(f.v[1], f.v[2], 1.0);
  r.Dropped(f.v[3], f.v[4], 2.0);
  EXPECT_EQ(r.min_dropped(), 2.0);  // List alone (a refusal) does not count as a drop
  ++f.version[f.v[4]];              // v4 contracted: its edge is stale
  const size_t from_list = r.Offer(/*e=*/1.5, /*reach=*/2.5);
  ASSERT_EQ(from_list, 1u);
  ASSERT_EQ(r.offers().size(), 1u);
  EXPECT_EQ(r.offers()[0].a, f.v[1]);
  EXPECT_EQ(r.offers()[0].cost, 1.0);
  EXPECT_EQ(r.min_dropped(), 3.0);  // the one kept
  EXPECT_EQ(r.listed(), 1u);
  // Offered ones left the list: the next rise does not offer them again.
  EXPECT_EQ(r.Offer(10, 10), 1u);
  EXPECT_EQ(r.offers()[0].cost, 3.0);
  EXPECT_EQ(r.listed(), 0u);
}

TEST(RiseLists, LinkRefusalComesBackOnlyOnceAStarChanged) {
  Fixture f;
  RiseLists r(&f.store, &f.version, /*listing=*/true);
  r.Refused(f.v[0], f.v[1], f.version[f.v[0]], f.version[f.v[1]]);
  EXPECT_EQ(r.Offer(1, 1), 0u);
  EXPECT_TRUE(r.offers().empty());
  EXPECT_EQ(r.listed(), 1u);
  f.store.AddTriangle(f.v[1], f.v[0], f.v[3]);  // v0's and v1's stars change
  EXPECT_EQ(r.Offer(2, 2), 0u);
  ASSERT_EQ(r.offers().size(), 1u);
  EXPECT_EQ(r.offers()[0].cost, 2.0);  // at the rise's E0
  EXPECT_EQ(r.listed(), 0u);
}

TEST(RiseLists, WithoutListingOnlyTheCheapestDropStays) {
  Fixture f;
  RiseLists r(&f.store, &f.version, /*listing=*/false);
  r.Dropped(f.v[0], f.v[1], 4.0);
  r.Dropped(f.v[1], f.v[2], 5.0);
  r.Refused(f.v[0], f.v[1], 0, 0);
  EXPECT_EQ(r.listed(), 0u);
  EXPECT_EQ(r.min_dropped(), 4.0);
  r.ForgetDropped();
  EXPECT_EQ(r.min_dropped(), std::numeric_limits<double>::infinity());
}

TEST(RiseLists, NextCostSkipsStaleNodesAndSeesDrops) {
  Fixture f;
  RiseLists r(&f.store, &f.version, /*listing=*/true);
  EdgeQueue q(1.0);
  q.Push(0.5, QEntry{f.v[0], f.v[1], 0, 0, {}, 0.5});
  q.Push(0.7, QEntry{f.v[1], f.v[2], 0, 0, {}, 0.7});
  ++f.version[f.v[0]];
  EXPECT_EQ(r.NextCost(&q), 0.7);  // the stale 0.5 is skipped
  r.Dropped(f.v[3], f.v[4], 0.6);
  EXPECT_EQ(r.NextCost(&q), 0.6);
  EdgeQueue empty(1.0);
  EXPECT_EQ(r.NextCost(&empty), 0.6);
}

TEST(RiseLists, SweepDropsStaleOnlyBeyondTheLimit) {
  Fixture f;
  RiseLists r(&f.store, &f.version, /*listing=*/true);
  r.List(f.v[0], f.v[1], 1);
  r.List(f.v[3], f.v[4], 1);
  ++f.version[f.v[0]];
  r.SweepBeyond(2);
  EXPECT_EQ(r.listed(), 2u);
  r.SweepBeyond(1);
  EXPECT_EQ(r.listed(), 1u);
}

TEST(RiseLists, AdoptMapsIdsAndListsRefusalsAtTheGivenError) {
  Fixture from, into;
  RiseLists a(&from.store, &from.version, true), b(&into.store, &into.version, true);
  a.Dropped(from.v[0], from.v[1], 2.0);
  a.Refused(from.v[1], from.v[2], 0, 0);
  a.List(from.v[3], from.v[4], 9.0);
  ++from.version[from.v[3]];  // stale: not adopted
  into.version[into.v[5]] = 7;
  PartVertexMap map;  // from's ids reversed
  map.Reset(6);
  for (VertexId v = 0; v < 6; ++v) map[PartVertex{v}] = 5 - v;
  b.Adopt(a, map, /*error=*/0.25);
  EXPECT_EQ(b.min_dropped(), 2.0);
  EXPECT_EQ(b.listed(), 2u);
  b.Offer(100, 100);
  ASSERT_EQ(b.offers().size(), 2u);
  EXPECT_EQ(b.offers()[0].a, 4u);  // mapped, the smaller id first
  EXPECT_EQ(b.offers()[0].b, 5u);
  EXPECT_EQ(b.offers()[0].vb, 7u);  // this store's stamps
  EXPECT_EQ(b.offers()[1].cost, 0.25);
}

}  // namespace
}  // namespace tandem
