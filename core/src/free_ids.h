// FreeIds: the dead ids of one of MeshStore's arrays, handed out again lowest first.
//
// A contraction frees a vertex and two triangles at the random place the queue's cost order
// takes it to; the next layer's commit takes the ids back. Handed out last-freed first (a
// stack), a layer's vertices and triangles, made in scan order, went to ids scattered over
// the whole array, and the live mesh spread over all of it: every neighbour a random cache
// line and page. Lowest first, a layer's new records follow its scan order, and the live ids
// stay packed at the low end (docs/decisions.md: the measurements). A bitmap, one bit an id:
// Take scans forward from the lowest word that may hold a free id, and that only moves back
// when an id below it is released, so a layer's takes cost about one pass over the bits.
#ifndef TANDEM_FREE_IDS_H_
#define TANDEM_FREE_IDS_H_

#include <bit>
#include <cassert>
#include <cstddef>
#include <cstdint>

#include "grow.h"
#include "pod_array.h"

namespace tandem {

class FreeIds {
 public:
  bool empty() const { return count_ == 0; }
  size_t size() const { return count_; }

  void Release(uint32_t id) {
    const size_t word = id >> 6;
    if (word >= bits_.size()) GrowTo(bits_, word + 1, uint64_t{0});
    assert(!(bits_[word] >> (id & 63) & 1));
    bits_[word] |= uint64_t{1} << (id & 63);
    ++count_;
    if (word < first_) first_ = word;
  }

  bool Contains(uint32_t id) const {
    const size_t word = id >> 6;
    return word < bits_.size() && (bits_[word] >> (id & 63) & 1) != 0;
  }

  // Takes `id`, which must be free.
  void Take(uint32_t id) {
    assert(Contains(id));
    bits_[id >> 6] &= ~(uint64_t{1} << (id & 63));
    --count_;
  }

  // The lowest free id (not empty), taken.
  uint32_t TakeLowest() {
    assert(count_ > 0);
    while (bits_[first_] == 0) ++first_;
    uint64_t& w = bits_[first_];
    const uint32_t id = static_cast<uint32_t>((first_ << 6) | std::countr_zero(w));
    w &= w - 1;
    --count_;
    return id;
  }

  size_t MemoryBytes() const { return bits_.MemoryBytes(); }

 private:
  PodArray<uint64_t> bits_;
  size_t count_ = 0;
  size_t first_ = 0;  // no free id in the words below
};

}  // namespace tandem

#endif  // TANDEM_FREE_IDS_H_
