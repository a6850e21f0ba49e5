// Growth of the session's big arrays: by an eighth of what they hold, not by double.
//
// std::vector doubles its capacity when it runs out, so an array that has just passed a power
// of two holds up to twice what it uses, and keeps it for the rest of the session (ids are
// recycled, the arrays never shrink). The session's memory, as its budget counts it
// (TandemSession::MemoryBytes), is capacity: after the flat cap of a closed 2048² volume (a
// million triangles in each part's first layer) the store, the quadrics and the incidence
// pool stood at 1.5-1.9x their use, and the server refused the stream at slice 2.
// Growing by an eighth keeps appends amortised O(1) (an element is copied about 9 times over
// the array's life, plain memcpy of records, a few ms per million vertices), and a caller
// that knows how much is coming (a layer's commit) reserves it exactly. The biggest arrays are
// PodArrays (pod_array.h), whose large blocks grow in place without the copy.
#ifndef TANDEM_GROW_H_
#define TANDEM_GROW_H_

#include <algorithm>
#include <cstddef>
#include <utility>
#include <vector>

namespace tandem {

// Makes room for n elements in v: its capacity becomes at least n, and at least 9/8 of what
// it was when it has to grow at all.
template <class V>
void ReserveFor(V& v, size_t n) {
  if (n <= v.capacity()) return;
  v.reserve(std::max(n, v.capacity() + v.capacity() / 8));
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
