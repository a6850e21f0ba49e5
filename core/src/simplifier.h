// Simplifier: the edge-contraction engine shared by the three schedules (paper §2, "Surface
// simplification", and §3, "Algorithm prototype" and "Time-lag").
//
// Candidate edges wait in W (edge_queues.h) until the front passes their release key (the
// candidate's reach for tandem-lag, its layer + 1 for tandem without lag), then go to Q,
// ordered by cost ε_α. An entry carries the version stamps of its two vertices; a vertex's
// stamp changes when it is contracted, so stale entries are recognised by integers, never by
// comparing costs. Costs are recomputed when an entry is popped (a vertex's quadric keeps
// growing until the layer above it is extracted, and the memoryless isotropy term depends on
// the current neighbourhood), and an entry whose cost went up is pushed back. A popped edge
// is contracted if it passes the checks of contraction_checks.h.
//
// The schedule (schedule.cc) calls: AddTriangles (after EXTRACT), Delay (new edges into W),
// Activate(front) (W -> Q for keys <= front, a large release a chunk at a time), Simplify
// (contract while MinCost <= E0).
#ifndef TANDEM_SIMPLIFIER_H_
#define TANDEM_SIMPLIFIER_H_

#include <algorithm>
#include <atomic>
#include <cassert>
#include <cstdint>
#include <functional>
#include <limits>
#include <span>
#include <vector>

#include "chunked_release.h"
#include "contraction_checks.h"
#include "degenerate.h"
#include "edge_queues.h"
#include "held_edges.h"
#include "mesh_store.h"
#include "part_ids.h"
#include "quadric_store.h"
#include "rise_lists.h"
#include "sag_correction.h"
#include "simplifier_options.h"
#include "tandem/executor.h"
#include "tandem/geometry.h"
#include "tandem/stats.h"
#include "tandem/types.h"

namespace tandem {

class Simplifier {
 public:
  Simplifier(MeshStore* store, const SimplifierOptions& options);

  // Accumulates the plane quadrics of new triangles into their vertices (a vertex on slice
  // k is complete once layer k+1 is in; quadric_store.h) and registers new vertices (rad = 1).
  void AddTriangles(std::span<const TriId> tris, std::span<const VertexId> new_verts);
  // DELAY: puts the edges of these triangles into W (or Q for kImmediate), each edge once.
  // With the tandem release rules, `tris` must be one new layer (the schedules' DELAY(k)):
  // its edges on the plane below were queued with the layer underneath and are not again.
  // `layer_edges` (LayerExtractor::CommitLayer's, one per triangle) says which edges those
  // are, and in a label layer which triangle queues each (its edges between two older
  // vertices are still found in the store); without it they are found in the store.
  void Delay(std::span<const TriId> tris, std::span<const uint8_t> layer_edges = {});
  // ACTIVATE(front): the entries of W whose key is <= front (+inf for ACTIVATE(∞)) are
  // evaluated into Q in W's order. A release of more than release_chunk edges enters Q a
  // chunk at a time (chunked_release.h), each chunk simplified before the next is evaluated,
  // and its last chunk is left in Q for the SIMPLIFY that follows: Q holds a chunk, not the
  // release (a closed volume's cap releases a whole layer at once; docs/decisions.md 8).
  void Activate(double front);
  // SIMPLIFY(E0): contracts while Q's minimum cost <= E0, and with target_triangles > 0
  // while more than that many triangles remain. past_error: in cost order beyond E0, without
  // the distance guard (a multiple of E0, it would stall there), down to target_triangles
  // (call RequeueAll first).
  void Simplify(int64_t target_triangles = 0, bool past_error = false);
  // Puts every edge of the current mesh into Q, including those costing more than E0
  // (which Q otherwise drops), for a final pass past E0 down to a target triangle count.
  void RequeueAll();
  // Queues every edge at the given vertices (once each), as DELAY does: the seam of merged
  // slabs, whose edges waited for the merge (kSeam).
  void PushEdgesAround(std::span<const VertexId> verts);
  // E0 as it is now (SimplifierOptions::error, or what RaiseError made it).
  double error() const { return opt_.error; }
  // Raises E0 to `e` (>= error()) between SIMPLIFY steps, for a target triangle count
  // (schedule.h; simplifier_rises.cc): Q is re-bucketed for the new E0 and offered what e
  // brings within reach, the listed edges (rise_lists.h) or, without lists, every released
  // edge of the mesh once e reaches an edge Q dropped.
  void RaiseError(double e);
  // After SIMPLIFY(E0): about the least cost above E0 among the mesh's edges (the least
  // queued or dropped since Q last held every released edge; +inf if none): raising E0 to
  // less contracts nothing.
  double NextCost();
  // Sets E0 to e <= error() once no SIMPLIFY follows: the bound the sag correction and the
  // tidying keep to, and what the session reports as reached.
  void LowerErrorAfterSimplify(double e) {
    assert(e <= opt_.error);
    opt_.error = e;
  }

