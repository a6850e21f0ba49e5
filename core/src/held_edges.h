// HeldEdges: evaluated edges the late lag holds back until the front reaches their key
// (SimplifierOptions::late_lag), in a ring of one slot per integer front.
#ifndef TANDEM_HELD_EDGES_H_
#define TANDEM_HELD_EDGES_H_

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "edge_queues.h"

namespace tandem {

class HeldEdges {
 public:
  struct Entry {  // re-evaluated at release: the ends' versions say whether it still stands
    VertexId a, b;
    uint32_t va, vb;
  };
  bool empty() const { return size_ == 0; }
  size_t size() const { return size_; }
  // Holds `h` until the front reaches `key` (> the current front). A key past the ring waits
  // in its last slot, and may enter Q early, never ahead of its reach.
  void Hold(double key, const Entry& h) {
    if (slots_.empty()) slots_.resize(kFronts);
    const int64_t last = base_ + kFronts - 1;
    const int64_t at =
        key < static_cast<double>(last) ? static_cast<int64_t>(std::ceil(key)) : last;
    std::vector<Entry>& slot = slots_[static_cast<size_t>(std::max(at, base_)) & (kFronts - 1)];
    const size_t capacity = slot.capacity();
    slot.push_back(h);
    capacity_ += slot.capacity() - capacity;
    ++size_;
  }
  // The entries of the fronts passed up to `front` (+inf: all), each to push(entry), then
  // stale ones swept out once the held entries have doubled since the last sweep.
  template <typename Push, typename IsStale>
  void Release(double front, Push push, IsStale stale) {
    int64_t end = base_ + kFronts;
    if (std::isfinite(front)) end = std::min(end, static_cast<int64_t>(std::floor(front)) + 1);
    if (size_ != 0 && !slots_.empty()) {
      for (int64_t f = base_; f < end; ++f) {
        std::vector<Entry>& slot = slots_[static_cast<size_t>(f) & (kFronts - 1)];
        for (const Entry& h : slot) {
          if (!stale(h)) push(h);
        }
        size_ -= slot.size();
        // Freed, not cleared: the slot serves again only kFronts fronts later.
        capacity_ -= slot.capacity();
        std::vector<Entry>().swap(slot);
      }
    }
    if (std::isfinite(front)) base_ = std::max(end, static_cast<int64_t>(std::floor(front)) + 1);
    if (size_ > 2 * swept_ + 1024) {
      size_ = 0;
      for (auto& slot : slots_) {
        std::erase_if(slot, [&](const Entry& h) { return stale(h); });
        size_ += slot.size();
      }
      swept_ = size_;
    }
  }
  size_t MemoryBytes() const {
    return slots_.capacity() * sizeof(slots_[0]) + capacity_ * sizeof(Entry);
  }

 private:
  static constexpr int64_t kFronts = int64_t{1} << 10;
  static_assert((kFronts & (kFronts - 1)) == 0);
  std::vector<std::vector<Entry>> slots_;  // empty until the first hold
  int64_t base_ = 0;                       // the first front a slot stands for
  size_t size_ = 0, swept_ = 0;
  size_t capacity_ = 0;  // the slots' capacities, in entries
};

}  // namespace tandem

#endif  // TANDEM_HELD_EDGES_H_
