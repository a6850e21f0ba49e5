#include "simplifier.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <utility>

#include "grow.h"

namespace tandem {

Simplifier::Simplifier(MeshStore* store, const SimplifierOptions& options)
    : store_(store), opt_(options), quadrics_(store, options.check_quadrics),
      q_(options.error),
      rises_(store, &version_, options.rises),
      release_(store, &version_, options.release_chunk, options.tile_x, options.tile_y) {}

void Simplifier::EnsureVertexCapacity() {
  const size_t n = store_->vertex_capacity();
  if (quadrics_.size() >= n) return;
  quadrics_.EnsureCapacity(n);
  GrowTo(version_, n);
}

void Simplifier::AddTriangles(std::span<const TriId> tris, std::span<const VertexId> new_verts) {
  EnsureVertexCapacity();
  for (VertexId v : new_verts) {
    // Ids may be recycled from contracted vertices: start clean (the store reset rad).
    quadrics_.Reset(v);
    ++version_[v];
  }
  for (size_t i = 0; i < tris.size(); ++i) {
    // Corners on the plane below were made a layer ago, out of cache: start them early.
    if (i + kAhead < tris.size()) {
      for (VertexId v : store_->triangle(tris[i + kAhead])) PrefetchVertex(v);
    }
    if (i + kAhead / 2 < tris.size()) {
      for (VertexId v : store_->triangle(tris[i + kAhead / 2])) PrefetchQuadric(v);
    }
    const auto& tri = store_->triangle(tris[i]);
    const Quadric h = PlaneQuadric(store_->position(tri[0]), store_->position(tri[1]),
                                   store_->position(tri[2]));
    for (VertexId v : tri) quadrics_.AddPlane(v, h);
  }
}

// Evaluate's body, cloned for CPUs with AVX2 and picked once at load: the packed evaluation's
// pairs then take three-operand instructions, without the register copies SSE2's two-operand
// form needs (no FMA: the same roundings). Declared and called in this file only: clang 14
// compiles a call from another file to a target_clones function as a call to its resolver,
// which returns a clone's address and evaluates nothing.
#if defined(__x86_64__) && defined(__ELF__)
#define TANDEM_AVX2_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define TANDEM_AVX2_CLONES
#endif

struct SimplifierEvaluation {
  // Clang wants the attribute on the declaration and the definition.
  TANDEM_AVX2_CLONES static bool Run(Simplifier& s, VertexId a, VertexId b,
                                     Simplifier::Candidate* c);
};

TANDEM_AVX2_CLONES bool SimplifierEvaluation::Run(Simplifier& s, VertexId a, VertexId b,
                                                  Simplifier::Candidate* c) {
  const MeshStore& store = *s.store_;
  const uint8_t ma = store.box_mask(a), mb = store.box_mask(b);
  const uint8_t common = ma & mb;
  if (common != ma && common != mb) return false;  // on different box faces: refuse
  const PackedQuadric h = s.quadrics_.Sum(a, b);
  if ((ma | mb) != 0 || s.opt_.alpha > 0.0) return s.EvaluateBoxedOrIsotropic(a, b, h, c);
  // Most edges are off the box: nothing fixed, the reference point the midpoint.
  const Vec3 ref = (store.position(a) + store.position(b)) * 0.5;
  if (!quadric_internal::MinimizeFullRank(h, ref, &c->pos)) {
    c->pos = MinimizeQuadricSolve(h.Unpack(), ref, 0);
  }
  c->eps0 = ShapeError(h, c->pos);
  c->cost = c->eps0;
  c->box_mask = 0;
  return true;
}

bool Simplifier::Evaluate(VertexId a, VertexId b, Candidate* c) {
  return SimplifierEvaluation::Run(*this, a, b, c);
}

bool Simplifier::EvaluateBoxedOrIsotropic(VertexId a, VertexId b, const PackedQuadric& h,
                                          Candidate* c) {
  const uint8_t ma = store_->box_mask(a), mb = store_->box_mask(b);
  const uint8_t fixed = (ma | mb) == 0 ? 0 : FixedAxes(ma | mb);
  const Vec3 ref = (ma | mb) == 0 ? (store_->position(a) + store_->position(b)) * 0.5
                                  : BoxedMidpoint(store_->position(a), ma, store_->position(b), mb);

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
    const Quadric combined =
        IsotropicCostQuadric(h.Unpack(), std::move(g), area, opt_.alpha, opt_.error);
    c->pos = MinimizeQuadric(combined, ref, fixed);
    c->cost = IsotropicCost(combined, c->pos);
    c->eps0 = ShapeError(h, c->pos);
  } else {
    c->pos = MinimizeQuadric(h.Unpack(), ref, fixed);
    c->eps0 = ShapeError(h, c->pos);
    c->cost = c->eps0;
  }
  c->box_mask = ma | mb;
  return true;
}

