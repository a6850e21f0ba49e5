#include "simplifier.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstring>
#include <future>
#include <numbers>
#include <system_error>

namespace tandem {
namespace {

// Bits of BoxFace per axis, and the axes they fix.
uint8_t FixedAxes(uint8_t box_mask) {
  uint8_t axes = 0;
  if (box_mask & (kBoxXMin | kBoxXMax)) axes |= 1;
  if (box_mask & (kBoxYMin | kBoxYMax)) axes |= 2;
  if (box_mask & (kBoxZMin | kBoxZMax)) axes |= 4;
  return axes;
}

}  // namespace

Simplifier::Simplifier(MeshStore* store, const SimplifierOptions& options)
    : store_(store), opt_(options) {}

void Simplifier::EnsureVertexCapacity() {
  const size_t n = store_->vertex_capacity();
  if (vs_.size() >= n) return;
  vs_.resize(n);
}

void Simplifier::AddTriangles(std::span<const TriId> tris, std::span<const VertexId> new_verts) {
  EnsureVertexCapacity();
  for (VertexId v : new_verts) {
    // Ids may be recycled from contracted vertices: start clean.
    vs_[v].q = Quadric{};
    vs_[v].rad = 1.0;
    ++vs_[v].version;
  }
  for (TriId t : tris) {
    const auto& tri = store_->triangle(t);
    const Quadric h = PlaneQuadric(store_->position(tri[0]), store_->position(tri[1]),
                                   store_->position(tri[2]));
    for (VertexId v : tri) vs_[v].q += h;
  }
}

double Simplifier::ReleaseKey(VertexId a, VertexId b, Candidate* c) const {
  // The paper's time-lag bookkeeping: height(c) = (height(a) + height(b)) / 2 and
  // rad(c) = (|a - b| + rad(a) + rad(b)) / 2, lengths in slice units.
  c->height = 0.5 * (store_->height(a) + store_->height(b));
  c->rad = 0.5 * (Norm(store_->position(a) - store_->position(b)) / opt_.slice_spacing +
                  vs_[a].rad + vs_[b].rad);
  c->layer = std::max(store_->layer(a), store_->layer(b));
  switch (opt_.release) {
    case ReleaseRule::kImmediate: return -std::numeric_limits<double>::infinity();
    case ReleaseRule::kLayer: return static_cast<double>(c->layer + 1);
    case ReleaseRule::kReach:
      // The paper argues reach > k for any edge touching the front (slice k), so the top of
      // layer k stays untouched until layer k+1 is in. That holds for original vertices, but
      // a contracted vertex keeps an averaged height that can lie well below its position:
      // an edge from it to a front vertex can then reach <= k. Requiring layer + 1 <= front
      // as well keeps the paper's guarantee (and every quadric in Q complete).
      return std::max(c->height + c->rad, static_cast<double>(c->layer + 1));
  }
  return 0;
}

bool Simplifier::Evaluate(VertexId a, VertexId b, Candidate* c) {
  const uint8_t ma = store_->box_mask(a), mb = store_->box_mask(b);
  const uint8_t common = ma & mb;
  if (common != ma && common != mb) return false;  // on different box faces: refuse
  const VertexId big = (common == ma) ? b : a;       // the vertex on more box faces
  const Vec3 pa = store_->position(a), pb = store_->position(b);
  Quadric h = vs_[a].q;
  h += vs_[b].q;
  const uint8_t fixed = FixedAxes(ma | mb);
  // Reference point: the midpoint, with box-fixed coordinates taken from the box vertex.
  Vec3 ref = (pa + pb) * 0.5;
  const Vec3 pbig = store_->position(big);
  for (int i = 0; i < 3; ++i) {
    if ((fixed >> i) & 1) ref[i] = pbig[i];
  }

  if (opt_.alpha > 0.0) {
    // Memoryless isotropy term over T_ab, the triangles around a or b (each once).
    Quadric g;
    double area = 0.0;
    auto add = [&](TriId t, bool skip_shared) {
      const auto& tri = store_->triangle(t);
      if (skip_shared && (tri[0] == a || tri[1] == a || tri[2] == a)) return;
      const Quadric gt = IsotropyQuadric(store_->position(tri[0]), store_->position(tri[1]),
                                         store_->position(tri[2]));
      g += gt;
      area += gt.a00;  // G_t's diagonal is w_t
    };
    for (TriId t : store_->vertex_triangles(a)) add(t, false);
    for (TriId t : store_->vertex_triangles(b)) add(t, true);
    Quadric combined;
    if (h.w > 0.0) {
      combined = h;
      combined *= (1.0 - opt_.alpha) / h.w;
    }
    if (area > 0.0 && h.w > 0.0) {
      const double big_w = 3.0 * area * std::sqrt(h.w) / opt_.error;
      g *= opt_.alpha / big_w;
      combined += g;
    }
    combined.w = 0.0;
    c->pos = MinimizeQuadric(combined, ref, fixed);
    c->cost = std::sqrt(std::max(0.0, combined.Evaluate(c->pos)));
    c->eps0 = ShapeError(h, c->pos);
  } else {
    c->pos = MinimizeQuadric(h, ref, fixed);
    c->eps0 = ShapeError(h, c->pos);
    c->cost = c->eps0;
  }
  c->box_mask = ma | mb;
  return true;
}

namespace {

// 4-ary min-heap on a vector of Simplifier::QNode-like nodes (children of i: 4i + 1 .. 4i + 4).
template <typename Node, typename Before>
void HeapSiftUp(std::vector<Node>& h, size_t i, Before before) {
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
// cache misses, made the binary heap's pop a tenth of the run time.
template <typename Node, typename Before>
void HeapPopFront(std::vector<Node>& h, Before before) {
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

}  // namespace

size_t Simplifier::QBucket(double key) const {
  // Monotone in the key, so bucket order then heap order is exactly (key, seq) order.
  const double b = key * q_scale_;
  return b < static_cast<double>(kQBuckets - 1) ? static_cast<size_t>(b) : kQBuckets - 1;
}

void Simplifier::QEnter() {
  // Makes q_cur_ the lowest non-empty bucket and restores its heap order (nodes appended
  // while it was not current are sifted in). Buckets below q_cur_ are always empty.
  while (q_buckets_[q_cur_].empty()) {
    ++q_cur_;
    assert(q_cur_ < kQBuckets);
  }
  std::vector<QNode>& h = q_buckets_[q_cur_];
  for (size_t i = q_heaped_[q_cur_]; i < h.size(); ++i) HeapSiftUp(h, i, QNodeBeforeFn{});
  q_heaped_[q_cur_] = h.size();
}

void Simplifier::HeapPush(double key, const QEntry& e) {
  uint32_t slot;
  if (!q_free_.empty()) {
    slot = q_free_.back();
    q_free_.pop_back();
    q_slots_[slot] = e;
  } else {
    slot = static_cast<uint32_t>(q_slots_.size());
    q_slots_.push_back(e);
  }
  if (q_buckets_.empty()) {
    q_buckets_.resize(kQBuckets);
    q_heaped_.assign(kQBuckets, 0);
    q_scale_ = static_cast<double>(kQBuckets - 1) / opt_.error;
    q_cur_ = kQBuckets - 1;
  }
  const size_t b = QBucket(key);
  q_buckets_[b].push_back(QNode{key, slot, q_seq_++});
  ++q_size_;
  if (b < q_cur_) {
    q_cur_ = b;  // was empty: a heap of one
    q_heaped_[b] = 1;
  } else if (b == q_cur_) {
    HeapSiftUp(q_buckets_[b], q_buckets_[b].size() - 1, QNodeBeforeFn{});
    q_heaped_[b] = q_buckets_[b].size();
  }
  // Otherwise appended: QEnter sifts it in when its bucket becomes the lowest.
}

const Simplifier::QNode& Simplifier::QTop() {
  QEnter();
  return q_buckets_[q_cur_][0];
}

Simplifier::QEntry Simplifier::HeapPop() {
  QEnter();
  std::vector<QNode>& h = q_buckets_[q_cur_];
  const uint32_t slot = h[0].slot;
  HeapPopFront(h, QNodeBeforeFn{});
  q_heaped_[q_cur_] = h.size();
  --q_size_;
  q_free_.push_back(slot);
  return q_slots_[slot];
}

void Simplifier::QClear() {
  for (auto& bucket : q_buckets_) bucket.clear();
  std::fill(q_heaped_.begin(), q_heaped_.end(), 0);
  q_cur_ = q_buckets_.empty() ? 0 : kQBuckets - 1;
  q_size_ = 0;
  q_slots_.clear();
  q_free_.clear();
}

void Simplifier::PushQ(VertexId a, VertexId b, const Candidate& c) {
  // An edge costing more than E0 can never be popped by SIMPLIFY(E0): keeping it would only
  // grow the heap (on a CT, most of Q). A later neighbour contraction re-pushes it with its
  // new cost; a target triangle count re-queues every edge first (RequeueAll).
  if (!keep_expensive_ && c.cost > opt_.error) return;
  HeapPush(c.cost, QEntry{a, b, vs_[a].version, vs_[b].version, c.pos, c.eps0});
}

void Simplifier::RequeueAll() {
  keep_expensive_ = true;
  QClear();
  for (TriId t = 0; t < store_->triangle_capacity(); ++t) {
    if (store_->triangle_alive(t)) PushTriangleEdges(t, /*new_layer=*/false);
  }
  FlushBatch();
}

bool Simplifier::HasHalfEdge(VertexId a, VertexId b) const {
  bool found = false;
  for (TriId u : store_->vertex_triangles(a)) {
    const auto& o = store_->triangle(u);
    for (int j = 0; j < 3; ++j) found |= (o[j] == a && o[(j + 1) % 3] == b);
  }
  return found;
}

void Simplifier::PushTriangleEdges(TriId t, bool new_layer) {
  // Each edge once: an interior edge is traversed a -> b by one triangle and b -> a by the
  // other, so it is pushed from the a < b side; an edge with no reverse half-edge (box
  // boundary, or the front before the next layer) is pushed from its only triangle.
  const auto& tri = store_->triangle(t);
  // A new layer's triangle t: an edge whose two ends were both made by earlier layers lies
  // on the plane below, in a face of t's cube that the cube underneath shares (marching
  // cubes cuts shared faces alike), and that cube's triangle, the reverse half-edge, queued
  // it as a front edge when its layer was delayed. The schedules never touch the front, so
  // that entry is still valid: queueing the edge again only made a duplicate that was
  // evaluated, queued and popped for nothing (a tenth of the released edges on the Link,
  // and a refused edge was counted twice). Without the reverse half-edge (the first layer's
  // bottom, on the box) it is queued here.
  const int32_t layer = new_layer ? std::max({store_->layer(tri[0]), store_->layer(tri[1]),
                                              store_->layer(tri[2])})
                                  : 0;
  // A new layer is as marching cubes made it, so an edge off the slab's two planes (its ends
  // at different heights) and off the box (no box face in common) is inside the slab, where
  // two of the layer's triangles share it: its reverse half-edge exists without looking
  // (the search below touches b's list and triangles, a cache miss or two per edge).
  constexpr uint8_t kBoxFaces = kBoxXMin | kBoxXMax | kBoxYMin | kBoxYMax | kBoxZMin | kBoxZMax;
  for (int k = 0; k < 3; ++k) {
    const VertexId a = tri[k], b = tri[(k + 1) % 3];
    const bool queued_below =
        new_layer && store_->layer(a) < layer && store_->layer(b) < layer;
    if (a > b && new_layer && store_->height(a) != store_->height(b) &&
        (store_->box_mask(a) & store_->box_mask(b) & kBoxFaces) == 0) {
      continue;
    }
    if ((a > b || queued_below) && HasHalfEdge(b, a)) continue;
    AddToBatch(a, b);
  }
}

void Simplifier::AddToBatch(VertexId a, VertexId b, bool released) {
  if (Pinned(a, b)) return;
  batch_.push_back(a < b ? BatchEdge{a, b, released} : BatchEdge{b, a, released});
  // Flushing early changes nothing (evaluations only read; pushes keep batch order) and
  // bounds the batch's memory when DELAY gets the whole mesh (classical, RequeueAll).
  if (batch_.size() >= kMaxBatch) FlushBatch();
}

void Simplifier::EvaluateBatchRange(size_t begin, size_t end) {
  // PushEdge's decisions without its pushes; reads the store and the quadrics only.
  for (size_t i = begin; i < end; ++i) {
    const BatchEdge e = batch_[i];
    BatchResult& r = batch_results_[i];
    r.c = Candidate{};
    r.key = -std::numeric_limits<double>::infinity();
    // An edge ACTIVATE released has not changed since its key was found <= the front, and
    // Q keeps no release data: the key need not be recomputed.
    if (opt_.release != ReleaseRule::kImmediate && !e.released) {
      r.key = ReleaseKey(e.a, e.b, &r.c);
      if (r.key > front_) {
        r.to = 0;
        continue;
      }
    }
    r.to = Evaluate(e.a, e.b, &r.c) ? 1 : 2;
  }
}

void Simplifier::FlushBatch() {
  const size_t n = batch_.size();
  if (n == 0) return;
  batch_results_.resize(n);
  // Below this size a thread costs more than it saves (a solve is ~1 µs).
  constexpr size_t kParallelMin = 1024;
  bool done = false;
  if (opt_.parallel && n >= kParallelMin) {
    try {
      auto first_half = std::async(std::launch::async, [this, n] { EvaluateBatchRange(0, n / 2); });
      EvaluateBatchRange(n / 2, n);
      first_half.get();
      done = true;
    } catch (const std::system_error&) {
      // No thread to be had: the sequential loop below gives the same result.
    }
  }
  if (!done) EvaluateBatchRange(0, n);
  for (size_t i = 0; i < n; ++i) {
    const BatchEdge e = batch_[i];
    const BatchResult& r = batch_results_[i];
    if (r.to == 0) {
      PushW(Entry{r.key, e.a, e.b, vs_[e.a].version, vs_[e.b].version});
    } else if (r.to == 1) {
      PushQ(e.a, e.b, r.c);
    } else {
      ++refusals_.box;
    }
  }
  batch_.clear();
}

void Simplifier::PushEdge(VertexId a, VertexId b) {
  if (Pinned(a, b)) return;
  if (a > b) std::swap(a, b);
  Candidate c;
  if (opt_.release != ReleaseRule::kImmediate) {
    // Waiting edges need only their release key; the quadric solve happens at ACTIVATE,
    // when the endpoints' quadrics are complete.
    const double key = ReleaseKey(a, b, &c);
    if (key > front_) {
      PushW(Entry{key, a, b, vs_[a].version, vs_[b].version});
      return;
    }
  }
  if (!Evaluate(a, b, &c)) {
    ++refusals_.box;
    return;
  }
  PushQ(a, b, c);
}

void Simplifier::Delay(std::span<const TriId> tris) {
  EnsureVertexCapacity();
  // The tandem schedules delay one new layer at a time; classical delays the whole mesh.
  const bool new_layer = opt_.release != ReleaseRule::kImmediate;
  for (TriId t : tris) {
    if (store_->triangle_alive(t)) PushTriangleEdges(t, new_layer);
  }
  FlushBatch();
}

void Simplifier::PushW(const Entry& e) {
  // Bucket = the first integer front >= key. Fronts only grow, so buckets below the
  // current one are always empty and get recycled by advancing w_base_. A key outside a
  // window of kWBuckets fronts (a vertex whose rad is huge in slice units, on a grid far
  // finer across than between its slices, or an infinite key) waits in w_far_ instead, so
  // no input can make the bucket vector large.
  if (!(e.key < kFarKey)) {  // also NaN
    w_far_.push_back(e);
    ++w_size_;
    return;
  }
  const int64_t release = static_cast<int64_t>(std::ceil(e.key));
  if (w_.empty()) w_base_ = release;
  if (release < w_base_) {  // cannot happen for keys > front; keep it correct anyway
    if (w_base_ - release + static_cast<int64_t>(w_.size()) > kWBuckets) {
      w_far_.push_back(e);
      ++w_size_;
      return;
    }
    w_.insert(w_.begin(), static_cast<size_t>(w_base_ - release), {});
    w_base_ = release;
  }
  const size_t b = static_cast<size_t>(release - w_base_);
  if (b >= static_cast<size_t>(kWBuckets)) {
    w_far_.push_back(e);
    ++w_size_;
    return;
  }
  if (b >= w_.size()) w_.resize(b + 1);
  w_[b].push_back(e);
  ++w_size_;
}

void Simplifier::Activate(double front) {
  front_ = front;
  // Edges activated at the same front go into the heap Q, whose order does not depend on
  // insertion order (ties broken by vertex ids), so bucket order is irrelevant.
  size_t b = 0;
  for (; b < w_.size() && static_cast<double>(w_base_) + static_cast<double>(b) <= front_; ++b) {
    std::vector<Entry> bucket;
    bucket.swap(w_[b]);
    w_size_ -= bucket.size();
    for (const Entry& e : bucket) {
      if (Stale(e)) continue;
      AddToBatch(e.a, e.b, /*released=*/true);  // evaluated now: the quadrics are complete
    }
  }
  if (!w_far_.empty()) {
    // Released ones go with the rest; the others stay (empty on ordinary grids).
    size_t kept = 0;
    for (const Entry& e : w_far_) {
      if (!(e.key > front_)) {
        --w_size_;
        if (!Stale(e)) AddToBatch(e.a, e.b, /*released=*/true);
      } else {
        w_far_[kept++] = e;
      }
    }
    w_far_.resize(kept);
  }
  FlushBatch();
  if (b > 0) {
    w_.erase(w_.begin(), w_.begin() + static_cast<std::ptrdiff_t>(b));
    w_base_ += static_cast<int64_t>(b);
  }
}

size_t Simplifier::QBytes() const {
  size_t bytes = q_buckets_.capacity() * sizeof(std::vector<QNode>) + q_heaped_.capacity() * sizeof(size_t);
  for (const auto& bucket : q_buckets_) bytes += bucket.capacity() * sizeof(QNode);
  return bytes;
}

size_t Simplifier::WaitingBytes() const {
  size_t bytes = w_.capacity() * sizeof(std::vector<Entry>);
  for (const auto& bucket : w_) bytes += bucket.capacity() * sizeof(Entry);
  bytes += w_far_.capacity() * sizeof(Entry);
  return bytes;
}

namespace {

constexpr int kNextCorner[3] = {1, 2, 0};  // indexed by CornerOf (mesh_store.h)
constexpr int kPrevCorner[3] = {2, 0, 1};

// Occurrences of x in a fan array of Simplifier::kFanMax entries (unused ones kInvalid).
// A fixed length and no loop exit: no branch to mispredict. Written with vector extensions
// (GCC, Clang: four lanes at a time, on any target): at 16 entries GCC unrolled the plain
// loop into scalar compares, twice the instructions of the vector loop.
template <size_t N>
int CountOf(const VertexId (&v)[N], VertexId x) {
  static_assert(N % 4 == 0);
  using V4 = uint32_t __attribute__((vector_size(16)));
  const V4 xs = {x, x, x, x};
  V4 acc = {0, 0, 0, 0};
  for (size_t i = 0; i < N; i += 4) {
    V4 chunk;
    std::memcpy(&chunk, v + i, sizeof(chunk));
    acc -= reinterpret_cast<V4>(chunk == xs);  // a match is all ones: -1
  }
  return static_cast<int>(acc[0] + acc[1] + acc[2] + acc[3]);
}

}  // namespace

bool Simplifier::LinkConditionFans(VertexId a, VertexId b) {
  // The fans of a and b as flat arrays: for each triangle at v, its corner after v (x) and
  // its corner before v (y), in the triangle's order; the caller checked they fit. Written
  // without early exits where the outcome varies from call to call: the link condition was
  // the largest source of mispredicted branches in the simplifier.
  VertexId xa[kFanMax], ya[kFanMax], xb[kFanMax], yb[kFanMax];
  for (VertexId* v : {xa, ya, xb, yb}) std::fill(v, v + kFanMax, kInvalid);
  int n_a = 0, n_b = 0;
  VertexId apex[4];
  int napex = 0;
  for (TriId t : store_->vertex_triangles(a)) {
    const auto& tri = store_->triangle(t);
    const int i = CornerOf(tri, a);
    const VertexId x = tri[kNextCorner[i]], y = tri[kPrevCorner[i]];
    xa[n_a] = x;
    ya[n_a++] = y;
    // The triangle's third corner is an apex if the triangle holds b (kept only then).
    apex[std::min(napex, 3)] = (x == b) ? y : x;
    napex += (x == b) | (y == b);
  }
  if (napex == 0) return false;  // a and b are not adjacent (any more)
  if (napex > 2) return false;   // edge in three triangles: not a manifold, refuse
  if (napex == 1) apex[1] = kInvalid;
  // An apex is a common neighbour; two equal apexes are one common neighbour for two
  // triangles on ab (the marks' version: common != napex).
  if (napex == 2 && apex[0] == apex[1]) return false;
  for (TriId t : store_->vertex_triangles(b)) {
    const auto& tri = store_->triangle(t);
    const int i = CornerOf(tri, b);
    xb[n_b] = tri[kNextCorner[i]];
    yb[n_b++] = tri[kPrevCorner[i]];
  }
  // Whether the x and y corners of a fan are different sets of vertices. They are whenever
  // the vertex is on the boundary (an edge (v, w) in one triangle puts w in one set only),
  // and on a consistently oriented manifold only then (an interior edge is one triangle's x
  // and the other's y). Otherwise every neighbour is an x corner. Half the comparisons of
  // counting each neighbour among all 2n corners.
  auto sets_differ = [](const VertexId(&x)[kFanMax], const VertexId(&y)[kFanMax], int n) {
    bool any = false;
    for (int i = 0; i < n; ++i) any |= (CountOf(y, x[i]) == 0) | (CountOf(x, y[i]) == 0);
    return any;
  };
  auto in_fan_a = [&](VertexId v) { return CountOf(xa, v) + CountOf(ya, v); };
  // (1) a common neighbour that is not an apex. b's neighbours are its x corners, and its
  // y corners too where the two differ.
  const bool b_open = sets_differ(xb, yb, n_b);
  bool stray = false;
  for (int i = 0; i < n_b; ++i) {
    const VertexId x = xb[i];
    stray |= (x != a) & (x != apex[0]) & (x != apex[1]) & (in_fan_a(x) != 0);
  }
  if (b_open) {
    for (int i = 0; i < n_b; ++i) {
      const VertexId y = yb[i];
      stray |= (y != a) & (y != apex[0]) & (y != apex[1]) & (in_fan_a(y) != 0);
    }
  }
  if (stray) return false;
  if (napex == 1) {  // (3) boundary edge: not both ac and bc boundary edges
    const VertexId c = apex[0];
    return !(in_fan_a(c) == 1 && CountOf(xb, c) + CountOf(yb, c) == 1);
  }
  // (2) an interior edge between two boundary vertices; a vertex is on the boundary when one
  // of its edges lies in a single triangle.
  auto on_boundary = [](const VertexId(&x)[kFanMax], const VertexId(&y)[kFanMax], int n) {
    bool any = false;
    for (int i = 0; i < n; ++i) {
      any |=
          (CountOf(x, x[i]) + CountOf(y, x[i]) == 1) | (CountOf(x, y[i]) + CountOf(y, y[i]) == 1);
    }
    return any;
  };
  // Sets that do not differ mean no boundary; the exact count only where they do (rare).
  if (b_open && on_boundary(xb, yb, n_b) && on_boundary(xa, ya, n_a)) return false;
  // (3) interior: triangles a-c-d and b-c-d both present?
  const VertexId c = apex[0], d = apex[1];
  auto has_cd = [c, d](const VertexId(&x)[kFanMax], const VertexId(&y)[kFanMax], int n) {
    bool any = false;
    for (int i = 0; i < n; ++i) any |= ((x[i] == c) & (y[i] == d)) | ((x[i] == d) & (y[i] == c));
    return any;
  };
  return !(has_cd(xa, ya, n_a) && has_cd(xb, yb, n_b));
}

bool Simplifier::LinkCondition(VertexId a, VertexId b) {
  if (store_->vertex_triangles(a).size() <= kFanMax &&
      store_->vertex_triangles(b).size() <= kFanMax) {
    return LinkConditionFans(a, b);
  }
  return LinkConditionMarks(a, b);
}

bool Simplifier::LinkConditionMarks(VertexId a, VertexId b) {
  // Lk(a) ∩ Lk(b) = Lk(ab), on the complex completed by a dummy vertex ω joined to every
  // boundary edge (Dey, Edelsbrunner, Guha, Nekhayev 1999). With manifold input it reduces
  // to: (1) the common neighbours of a and b are exactly the apexes of ab's triangles;
  // (2) ω: if a and b are both on the boundary, ab is a boundary edge; (3) no edge of both
  // links: for an interior edge with apexes c, d, not both acd and bcd are triangles; for a
  // boundary edge with apex c, not both ac and bc are boundary edges.
  // Allocated on first use: most meshes never have a fan this large.
  if (mark_.size() < store_->vertex_capacity()) mark_.resize(store_->vertex_capacity());
  if (++mark_epoch_ == 0) {
    std::fill(mark_.begin(), mark_.end(), Mark{});
    mark_epoch_ = 1;
  }
  const uint32_t ep = mark_epoch_;
  // Neighbours of a and of b, each with the number of triangles on edge (a, x) or (b, x)
  // (saturating at 127: bit 7 of count_b is the "seen" flag of the pass over b below). One
  // Mark per vertex keeps both tallies in one cache line.
  auto tally = [&](VertexId v, uint32_t Mark::*epoch, uint8_t Mark::*count) {
    for (TriId t : store_->vertex_triangles(v)) {
      for (VertexId x : store_->triangle(t)) {
        if (x == v) continue;
        Mark& m = mark_[x];
        if (m.*epoch != ep) {
          m.*epoch = ep;
          m.*count = 0;
        }
        if (m.*count < 127) ++(m.*count);
      }
    }
  };
  tally(a, &Mark::epoch_a, &Mark::count_a);  // inlined: same instructions as two loops
  tally(b, &Mark::epoch_b, &Mark::count_b);
  VertexId apex[2];
  int napex = 0;
  bool a_boundary = false;
  for (TriId t : store_->vertex_triangles(a)) {
    const auto& tri = store_->triangle(t);
    for (VertexId x : tri) a_boundary |= (x != a && mark_[x].count_a == 1);
    if (tri[0] != b && tri[1] != b && tri[2] != b) continue;
    if (napex == 2) return false;  // edge in three triangles: not a manifold, refuse
    for (VertexId x : tri) {
      if (x != a && x != b) apex[napex++] = x;
    }
  }
  if (napex == 0) return false;  // a and b are not adjacent (any more)
  // Each neighbour x of b once: (b, x) in one triangle makes b a boundary vertex; a common
  // neighbour must be an apex.
  bool b_boundary = false;
  int common = 0;
  for (TriId t : store_->vertex_triangles(b)) {
    for (VertexId x : store_->triangle(t)) {
      if (x == b) continue;
      Mark& m = mark_[x];
      const uint8_t cb = m.count_b;
      if (cb & 0x80) continue;  // seen
      m.count_b = static_cast<uint8_t>(cb | 0x80);
      if (cb == 1) b_boundary = true;
      if (x != a && m.epoch_a == ep) {
        ++common;
        bool is_apex = false;
        for (int k = 0; k < napex; ++k) is_apex |= apex[k] == x;
        if (!is_apex) return false;  // (1) a common neighbour that is not an apex
        if (napex == 1 && m.count_a == 1 && cb == 1) return false;  // (3) boundary
      }
    }
  }
  if (common != napex) return false;
  if (napex == 2) {
    if (a_boundary && b_boundary) return false;  // (2) interior edge between boundaries
    // (3) interior: triangles a-c-d and b-c-d both present?
    const VertexId c = apex[0], d = apex[1];
    auto has_triangle = [&](VertexId v) {
      for (TriId t : store_->vertex_triangles(v)) {
        const auto& tri = store_->triangle(t);
        bool hc = false, hd = false;
        for (VertexId x : tri) {
          hc |= x == c;
          hd |= x == d;
        }
        if (hc && hd) return true;
      }
      return false;
    };
    if (has_triangle(a) && has_triangle(b)) return false;
  }
  return true;
}

bool Simplifier::GeometryOk(VertexId a, VertexId b, Vec3 pos, bool guard) {
  // Triangles that survive the contraction move one corner (a or b) to pos. The distance
  // guard bounds how far pos lies from each one's present plane: |n·(pos - p0)| <= K E0 |n|.
  // Which triangles are on ab (removed) and which are already degenerate (exact iso hits: no
  // constraint) varies from call to call: branching on it was mispredicted. The survivors
  // are gathered first (written always, kept by a count), the degenerate ones masked out;
  // a refusal is rare and may branch.
  const auto ta = store_->vertex_triangles(a), tb = store_->vertex_triangles(b);
  if (survivors_.size() < ta.size() + tb.size()) survivors_.resize(ta.size() + tb.size());
  size_t n = 0;
  for (VertexId v : {a, b}) {
    const VertexId other = (v == a) ? b : a;
    for (TriId t : (v == a) ? ta : tb) {
      const auto& tri = store_->triangle(t);
      survivors_[n] = {t, v};
      n += static_cast<size_t>((tri[0] != other) + (tri[1] != other) + (tri[2] != other) == 3);
    }
  }
  const double bound = guard ? opt_.distance_guard * opt_.error : 0.0;
  const bool guarded = bound > 0.0;
  for (size_t i = 0; i < n; ++i) {
    const auto [t, v] = survivors_[i];
    const auto& tri = store_->triangle(t);
    Vec3 p[3];
    for (int k = 0; k < 3; ++k) p[k] = store_->position(tri[k]);
    const Vec3 n_old = TwiceAreaVector(p[0], p[1], p[2]);
    const double old2 = Dot(n_old, n_old);
    const double off = Dot(n_old, pos - p[0]);
    const bool far = guarded && off * off > bound * bound * old2;  // guarded: fixed per run
    p[CornerOf(tri, v)] = pos;
    const CornerMove move = MoveCorners(n_old, p[0], p[1], p[2]);
    if ((old2 != 0.0) & (far | move.collapses | move.flips)) {
      if (far) {
        ++refusals_.distance;
      } else if (move.collapses) {
        ++refusals_.degenerate;
      } else {
        ++refusals_.flip;
      }
      return false;
    }
  }
  return true;
}

void Simplifier::Contract(VertexId a, VertexId b, const Candidate& c) {
  // a survives as c; b's triangles move to a; the triangles on ab disappear.
  TriId on_ab[3];  // the link condition passed: ab is in one or two triangles
  int n_ab = 0;
  for (TriId t : store_->vertex_triangles(a)) {
    const auto& tri = store_->triangle(t);
    on_ab[std::min(n_ab, 2)] = t;  // branch-free: which ones they are is unpredictable
    n_ab += static_cast<int>(tri[0] == b) + static_cast<int>(tri[1] == b) +
            static_cast<int>(tri[2] == b);
  }
  assert(n_ab == 1 || n_ab == 2);
  for (int i = 0; i < n_ab; ++i) store_->RemoveTriangle(on_ab[i]);
  store_->MoveTriangles(b, a);
  store_->RemoveVertex(b);
  ++vs_[b].version;
  vs_[a].q += vs_[b].q;
  store_->set_position(a, c.pos);
  store_->set_height(a, c.height);
  store_->set_layer(a, c.layer);
  store_->set_box_mask(a, c.box_mask);
  vs_[a].rad = c.rad;
  ++vs_[a].version;
  ++contractions_;
  // Recorded from the geometry, not from the release key, so a broken key shows up here.
  max_reach_over_front_ = std::max(max_reach_over_front_, c.height + c.rad - front_);
  max_layer_over_front_ = std::max(max_layer_over_front_, static_cast<double>(c.layer) - front_);
  // Re-evaluate the edges around c, in increasing neighbour id. Each neighbour once before
  // sorting (the sort of all corners, every neighbour twice, was a third of this function,
  // mispredicted branches mostly): the corner after c in each triangle covers a closed fan;
  // on the boundary one neighbour is only ever the corner before c.
  scratch_.clear();
  const auto fan = store_->vertex_triangles(a);
  for (TriId t : fan) {
    const auto& tri = store_->triangle(t);
    scratch_.push_back(tri[kNextCorner[CornerOf(tri, a)]]);
  }
  const size_t nexts = scratch_.size();
  for (TriId t : fan) {
    const auto& tri = store_->triangle(t);
    const VertexId prev = tri[kPrevCorner[CornerOf(tri, a)]];
    bool found = false;  // no early exit: where it would leave is unpredictable
    for (size_t i = 0; i < nexts; ++i) found |= scratch_[i] == prev;
    if (!found) scratch_.push_back(prev);
  }
  std::sort(scratch_.begin(), scratch_.end());
  scratch_.erase(std::unique(scratch_.begin(), scratch_.end()), scratch_.end());
  std::vector<VertexId> nbrs;
  nbrs.swap(scratch_);
  for (VertexId x : nbrs) PushEdge(a, x);
  nbrs.swap(scratch_);
}

void Simplifier::Simplify(int64_t target_triangles) {
  const bool to_target = target_triangles > 0;
  while (q_size_ > 0) {
    if (to_target && static_cast<int64_t>(store_->num_triangles()) <= target_triangles) break;
    const double key = QTop().key;
    if (!to_target && key > opt_.error) break;
    const QEntry e = HeapPop();
    if (Stale(e)) continue;
    Candidate c;
    c.pos = e.pos;
    c.cost = key;
    c.eps0 = e.eps0;
    if (opt_.alpha > 0.0) {
      // The memoryless isotropy term depends on the current neighbourhood: recompute.
      if (!Evaluate(e.a, e.b, &c)) {
        ++refusals_.box;
        continue;
      }
      if (c.cost > key * (1.0 + 1e-12) + 1e-300) {  // cost grew since it was queued
        PushQ(e.a, e.b, c);
        continue;
      }
    }
    if (!to_target && c.eps0 > opt_.error) {
      ++refusals_.error;  // conservative rule: ε_α <= E0 but ε0 > E0
      continue;
    }
    if (!LinkCondition(e.a, e.b)) {
      ++refusals_.link;
      continue;
    }
    // Past E0, toward a target triangle count, the guard (a multiple of E0) would stall.
    if (!GeometryOk(e.a, e.b, c.pos, /*guard=*/!to_target)) continue;
    const uint8_t ma = store_->box_mask(e.a), mb = store_->box_mask(e.b);
    c.box_mask = ma | mb;
    ReleaseKey(e.a, e.b, &c);  // height, rad, layer of the new vertex
    Contract(e.a, e.b, c);
  }
}

void Simplifier::AdoptVertex(const Simplifier& from, VertexId src, VertexId dst, bool shared) {
  EnsureVertexCapacity();
  if (shared) {
    vs_[dst].q += from.vs_[src].q;  // a seam vertex: each part saw its own triangles
  } else {
    vs_[dst].q = from.vs_[src].q;
    vs_[dst].rad = from.vs_[src].rad;
  }
  ++vs_[dst].version;
}

void Simplifier::AdoptCounters(const Simplifier& from) {
  refusals_ += from.refusals_;
  contractions_ += from.contractions_;
  max_reach_over_front_ = std::max(max_reach_over_front_, from.max_reach_over_front_);
  max_layer_over_front_ = std::max(max_layer_over_front_, from.max_layer_over_front_);
}

void Simplifier::PushEdgesAround(std::span<const VertexId> verts) {
  EnsureVertexCapacity();
  std::vector<BatchEdge> edges;
  for (VertexId v : verts) {
    for (TriId t : store_->vertex_triangles(v)) {
      for (VertexId x : store_->triangle(t)) {
        if (x != v) edges.push_back(v < x ? BatchEdge{v, x, false} : BatchEdge{x, v, false});
      }
    }
  }
  std::sort(edges.begin(), edges.end(), [](const BatchEdge& p, const BatchEdge& q) {
    return p.a != q.a ? p.a < q.a : p.b < q.b;
  });
  edges.erase(std::unique(edges.begin(), edges.end(),
                          [](const BatchEdge& p, const BatchEdge& q) {
                            return p.a == q.a && p.b == q.b;
                          }),
              edges.end());
  for (const BatchEdge& e : edges) AddToBatch(e.a, e.b);
  FlushBatch();
}

double Simplifier::MaxShapeError() const {
  double worst = 0.0;
  for (VertexId v = 0; v < store_->vertex_capacity(); ++v) {
    if (!store_->vertex_alive(v) || v >= vs_.size()) continue;
    worst = std::max(worst, ShapeError(vs_[v].q, store_->position(v)));
  }
  return worst;
}

int64_t Simplifier::CorrectSag(double fraction) {
  // A coarse triangle is a chord of the curved surface it replaces: on average its interior
  // lies off the surface, on the concave side, by s = Σ eᵀKe / 24 over its three edges e
  // (K the curvature tensor: linear interpolation of a quadratic errs by ½ Σ λiλj eᵀKe,
  // and λiλj averages 1/12 over a triangle). The quadric minimiser puts each vertex off
  // the surface on the convex side, by ½ of the mean of yᵀKy over the patch it absorbed
  // (y: offsets from the vertex), which cancels only part of s. What is left is a bias
  // toward the concave side, a large part of the RMS distance (Link 512³: a uniform
  // outward shift of E0/6 alone lowers it by 6%). Each vertex moves along its normal by
  // `fraction` times the area-weighted mean s of its triangles. For Voronoi-sized patches
  // the model gives 0.45; the patches of a simplified mesh are larger and lift more, and
  // 0.3 measured best (0.25-0.4 within 2% on the synthetic inputs, the engine CT best at
  // 0.25-0.3; issue 6 notes). eᵀKe is taken from the mesh itself, (n_j - n_i)·(x_j - x_i)
  // with area-weighted vertex normals: nothing more is stored while simplifying.
  if (!(fraction > 0.0)) return 0;
  std::vector<VertexId> verts;
  for (VertexId v = 0; v < store_->vertex_capacity(); ++v) {
    if (store_->vertex_alive(v)) verts.push_back(v);
  }
  std::vector<Vec3> normal(store_->vertex_capacity());
  VertexNormals(verts, normal);
  return CorrectSagAt(verts, normal, fraction);
}

namespace {

// The triangles of a fan in increasing id: every sum over them is then taken in the order of
// a pass over all triangles, whichever vertex asks.
void SortedFan(const MeshStore& store, VertexId v, std::vector<TriId>* fan) {
  const auto tris = store.vertex_triangles(v);
  fan->assign(tris.begin(), tris.end());
  std::sort(fan->begin(), fan->end());
}

}  // namespace

void Simplifier::VertexNormals(std::span<const VertexId> verts, std::span<Vec3> normal) {
  std::vector<TriId> fan;
  for (VertexId v : verts) {
    SortedFan(*store_, v, &fan);
    Vec3 n{};
    for (TriId t : fan) {
      const auto& tri = store_->triangle(t);
      n = n + TwiceAreaVector(store_->position(tri[0]), store_->position(tri[1]),
                              store_->position(tri[2]));
    }
    const double len = Norm(n);
    normal[v] = len > 0.0 ? n * (1.0 / len) : Vec3{};
  }
}

double Simplifier::MaxEdgeReach(VertexId v) const {
  double reach = store_->height(v) + vs_[v].rad;
  for (TriId t : store_->vertex_triangles(v)) {
    for (VertexId x : store_->triangle(t)) {
      if (x == v) continue;
      Candidate c;
      ReleaseKey(v, x, &c);
      reach = std::max(reach, c.height + c.rad);
    }
  }
  return reach;
}

double Simplifier::ShapeErrorAt(VertexId v) const {
  return ShapeError(vs_[v].q, store_->position(v));
}

void Simplifier::Freeze(VertexId v) {
  store_->set_box_mask(v, store_->box_mask(v) | kFrozen);
  ++vs_[v].version;
}

int64_t Simplifier::CorrectSagAt(std::span<const VertexId> verts, std::span<const Vec3> normal,
                                 double fraction) {
  if (!(fraction > 0.0) || verts.empty()) return 0;
  // Near a crease (a sharp edge of a machined part) the vertex normal is an average of
  // faces that meet at an angle: the sag estimate there measures the crease, not a
  // curvature, and moving the vertex cuts the edge (the engine CT's Hausdorff distance grew
  // by 9%). A vertex with a triangle whose normal is more than kSagCreaseDegrees from its
  // own stays where it is: at 25 degrees the engine keeps its Hausdorff distance while every
  // smooth input keeps its gain; at 40 the engine loses it again.
  constexpr double kSagCreaseDegrees = 25.0;
  const double cos_crease = std::cos(kSagCreaseDegrees * std::numbers::pi / 180.0);
  if (sag_slot_.size() < store_->vertex_capacity()) sag_slot_.resize(store_->vertex_capacity(), kInvalid);
  std::vector<Vec3> moved(verts.size());
  std::vector<uint8_t> moving(verts.size(), 0);
  std::vector<TriId> fan, checks;
  auto corners = [&](TriId t, Vec3 p[3]) {
    const auto& tri = store_->triangle(t);
    for (int k = 0; k < 3; ++k) p[k] = store_->position(tri[k]);
  };
  // The step of each vertex, limited so that ε0 <= max(E0, ε0 now): its triangles' mean sag
  // (Σ w·s/24 over area) along its normal, unless it is on the box or at a crease.
  for (size_t i = 0; i < verts.size(); ++i) {
    const VertexId v = verts[i];
    sag_slot_[v] = static_cast<uint32_t>(i);
    moved[i] = store_->position(v);
    if ((store_->box_mask(v) & ~kFrozen) != 0) continue;
    SortedFan(*store_, v, &fan);
    double sag = 0.0, area = 0.0;
    bool crease = false;
    for (TriId t : fan) {
      const auto& tri = store_->triangle(t);
      Vec3 p[3];
      corners(t, p);
      const Vec3 fn = TwiceAreaVector(p[0], p[1], p[2]);  // 2·area·unit normal
      const double w = 0.5 * Norm(fn);
      if (w > 0.0) crease |= Dot(fn, normal[v]) < cos_crease * 2.0 * w;
      double s = 0.0;
      for (int k = 0; k < 3; ++k) {
        const int j = (k + 1) % 3;
        s += Dot(normal[tri[j]] - normal[tri[k]], p[j] - p[k]);
      }
      sag += w * s / 24.0;
      area += w;
    }
    const Quadric& q = vs_[v].q;
    const Vec3 n = normal[v];
    if (area <= 0.0 || crease || q.w <= 0.0 || Dot(n, n) == 0.0) continue;
    const double step = fraction * sag / area;
    const Vec3 d = step < 0.0 ? n * -1.0 : n;  // t >= 0 along d
    const Vec3 x = moved[i];
    const double t =
        StepWithinError(q, x, d, std::abs(step), std::max(opt_.error, ShapeError(q, x)));
    if (!(t > 0.0)) continue;
    moved[i] = x + d * t;
    moving[i] = 1;
    checks.insert(checks.end(), fan.begin(), fan.end());
  }
  // No triangle may turn over or collapse: put the corners of any that would back, until
  // none does (each round puts at least one vertex back, and the mesh as it was is valid).
  std::sort(checks.begin(), checks.end());
  checks.erase(std::unique(checks.begin(), checks.end()), checks.end());
  auto slot = [&](VertexId v) { return sag_slot_[v]; };
  auto is_moving = [&](VertexId v) { return slot(v) != kInvalid && moving[slot(v)]; };
  auto now = [&](VertexId v) { return is_moving(v) ? moved[slot(v)] : store_->position(v); };
  for (bool again = true; again;) {
    again = false;
    for (TriId t : checks) {
      const auto& tri = store_->triangle(t);
      if (!(is_moving(tri[0]) | is_moving(tri[1]) | is_moving(tri[2]))) continue;
      Vec3 p[3];
      corners(t, p);
      const Vec3 n_old = TwiceAreaVector(p[0], p[1], p[2]);
      if (Dot(n_old, n_old) == 0.0) continue;  // already degenerate: no orientation to keep
      if (MovedCornerKeepsOrientation(n_old, now(tri[0]), now(tri[1]), now(tri[2]))) continue;
      for (VertexId v : tri) {
        if (is_moving(v)) {
          moving[slot(v)] = 0;
          again = true;
        }
      }
    }
  }
  int64_t count = 0;
  for (size_t i = 0; i < verts.size(); ++i) {
    const VertexId v = verts[i];
    sag_slot_[v] = kInvalid;
    if (!moving[i]) continue;
    store_->set_position(v, moved[i]);
    ++vs_[v].version;
    ++count;
  }
  return count;
}

size_t Simplifier::MemoryBytes() const {
  return vs_.capacity() * sizeof(VertexState) +
         mark_.capacity() * sizeof(Mark) + QBytes() +
         q_slots_.capacity() * sizeof(QEntry) + q_free_.capacity() * sizeof(uint32_t) + WaitingBytes() +
         scratch_.capacity() * sizeof(VertexId) + survivors_.capacity() * sizeof(Survivor) +
         sag_slot_.capacity() * sizeof(uint32_t) +
         batch_.capacity() * sizeof(BatchEdge) +
         batch_results_.capacity() * sizeof(BatchResult);
}

}  // namespace tandem