  // Error(K) = max ε0 over live vertices, as MeasuredShapeError measures it (rounding noise
  // is not error).
  double MaxShapeError() const;
  // Sag correction (sag_correction.h) of every live vertex with the current quadrics.
  // Returns the number of vertices moved. Run it once, on the final mesh; with an executor,
  // its normals and steps in ranges side by side (the same result).
  int64_t CorrectSag(double fraction, Executor* executor = nullptr);
  // Mends the zero-area triangles of the final mesh (degenerate.h): flips, and moves within
  // the error bound (ε0 <= max(E0, ε0 now)).
  DegenerateCounts TidyDegenerate();

  size_t MemoryBytes() const;
  // What AddTriangles adds for a new vertex id (its planes' matrix and stamp).
  static size_t VertexBytes();
  // Called where the simplifier's memory grows and where long work may stop: after each
  // batch of edges is queued (DELAY, each chunk of a release, a rise) and every
  // kCheckEvery edges SIMPLIFY pops. The owner reports to its budget there (meter.h); a
  // SessionStop it throws leaves the simplifier fit only to be destroyed.
  void set_checkpoint(std::function<void()> f) { checkpoint_ = std::move(f); }
  // CPU seconds the work handed to an executor (the batch evaluations on `parallel`, the sag
  // correction's ranges) took on other threads since the last call (the phase times count
  // them with the calling thread's own).
  double TakeHelperSeconds() {
    const double s = helper_seconds_;
    helper_seconds_ = 0;
    return s;
  }

 private:
  // Reached through simplifier_access.h only: the sealer's (SimplifierSealAccess), the slabs'
  // merge and seam (SimplifierSeamAccess) and the counters a session reports
  // (SimplifierProbe).
  friend struct SimplifierSealAccess;
  friend struct SimplifierSeamAccess;
  friend struct SimplifierProbe;
  friend struct SimplifierEvaluation;  // Evaluate's body in CPU-dispatched clones (simplifier.cc)

  // Split sessions (tandem.h) merge their parts into one: after the session has copied a
  // vertex `src` of another part's store into this one's as `dst`, AdoptVertex takes over its
  // quadric and radius (`shared`: dst is the seam vertex both parts held; the quadrics add).
  // AdoptCounters adds the other part's contraction and refusal counts; the schedule queues
  // queues the seam's edges (PushEdgesAround). With SimplifierOptions::rises, AdoptQueues
  // then takes over the other part's queued and listed edges (map: its vertex ids to this
  // store's), so that E0 can rise on past the merge without evaluating every edge of the
  // merged mesh again (its W is empty after ACTIVATE(∞); no entry is at a seam vertex: those
  // edges were pinned).
  void AdoptVertex(const Simplifier& from, PartVertex src, VertexId dst, bool shared);
  void AdoptQueues(const Simplifier& from, const PartVertexMap& map);
  void AdoptCounters(const Simplifier& from);

