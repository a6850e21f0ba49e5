// The narrow doors into the Simplifier for the units beside the paper's engine (simplifier.h
// holds DELAY, ACTIVATE, SIMPLIFY and the final passes): each struct names its caller and
// forwards to the private members it may use, so the engine's public surface stays the paper's.
#ifndef TANDEM_SIMPLIFIER_ACCESS_H_
#define TANDEM_SIMPLIFIER_ACCESS_H_

#include <cstdint>
#include <functional>
#include <span>

#include "simplifier.h"

namespace tandem {

// The sealer (sealer.h): freezing vertices whose edges the front has passed, and the sag
// correction and tidying of a chunk as it is sealed.
struct SimplifierSealAccess {
  static void Freeze(Simplifier& s, VertexId v) { s.Freeze(v); }
  static void DropQuadric(Simplifier& s, VertexId v) { s.DropQuadric(v); }
  static double rad(const Simplifier& s, VertexId v) { return s.rad(v); }
  static bool EdgesReachAtMost(const Simplifier& s, VertexId v, double limit) {
    return s.EdgesReachAtMost(v, limit);
  }
  static double MeasuredShapeErrorAt(const Simplifier& s, VertexId v) {
    return s.MeasuredShapeErrorAt(v);
  }
  static int64_t CorrectSagAt(Simplifier& s, std::span<const VertexId> verts,
                              VertexNormalTable normal, double fraction,
                              Executor* executor = nullptr) {
    return s.CorrectSagAt(verts, normal, fraction, executor);
  }
  static DegenerateCounts TidyDegenerateAmong(Simplifier& s, std::span<const TriId> tris,
                                              const std::function<bool(VertexId)>& movable,
                                              bool flips = true) {
    return s.TidyDegenerateAmong(tris, movable, flips);
  }
  static void VertexNormals(Simplifier& s, std::span<const VertexId> verts,
                            std::span<Vec3> normal) {
    s.VertexNormals(verts, normal);
  }
};

// The slabs (slabs.h): merging a part into its neighbour, and coarsening and mending the seam
// between two slabs through the engine's one rule set (MayContract, ContractAt).
struct SimplifierSeamAccess {
  static void AdoptVertex(Simplifier& s, const Simplifier& from, PartVertex src, VertexId dst,
                          bool shared) {
    s.AdoptVertex(from, src, dst, shared);
  }
  static void AdoptQueues(Simplifier& s, const Simplifier& from, const PartVertexMap& map) {
    s.AdoptQueues(from, map);
  }
  static void AdoptCounters(Simplifier& s, const Simplifier& from) { s.AdoptCounters(from); }
  static Quadric quadric(const Simplifier& s, VertexId v) { return s.quadric(v); }
  static void KeepQuadric(Simplifier& s, VertexId v) { s.KeepQuadric(v); }
  static double distance_bound(const Simplifier& s) { return s.distance_bound(); }
  static double TidySize(const Simplifier& s) { return s.TidySize(); }
  static bool MayContract(Simplifier& s, VertexId a, VertexId b, Vec3 pos, double guard) {
    return s.MayContract(a, b, pos, guard);
  }
  static void ContractAt(Simplifier& s, VertexId a, VertexId b, Vec3 pos, double eps0,
                         bool onto_a) {
    s.ContractAt(a, b, pos, eps0, onto_a);
  }
};

// Introspection (session_impl.cc's stats and progress line, and the tests): the counters and
// sizes the engine keeps about its own work.
struct SimplifierProbe {
  static const RefusalCounts& refusals(const Simplifier& s) { return s.refusals(); }
  static int64_t contractions(const Simplifier& s) { return s.contractions(); }
  static int64_t evaluations(const Simplifier& s) { return s.evaluations(); }
  static int64_t q_pushes(const Simplifier& s) { return s.q_pushes(); }
  static int64_t w_pushes(const Simplifier& s) { return s.w_pushes(); }
  static int64_t deferred_edges(const Simplifier& s) { return s.deferred_edges(); }
  static double max_reach_over_front(const Simplifier& s) { return s.max_reach_over_front(); }
  static double max_layer_over_front(const Simplifier& s) { return s.max_layer_over_front(); }
  static size_t queue_sizes(const Simplifier& s) { return s.queue_sizes(); }
  static int64_t quadric_mismatches(const Simplifier& s) { return s.quadric_mismatches(); }
  static size_t StepPeakBytes(const Simplifier& s) { return s.StepPeakBytes(); }
  static void TrackProgress(Simplifier& s, bool on) { s.TrackProgress(on); }
  static int64_t progress_done(const Simplifier& s) { return s.progress_done(); }
  static int64_t progress_total(const Simplifier& s) { return s.progress_total(); }
  static Quadric quadric(const Simplifier& s, VertexId v) { return s.quadric(v); }
  // Simplifier::Evaluate called from another file, as the batch evaluation calls it: edge ab's
  // placement, cost and ε0; false where it refuses the edge (ends on different box faces).
  static bool Evaluate(Simplifier& s, VertexId a, VertexId b, Vec3* pos, double* cost,
                       double* eps0) {
    Simplifier::Candidate c;
    if (!s.Evaluate(a, b, &c)) return false;
    *pos = c.pos, *cost = c.cost, *eps0 = c.eps0;
    return true;
  }
};

}  // namespace tandem

#endif  // TANDEM_SIMPLIFIER_ACCESS_H_
