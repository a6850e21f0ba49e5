// The Simplifier's side of a slab merge (slabs.h): adopting another slab's vertices, queues and
// counters, and the seam coarsening's contractions decided outside SIMPLIFY.
#include <algorithm>
#include <cassert>
#include <utility>
#include <vector>

#include "simplifier.h"

namespace tandem {

void Simplifier::AdoptVertex(const Simplifier& from, PartVertex src, VertexId dst, bool shared) {
  EnsureVertexCapacity();
  quadrics_.Adopt(from.quadrics_, src, dst, shared);
  if (!shared) store_->set_rad(dst, from.store_->rad(InPart(src)));
  ++version_[dst];
}

bool Simplifier::MayContract(VertexId a, VertexId b, Vec3 pos, double guard) {
  RefusalCounts uncounted;
  return LinkCondition(*store_, a, b, &link_scratch_) &&
         GeometryOk(*store_, a, b, pos, guard, opt_.offset_edges, &survivors_, &uncounted);
}

void Simplifier::ContractAt(VertexId a, VertexId b, Vec3 pos, double eps0, bool onto_a) {
  Candidate c;
  c.pos = pos;
  c.eps0 = c.cost = eps0;
  c.box_mask = store_->box_mask(a) | store_->box_mask(b);
  ReleaseKey(a, b, &c);  // height, rad, layer of the new vertex
  if (onto_a) {
    c.height = store_->height(a);
    c.rad = store_->rad(a);
    c.layer = store_->layer(a);
  }
  Contract(a, b, c);
}

void Simplifier::AdoptQueues(const Simplifier& from, const PartVertexMap& map) {
  if (!opt_.rises) return;
  auto ends = [&](VertexId a, VertexId b) {  // from's ids
    const VertexId x = map[PartVertex{a}], y = map[PartVertex{b}];
    assert(x != kInvalid && y != kInvalid && !Pinned(x, y));
    return x < y ? std::pair{x, y} : std::pair{y, x};
  };
  from.q_.ForEachInPushOrder([&](const QNode& n, const QPlacement& p) {
    if (from.Stale(n)) return;
    const auto [a, b] = ends(n.a, n.b);
    ++q_pushes_;
    q_.Push(n.key, QEntry{a, b, version_[a], version_[b], p.pos, p.eps0});
  });
  // The merged stars are new: each refusal is offered again at the next rise.
  rises_.Adopt(from.rises_, map, from.opt_.error);
}

void Simplifier::AdoptCounters(const Simplifier& from) {
  refusals_ += from.refusals_;
  contractions_ += from.contractions_;
  evaluations_ += from.evaluations_;
  q_pushes_ += from.q_pushes_;
  w_pushes_ += from.w_pushes_;
  quadrics_.AddMismatches(from.quadrics_.mismatches());
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

}  // namespace tandem