void Simplifier::PushQ(VertexId a, VertexId b, const Candidate& c) {
  // An edge costing more than E0 can never be popped by SIMPLIFY(E0): keeping it would only
  // grow the heap (on a CT, most of Q). A later neighbour contraction re-pushes it with its
  // new cost; a rise of E0 offers it again (RaiseError), and a target triangle count's last
  // pass re-queues every edge (RequeueAll).
  if (!keep_expensive_ && c.cost > opt_.keep * opt_.error) {
    rises_.Dropped(a, b, c.cost);
    return;
  }
  // Zero-cost edges (an exactly flat patch: a binary mask's faces) would all tie, and Q pops
  // ties newest first: each survivor's re-pushed edges came next, so it took its neighbours
  // one after the other into a fan of thousands of triangles, every check over the whole fan
  // (docs/decisions.md 3). They pop shortest first instead: the key is the squared length,
  // scaled to 2^-960 of it, below any cost but 0.
  double key = c.cost;
  if (key == 0) {
    const Vec3 d = store_->position(a) - store_->position(b);
    key = Dot(d, d) * 0x1p-960;
  }
  ++q_pushes_;
  q_.Push(key, QEntry{a, b, version_[a], version_[b], c.pos, c.eps0});
}

bool Simplifier::HasHalfEdge(VertexId a, VertexId b) const {
  bool found = false;
  for (TriId u : store_->vertex_triangles(a)) {
    const auto& o = store_->triangle(u);
    for (int j = 0; j < 3; ++j) found |= (o[j] == a && o[(j + 1) % 3] == b);
  }
  return found;
}

int32_t Simplifier::LayerOf(TriId t) const {
  const auto& o = store_->triangle(t);
  return std::max({store_->layer(o[0]), store_->layer(o[1]), store_->layer(o[2])});
}

bool Simplifier::QueuedElsewhere(TriId t, VertexId a, VertexId b, bool new_layer,
                                 int32_t layer) const {
  // Where 3 or more labels meet, an edge lies in as many triangles, facing either way, so
  // half-edges cannot say which triangle queues it: the one of least id does, among the new
  // layer's (an edge in a triangle of an older layer was queued with that layer).
  for (TriId u : store_->vertex_triangles(a)) {
    const auto& o = store_->triangle(u);
    if (u == t || (o[0] != b && o[1] != b && o[2] != b)) continue;
    if (u < t || (new_layer && LayerOf(u) < layer)) return true;
  }
  return false;
}

void Simplifier::PushComplexTriangleEdges(TriId t, bool new_layer) {
  const int32_t layer = new_layer ? LayerOf(t) : 0;
  const auto& tri = store_->triangle(t);
  for (int k = 0; k < 3; ++k) {
    const VertexId a = tri[k], b = tri[(k + 1) % 3];
    if (!QueuedElsewhere(t, a, b, new_layer, layer)) AddToBatch(a, b);
  }
}

