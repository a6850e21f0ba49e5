// The simplifier's queues alone: Q's order (key, then newest first among equal keys) across its
// buckets, and W's release by front (bucket by bucket, each in push order, far keys last).
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "edge_queues.h"

namespace tandem {
namespace {

// What the simplifier does with W at each ACTIVATE: TakeUpTo, then take(WEdge) for each entry
// in that order, then done(); take and done may Push.
template <typename Take, typename Done>
void ReleaseUpTo(WaitingQueue& w, double front, Take&& take, Done&& done) {
  PodArray<WEdge> released;
  w.TakeUpTo(front, &released);
  for (const WEdge& e : released) take(e);
  done();
}

QEntry EntryFor(uint32_t id) { return QEntry{id, id + 1, 0, 0, Vec3{double(id), 0, 0}, 0.0}; }

// Q pops in (key ascending, push order descending) order, whatever the keys' buckets: keys
// spread over the range, beyond it (the last bucket), many equal keys, pushes between pops.
TEST(EdgeQueue, PopsBySmallestKeyThenNewestFirst) {
  const double max_key = 2.0;
  EdgeQueue q(max_key);
  struct Pushed {
    double key;
    uint32_t seq;
  };
  std::vector<Pushed> reference;  // what is in Q
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 3.0);  // a third beyond max_key
  std::uniform_real_distribution<double> binade(-24.0, 1.0);  // 2^-24 .. 2 x max_key
  uint32_t seq = 0;
  auto push = [&](double key) {
    q.Push(key, EntryFor(seq));
    reference.push_back({key, seq++});
  };
  auto pop = [&] {
    ASSERT_FALSE(q.empty());
    auto best = std::min_element(reference.begin(), reference.end(), [](auto& x, auto& y) {
      return std::tie(x.key, y.seq) < std::tie(y.key, x.seq);
    });
    EXPECT_EQ(q.Top().key, best->key);
    const QNode e = q.Pop();
    EXPECT_EQ(e.a, best->seq);
    EXPECT_EQ(e.b, best->seq + 1);
    EXPECT_EQ(q.Placement(e).pos.x, double(best->seq));  // the placement travels with its node
    reference.erase(best);
  };
  for (int round = 0; round < 200; ++round) {
    for (int i = 0; i < 20; ++i) {
      // Every third key evenly over the range, every third on a log scale (down to below
      // the lowest bucket), the rest equal ones.
      const double key = (i % 3 == 0)   ? 0.25
                         : (i % 5 == 0) ? 0.0
                         : (i % 3 == 1) ? u(rng)
                                        : max_key * std::exp2(binade(rng));
      push(round % 7 == 0 ? std::round(key) : key);
    }
    for (int i = 0; i < 15; ++i) pop();
    EXPECT_EQ(q.size(), reference.size());
  }
  while (!reference.empty()) pop();
  EXPECT_TRUE(q.empty());
}

// Buckets are log-spaced below E0: keys a few percent apart, even a thousandth of E0 and
// below, go to different buckets (evenly spaced ones put every key under E0 / 1023 into the
// first, whose heap then held a nearly flat patch's every edge), in key order.
TEST(EdgeQueue, BucketsSpreadSmallKeys) {
  const double e0 = 0.2;
  EdgeQueue q(e0);
  EXPECT_EQ(q.Bucket(0.0), 0u);
  EXPECT_EQ(q.Bucket(e0), EdgeQueue::kBuckets - 2);
  EXPECT_EQ(q.Bucket(std::nextafter(e0, 1.0)), EdgeQueue::kBuckets - 1);
  EXPECT_EQ(q.Bucket(1e300), EdgeQueue::kBuckets - 1);
  EXPECT_EQ(q.Bucket(std::numeric_limits<double>::quiet_NaN()), EdgeQueue::kBuckets - 1);
  EXPECT_EQ(q.Bucket(std::numeric_limits<double>::denorm_min()), 0u);
  size_t previous = 0;
  for (double key = e0 * std::exp2(-15.0); key <= e0; key *= 1.03) {
    const size_t b = q.Bucket(key);
    EXPECT_GT(b, previous) << key;  // 3 % apart: another bucket
    previous = b;
  }
}

// TopLive drops the stale nodes appended to a bucket before sifting it in (their slots go
// back for reuse: every live node keeps its own placement), and the live ones pop in the
// order Top/Pop gives them with the stale ones skipped; with only stale nodes left above the
// lowest bucket it returns null and Q is empty.
TEST(EdgeQueue, TopLiveDropsStaleNodesAndKeepsTheOrder) {
  EdgeQueue q(1.0), all(1.0);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.2);
  std::vector<bool> stale_id;
  auto stale = [&](const QNode& n) { return stale_id[n.a]; };
  uint32_t id = 0;
  size_t dropped_early = 0;
  for (int round = 0; round < 50; ++round) {
    for (int i = 0; i < 400; ++i, ++id) {
      const double key = i % 4 == 0 ? 0.5 : u(rng);
      q.Push(key, EntryFor(id));
      all.Push(key, EntryFor(id));
      stale_id.push_back(false);
    }
    // Most go stale while they wait (a neighbour's contraction re-pushed them).
    for (uint32_t k = 0; k < id; ++k) stale_id[k] = stale_id[k] || rng() % 3 != 0;
    for (int i = 0; i < 100; ++i) {
      while (!all.empty() && stale(all.Top())) all.Pop();  // the loop before TopLive
      const size_t before = q.size();
      const QNode* top = q.TopLive(stale);
      if (all.empty()) {
        ASSERT_EQ(top, nullptr);
        break;
      }
      ASSERT_NE(top, nullptr);
      dropped_early += before - q.size();
      if (stale(*top)) {  // on the heap already when it went stale: popped and skipped
        q.Pop();
        --i;
        continue;
      }
      const QNode x = q.Pop(), y = all.Pop();
      ASSERT_EQ(x.a, y.a);
      ASSERT_EQ(x.key, y.key);
      ASSERT_EQ(q.Placement(x).pos.x, double(x.a));
    }
  }
  EXPECT_GT(dropped_early, size_t{id} / 4);  // most stale ones never reached a heap
  // Nodes appended to buckets above the lowest, all stale: none is left.
  EdgeQueue waiting(1.0);
  waiting.Push(0.1, EntryFor(0));  // the lowest bucket's heap
  for (uint32_t k = 1; k < 1000; ++k) waiting.Push(0.2 + k * 1e-4, EntryFor(k));
  waiting.Pop();
  for (uint32_t k = 0; k < 1000; ++k) stale_id[k] = true;
  EXPECT_EQ(waiting.TopLive(stale), nullptr);
  EXPECT_TRUE(waiting.empty());
}

