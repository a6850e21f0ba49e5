// The simplifier's two queues of candidate edges (paper §3: the heap Q of PQ-SIMPLIFY and the
// waiting queue W of the tandem algorithm with time-lag).
//
// EdgeQueue (Q): candidate edges ordered by cost ε_α, smallest first, as key buckets with a
// 4-ary heap on the lowest one. Equal keys pop in reverse push order (newest first), so the
// output depends on the order of pushes: the simplifier keeps that order deterministic.
// WaitingQueue (W): edges ordered by a release key, as one bucket per integer front, since the
// front only advances by whole slices; TakeUpTo(front) hands over every entry whose key is
// <= front, bucket by bucket, each bucket in push order.
//
// Entries carry the version stamps of their two vertices: the simplifier recognises stale ones
// by comparing integers (Simplifier::Stale), the queues never look at the mesh.
#ifndef TANDEM_EDGE_QUEUES_H_
#define TANDEM_EDGE_QUEUES_H_

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <vector>

#include "grow.h"
#include "pod_array.h"
#include "tandem/types.h"

namespace tandem {

// 4-ary min-heap on a vector of nodes (children of i: 4i + 1 .. 4i + 4); before(x, y): x pops
// first.
template <typename Node, typename Before>
void HeapSiftUp(PodArray<Node>& h, size_t i, Before before) {
  const Node node = h[i];
  while (i > 0) {
    const size_t parent = (i - 1) / 4;
    if (!before(node, h[parent])) break;
    h[i] = h[parent];
    i = parent;
  }
  h[i] = node;
}

// Removes h[0]. Floyd's pop: the hole goes from the root down to a leaf along the smallest
// children, then the last node sifts up from there (it rarely rises far). The choice among
// four children is branch-free: the comparisons are unpredictable, and mispredictions, not
// cache misses, made a binary heap's pop a tenth of the run time.
template <typename Node, typename Before>
void HeapPopFront(PodArray<Node>& h, Before before) {
  const Node last = h.back();
  h.pop_back();
  const size_t n = h.size();
  if (n == 0) return;
  size_t hole = 0;
  for (;;) {
    const size_t first = 4 * hole + 1;
    size_t best;
    if (first + 3 < n) {
      const size_t m01 = first + before(h[first + 1], h[first]);
      const size_t m23 = first + 2 + before(h[first + 3], h[first + 2]);
      best = before(h[m23], h[m01]) ? m23 : m01;
    } else if (first < n) {
      best = first;
      for (size_t c = first + 1; c < n; ++c) best = before(h[c], h[best]) ? c : best;
    } else {
      break;
    }
    h[hole] = h[best];
    hole = best;
  }
  h[hole] = last;
  HeapSiftUp(h, hole, before);
}

// A queued edge's evaluation (Q). With α = 0 the cost depends only on the two quadrics, which
// cannot change while the stamps match (vertices in Q are complete), so a popped entry is used
// as it is; with α > 0 it is recomputed.
struct QEntry {
  VertexId a, b;
  uint32_t va, vb;  // version stamps
  Vec3 pos;         // the placement computed with the cost
  double eps0;      // ε0 at pos
};

// Heap node: the key, the edge and its stamps (32 bytes, two per cache line), so that a stale
// entry (most pops: five in six on a dense surface) is recognised without reading the rest of
// its entry, which waits in a slot (a cache miss per read: the entry was written long ago).
// Equal keys pop newest first: that keeps consecutive contractions in the same, cached,
// region. (Zero-cost edges on flat patches, which would all tie, come keyed by their length:
// Simplifier::PushQ.)
struct QNode {
  double key;
  uint32_t slot;  // index into the placements' slots
  uint32_t seq;   // push counter (wraps; only orders ties)
  VertexId a, b;
  uint32_t va, vb;  // version stamps
};
static_assert(sizeof(QNode) == 32);
// x pops before y: smaller key, or equal key and pushed later.
inline bool QNodeBefore(const QNode& x, const QNode& y) {
  return (x.key < y.key) | ((x.key == y.key) & (x.seq > y.seq));  // no branches
}
struct QNodeBeforeFn {  // as a type, so that the heap templates inline it
  bool operator()(const QNode& x, const QNode& y) const { return QNodeBefore(x, y); }
};
// The rest of a queued entry.
struct QPlacement {
  Vec3 pos;
  double eps0;
};
// Q. Nodes by key in kBuckets buckets, log-spaced up to max_key (the last one holds every key
// beyond, which only a target triangle count queues). Only the lowest non-empty
// bucket is kept as a 4-ary heap; pushes into higher buckets are appended and sifted in when
// their bucket becomes the lowest. Pops sift through a bucket of tens of nodes instead of a
// heap of all (most popped entries are stale re-evaluations). Push, Top and Pop are on the
// contraction loop: defined here, inline.
class EdgeQueue {
 public:
  // max_key (E0): keys above it all share the last bucket. Allocates nothing until a push.
  explicit EdgeQueue(double max_key)
      : max_key_(max_key),
        bucket_base_(static_cast<int64_t>(std::bit_cast<uint64_t>(max_key) >> kMantissaShift) -
                     static_cast<int64_t>(kBuckets - 2)) {}

  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  void Push(double key, const QEntry& e);
  const QNode& Top();  // the node of the smallest key (not empty)
  // Top, once the nodes appended to a bucket while it was not the lowest have been sifted
  // in less those stale(node) rejects (their slots freed, as a Pop would); null when no
  // node is left. The live nodes pop in the same order: a stale one is skipped either way,
  // and most are stale by the time their bucket comes up (on a dense surface, five pops in
  // six were), so they need neither a sift-in nor a pop's sift-down.
  template <typename Stale>
  const QNode* TopLive(Stale&& stale);
  // Removes the node of the smallest key; its slot is recycled, so Placement(node) is valid
  // until the next Push.
  QNode Pop();
  const QPlacement& Placement(const QNode& n) const { return slots_[n.slot]; }
  // The node Top() would return unless a smaller key is pushed first, or null: a hint for
  // prefetching, without Top's sifting.
  const QNode* Next() const {
    return (size_ > 0 && heaped_[cur_] > 0) ? &buckets_[cur_][0] : nullptr;
  }
  void Clear();
  // For progress: (*below)[b] = the nodes in the buckets below b, b = 0 .. kBuckets (the
  // last: all of them); the bucket pops come from now.
  void CountBelow(std::vector<int64_t>* below) const {
    below->assign(kBuckets + 1, 0);
    for (size_t b = 0; b < buckets_.size(); ++b) {
      (*below)[b + 1] = (*below)[b] + static_cast<int64_t>(buckets_[b].size());
    }
    for (size_t b = buckets_.size(); b < kBuckets; ++b) (*below)[b + 1] = (*below)[b];
  }
  size_t current_bucket() const { return cur_; }
  // Q over again with its buckets spaced below max_key, holding the nodes keep(node) accepts,
  // pushed in ForEach's order. Each bucket and the slots are sized exactly first: pushed one
  // by one into a fresh queue, they regrew from empty (grow.h's eighths: about 40 copies of
  // a bucket of a hundred), a third of a target run's rises on a CT.
  // more(room) calls room(key) for each push the caller will make next, so that those find
  // their room too (a rise's offered edges).
  template <typename Keep, typename More>
  EdgeQueue Rebuilt(double max_key, Keep&& keep, More&& more) const;
  // Calls f(node, placement) for every queued node, in no particular order.
  template <typename F>
  void ForEach(F&& f) const {
    for (const auto& bucket : buckets_) {
      for (const QNode& n : bucket) f(n, slots_[n.slot]);
    }
  }
  // Calls f(node, placement) for every queued node in the order it was pushed, key bucket by
  // key bucket: pushed in this order into another Q, equal keys pop in the same order as
  // here, whatever the heap's layout (which depends on the nodes TopLive dropped).
  template <typename F>
  void ForEachInPushOrder(F&& f) const {
    VisitInPushOrder([&](const QNode& n, const QPlacement& p, size_t) { f(n, p); });
  }
  // Q empties at the end of every SIMPLIFY(E0) (edges above E0 are never queued), but each of
  // its buckets and its slots kept the capacity of their own peaks, most of a dense
  // session's memory. Trim, on an empty Q holding more than 4 MiB, frees every bucket and
  // slot array larger than 1 KiB; the order of what is pushed next is unchanged.
  void Trim();
  // Bytes in memory (PodArray::MemoryBytes: a mapped array's pages past what it ever held
  // are not), and bytes reserved.
  size_t MemoryBytes() const { return Bytes(false); }
  size_t CapacityBytes() const { return Bytes(true); }