void Simplifier::PushTriangleEdges(TriId t, bool new_layer) {
  if (store_->labeled()) {
    PushComplexTriangleEdges(t, new_layer);
    return;
  }
  // Each edge once: an interior edge is traversed a -> b by one triangle and b -> a by the
  // other, so it is pushed from the a < b side; an edge with no reverse half-edge (box
  // boundary, or the front before the next layer) is pushed from its only triangle.
  const auto& tri = store_->triangle(t);
  // A new layer's triangle t: an edge whose two ends were both made by earlier layers lies
  // on the plane below, in a face of t's cube that the cube underneath shares (marching
  // cubes cuts shared faces alike), and that cube's triangle, the reverse half-edge, queued
  // it as a front edge when its layer was delayed. The schedules never touch the front, so
  // that entry is still valid: queueing the edge again only made a duplicate that was
  // evaluated, queued and popped for nothing (and a refused edge was counted twice).
  // Without the reverse half-edge (the first layer's
  // bottom, on the box) it is queued here.
  const int32_t layer = new_layer ? std::max({store_->layer(tri[0]), store_->layer(tri[1]),
                                              store_->layer(tri[2])})
                                  : 0;
  // A new layer is as marching cubes made it, so an edge off the slab's two planes (its ends
  // at different heights) and off the box (no box face in common) is inside the slab, where
  // two of the layer's triangles share it: its reverse half-edge exists without looking
  // (the search below touches b's list and triangles, a cache miss or two per edge).
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

void Simplifier::PushEdge(VertexId a, VertexId b) {
  if (Pinned(a, b)) return;
  if (a > b) std::swap(a, b);
  Candidate c;
  if (opt_.release != ReleaseRule::kImmediate) {
    // Waiting edges need only their release key; the quadric solve happens at ACTIVATE,
    // when the endpoints' quadrics are complete.
    const double key = ReleaseKey(a, b, &c);
    if (key > front_) {
      ++w_pushes_;
      w_.Push(WEntry{key, a, b, version_[a], version_[b]});
      return;
    }
  }
  ++evaluations_;
  if (!Evaluate(a, b, &c)) {
    ++refusals_.box;
    return;
  }
  if (!Hold(a, b, c)) PushReady(a, b, c);
}

bool Simplifier::HoldWide(VertexId a, VertexId b) {
  // rad(c) >= late_radius, i.e. |a - b| / sz >= 2 late_radius - rad(a) - rad(b), squared:
  // no root for the many narrow patches.
  const double need = 2 * opt_.late_radius - store_->rad(a) - store_->rad(b);
  if (need > 0) {
    const Vec3 d = store_->position(a) - store_->position(b);
    const double reach = need * opt_.slice_spacing;
    if (Dot(d, d) < reach * reach) return false;
  }
  Candidate at;  // a released edge's candidate has no release data
  ReleaseKey(a, b, &at);
  const double key = std::max(at.height + (1 + opt_.late_lag) * at.rad,
                              static_cast<double>(at.layer + 1));
  if (key <= front_) return false;
  held_.Hold(key, {a, b, version_[a], version_[b]});
  return true;
}

void Simplifier::Delay(std::span<const TriId> tris, std::span<const uint8_t> layer_edges) {
  EnsureVertexCapacity();
  // The tandem schedules delay one new layer at a time; classical delays the whole mesh.
  const bool new_layer = opt_.release != ReleaseRule::kImmediate;
  if (new_layer && !layer_edges.empty()) {
    // The extractor's rules: the same edges in the same order as PushTriangleEdges finds
    // them, without its searches of the store (the ends' records are read by AddToBatch).
    assert(layer_edges.size() == tris.size());
    for (size_t i = 0; i < tris.size(); ++i) {
      if (i + kAhead < tris.size()) {
        for (VertexId v : store_->triangle(tris[i + kAhead])) store_->Prefetch(v);
      }
      if (!store_->triangle_alive(tris[i])) continue;
      const auto& tri = store_->triangle(tris[i]);
      for (int k = 0; k < 3; ++k) {
        const VertexId a = tri[k], b = tri[(k + 1) % 3];
        const LayerEdge rule = EdgeOf(layer_edges[i], k);
        if (rule == kEdgeOnce || (rule == kEdgeShared && a < b) ||
            (rule == kEdgeSearch &&
             !QueuedElsewhere(tris[i], a, b, /*new_layer=*/true, LayerOf(tris[i])))) {
          AddToBatch(a, b);
        }
      }
    }
    FlushBatch();
    return;
  }
  for (size_t i = 0; i < tris.size(); ++i) {
    if (i + kAhead < tris.size() && store_->triangle_alive(tris[i + kAhead])) {
      for (VertexId v : store_->triangle(tris[i + kAhead])) store_->Prefetch(v);
    }
    if (store_->triangle_alive(tris[i])) PushTriangleEdges(tris[i], new_layer);
  }
  FlushBatch();
}

void Simplifier::TrackStart() {
  q_.CountBelow(&below_);
  if (chunk_span_ == 0) {
    progress_done_.store(0, std::memory_order_relaxed);
    progress_total_.store(below_.back(), std::memory_order_relaxed);
  }
}

void Simplifier::TrackAt(size_t bucket) {
  const int64_t behind = below_[std::min(bucket, EdgeQueue::kBuckets)], all = below_.back();
  const int64_t done = chunk_span_ == 0 ? behind
                       : all > 0        ? chunk_base_ + chunk_span_ * behind / all
                                        : chunk_base_ + chunk_span_;
  progress_done_.store(done, std::memory_order_relaxed);
}

void Simplifier::Activate(double front) {
  // ACTIVATE(front): W's entries with key <= front are evaluated into Q in W's order. A large
  // release enters a chunk at a time (chunked_release.h), each chunk simplified before the
  // next is evaluated, so that Q holds a chunk, not the release; the last chunk is left for
  // the SIMPLIFY that follows.
  front_ = front;
  const size_t chunks = release_.Take(&w_, front_);
  if (!held_.empty()) {
    // Evaluated again: a neighbour's contraction may have moved an end since.
    held_.Release(
        front_,
        [this](const HeldEdges::Entry& h) {
          Candidate c;
          ++evaluations_;
          if (Evaluate(h.a, h.b, &c)) PushReady(h.a, h.b, c);
        },
        [this](const HeldEdges::Entry& h) { return Stale(h); });
  }
  const size_t chunk = release_.chunk(), n = release_.size();
  if (chunks > 1 && track_) {
    progress_done_.store(0, std::memory_order_relaxed);
    progress_total_.store(static_cast<int64_t>(n), std::memory_order_relaxed);
  }
  step_peak_bytes_ = chunks == 0 ? MemoryBytes() : 0;
  for (size_t g = 0; g < chunks; ++g) {
    release_.ForEachIn(g, [this](const WEdge& e) { AddToBatch(e.a, e.b, /*released=*/true); });
    FlushBatch();
    step_peak_bytes_ = std::max(step_peak_bytes_, MemoryBytes());
    if (chunks > 1) {
      chunk_base_ = static_cast<int64_t>(g * chunk);
      chunk_span_ = static_cast<int64_t>(std::min(n, (g + 1) * chunk) - g * chunk);
    }
    if (g + 1 < chunks) Simplify();
  }
  release_.Done();
}

void Simplifier::Contract(VertexId a, VertexId b, const Candidate& c) {
  // a survives as c; b's triangles move to a; the triangles on ab disappear.
  // The link condition passed: ab is in one or two triangles, or in a label session's
  // complex in up to kMaxEdgeTriangles.
  TriId on_ab[kMaxEdgeTriangles + 1];
  int n_ab = 0;
  for (TriId t : store_->vertex_triangles(a)) {
    const auto& tri = store_->triangle(t);
    on_ab[std::min(n_ab, kMaxEdgeTriangles)] = t;  // branch-free: which ones is unpredictable
    n_ab += static_cast<int>(tri[0] == b) + static_cast<int>(tri[1] == b) +
            static_cast<int>(tri[2] == b);
  }
  assert(n_ab >= 1 && n_ab <= (store_->labeled() ? kMaxEdgeTriangles : 2));
  for (int i = 0; i < n_ab; ++i) store_->RemoveTriangle(on_ab[i]);
  store_->MoveTriangles(b, a);
  store_->RemoveVertex(b);
  ++version_[b];
  quadrics_.Merge(a, b);  // before a moves
  store_->set_position(a, c.pos);
  store_->set_height(a, c.height);
  store_->set_layer(a, c.layer);
  store_->set_box_mask(a, c.box_mask);
  store_->set_rad(a, c.rad);
  ++version_[a];
  ++contractions_;
  // Recorded from the geometry, not from the release key, so a broken key shows up here.
  max_reach_over_front_ = std::max(max_reach_over_front_, c.height + c.rad - front_);
  max_layer_over_front_ = std::max(max_layer_over_front_, static_cast<double>(c.layer) - front_);
  if (in_pass_) {  // its edges are queued at the pass's end (FlushMarked)
    is_marked_[a] = 1;
    marked_.push_back(a);
    return;
  }
  // Re-evaluate the edges around c, in increasing neighbour id.
  ListNeighbours(a);
  std::vector<VertexId> nbrs;
  nbrs.swap(scratch_);
  for (VertexId x : nbrs) {  // their records are in cache: the checks read them
    PrefetchVertex(x);
    PrefetchQuadric(x);
  }
  for (VertexId x : nbrs) PushEdge(a, x);
  nbrs.swap(scratch_);
}

namespace {

// A fan of at most N triangles (N a multiple of 4) around a: its neighbours, each once, in
// increasing id, into out (2 N entries); returns how many. Each triangle read once, the next
// corners kept in a fixed array searched four at a time (CountOf), the list sorted on the stack.
template <size_t N>
size_t SortedNeighbours(const MeshStore& store, VertexId a, std::span<const TriId> fan,
                        VertexId* out) {
  VertexId next[N], prev[N];
  std::fill(next, next + N, kInvalid);
  const size_t n = fan.size();
  for (size_t i = 0; i < n; ++i) {
    const auto& tri = store.triangle(fan[i]);
    const int c = CornerOf(tri, a);
    next[i] = tri[kNextCorner[c]];
    prev[i] = tri[kPrevCorner[c]];
  }
  std::copy(next, next + n, out);
  size_t m = n;
  for (size_t i = 0; i < n; ++i) {  // no early exit: where it would leave is unpredictable
    out[m] = prev[i];
    m += static_cast<size_t>(CountOf(next, prev[i]) == 0);
  }
  for (size_t i = 1; i < m; ++i) {  // insertion sort: a fan's dozen at most
    const VertexId x = out[i];
    size_t j = i;
    for (; j > 0 && out[j - 1] > x; --j) out[j] = out[j - 1];
    out[j] = x;
  }
  size_t k = 0;  // each once (a vertex the next corner of two triangles: not a manifold)
  for (size_t i = 0; i < m; ++i) {
    out[k] = out[i];
    k += static_cast<size_t>(k == 0 || out[k - 1] != out[i]);
  }
  return k;
}

}  // namespace

void Simplifier::ListNeighbours(VertexId a) {
  // Each neighbour once before
  // sorting (sorting all corners, every neighbour twice, costs mispredicted branches): the
  // corner after a in each triangle covers a closed fan;
  // on the boundary one neighbour is only ever the corner before a.
  // A fan that fits (nearly all) keeps its next corners in a fixed array too, searched four
  // at a time (CountOf), of 8 entries where they fit (most fans on a dense surface).
  const auto fan = store_->vertex_triangles(a);
  if (fan.size() <= kFanMax) {
    VertexId out[2 * kFanMax];
    const size_t k = fan.size() <= 8 ? SortedNeighbours<8>(*store_, a, fan, out)
                                     : SortedNeighbours<kFanMax>(*store_, a, fan, out);
    scratch_.assign(out, out + k);
    return;
  }
  scratch_.clear();
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
}

void Simplifier::FlushMarked() {
  // A marked vertex is alive: its queued edges are stale, so no contraction took it since.
  for (size_t i = 0; i < marked_.size(); ++i) {
    if (i + 2 < marked_.size()) store_->PrefetchFan(marked_[i + 2]);
    const VertexId v = marked_[i];
    assert(store_->vertex_alive(v));
    ListNeighbours(v);
    for (VertexId x : scratch_) {
      PrefetchVertex(x);
      PrefetchQuadric(x);
    }
    // An edge between two marked vertices once (PushEdge reads no scratch_).
    for (VertexId x : scratch_) {
      if (is_marked_[x] == 0 || v < x) PushEdge(v, x);
    }
  }
  for (VertexId v : marked_) is_marked_[v] = 0;
  marked_.clear();
}

// A popped edge's candidate: placed now if a rise queued it unplaced, and at α > 0 evaluated
// again (the memoryless isotropy term depends on the current neighbourhood), pushed back if
// its cost grew since it was queued. False: not contracted now.
[[gnu::always_inline]] inline bool Simplifier::Reevaluate(const QNode& e, Candidate* c) {
  const double key = c->cost;
  if (std::isnan(c->eps0)) {  // queued unplaced by a rise (α = 0: the key is its cost)
    ++evaluations_;
    if (!Evaluate(e.a, e.b, c)) {
      ++refusals_.box;
      return false;
    }
  }
  if (opt_.alpha > 0.0) {
    ++evaluations_;
    if (!Evaluate(e.a, e.b, c)) {
      ++refusals_.box;
      return false;
    }
    if (c->cost > key * (1.0 + 1e-12) + 1e-300) {
      PushQ(e.a, e.b, *c);
      return false;
    }
  }
  return true;
}

void Simplifier::Simplify(int64_t target_triangles, bool past_error) {
  const bool to_target = target_triangles > 0;
  const auto stale = [this](const QNode& n) { return Stale(n); };
  if (track_) TrackStart();
  uint32_t pops = 0;  // (a local: a register, where a member would be stored every pop)
  // Passes for the lock-step's SIMPLIFY(E0) only: a target, a pass past E0 and classical (the
  // cost order the lock-step is measured against) keep the exact order.
  in_pass_ = opt_.passes && !to_target && !past_error && opt_.release != ReleaseRule::kImmediate;
  if (in_pass_ && is_marked_.size() < store_->vertex_capacity()) {
    is_marked_.resize(store_->vertex_capacity());
  }
  // A refused edge is pushed again when a contraction at one of its ends changes it; with
  // rises it is listed as well (RiseLists), to be offered again at a rise of E0.
  while (!q_.empty() || !marked_.empty()) {
    if ((++pops & (kCheckEvery - 1)) == 0) {
      Checkpoint();  // contractions queue new edges
      if (track_) TrackAt(q_.current_bucket());
    }
    if (to_target && static_cast<int64_t>(store_->num_triangles()) <= target_triangles) break;
    const QNode* top = q_.TopLive(stale);  // pop: MinCost(Q) <= E0
    if (top == nullptr || (!past_error && top->key > opt_.error)) {
      if (marked_.empty()) break;
      FlushMarked();  // the last pass's survivors may have edges within E0
      continue;
    }
    const double key = top->key;
    const QNode e = q_.Pop();
    const QNode* next = q_.Next();
    const QNode ahead = next != nullptr ? *next : QNode{};
    if (next != nullptr) next = &ahead;  // Q's node may move as contractions push
    PrefetchAhead(next, Ahead::kRecords);
    if (Stale(e)) continue;  // stale: an end was contracted or moved since
    PrefetchEnds(e);
    const QPlacement& placement = q_.Placement(e);
    Candidate c{.pos = placement.pos, .cost = key, .eps0 = placement.eps0};
    if (!Reevaluate(e, &c)) continue;
    if (!past_error && c.eps0 > opt_.error) {
      ++refusals_.error;  // conservative rule: ε_α <= E0 but ε0 > E0
      rises_.List(e.a, e.b, c.eps0);
      continue;
    }
    PrefetchAhead(next, Ahead::kStars);
    if (!LinkCondition(*store_, e.a, e.b, &link_scratch_)) {
      ++refusals_.link;
      rises_.Refused(e.a, e.b, e.va, e.vb);
      continue;
    }
    PrefetchApexes(e);
    // Past E0 the guard (a multiple of E0) would stall.
    const double guard = past_error ? 0.0 : opt_.distance_guard * opt_.error;
    if (!GeometryOk(*store_, e.a, e.b, c.pos, guard, opt_.offset_edges, &survivors_, &refusals_)) {
      // Offered at the next rise; at α = 0 with its key, which is its cost.
      rises_.List(e.a, e.b, opt_.alpha > 0.0 ? opt_.error : key);
      continue;
    }
    c.box_mask = store_->box_mask(e.a) | store_->box_mask(e.b);
    ReleaseKey(e.a, e.b, &c);  // height, rad, layer of the new vertex
    Contract(e.a, e.b, c);
    PrefetchAhead(next, Ahead::kFans);
  }
  in_pass_ = false;
  if (track_) TrackAt(EdgeQueue::kBuckets);
  if (q_.empty()) q_.Trim();
  // Kept edges (keep > 1) stay queued past SIMPLIFY, and most go stale as their neighbours
  // contract: when they outnumber the mesh's edges (about 1.5 per triangle), Q keeps the
  // live ones only.
  if (q_.size() > 3 * store_->num_triangles() + 1024) Rebucket(opt_.error);
  rises_.SweepBeyond(3 * store_->num_triangles() + 1024);
  if (chunk_span_ != 0) release_.Sweep(&w_);  // a chunk's: W and the chunks to come
  chunk_base_ = chunk_span_ = 0;
}

void Simplifier::Rebucket(double max_key) {
  // Its buckets are spaced below E0.
  q_ = q_.Rebuilt(max_key, [this](const QNode& n) { return !Stale(n); }, [](auto&&) {});
}

size_t Simplifier::VertexBytes() { return QuadricStore::VertexBytes() + sizeof(uint32_t); }

size_t Simplifier::MemoryBytes() const {
  return quadrics_.MemoryBytes() +
         version_.MemoryBytes() + link_scratch_.MemoryBytes() + q_.MemoryBytes() +
         w_.MemoryBytes() + scratch_.capacity() * sizeof(VertexId) +
         marked_.capacity() * sizeof(VertexId) + is_marked_.capacity() +
         survivors_.capacity() * sizeof(Survivor) + sag_scratch_.MemoryBytes() +
         batch_.capacity() * sizeof(BatchEdge) + batch_results_.capacity() * sizeof(BatchResult) +
         release_.MemoryBytes() + rises_.MemoryBytes() + held_.MemoryBytes();
}

}  // namespace tandem