TEST(EdgeQueue, ClearEmptiesAndKeepsWorking) {
  EdgeQueue q(1.0);
  q.Clear();  // before any push: nothing allocated
  for (uint32_t i = 0; i < 100; ++i) q.Push(1.0 - i * 0.01, EntryFor(i));
  q.Clear();
  EXPECT_TRUE(q.empty());
  q.Push(0.5, EntryFor(1));
  q.Push(0.5, EntryFor(2));
  q.Push(0.1, EntryFor(3));
  EXPECT_EQ(q.Pop().a, 3u);
  EXPECT_EQ(q.Pop().a, 2u);  // equal keys: newest first
  EXPECT_EQ(q.Pop().a, 1u);
  EXPECT_TRUE(q.empty());
}

// Trim on an empty Q gives back what its buckets and slots grew to, and Q then pops in the
// same order as a Q that was never trimmed.
TEST(EdgeQueue, TrimFreesThePeakAndKeepsTheOrder) {
  EdgeQueue trimmed(1.0), kept(1.0);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int round = 0; round < 3; ++round) {
    for (uint32_t i = 0; i < 200000; ++i) {
      const double key = (i % 4 == 0) ? 0.5 : u(rng);
      trimmed.Push(key, EntryFor(i));
      kept.Push(key, EntryFor(i));
    }
    const size_t peak = trimmed.MemoryBytes();
    while (!kept.empty()) {
      const QNode x = trimmed.Pop(), y = kept.Pop();
      ASSERT_EQ(x.a, y.a);
      ASSERT_EQ(x.key, y.key);
    }
    ASSERT_TRUE(trimmed.empty());
    trimmed.Trim();
    EXPECT_LT(trimmed.MemoryBytes(), peak / 8);
    // Untrimmed, most of the peak stays: the slots, and every bucket under 128 KiB (a bigger
    // one is freed once popped empty).
    EXPECT_GE(kept.MemoryBytes(), peak / 2);
  }
}

