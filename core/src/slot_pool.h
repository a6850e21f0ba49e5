// SlotPool: values packed in one array, for the few vertices of a store that need one (the
// simplifier's quadrics kept in full, the sealer's normals of frozen vertices), each reached
// through a 32-bit slot the caller keeps per vertex id. Free slots come back lowest first
// (free_ids.h), so the values in use stay packed at the low end.
#ifndef TANDEM_SLOT_POOL_H_
#define TANDEM_SLOT_POOL_H_

#include <cstddef>
#include <cstdint>

#include "free_ids.h"
#include "grow.h"
#include "pod_array.h"

namespace tandem {

template <class T>
class SlotPool {
 public:
  uint32_t Take() {
    if (!free_.empty()) return free_.TakeLowest();
    PushBack(values_, T{});
    return static_cast<uint32_t>(values_.size() - 1);
  }
  void Release(uint32_t slot) { free_.Release(slot); }
  T& operator[](uint32_t slot) { return values_[slot]; }
  const T& operator[](uint32_t slot) const { return values_[slot]; }
  const PodArray<T>& values() const { return values_; }  // by slot, free ones included
  size_t MemoryBytes() const { return values_.MemoryBytes() + free_.MemoryBytes(); }

 private:
  PodArray<T> values_;
  FreeIds free_;
};

}  // namespace tandem

#endif  // TANDEM_SLOT_POOL_H_
