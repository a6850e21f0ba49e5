#include "rise_lists.h"

#include <cassert>
#include <utility>

namespace tandem {

size_t RiseLists::Offer(double e, double reach) {
  // In place: the list holds about every edge of the mesh (each costs more than E0 after
  // SIMPLIFY), so a second copy would be most of the session's growth in memory.
  ForgetDropped();
  offered_.clear();
  size_t kept = 0;
  for (const DroppedEdge& d : dropped_) {
    if (Stale(d)) continue;
    if (d.cost <= reach) {
      offered_.push_back(d);
    } else {
      dropped_[kept++] = d;
      min_dropped_ = std::min(min_dropped_, d.cost);
    }
  }
  dropped_.resize(kept);
  // A link refusal stands while both stars do; the others are offered after the list's.
  const size_t from_list = offered_.size();
  kept = 0;
  for (const RefusedEdge& r : refused_) {
    if (Stale(r)) continue;
    if (store_->star_stamp(r.a) == r.sa && store_->star_stamp(r.b) == r.sb) {
      refused_[kept++] = r;
    } else {
      offered_.push_back(DroppedEdge{e, r.a, r.b, r.va, r.vb});
    }
  }
  refused_.resize(kept);
  return from_list;
}

void RiseLists::SweepBeyond(size_t limit) {
  if (dropped_.size() > limit) {
    std::erase_if(dropped_, [this](const DroppedEdge& d) { return Stale(d); });
  }
  if (refused_.size() > limit) {
    std::erase_if(refused_, [this](const RefusedEdge& r) { return Stale(r); });
  }
}

void RiseLists::Adopt(const RiseLists& from, const PartVertexMap& map, double error) {
  auto ends = [&](VertexId a, VertexId b) {  // from's ids
    const VertexId x = map[PartVertex{a}], y = map[PartVertex{b}];
    assert(x != kInvalid && y != kInvalid);
    return x < y ? std::pair{x, y} : std::pair{y, x};
  };
  for (const DroppedEdge& d : from.dropped_) {
    if (from.Stale(d)) continue;
    const auto [a, b] = ends(d.a, d.b);
    List(a, b, d.cost);
  }
  for (const RefusedEdge& r : from.refused_) {
    if (from.Stale(r)) continue;
    const auto [a, b] = ends(r.a, r.b);
    List(a, b, error);
  }
  min_dropped_ = std::min(min_dropped_, from.min_dropped_);
}

}  // namespace tandem