  static constexpr size_t kBuckets = 1024;
  // What a bucket (or slot array) keeps of its capacity, the one rule in two places: popped
  // empty during SIMPLIFY (Enter), a bucket up to kKeepPopped bytes, as it will fill again
  // at once; in Trim, after SIMPLIFY, arrays up to kKeepTrimmed only (at most 1 MiB over all
  // the buckets), since Q refills from nothing at the next step.
  static constexpr size_t kKeepPopped = size_t{128} << 10, kKeepTrimmed = 1024;
  static bool Keeps(size_t bytes, size_t keep) { return bytes <= keep; }
  // The bucket a key goes to (public for the tests).
  size_t Bucket(double key) const {
    // Monotone in the key, so bucket order then heap order is exactly (key, seq) order. On a
    // log scale: 64 buckets per binade over the 16 binades below E0 (keys under E0 / 2^16
    // share bucket 0). Evenly spaced buckets put every key under E0 / 1023 into one: a
    // nearly flat patch (a scan's end cap) made that bucket's heap millions deep, its pops
    // cache misses all the way down (docs/decisions.md 1).
    if (!(key <= max_key_)) return kBuckets - 1;  // NaN too
    if (key <= 0.0) return 0;
    // Positive doubles' bits grow with the value.
    const int64_t b = static_cast<int64_t>(std::bit_cast<uint64_t>(key) >> kMantissaShift) - bucket_base_;
    return b <= 0 ? 0 : static_cast<size_t>(b);
  }