// Rebuilt keeps what its filter accepts, respaced below a new E0, and pops it in the order Q
// itself would have popped it, equal keys included (in push order, whatever the heaps'
// layout); each bucket and the slots are sized exactly (pushed into an empty Q one by one
// they regrew by eighths: a third of a target run's rises), with room for the pushes the
// caller announces.
TEST(EdgeQueue, RebuiltKeepsTheAcceptedInOrderAndSizesItsArraysExactly) {
  EdgeQueue q(0.5), same(0.5);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 2.0);
  for (uint32_t i = 0; i < 20000; ++i) {
    const double key = i % 5 == 0 ? 0.25 : u(rng);  // a fifth tie, in one bucket
    q.Push(key, EntryFor(i));
    same.Push(key, EntryFor(i));
  }
  for (int i = 0; i < 3000; ++i) q.Pop(), same.Pop();  // a recycled slot or two
  auto keep = [](const QNode& n) { return n.a % 3 != 0; };
  auto nothing_more = [](auto&&) {};
  EdgeQueue rebuilt = q.Rebuilt(1.0, keep, nothing_more);
  std::vector<uint32_t> order;  // what Q would have popped of the kept ones
  while (!same.empty()) {
    const QNode n = same.Pop();
    if (keep(n)) order.push_back(n.a);
  }
  EdgeQueue pushed(1.0);  // the same nodes pushed one by one, in push order
  q.ForEachInPushOrder([&](const QNode& n, const QPlacement& p) {
    if (keep(n)) pushed.Push(n.key, QEntry{n.a, n.b, n.va, n.vb, p.pos, p.eps0});
  });
  {
    EdgeQueue copy = q.Rebuilt(1.0, keep, nothing_more);
    for (size_t i = 0; i < order.size(); ++i) ASSERT_EQ(copy.Pop().a, order[i]) << i;
    EXPECT_TRUE(copy.empty());
  }
  ASSERT_EQ(rebuilt.size(), pushed.size());
  const size_t pushed_size = pushed.size();
  ASSERT_GT(rebuilt.size(), 10000u);
  const size_t fixed = EdgeQueue::kBuckets * (sizeof(PodArray<QNode>) + sizeof(size_t));
  EXPECT_EQ(rebuilt.CapacityBytes(),
            fixed + rebuilt.size() * (sizeof(QNode) + sizeof(QPlacement)));
  EXPECT_LE(rebuilt.MemoryBytes(), rebuilt.CapacityBytes());
  EXPECT_GT(pushed.CapacityBytes(), rebuilt.CapacityBytes());
  while (!pushed.empty()) {
    const QNode x = rebuilt.Pop(), y = pushed.Pop();
    ASSERT_EQ(x.a, y.a);
    ASSERT_EQ(x.key, y.key);
    ASSERT_EQ(rebuilt.Placement(x).pos.x, pushed.Placement(y).pos.x);
  }
  EXPECT_TRUE(rebuilt.empty());
  EXPECT_TRUE(EdgeQueue(1.0).Rebuilt(2.0, keep, nothing_more).empty());
  // Room for the pushes announced (a rise's offers): made, and they need no more.
  std::vector<double> offers;
  for (int i = 0; i < 5000; ++i) offers.push_back(u(rng));
  EdgeQueue roomy = q.Rebuilt(1.0, keep, [&](auto&& room) {
    for (double key : offers) room(key);
  });
  const size_t before = roomy.CapacityBytes();
  for (uint32_t i = 0; i < offers.size(); ++i) roomy.Push(offers[i], EntryFor(i));
  EXPECT_EQ(roomy.CapacityBytes(), before);
  EXPECT_EQ(roomy.size(), pushed_size + offers.size());
}

// W hands out entries with key <= front, bucket by bucket (a bucket per integer front, ceil of
// the key), each bucket in push order; keys beyond the window, infinite and NaN ones wait in
// the far list and are released after the buckets (a NaN key by the next release).
TEST(WaitingQueue, ReleasesUpToTheFrontInBucketThenPushOrder) {
  WaitingQueue w;
  const double inf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto entry = [](double key, uint32_t id) { return WEntry{key, id, id, 0, 0}; };
  w.Push(entry(3.5, 0));
  w.Push(entry(2.0, 1));
  w.Push(entry(1.2, 2));
  w.Push(entry(4.0, 3));
  w.Push(entry(3.1, 4));  // same bucket (4) as 3.5 and 4.0, pushed after both
  w.Push(entry(1e20, 5));  // far
  w.Push(entry(inf, 6));
  w.Push(entry(nan, 7));
  w.Push(entry(1.9, 8));
  EXPECT_EQ(w.size(), 9u);
  auto release = [&](double front) {
    std::vector<uint32_t> out;
    int done = 0;
    ReleaseUpTo(w, front, [&](const WEdge& e) { out.push_back(e.a); }, [&] { ++done; });
    EXPECT_EQ(done, 1);
    return out;
  };
  EXPECT_EQ(release(1.5), std::vector<uint32_t>{7});
  EXPECT_EQ(release(2.0), (std::vector<uint32_t>{1, 2, 8}));  // bucket 2, push order
  EXPECT_EQ(release(3.0), std::vector<uint32_t>{});
  EXPECT_EQ(release(4.0), (std::vector<uint32_t>{0, 3, 4}));
  EXPECT_EQ(w.size(), 2u);
  EXPECT_EQ(release(1e30), std::vector<uint32_t>{5});
  EXPECT_EQ(release(inf), std::vector<uint32_t>{6});
  EXPECT_EQ(w.size(), 0u);
}

