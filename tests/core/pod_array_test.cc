// PodArray: std::vector's behaviour for the session's big arrays (contents, capacity, order),
// with blocks of 256 KiB or more mapped: grown without copying (the old pages are not faulted
// in again) and handed back to the kernel when freed.
#include <sys/resource.h>

#include <array>
#include <cstdint>
#include <fstream>
#include <numeric>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "grow.h"
#include "pod_array.h"
#include "pod_array_config.h"

namespace tandem {
namespace {

struct alignas(64) Record {
  double x = 1.5;
  uint32_t id = 7;
};

// Resident anonymous memory of this process, in KiB (0 where /proc is missing).
int64_t RssAnonKiB() {
  std::ifstream status("/proc/self/status");
  std::string key;
  int64_t value = 0;
  while (status >> key) {
    if (key == "RssAnon:") {
      status >> value;
      return value;
    }
    status.ignore(1 << 10, '\n');
  }
  return 0;
}

int64_t MinorFaults() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_minflt;
}

// The same pushes, resizes and erasures on a PodArray and a std::vector, through the
// heap/mapping threshold and back: equal contents, and equal capacities (MemoryBytes and
// the server's budget count capacity).
TEST(PodArray, BehavesAsAVectorAcrossTheMappingThreshold) {
  PodArray<uint32_t> a;
  std::vector<uint32_t> v;
  const size_t n = 3 * kPodMapBytes / sizeof(uint32_t);  // 3 MiB of elements
  for (uint32_t i = 0; i < n; ++i) {
    a.push_back(i * 7u);
    v.push_back(i * 7u);
    ASSERT_EQ(a.capacity(), v.capacity()) << i;
  }
  ASSERT_EQ(a.size(), v.size());
  EXPECT_TRUE(std::equal(a.begin(), a.end(), v.begin()));
  GrowTo(a, n + 1000, 5u);
  GrowTo(v, n + 1000, 5u);
  EXPECT_EQ(a.capacity(), v.capacity());
  EXPECT_TRUE(std::equal(a.begin(), a.end(), v.begin(), v.end()));
  // Keep one in sixteen: from a mapping back to the heap once shrunk.
  EXPECT_EQ(erase_if(a, [](uint32_t x) { return x % 16 != 0; }),
            std::erase_if(v, [](uint32_t x) { return x % 16 != 0; }));
  a.shrink_to_fit();
  v.shrink_to_fit();
  EXPECT_EQ(a.capacity(), v.capacity());
  EXPECT_TRUE(std::equal(a.begin(), a.end(), v.begin(), v.end()));
  // Copies, moves, appends and front erasures.
  PodArray<uint32_t> b = a;
  PodArray<uint32_t> c = std::move(a);
  EXPECT_TRUE(a.empty());
  EXPECT_TRUE(std::equal(b.begin(), b.end(), c.begin(), c.end()));
  c.append(b.begin(), b.begin() + 10);
  c.erase_front(5);
  std::vector<uint32_t> expect(v.begin() + 5, v.end());
  expect.insert(expect.end(), v.begin(), v.begin() + 10);
  EXPECT_TRUE(std::equal(c.begin(), c.end(), expect.begin(), expect.end()));
  c.clear();
  EXPECT_TRUE(c.empty());
  EXPECT_GT(c.capacity(), 0u);
}

// Over-aligned records keep their alignment on the heap and in a mapping, and new elements
// are value-initialised.
TEST(PodArray, KeepsAlignmentAndInitialisesNewElements) {
  PodArray<Record> r;
  for (size_t n : {size_t{1}, size_t{100}, 2 * kPodMapBytes / sizeof(Record), size_t{3}}) {
    r.resize(n);
    EXPECT_EQ(reinterpret_cast<uintptr_t>(r.data()) % alignof(Record), 0u) << n;
    EXPECT_EQ(r[n - 1].x, 1.5);
    EXPECT_EQ(r[n - 1].id, 7u);
    r.resize(0);
    r.shrink_to_fit();
  }
}

// grow.h: an array pushed from empty doubles while small, so that Q's and W's buckets,
// which regrow from empty every step, are not copied at every few pushes; big arrays still
// grow by an eighth (the session's budget counts capacity).
// ReserveFor: small arrays double (from 8 elements), a std::vector past 16 KiB grows by 16 KiB
// until an eighth is more, since its capacity is memory; a PodArray that maps its large blocks
// doubles all the way, and what the budget counts of it (MemoryBytes) stays the pages written.
TEST(Grow, SmallArraysDoubleBigOnesGrowByAnEighth) {
  std::vector<uint64_t> a;
  int grows = 0;
  size_t cap = 0;
  for (uint64_t i = 0; i < 2048; ++i) {  // to 16 KiB
    PushBack(a, i);
    if (a.capacity() != cap) ++grows, cap = a.capacity();
  }
  EXPECT_LE(grows, 9);  // 8, 16, ..., 2048 (by eighths from empty: 57)
  EXPECT_EQ(a[2047], 2047u);
  std::vector<uint64_t> big;
  big.reserve(size_t{1} << 20);  // 8 MiB
  big.resize(big.capacity());
  PushBack(big, uint64_t{1});
  EXPECT_EQ(big.capacity(), (size_t{1} << 20) * 9 / 8);
  std::vector<uint64_t> mid;  // past 16 KiB, by 16 KiB until an eighth is more
  mid.reserve(4096);
  mid.resize(4096);
  PushBack(mid, uint64_t{1});
  EXPECT_EQ(mid.capacity(), 4096u + 2048u);
}

#if TANDEM_POD_MAP
TEST(Grow, APodArrayDoublesAndCountsThePagesWritten) {
  PodArray<uint64_t> a;
  int grows = 0;
  size_t cap = 0;
  for (uint64_t i = 0; i < (uint64_t{1} << 20); ++i) {  // to 8 MiB
    PushBack(a, i);
    if (a.capacity() != cap) ++grows, cap = a.capacity();
  }
  EXPECT_EQ(grows, 18);  // 8, 16, ..., 2^20 (by eighths past 16 KiB: 47)
  EXPECT_EQ(a[(size_t{1} << 20) - 1], (uint64_t{1} << 20) - 1);
  PushBack(a, uint64_t{1});
  EXPECT_EQ(a.capacity(), size_t{1} << 21);
  // Twice the room, but only the pages written are memory.
  EXPECT_LE(a.MemoryBytes(), ((size_t{1} << 20) + 1) * sizeof(uint64_t) + kPodPage);
}
#endif

#if TANDEM_POD_MAP
// A mapped array grows without copying: reserving twice the room faults in none of the
// pages already written (a std::vector copies them into a new block and touches each), and
// freeing it hands its pages back (on glibc's heap, blocks of a few MiB stay resident once
// the mmap threshold has risen).
TEST(PodArray, AMappedArrayGrowsInPlaceAndIsHandedBack) {
  constexpr size_t kBytes = size_t{64} << 20;
  constexpr size_t kPages = kBytes / 4096;
  const int64_t rss_before = RssAnonKiB();
  {
    PodArray<uint64_t> a;
    a.resize(kBytes / sizeof(uint64_t), 1);  // written: every page faulted in once
    EXPECT_GT(RssAnonKiB() - rss_before, 60 << 10);
    const int64_t faults = MinorFaults();
    a.reserve(2 * a.size());
    EXPECT_LT(MinorFaults() - faults, static_cast<int64_t>(kPages / 16));
    EXPECT_EQ(a[a.size() - 1], 1u);
    EXPECT_EQ(std::accumulate(a.begin(), a.end(), uint64_t{0}), a.size());
  }
  EXPECT_LT(RssAnonKiB() - rss_before, 4 << 10);
}

// What a mapped array counts (MemoryBytes, the session budget's figure) is what it takes in
// memory: the pages up to the most it ever held, not the capacity it reserved. 64 MiB
// reserved and 8 written take about 8 (RssAnon) and count 8; cleared, the pages stay and so
// does the count; a heap block moved to pages of its own was copied whole and counts so.
TEST(PodArray, AMappedArrayCountsThePagesItWrote) {
  constexpr size_t kMiB = size_t{1} << 20;
  const int64_t rss_before = RssAnonKiB();
  PodArray<uint64_t> a;
  a.reserve(64 * kMiB / sizeof(uint64_t));
  EXPECT_EQ(a.MemoryBytes(), 0u);
  a.resize(8 * kMiB / sizeof(uint64_t), 1);
  EXPECT_EQ(a.MemoryBytes(), 8 * kMiB);
  const int64_t rss = RssAnonKiB() - rss_before;
  EXPECT_GT(rss, 7 << 10);
  EXPECT_LT(rss, 12 << 10);  // not the 64 MiB of its capacity
  a.clear();
  a.push_back(2);
  EXPECT_EQ(a.MemoryBytes(), 8 * kMiB);
  a.resize(1000);  // 8,000 bytes, within the pages held
  a.shrink_to_fit();  // a heap block again: its capacity
  EXPECT_EQ(a.MemoryBytes(), 8000u);
  a.reserve(kMiB);  // mapped again, the 8,000 bytes copied: two pages
  EXPECT_EQ(a.MemoryBytes(), 8192u);
  a.resize(a.size() + 1);  // one more element, still within them
  EXPECT_EQ(a.MemoryBytes(), 8192u);
  PodArray<uint64_t> small;  // a heap block counts its capacity, written or not
  small.reserve(100);
  EXPECT_EQ(small.MemoryBytes(), 800u);
}
#endif

}  // namespace
}  // namespace tandem