  // TidyDegenerate's inflation size (a tenth of E0, at most a twentieth of a slice), for the
  // seam's mend.
  double TidySize() const;
  // Seam coarsening (slabs.h, CoarsenSettlingSeam): the plane quadric of v (this side's
  // triangles), the distance guard's bound K·E0, and a contraction ab -> pos decided outside
  // (both slabs contract their copies of one seam edge to one point): a survives, as Simplify
  // would contract it, without the checks, which the caller made (`onto_a`: a keeps its
  // height, radius and layer, as its other copy does).
  Quadric quadric(VertexId v) const { return quadrics_.Get(v); }
  // Before v moves outside the simplifier (a seam's mend): its quadric in full, as it is.
  void KeepQuadric(VertexId v) {
    EnsureVertexCapacity();
    quadrics_.Keep(v);
  }
  // v left the store outside the simplifier (sealing).
  void DropQuadric(VertexId v) { quadrics_.Drop(v); }
  // SimplifierOptions::check_quadrics: quadrics read that differ from the full sums kept
  // alongside (a vertex moved without Keep).
  int64_t quadric_mismatches() const { return quadrics_.mismatches(); }
  double distance_bound() const { return opt_.distance_guard * opt_.error; }
  // SIMPLIFY's checks for ab -> pos (the link condition, then the geometry checks with the
  // distance guard's bound `guard`), refusals not counted: the caller decides for a pair.
  bool MayContract(VertexId a, VertexId b, Vec3 pos, double guard);
  void ContractAt(VertexId a, VertexId b, Vec3 pos, double eps0, bool onto_a);

  // Sealing (sealer.h). CorrectSag for the vertices `verts` only (sealing moves each vertex
  // once, as it freezes): normal[v] must hold the unit normal of every vertex of their triangles
  // (VertexNormals).
  int64_t CorrectSagAt(std::span<const VertexId> verts, VertexNormalTable normal,
                       double fraction, Executor* executor = nullptr);
  // TidyDegenerate among `tris` (a sealed chunk's, as it is sealed): frozen vertices may move too,
  // where `movable` (the sealer: not handed out yet) and the error bound allow. Without
  // `flips`, corners move only (tris the simplifier still works on).
  DegenerateCounts TidyDegenerateAmong(std::span<const TriId> tris,
                                       const std::function<bool(VertexId)>& movable,
                                       bool flips = true);
  // Area-weighted unit vertex normals of `verts` from their current triangles, into normal[v].
  void VertexNormals(std::span<const VertexId> verts, std::span<Vec3> normal);

  // A frozen vertex (kFrozen) is never contracted, moved or queued again;
  // entries already queued at it go stale.
  void Freeze(VertexId v);
  double rad(VertexId v) const { return store_->rad(v); }
  // Whether v's reach and that of every contraction of v with a neighbour, height(c) + rad(c)
  // (ReleaseKey), are <= limit: once the front has passed them, every edge at v has been
  // offered to Q. Stops at the first beyond, and skips the length where the rest is beyond.
  bool EdgesReachAtMost(VertexId v, double limit) const;
  // ε0 of v at its current position, as Error(K) measures it (MeasuredShapeError).
  double MeasuredShapeErrorAt(VertexId v) const;

  // The counters a session reports (SimplifierProbe).
  const RefusalCounts& refusals() const { return refusals_; }
  int64_t contractions() const { return contractions_; }
  // Edge evaluations (quadric solves) so far: what RaiseError's re-offers save is seen here.
  int64_t evaluations() const { return evaluations_; }
  // Entries pushed into Q and into W so far (most Q entries are popped stale).
  int64_t q_pushes() const { return q_pushes_; }
  int64_t w_pushes() const { return w_pushes_; }
  // Edges a chunked release held back for a later chunk (an end not ready yet) so far: the
  // chunks' borders, which compact chunks keep short (SimplifierOptions::tile_x).
  int64_t deferred_edges() const { return release_.deferred(); }
  // Over the contractions applied: the largest reach(c) - front (<= 0: none ran ahead of the
  // front, the time-lag rule) and the largest layer(c) - front (<= -1: the newest layer was
  // never touched). -inf when none was applied.
  double max_reach_over_front() const { return max_reach_over_front_; }
  double max_layer_over_front() const { return max_layer_over_front_; }
  size_t queue_sizes() const { return q_.size() + w_.size(); }
  // MemoryBytes as the last ACTIVATE left it (the largest over its
  // chunks): the fullest moment of a step, Q holding every edge it released, which SIMPLIFY
  // empties and Trim frees before the step ends.
  size_t StepPeakBytes() const { return step_peak_bytes_; }
  // How far the SIMPLIFY running now has come, for a status line read on another thread:
  // with tracking on, each SIMPLIFY counts its Q's nodes by key bucket as it starts (total)
  // and, every kCheckEvery pops, those in the buckets below the one it pops from (done): the
  // share of the queue it began with that lies behind it (new edges a contraction queues
  // are not counted).
  void TrackProgress(bool on) { track_ = on; }
  int64_t progress_done() const { return progress_done_.load(std::memory_order_relaxed); }
  int64_t progress_total() const { return progress_total_.load(std::memory_order_relaxed); }