// A bucketed edge takes 16 bytes: its key only chose the bucket (a far one keeps it).
TEST(WaitingQueue, ABucketedEdgeTakesSixteenBytes) {
  WaitingQueue w;
  constexpr uint32_t n = uint32_t{1} << 17;
  for (uint32_t i = 0; i < n; ++i) w.Push(WEntry{2.5, i, i + 1, 0, 0});
  EXPECT_LE(w.MemoryBytes(), size_t{n} * 16 * 9 / 8 + 4096);  // grow.h: by an eighth
  EXPECT_LT(w.MemoryBytes(), size_t{n} * 24);  // what 24-byte entries took at the least
  std::vector<uint32_t> out;
  ReleaseUpTo(w, 3.0, [&](const WEdge& e) { out.push_back(e.b - e.a); }, [] {});
  EXPECT_EQ(out, std::vector<uint32_t>(n, 1u));
}

// RemoveIf drops entries (the simplifier's stale ones) from every bucket and the far list,
// keeps the others in order, and gives back the memory of a bucket left under half full.
TEST(WaitingQueue, RemoveIfKeepsTheRestInOrder) {
  WaitingQueue w;
  constexpr uint32_t n = uint32_t{1} << 14;
  for (uint32_t i = 0; i < n; ++i) w.Push(WEntry{i % 2 ? 2.5 : 3.5, i, i + 1, 0, 0});
  w.Push(WEntry{1e30, 7, 8, 0, 0});  // far, odd
  w.Push(WEntry{1e30, 8, 9, 0, 0});  // far, even
  const size_t before = w.MemoryBytes();
  w.RemoveIf([](const WEdge& e) { return e.a % 4 != 0; });  // keeps a quarter: a % 4 == 0
  EXPECT_EQ(w.size(), size_t{n} / 4 + 1);
  EXPECT_LT(w.MemoryBytes(), before / 2);
  PodArray<WEdge> out;
  w.TakeUpTo(std::numeric_limits<double>::infinity(), &out);
  ASSERT_EQ(out.size(), size_t{n} / 4 + 1);
  for (size_t i = 0; i + 1 < out.size(); ++i) EXPECT_EQ(out[i].a, 4 * i);  // bucket 4, in order
  EXPECT_EQ(out.back().a, 8u);
}

// A far key pushed while the far entries are released (a re-evaluated edge whose reach is
// huge) is kept for a later release, with the far entries not released yet.
TEST(WaitingQueue, AFarKeyPushedDuringTheFarReleaseIsKept) {
  WaitingQueue w;
  auto entry = [](double key, uint32_t id) { return WEntry{key, id, id, 0, 0}; };
  for (uint32_t i = 0; i < 64; ++i) w.Push(entry(i % 2 ? 1e20 : 1e30, i));  // all far
  std::vector<uint32_t> out;
  ReleaseUpTo(w,
      1e25,
      [&](const WEdge& e) {
        out.push_back(e.a);
        w.Push(entry(1e40, 100 + e.a));  // far again, during the scan
      },
      [] {});
  EXPECT_EQ(out.size(), 32u);
  EXPECT_EQ(w.size(), 64u);  // 32 kept + 32 pushed
  std::vector<uint32_t> rest;
  ReleaseUpTo(w, std::numeric_limits<double>::infinity(),
                [&](const WEdge& e) { rest.push_back(e.a); }, [] {});
  EXPECT_EQ(rest.size(), 64u);
  EXPECT_EQ(w.size(), 0u);
}

