#include "chunked_release.h"

#include <algorithm>

namespace tandem {

size_t ChunkedRelease::Take(WaitingQueue* w, double front) {
  w->TakeUpTo(front, &released_);  // in W's order: Q breaks ties by push order
  // Stale entries are no edges: they neither enter Q nor count towards a chunk or a vertex's
  // readiness, so a sweep of W changes nothing.
  erase_if(released_, [this](const WEdge& e) { return Stale(e); });
  n_ = released_.size();
  // At most 65,535 chunks (ready_ holds 16 bits): only a release of more than 4 G edges, or
  // a test's tiny chunks, takes larger ones.
  chunk_now_ = chunk_ == 0 ? 0 : std::max(chunk_, (n_ + 65534) / 65535);
  if (chunk_now_ == 0 || n_ <= chunk_now_) {
    chunk_now_ = n_;
    groups_count_ = n_ == 0 ? 0 : 1;
    if (n_ == 0) released_ = {};
    return groups_count_;
  }
  // What W held past its stale entries goes back now (most of a closing cap's release).
  released_.shrink_to_fit();
  OrderRelease();
  groups_count_ = (n_ + chunk_now_ - 1) / chunk_now_;
  ready_.assign(store_->vertex_capacity(), 0);
  for (size_t i = 0; i < n_; ++i) {
    ready_[released_[i].a] = ready_[released_[i].b] = static_cast<uint16_t>(i / chunk_now_);
  }
  // Last edge first, so that each chunk, once taken, is cut off the end and its pages go
  // back (a PodArray shrinks in place): the release and the edges its chunks leave for later
  // ones are not held twice.
  std::reverse(released_.begin(), released_.end());
  groups_.assign(groups_count_, {});
  swept_ = w->size();
  waiting_ = 0;
  return groups_count_;
}

void ChunkedRelease::Sweep(WaitingQueue* w) {
  // A chunk's contractions re-push the edges around each survivor; those whose reach is past
  // the front go to W, and most of them are stale a few contractions later. Those whose far
  // end waits for a later chunk go to that chunk's group, and go stale the same way.
  const auto grown = [this](size_t now, size_t then) { return now > then + then / 2 + chunk_now_; };
  const auto stale = [this](const WEdge& e) { return Stale(e); };
  if (grown(w->size(), swept_)) {
    w->RemoveIf(stale);
    swept_ = w->size();
  }
  size_t held = 0;
  for (size_t k = group_ + size_t{1}; k < groups_count_; ++k) held += groups_[k].size();
  if (grown(held, waiting_)) {
    held = 0;
    for (size_t k = group_ + size_t{1}; k < groups_count_; ++k) {
      erase_if(groups_[k], stale);
      groups_[k].shrink_to_fit();
      held += groups_[k].size();
    }
    waiting_ = held;
  }
}

void ChunkedRelease::Done() {
  // Freed, not cleared (`= {}` on a std::vector keeps its capacity).
  released_ = {};
  ready_ = {};
  std::vector<PodArray<WEdge>>().swap(groups_);
  group_ = 0;
  groups_count_ = 0;
}

void ChunkedRelease::OrderRelease() {
  // W's order follows the layer's scan for new edges and the contractions' order for the
  // others, so a chunk of it was a few rows across the whole slab, with the edges pushed again
  // last: a vertex waited for the chunk of its last released edge, and every chunk's
  // contractions reached over the whole front. In tiles along a Z-order curve a chunk is a
  // compact patch, whose records stay in cache while it is simplified (docs/decisions.md).
  if (!(tile_x_ > 0.0 && tile_y_ > 0.0)) return;
  // Tiles coarser by a power of four (the curve's numbers shifted) for about 8 edges each:
  // the sort's counts are then a fraction of the release, not 65,536 for every one.
  const size_t n = released_.size();
  int bits = 2;
  while (bits < 16 && (size_t{8} << bits) < n) bits += 2;
  const int shift = 16 - bits;
  PodArray<uint16_t> keys;
  keys.resize(n);
  constexpr size_t kAhead = 8;  // records a loop over released edges starts loading ahead
  for (size_t i = 0; i < n; ++i) {
    if (i + kAhead < n) store_->Prefetch(released_[i + kAhead].a);
    const Vec3 p = store_->position(released_[i].a);
    keys[i] = static_cast<uint16_t>(ZOrderTile(p.x, p.y, tile_x_, tile_y_) >> shift);
  }
  SortByKey(released_.data(), keys.data(), n, bits);
}

size_t ChunkedRelease::MemoryBytes() const {
  size_t edges = groups_.capacity();  // a vector's header is about the size of a WEdge
  for (const auto& g : groups_) edges += g.MemoryBytes() / sizeof(WEdge);
  return released_.MemoryBytes() + edges * sizeof(WEdge) + ready_.MemoryBytes();
}

}  // namespace tandem