  static constexpr uint32_t kCheckEvery = 4096;  // a power of two
  // ε0 of v at its current position.
  double ShapeErrorAt(VertexId v) const;
  struct Candidate {  // the evaluation of a contraction ab -> c
    Vec3 pos;
    double cost = 0;   // ε_α(c)
    double eps0 = 0;   // ε0(c)
    double height = 0, rad = 0;  // of the new vertex (ReleaseKey fills them)
    int32_t layer = 0;
    uint8_t box_mask = 0;
  };

  void EnsureVertexCapacity();
  bool Evaluate(VertexId a, VertexId b, Candidate* c);  // false: box refusal
  // Evaluate's edges on the box or with α > 0 (out of line: the common case stays short).
  [[gnu::noinline]] bool EvaluateBoxedOrIsotropic(VertexId a, VertexId b, const PackedQuadric& h,
                                                  Candidate* c);
  // Release key from the cheap bookkeeping only (no quadric solve); fills height/rad/layer.
  inline double ReleaseKey(VertexId a, VertexId b, Candidate* c) const;  // (below the class)
  // Whether TidyDegenerate may move v to p (the error bound).
  bool TidyMayMove(VertexId v, Vec3 p) const;
  void PushEdge(VertexId a, VertexId b);  // evaluates, then to Q or W by key vs front
  void PushQ(VertexId a, VertexId b, const Candidate& c);
  // The late lag (SimplifierOptions::late_lag): holds an evaluated edge back (true) while
  // the front is short of its late key. Cheapest test first: most edges cost at most
  // late_share x E0, and most of the rest lie on narrow patches.
  bool Hold(VertexId a, VertexId b, const Candidate& c) {
    return opt_.late_lag > 0 && c.cost > opt_.late_share * opt_.error &&
           c.cost <= opt_.keep * opt_.error && HoldWide(a, b);
  }
  bool HoldWide(VertexId a, VertexId b);
  // PushQ, unless an end is not ready in a chunked release (Activate): then the
  // edge waits for that end's chunk.
  void PushReady(VertexId a, VertexId b, const Candidate& c) {
    if (!release_.Defer(a, b)) PushQ(a, b, c);
  }
  // Each edge of t once (see Delay), into batch_. new_layer: t belongs to the layer being
  // delayed, whose edges on the plane below were queued with the layer underneath.
  void PushTriangleEdges(TriId t, bool new_layer);
  void PushComplexTriangleEdges(TriId t, bool new_layer);  // the same in a label session
  // In a label session: edge ab of t is queued from another of its triangles (see Delay).
  bool QueuedElsewhere(TriId t, VertexId a, VertexId b, bool new_layer, int32_t layer) const;
  // The latest layer among t's corners.
  int32_t LayerOf(TriId t) const;
  bool HasHalfEdge(VertexId a, VertexId b) const;  // some triangle traverses a -> b
  // Batches: PushEdge's work for many edges, the pure part (release key, quadric solve)
  // possibly on two threads, then the pushes in batch order.
  void AddToBatch(VertexId a, VertexId b, bool released = false);  // FlushBatch at kMaxBatch
  void EvaluateBatchRange(size_t begin, size_t end);
  void FlushBatch();
  static constexpr size_t kMaxBatch = 16384;
  // A vertex's stamp changes whenever it is contracted away, moved, or its id is handed to a
  // new vertex (AddTriangles, AdoptVertex), and entries are made for live vertices only, so
  // matching stamps mean both ends are alive: the store's flags need not be read.
  template <typename E>
  bool Stale(const E& e) const {
    const bool stale = ((version_[e.a] ^ e.va) | (version_[e.b] ^ e.vb)) != 0;
    assert(stale || (store_->vertex_alive(e.a) && store_->vertex_alive(e.b)));
    return stale;
  }
  // Edges at a seam vertex wait for the merge (kSeam, mesh_store.h), edges at a frozen
  // vertex wait for nothing: neither is ever queued.
  bool Pinned(VertexId a, VertexId b) const {
    return ((store_->box_mask(a) | store_->box_mask(b)) & (kSeam | kFrozen)) != 0;
  }
  bool Reevaluate(const QNode& e, Candidate* c);  // SIMPLIFY's, for a popped edge
  void Contract(VertexId a, VertexId b, const Candidate& c);
  // a's neighbours into scratch_, each once, in increasing id.
  void ListNeighbours(VertexId a);
  // A pass's end (SimplifierOptions::passes): the marked survivors' edges to PushEdge, each
  // once; the marks cleared.
  void FlushMarked();
  // Q again for E0 = max_key, its live entries only (in no particular order: ties may pop
  // differently).
  void Rebucket(double max_key);
  // Prefetching: what the loops read next, a cache miss at a random id each, started early.
  // Loops over known edges or triangles start loading the records of the one kAhead places on.
  static constexpr size_t kAhead = 8;
  // What an evaluation reads of v: its store record; then, once the record is in (it holds
  // the slot), its planes' matrix and the rest of a quadric kept in full.
  void PrefetchVertex(VertexId v) const { store_->Prefetch(v); }
  void PrefetchQuadric(VertexId v) const { quadrics_.Prefetch(v); }
  // SIMPLIFY's next edge (null: none), a stage at a time as each one's address arrives: its
  // stamps, placement and end records as this edge is popped, its ends' star lists before
  // this edge's link condition, their triangles after this edge's contraction.
  enum class Ahead { kRecords, kStars, kFans };
  [[gnu::always_inline]] void PrefetchAhead(const QNode* next, Ahead stage) const {
    if (next == nullptr) return;
    switch (stage) {
      case Ahead::kRecords:
        __builtin_prefetch(&version_[next->a]);
        __builtin_prefetch(&version_[next->b]);
        __builtin_prefetch(&q_.Placement(*next));
        store_->Prefetch(next->a);
        store_->Prefetch(next->b);
        return;
      case Ahead::kStars:
        store_->PrefetchStar(next->a);
        store_->PrefetchStar(next->b);
        return;
      case Ahead::kFans:  // a dead end's list is empty
        store_->PrefetchFan(next->a);
        store_->PrefetchFan(next->b);
        return;
    }
  }
  // A live popped edge: its ends' star lists (in case it came to the top unforeseen), and
  // what Contract reads after the checks, the records (started an edge ago) and quadrics.
  [[gnu::always_inline]] void PrefetchEnds(const QNode& e) const {
    store_->PrefetchStar(e.a);
    store_->PrefetchStar(e.b);
    PrefetchVertex(e.a);
    PrefetchVertex(e.b);
    PrefetchQuadric(e.a);
    PrefetchQuadric(e.b);
  }
  // The apexes' star lists, which Contract searches to unlink the triangles on ab (their
  // records are in cache: the link condition prefetched every fan corner's).
  [[gnu::always_inline]] void PrefetchApexes(const QNode& e) const {
    for (TriId t : store_->vertex_triangles(e.a)) {
      const auto& tri = store_->triangle(t);
      if (tri[0] == e.b || tri[1] == e.b || tri[2] == e.b) {
        store_->PrefetchStar(tri[0] ^ tri[1] ^ tri[2] ^ e.a ^ e.b);
      }
    }
  }

