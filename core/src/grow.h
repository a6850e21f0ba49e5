// Growth of the session's arrays: a std::vector by an eighth of what it holds, not by double;
// a PodArray by double, since what it holds past its written pages is not memory.
//
// std::vector doubles its capacity when it runs out, so an array that has just passed a power
// of two holds up to twice what it uses, and keeps it for the rest of the session (ids are
// recycled, the arrays never shrink), and the session's budget counts a heap array's capacity
// (docs/decisions.md 4). Growing by an eighth keeps appends amortised O(1) (small arrays
// double, below), and a caller that knows how much is coming (a layer's commit) reserves it
// exactly. The biggest arrays are
// PodArrays (pod_array.h), whose large blocks grow in place without the copy, and whose count
// is the pages they wrote (docs/decisions.md 7): those double (ReserveFor).
#ifndef TANDEM_GROW_H_
#define TANDEM_GROW_H_

#include <algorithm>
#include <cstddef>
#include <type_traits>
#include <utility>
#include <vector>

#include "pod_array.h"

namespace tandem {

// Below this many bytes an array doubles (from 8 elements); above, it grows by this many
// bytes at a time until an eighth is more: grown by eighths from empty, Q's and W's buckets,
// regrown every step, were copied dozens of times (docs/decisions.md 4). At most 16 KiB of
// slack an array, over Q's thousand buckets a part.
inline constexpr size_t kGrowDoubleBytes = size_t{16} << 10;

// Makes room for n elements in v: its capacity becomes at least n, and when it has to grow
// at all, at least twice what it was (while small), else what it was plus the larger of an
// eighth and kGrowDoubleBytes. A PodArray that maps its large blocks doubles all the way: its
// heap block, below kPodMapBytes, holds at most half that of slack, and the capacity of its
// pages beyond is address space, not memory (MemoryBytes counts the pages written), while
// growing by eighths copied a heap block 15 times on its way to kPodMapBytes and remapped the
// pages 24 times more on the way to 16 times that: W's and Q's arrays regrow every step
// (docs/decisions.md). Without mappings (AddressSanitizer builds) capacity is memory, and
// PodArrays grow as the rest.
template <class V>
void ReserveFor(V& v, size_t n) {
  const size_t cap = v.capacity();
  if (n <= cap) return;
  if constexpr (TANDEM_POD_MAP && std::is_same_v<V, PodArray<typename V::value_type>>) {
    v.reserve(std::max(n, std::max<size_t>(2 * cap, 8)));
    return;
  }
  constexpr size_t kSmall =
      std::max<size_t>(kGrowDoubleBytes / sizeof(typename V::value_type), 8);
  v.reserve(std::max(n, cap + std::max(cap / 8, std::min(std::max<size_t>(cap, 8), kSmall))));
}

// push_back and resize, growing as ReserveFor does. PushBack's common case (room left) is
// inline and its growth out of line, so that a push keeps few registers to save (Q's and W's
// pushes, several a contraction).
template <class V, class U>
[[gnu::noinline]] void PushBackGrowing(V& v, U&& x) {
  ReserveFor(v, v.size() + 1);
  v.push_back(std::forward<U>(x));
}
template <class V, class U>
inline void PushBack(V& v, U&& x) {
  if (v.size() < v.capacity()) [[likely]] {
    v.push_back(std::forward<U>(x));
    return;
  }
  PushBackGrowing(v, std::forward<U>(x));
}
template <class V>
void GrowTo(V& v, size_t n, const typename V::value_type& value = typename V::value_type()) {
  ReserveFor(v, n);
  v.resize(n, value);
}

}  // namespace tandem

#endif  // TANDEM_GROW_H_
