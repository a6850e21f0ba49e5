// Growth of the session's arrays: a std::vector by an eighth of what it holds, not by double;
// a PodArray by double, since what it holds past its written pages is not memory.
//
// std::vector doubles its capacity when it runs out, so an array that has just passed a power
// of two holds up to twice what it uses, and keeps it for the rest of the session (ids are
// recycled, the arrays never shrink). The session's memory, as its budget counts it
// (TandemSession::MemoryBytes), was capacity: after the flat cap of a closed 2048² volume (a
// million triangles in each part's first layer) the store, the quadrics and the incidence
// pool stood at 1.5-1.9x their use, and the server refused the stream at slice 2.
// Growing by an eighth keeps appends amortised O(1) (an element is copied about 9 times over
// the array's life, plain memcpy of records, a few ms per million vertices; small arrays
// double, below), and a caller
// that knows how much is coming (a layer's commit) reserves it exactly. The biggest arrays are
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
// bytes at a time until an eighth is more. Grown by eighths from empty, a small array grew
// one element at a time up to 16 and was copied some 55 times on its way to 16 KiB; Q's and
// W's buckets regrow from empty every step, and on a 128³ volume those copies were 5 % of
// the run's instructions (8 % of its time in memmove): 625 M instructions before, 599 M now
// (`--parts 1`, Link 128³). The slack this adds is at most 16 KiB an array, and Q has a
// thousand buckets a part: a 64 KiB threshold saved a little more (591 M) for four times that.
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

// push_back and resize, growing as ReserveFor does.
template <class V, class U>
void PushBack(V& v, U&& x) {
  ReserveFor(v, v.size() + 1);
  v.push_back(std::forward<U>(x));
}
template <class V>
void GrowTo(V& v, size_t n, const typename V::value_type& value = typename V::value_type()) {
  ReserveFor(v, n);
  v.resize(n, value);
}

}  // namespace tandem

#endif  // TANDEM_GROW_H_
