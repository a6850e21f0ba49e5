// The Simplifier's rises of E0 toward a target triangle count (schedule.h): Q rebuilt for the
// new E0, the listed edges offered again (rise_lists.h), or every edge requeued.
#include <cassert>
#include <limits>
#include <vector>

#include "simplifier.h"

namespace tandem {

void Simplifier::RequeueAll() {
  keep_expensive_ = true;
  q_.Clear();
  for (TriId t = 0; t < store_->triangle_capacity(); ++t) {
    if (store_->triangle_alive(t)) PushTriangleEdges(t, /*new_layer=*/false);
  }
  FlushBatch();
}

void Simplifier::RaiseError(double e) {
  assert(e >= opt_.error);
  opt_.error = e;
  if (opt_.rises) {
    // Re-offer what e brings within keep x e; with α > 0 an edge's cost only grows with E0
    // (IsotropicCostQuadric), so one listed above that cannot be in Q's reach yet.
    const size_t from_list = rises_.Offer(e, opt_.keep * e);
    const std::vector<DroppedEdge>& offers = rises_.offers();
    const bool unplaced = opt_.alpha == 0.0;
    // Rebucket, with room for the offers.
    q_ = q_.Rebuilt(e, [this](const QNode& n) { return !Stale(n); }, [&](auto&& room) {
      for (size_t i = 0; i < offers.size(); ++i) {
        room(i < from_list && unplaced ? offers[i].cost : e);
      }
    });
    for (size_t i = 0; i < offers.size(); ++i) {
      const DroppedEdge& d = offers[i];
      if (i < from_list && unplaced) {
        // Its cost is what an evaluation would give (the stamps hold its quadrics and ends):
        // queued as it is, placed when popped. Most of those beyond e go stale in Q first.
        if (!Pinned(d.a, d.b)) {
          ++q_pushes_;
          q_.Push(d.cost, QEntry{d.a, d.b, d.va, d.vb, kUnplaced, kNaN});
        }
      } else {
        AddToBatch(d.a, d.b, /*released=*/true);  // a re-drop lists it again
      }
    }
    FlushBatch();
    return;
  }
  if (e <= rises_.min_dropped()) {
    Rebucket(e);
    return;
  }
  q_ = EdgeQueue(e);
  rises_.ForgetDropped();
  requeue_released_ = true;
  for (TriId t = 0; t < store_->triangle_capacity(); ++t) {
    if (store_->triangle_alive(t)) PushTriangleEdges(t, /*new_layer=*/false);
  }
  FlushBatch();
  requeue_released_ = false;
}

double Simplifier::NextCost() { return rises_.NextCost(&q_); }

}  // namespace tandem