// An entry pushed while a release runs (a re-evaluated edge whose key is past the front)
// waits for a later front.
TEST(WaitingQueue, PushesDuringAReleaseWait) {
  WaitingQueue w;
  w.Push(WEntry{1.0, 1, 1, 0, 0});
  std::vector<uint32_t> out;
  ReleaseUpTo(w,
      1.0,
      [&](const WEdge& e) {
        out.push_back(e.a);
        w.Push(WEntry{1.5, 2, 2, 0, 0});
      },
      [&] { w.Push(WEntry{2.0, 3, 3, 0, 0}); });
  EXPECT_EQ(out, std::vector<uint32_t>{1});
  EXPECT_EQ(w.size(), 2u);
  out.clear();
  ReleaseUpTo(w, 2.0, [&](const WEdge& e) { out.push_back(e.a); }, [] {});
  EXPECT_EQ(out, (std::vector<uint32_t>{2, 3}));
}

// A release's tiles (ZOrderTile): 256 along each axis, numbered along a Z-order curve, so that
// every aligned run of 4^k numbers is a square of 2^k x 2^k tiles; points beyond the range, and
// NaN, fall into the first or last tile of their axis.
TEST(ReleaseOrder, TilesAreNumberedAlongAZOrderCurve) {
  EXPECT_EQ(ZOrderTile(0.5, 0.5, 1, 1), 0);
  EXPECT_EQ(ZOrderTile(1.5, 0.5, 1, 1), 1);
  EXPECT_EQ(ZOrderTile(0.5, 1.5, 1, 1), 2);
  EXPECT_EQ(ZOrderTile(1.5, 1.5, 1, 1), 3);
  EXPECT_EQ(ZOrderTile(2.5, 0.5, 1, 1), 4);
  EXPECT_EQ(ZOrderTile(10.0, 20.0, 4, 8), ZOrderTile(2.0, 2.0, 1, 1));
  EXPECT_EQ(ZOrderTile(1e300, 1e300, 1, 1), 0xffff);
  EXPECT_EQ(ZOrderTile(-5.0, std::numeric_limits<double>::quiet_NaN(), 1, 1), 0);
  EXPECT_EQ(ZOrderTile(300.0, -1.0, 1, 1), ZOrderTile(255.0, 0.0, 1, 1));
  for (int k = 1; k <= 4; ++k) {
    const int side = 1 << k;
    for (int start = 0; start < 65536; start += side * side * 37) {
      const int run = start / (side * side) * (side * side);  // aligned
      int x0 = 1 << 20, x1 = -1, y0 = 1 << 20, y1 = -1;
      for (int x = 0; x < 256; ++x) {
        for (int y = 0; y < 256; ++y) {
          const int key = ZOrderTile(x + 0.5, y + 0.5, 1, 1);
          if (key < run || key >= run + side * side) continue;
          x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
        }
      }
      EXPECT_EQ(x1 - x0 + 1, side);
      EXPECT_EQ(y1 - y0 + 1, side);
    }
  }
}

// SortByKey orders in place by key, moving each item with its key: nothing lost, nothing
// doubled, and the same order on every run; keys of 16 bits, and of fewer.
TEST(ReleaseOrder, SortByKeyKeepsEveryItemWithItsKey) {
  std::mt19937 rng(3);
  for (size_t n : {size_t{0}, size_t{1}, size_t{7}, size_t{5000}, size_t{100000}}) {
    std::vector<uint16_t> keys(n);
    std::vector<WEdge> items(n);
    // Few distinct keys for the small cases, all of them for the large.
    std::uniform_int_distribution<int> key(0, n < 1000 ? 9 : 65535);
    for (size_t i = 0; i < n; ++i) {
      keys[i] = static_cast<uint16_t>(key(rng));
      items[i] = WEdge{static_cast<VertexId>(i), keys[i], 0, 0};  // b: the item's key
    }
    std::vector<uint16_t> sorted_keys = keys;
    std::vector<WEdge> sorted = items;
    SortByKey(sorted.data(), sorted_keys.data(), n, n < 1000 ? 4 : 16);
    EXPECT_TRUE(std::is_sorted(sorted_keys.begin(), sorted_keys.end()));
    std::vector<bool> seen(n, false);
    for (size_t i = 0; i < n; ++i) {
      EXPECT_EQ(sorted[i].b, sorted_keys[i]);  // moved with its key
      ASSERT_LT(sorted[i].a, n);
      EXPECT_FALSE(seen[sorted[i].a]);
      seen[sorted[i].a] = true;
    }
    std::vector<uint16_t> again_keys = keys;
    std::vector<WEdge> again = items;
    SortByKey(again.data(), again_keys.data(), n, n < 1000 ? 4 : 16);
    for (size_t i = 0; i < n; ++i) EXPECT_EQ(again[i].a, sorted[i].a);
  }
}

}  // namespace
}  // namespace tandem
