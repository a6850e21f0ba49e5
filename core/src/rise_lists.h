// RiseLists: the edges a run toward a target triangle count sets aside for a later rise of E0
// (Simplifier::RaiseError), so that a rise re-offers them instead of evaluating the whole mesh.
#ifndef TANDEM_RISE_LISTS_H_
#define TANDEM_RISE_LISTS_H_

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "edge_queues.h"
#include "mesh_store.h"
#include "part_ids.h"
#include "pod_array.h"
#include "tandem/types.h"

namespace tandem {

// An edge dropped by Q (its cost above keep x E0) or refused by the geometry checks, with
// the least E0 at which it is worth offering again: its cost, its ε0, or (refused) its key at
// α = 0, E0 otherwise, either way the next rise. 24 bytes: at α = 0 the cost is what an
// evaluation would give, and the placement is solved when Q pops the edge (docs/decisions.md).
struct DroppedEdge {
  double cost;
  VertexId a, b;
  uint32_t va, vb;  // version stamps
};
static_assert(sizeof(DroppedEdge) == 24);

// An edge the link condition refused, with its ends' star stamps (MeshStore::star_stamp): the
// condition reads only the two stars, so it is offered again only once a star has changed.
struct RefusedEdge {
  VertexId a, b;
  uint32_t va, vb;  // version stamps
  uint32_t sa, sb;  // star stamps
};
static_assert(sizeof(RefusedEdge) == 24);

class RiseLists {
 public:
  // `version`: the simplifier's vertex stamps (an entry whose stamps differ is stale);
  // `listing`: E0 will rise (SimplifierOptions::rises), so edges are listed; without it only
  // the cheapest dropped cost is kept.
  RiseLists(const MeshStore* store, const PodArray<uint32_t>* version, bool listing)
      : store_(store), version_(version), listing_(listing) {}
  bool listing() const { return listing_; }

  template <typename E>
  bool Stale(const E& e) const {
    return (((*version_)[e.a] ^ e.va) | ((*version_)[e.b] ^ e.vb)) != 0;
  }
  // Q dropped ab at `cost` (above keep x E0).
  void Dropped(VertexId a, VertexId b, double cost) {
    min_dropped_ = std::min(min_dropped_, cost);
    List(a, b, cost);
  }
  // SIMPLIFY refused ab (ε0 above E0, or the geometry checks): offered at a rise to `cost`.
  void List(VertexId a, VertexId b, double cost) {
    if (listing_) dropped_.push_back(DroppedEdge{cost, a, b, (*version_)[a], (*version_)[b]});
  }
  // The link condition refused ab (stamps va, vb as queued).
  void Refused(VertexId a, VertexId b, uint32_t va, uint32_t vb) {
    if (listing_) {
      refused_.push_back(RefusedEdge{a, b, va, vb, store_->star_stamp(a), store_->star_stamp(b)});
    }
  }
  // The cheapest cost dropped since Q last held every released edge (+inf: none).
  double min_dropped() const { return min_dropped_; }
  void ForgetDropped() { min_dropped_ = std::numeric_limits<double>::infinity(); }

  // A rise of E0 to e (listing): the live listed edges costing at most `reach`, then the link
  // refusals one of whose stars changed (cost e), leave the lists for offers(); returns how
  // many offers came from the dropped list. The rest stay, stale ones swept out.
  size_t Offer(double e, double reach);
  const std::vector<DroppedEdge>& offers() const { return offered_; }

  // After SIMPLIFY(E0): about the least cost above E0 among the mesh's edges: the least live
  // one in q (stale nodes on top are popped, as SIMPLIFY would skip them) or dropped.
  double NextCost(EdgeQueue* q) const {
    const auto stale = [this](const QNode& n) { return Stale(n); };
    for (;;) {
      const QNode* top = q->TopLive(stale);
      if (top == nullptr) return min_dropped_;
      if (!Stale(*top)) return std::min(min_dropped_, top->key);
      q->Pop();
    }
  }
  // Stale entries go once a list holds more than `limit` (about the mesh's edges).
  void SweepBeyond(size_t limit);
  // A slab merge: the other lists' live edges, ends mapped to this store's ids (`map`), stamps
  // of this one; its link refusals are listed at `error` (the merged stars are new).
  void Adopt(const RiseLists& from, const PartVertexMap& map, double error);
  size_t MemoryBytes() const {
    return (dropped_.capacity() + offered_.capacity()) * sizeof(DroppedEdge) +
           refused_.capacity() * sizeof(RefusedEdge);
  }
  size_t listed() const { return dropped_.size() + refused_.size(); }

 private:
  const MeshStore* store_;
  const PodArray<uint32_t>* version_;
  bool listing_;
  double min_dropped_ = std::numeric_limits<double>::infinity();
  std::vector<DroppedEdge> dropped_;
  std::vector<DroppedEdge> offered_;  // Offer's: what a rise offers to Q again
  std::vector<RefusedEdge> refused_;
};

}  // namespace tandem

#endif  // TANDEM_RISE_LISTS_H_