  MeshStore* store_;
  SimplifierOptions opt_;
  double front_ = -std::numeric_limits<double>::infinity();

  QuadricStore quadrics_;  // H_u of every vertex (AddTriangles, Contract)
  // A vertex's stamp (see Stale), apart: a queued entry's check reads only these, 16 to a
  // cache line, and most popped entries are stale.
  PodArray<uint32_t> version_;

  EdgeQueue q_;
  size_t step_peak_bytes_ = 0;  // StepPeakBytes
  bool keep_expensive_ = false;  // RequeueAll: also queue edges costing more than E0
  bool requeue_released_ = false;  // RaiseError: edges for W are in W already
  // Edges dropped or refused, for a rise of E0 (RaiseError), and the cheapest dropped.
  RiseLists rises_;
  // A rise queues a listed edge without its placement (RaiseError): marked by a NaN ε0.
  static constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  static constexpr Vec3 kUnplaced{kNaN, kNaN, kNaN};
  WaitingQueue w_;
  HeldEdges held_;  // the late lag's, re-evaluated as the front reaches them
  ChunkedRelease release_;  // ACTIVATE of a large release, a chunk at a time
  std::vector<VertexId> scratch_;
  LinkScratch link_scratch_;
  std::vector<Survivor> survivors_;  // GeometryOk's scratch
  SagScratch sag_scratch_;
  std::vector<Quadric> sag_quadrics_;  // CorrectSagAt: the quadrics of its verts
  std::vector<VertexId> sag_moved_;
  struct BatchEdge {
    VertexId a, b;  // a < b
    bool released;  // from W by ACTIVATE: its release key is known to be <= the front
  };
  struct BatchResult {
    Candidate c;
    double key;
    uint8_t to;  // 0: W (key > front), 1: Q, 2: refused (box)
  };
  std::vector<BatchEdge> batch_;
  std::vector<BatchResult> batch_results_;
  // A SIMPLIFY in passes: Contract marks its survivor (its edges in Q are stale, so it takes
  // no part in another contraction until FlushMarked queues them).
  bool in_pass_ = false;
  std::vector<VertexId> marked_;
  std::vector<uint8_t> is_marked_;  // by vertex id
  double helper_seconds_ = 0;  // TakeHelperSeconds; written by a helper before Wait returns
  RefusalCounts refusals_;
  int64_t contractions_ = 0;
  int64_t evaluations_ = 0;
  int64_t q_pushes_ = 0, w_pushes_ = 0;
  double max_reach_over_front_ = -std::numeric_limits<double>::infinity();
  double max_layer_over_front_ = -std::numeric_limits<double>::infinity();
  std::function<void()> checkpoint_;
  void Checkpoint() {
    if (checkpoint_) checkpoint_();
  }
  bool track_ = false;
  std::vector<int64_t> below_;  // tracking: nodes in the buckets below each, at the start
  std::atomic<int64_t> progress_done_{0}, progress_total_{0};
  // A release in chunks (Activate) counts in released edges: each chunk's
  // SIMPLIFY covers [chunk_base_, chunk_base_ + chunk_span_) of them; 0: not chunked.
  int64_t chunk_base_ = 0, chunk_span_ = 0;
  void TrackStart();
  void TrackAt(size_t bucket);
};

// Inline: every edge that enters W or Q takes one, from three files.
inline double Simplifier::ReleaseKey(VertexId a, VertexId b, Candidate* c) const {
  // The paper's time-lag bookkeeping: height(c) = (height(a) + height(b)) / 2 and
  // rad(c) = (|a - b| + rad(a) + rad(b)) / 2, lengths in slice units.
  c->height = 0.5 * (store_->height(a) + store_->height(b));
  c->rad = 0.5 * (Norm(store_->position(a) - store_->position(b)) / opt_.slice_spacing +
                  store_->rad(a) + store_->rad(b));
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

}  // namespace tandem

#endif  // TANDEM_SIMPLIFIER_H_