 private:
  void Advance();
  void Enter();
  // ForEachInPushOrder's walk: each bucket's nodes oldest push first (ages count back from
  // seq_, so a wrapped counter orders them too); f also gets the node's place in ForEach's
  // order.
  template <typename F>
  void VisitInPushOrder(F&& f) const {
    std::vector<uint32_t> order;
    size_t first = 0;  // the bucket's first node in ForEach's order
    for (const auto& bucket : buckets_) {
      order.resize(bucket.size());
      for (uint32_t i = 0; i < order.size(); ++i) order[i] = i;
      std::sort(order.begin(), order.end(), [&](uint32_t x, uint32_t y) {
        return seq_ - bucket[x].seq > seq_ - bucket[y].seq;
      });
      for (uint32_t i : order) f(bucket[i], slots_[bucket[i].slot], first + i);
      first += bucket.size();
    }
  }

  size_t Bytes(bool capacity) const;

  double max_key_;
  std::vector<PodArray<QNode>> buckets_;  // allocated by the first push
  std::vector<size_t> heaped_;  // per bucket: leading nodes in heap order
  size_t cur_ = 0;              // the lowest non-empty bucket (buckets below are empty)
  size_t size_ = 0;
  // A key's bucket is its sign, exponent and leading 6 mantissa bits, less this base: E0's
  // lands in bucket kBuckets - 2.
  static constexpr int kMantissaShift = 52 - 6;
  int64_t bucket_base_ = 0;
  PodArray<QPlacement> slots_;
  PodArray<uint32_t> free_;  // free slots
  uint32_t seq_ = 0;
};

template <typename Keep, typename More>
EdgeQueue EdgeQueue::Rebuilt(double max_key, Keep&& keep, More&& more) const {
  EdgeQueue q(max_key);
  std::vector<uint32_t> count(kBuckets, 0);
  std::vector<bool> kept;  // keep's answer per node in ForEach's order, asked once
  kept.reserve(size_);
  size_t total = 0;
  ForEach([&](const QNode& n, const QPlacement&) {
    const bool k = keep(n);
    kept.push_back(k);
    if (k) {
      ++count[q.Bucket(n.key)];
      ++total;
    }
  });
  const size_t kept_total = total;
  more([&](double key) {
    ++count[q.Bucket(key)];
    ++total;
  });
  if (total == 0) return q;
  q.buckets_.resize(kBuckets);
  q.heaped_.assign(kBuckets, 0);
  q.cur_ = kBuckets - 1;
  for (size_t b = 0; b < kBuckets; ++b) q.buckets_[b].reserve(count[b]);
  q.slots_.reserve(total);
  if (kept_total == 0) return q;
  // In push order (ForEachInPushOrder), with keep's answers from above.
  VisitInPushOrder([&](const QNode& n, const QPlacement& p, size_t i) {
    if (kept[i]) q.Push(n.key, QEntry{n.a, n.b, n.va, n.vb, p.pos, p.eps0});
  });
  return q;
}

inline void EdgeQueue::Advance() {
  // Makes cur_ the lowest non-empty bucket (Q is not empty).
  while (buckets_[cur_].empty()) {
    // Popped empty: a big bucket gives its memory back. Log-spaced buckets each fill in turn
    // as SIMPLIFY's keys rise, and kept, their peaks would add up (docs/decisions.md 1).
    if (!Keeps(buckets_[cur_].capacity() * sizeof(QNode), kKeepPopped)) {
      PodArray<QNode>().swap(buckets_[cur_]);
    }
    ++cur_;
    assert(cur_ < kBuckets);
  }
}

inline void EdgeQueue::Enter() {
  // Makes cur_ the lowest non-empty bucket and restores its heap order (nodes appended while
  // it was not current are sifted in).
  Advance();
  PodArray<QNode>& h = buckets_[cur_];
  for (size_t i = heaped_[cur_]; i < h.size(); ++i) HeapSiftUp(h, i, QNodeBeforeFn{});
  heaped_[cur_] = h.size();
}

inline void EdgeQueue::Push(double key, const QEntry& e) {
  uint32_t slot;
  if (!free_.empty()) {
    slot = free_.back();
    free_.pop_back();
    slots_[slot] = QPlacement{e.pos, e.eps0};
  } else {
    slot = static_cast<uint32_t>(slots_.size());
    PushBack(slots_, QPlacement{e.pos, e.eps0});  // grow.h: Q's peak is a step's peak
  }
  if (buckets_.empty()) {
    buckets_.resize(kBuckets);
    heaped_.assign(kBuckets, 0);
    cur_ = kBuckets - 1;
  }
  const size_t b = Bucket(key);
  PushBack(buckets_[b], QNode{key, slot, seq_++, e.a, e.b, e.va, e.vb});
  ++size_;
  if (b < cur_) {
    cur_ = b;  // was empty: a heap of one
    heaped_[b] = 1;
  } else if (b == cur_) {
    HeapSiftUp(buckets_[b], buckets_[b].size() - 1, QNodeBeforeFn{});
    heaped_[b] = buckets_[b].size();
  }
  // Otherwise appended: Enter sifts it in when its bucket becomes the lowest.
}

inline const QNode& EdgeQueue::Top() {
  Enter();
  return buckets_[cur_][0];
}

template <typename Stale>
const QNode* EdgeQueue::TopLive(Stale&& stale) {
  while (size_ > 0) {
    Advance();
    PodArray<QNode>& h = buckets_[cur_];
    size_t kept = heaped_[cur_];
    for (size_t i = kept; i < h.size(); ++i) {
      const QNode n = h[i];
      if (stale(n)) {
        PushBack(free_, n.slot);
        --size_;
      } else {
        h[kept++] = n;
      }
    }
    h.resize(kept);
    if (!h.empty()) {
      Enter();  // sifts the live ones in
      return &h[0];
    }
  }
  return nullptr;
}

inline QNode EdgeQueue::Pop() {
  Enter();
  PodArray<QNode>& h = buckets_[cur_];
  const QNode node = h[0];
  HeapPopFront(h, QNodeBeforeFn{});
  heaped_[cur_] = h.size();
  --size_;
  PushBack(free_, node.slot);
  return node;
}

// An edge waiting in W for the front (key = its release key).
struct WEntry {
  double key;
  VertexId a, b;
  uint32_t va, vb;  // version stamps
};
// What W keeps of an entry in a bucket, and hands out: the key only chose the bucket, so a
// bucketed edge takes 16 bytes, not 24 (W holds a layer and a half of edges while a cap waits
// out the time lag; docs/decisions.md 4). The far list keeps whole entries.
struct WEdge {
  VertexId a, b;
  uint32_t va, vb;  // version stamps
};

// W. Bucket i holds the entries released at front base_ + i, the first integer front >= key.
// Fronts only grow, so buckets below the current one are always empty and are recycled by
// advancing base_. A key outside a window of kBuckets fronts (a vertex whose rad is huge in
// slice units, on a grid far finer across than between its slices, or an infinite key)
// waits in far_ instead, scanned by every release, so no input can make the buckets many.
class WaitingQueue {
 public:
  size_t size() const { return size_; }
  void Push(const WEntry& e);
  // Moves every entry with key <= front into *out (replacing it): bucket by bucket, each in
  // push order, then the far ones in push order. One released bucket is handed over, not
  // copied: a cap's release holds no second copy of its edges.
  // Entries pushed after it (keys > front, far keys included) wait for a later call.
  void TakeUpTo(double front, PodArray<WEdge>* out);
  size_t MemoryBytes() const;
  // Removes the entries for which drop(WEdge) is true (stale ones), keeping the others in
  // order; a bucket left at half its capacity or less is shrunk to its size.
  template <typename Drop>
  void RemoveIf(Drop&& drop) {
    for (auto& bucket : buckets_) {
      size_ -= erase_if(bucket, drop);
      if (2 * bucket.size() <= bucket.capacity()) bucket.shrink_to_fit();
    }
    size_ -= erase_if(far_, [&](const WEntry& e) { return drop(WEdge{e.a, e.b, e.va, e.vb}); });
  }

  static constexpr int64_t kBuckets = int64_t{1} << 16;
  static constexpr double kFarKey = 0x1p52;  // keys at or above this are never bucketed

 private:
  std::vector<PodArray<WEdge>> buckets_;
  int64_t base_ = 0;
  size_t size_ = 0;  // all entries, far ones included
  PodArray<WEntry> far_;
};

// A released edge's tile for ACTIVATE's chunks (chunked_release.h): the point
// (x, y) in tiles of side tile_x by tile_y from the origin, 256 of them along each axis (those
// beyond, and NaN, fall into the first or last), numbered along a Z-order curve (x's 8 bits
// in the even bits, y's in the odd ones), so that a run of consecutive numbers is a compact
// patch of the plane.
inline uint16_t ZOrderTile(double x, double y, double tile_x, double tile_y) {
  auto tile = [](double v, double side) -> uint32_t {
    const double t = v / side;
    return t >= 0.0 ? static_cast<uint32_t>(std::min(t, 255.0)) : 0;
  };
  auto spread = [](uint32_t v) {
    v = (v | (v << 4)) & 0x0f0fu;
    v = (v | (v << 2)) & 0x3333u;
    return (v | (v << 1)) & 0x5555u;
  };
  return static_cast<uint16_t>(spread(tile(x, tile_x)) | (spread(tile(y, tile_y)) << 1));
}

// Orders items[i] by keys[i] (both permuted alike; every key below 2^bits, bits <= 16), in
// place: an American flag sort, every item moved at most once into its key's range, so a
// release is not held twice. Deterministic, not stable.
template <typename T>
void SortByKey(T* items, uint16_t* keys, size_t n, int bits) {
  const size_t count = size_t{1} << bits;
  std::vector<uint32_t> head(count + 1, 0);
  for (size_t i = 0; i < n; ++i) ++head[keys[i] + size_t{1}];
  for (size_t k = 0; k < count; ++k) head[k + 1] += head[k];
  std::vector<uint32_t> end(head.begin() + 1, head.end());
  for (size_t k = 0; k < count; ++k) {
    while (head[k] < end[k]) {
      const uint32_t i = head[k];
      const uint16_t key = keys[i];
      if (key == k) {
        ++head[k];
        continue;
      }
      const uint32_t j = head[key]++;  // where item i belongs; item j goes to i and is looked at next
      std::swap(items[i], items[j]);
      std::swap(keys[i], keys[j]);
    }
  }
}

}  // namespace tandem

#endif  // TANDEM_EDGE_QUEUES_H_
