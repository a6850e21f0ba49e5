// PodArray<T>: the session's big arrays of plain records (a std::vector's interface, the
// part the session uses), whose blocks of 256 KiB or more are pages of their own that grow in
// place.
//
// A std::vector grows by allocating a new block, copying, and freeing the old one. On
// glibc's heap the freed blocks stay resident for the process's life (the heap only shrinks
// from its top, and blocks past the mmap threshold come from the heap too once a large block
// has been freed: the threshold rises up to 32 MiB), so the session's arrays, grown by
// eighths (grow.h) and freed after each step (Q, W's buckets), kept the process resident far
// above its live heap. Mapped with mmap instead, a block returns to the kernel when freed,
// and grows with mremap: its pages move, nothing is copied and nothing is faulted in again
// (docs/decisions.md 6, also why not malloc's mmap threshold).
// Capacity follows std::vector's (libstdc++'s) rules exactly (push_back doubles the size,
// reserve gives what is asked). What the session's budget counts is MemoryBytes: a mapped
// block's written pages, not its capacity.
#ifndef TANDEM_POD_ARRAY_H_
#define TANDEM_POD_ARRAY_H_

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <new>
#include <type_traits>
#include <utility>

#include "pod_array_config.h"

namespace tandem {

// Resizes a block of `old_bytes` (nullptr when 0) to `new_bytes`, keeping the first
// min(old_bytes, new_bytes) bytes: heap blocks (operator new, aligned to `align`) below
// kPodMapBytes, whole pages of their own (mmap, grown and shrunk with mremap) from there
// on; 0 frees it. Throws std::bad_alloc.
void* ResizePodBlock(void* block, size_t old_bytes, size_t new_bytes, size_t align);
inline constexpr size_t kPodMapBytes = size_t{256} << 10;
// Whether a block of this many bytes is pages of its own (mmap), and the page size.
inline constexpr bool PodMapped(size_t bytes) { return TANDEM_POD_MAP && bytes >= kPodMapBytes; }
inline constexpr size_t kPodPage = 4096;

template <class T>
class PodArray {
  static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>,
                "PodArray holds plain records only: it moves them with memcpy and mremap");

 public:
  using value_type = T;
  using iterator = T*;
  using const_iterator = const T*;

  PodArray() = default;
  PodArray(const PodArray& o) {
    if (o.size_ > 0) {
      Reallocate(o.size_);
      std::memcpy(static_cast<void*>(data_), o.data_, o.size_ * sizeof(T));
      size_ = o.size_;
    }
  }
  PodArray(PodArray&& o) noexcept : data_(o.data_), size_(o.size_), cap_(o.cap_), high_(o.high_) {
    o.data_ = nullptr;
    o.size_ = o.cap_ = o.high_ = 0;
  }
  PodArray& operator=(const PodArray& o) {
    if (this != &o) PodArray(o).swap(*this);
    return *this;
  }
  PodArray& operator=(PodArray&& o) noexcept {
    PodArray(std::move(o)).swap(*this);
    return *this;
  }
  ~PodArray() { ResizePodBlock(data_, cap_ * sizeof(T), 0, alignof(T)); }

  size_t size() const { return size_; }
  size_t capacity() const { return cap_; }
  // The bytes the array takes in memory: its capacity's, except for a block of pages of its
  // own, where mmap gave the pages past the most it ever held no memory (none was written):
  // up to there, in whole pages. The session's budget counts this (docs/decisions.md).
  size_t MemoryBytes() const {
    const size_t bytes = cap_ * sizeof(T);
    if (!PodMapped(bytes)) return bytes;
    const size_t written = std::max(high_, size_) * sizeof(T);
    return std::min(bytes, (written + kPodPage - 1) / kPodPage * kPodPage);
  }
  bool empty() const { return size_ == 0; }
  T* data() { return data_; }
  const T* data() const { return data_; }
  T& operator[](size_t i) { return data_[i]; }
  const T& operator[](size_t i) const { return data_[i]; }
  T* begin() { return data_; }
  T* end() { return data_ + size_; }
  const T* begin() const { return data_; }
  const T* end() const { return data_ + size_; }
  T& back() { return data_[size_ - 1]; }
  const T& back() const { return data_[size_ - 1]; }

  void reserve(size_t n) {
    if (n > cap_) Reallocate(n);
  }
  void shrink_to_fit() {
    if (cap_ > size_) Reallocate(size_);
  }
  void clear() { SetSize(0); }
  void push_back(const T& x) {
    if (size_ == cap_) {
      const T copy = x;  // x may live in this array
      Reallocate(Grown(1));
      data_[size_++] = copy;
      return;
    }
    data_[size_++] = x;
  }
  void pop_back() { SetSize(size_ - 1); }
  void resize(size_t n, const T& value = T()) {
    if (n > cap_) Reallocate(Grown(n - size_));
    for (size_t i = size_; i < n; ++i) new (&data_[i]) T(value);
    SetSize(n);
  }
  void assign(size_t n, const T& value) {
    clear();
    resize(n, value);
  }
  // Appends [first, last), which must not lie in this array.
  void append(const T* first, const T* last) {
    const size_t n = static_cast<size_t>(last - first);
    if (size_ + n > cap_) Reallocate(Grown(n));
    if (n > 0) std::memcpy(static_cast<void*>(data_ + size_), first, n * sizeof(T));
    size_ += n;
  }
  // Removes the first n elements.
  void erase_front(size_t n) {
    std::memmove(static_cast<void*>(data_), data_ + n, (size_ - n) * sizeof(T));
    SetSize(size_ - n);
  }
  void swap(PodArray& o) noexcept {
    std::swap(data_, o.data_);
    std::swap(size_, o.size_);
    std::swap(cap_, o.cap_);
    std::swap(high_, o.high_);
  }

 private:
  // The capacity std::vector (libstdc++) moves to when `extra` more elements do not fit.
  size_t Grown(size_t extra) const { return size_ + (size_ > extra ? size_ : extra); }
  void Reallocate(size_t n) {
    // A heap block moving to pages of its own is copied whole: those pages are written.
    if (!PodMapped(cap_ * sizeof(T)) && PodMapped(n * sizeof(T))) high_ = std::max(high_, cap_);
    data_ = static_cast<T*>(ResizePodBlock(data_, cap_ * sizeof(T), n * sizeof(T), alignof(T)));
    cap_ = n;
    high_ = std::min(high_, n);  // shrunk: the pages past n are gone
    if (size_ > n) size_ = n;
  }
  // Sets the size to n, keeping the most held so far in high_.
  void SetSize(size_t n) {
    high_ = std::max(high_, size_);
    size_ = n;
  }

  T* data_ = nullptr;
  size_t size_ = 0;
  size_t cap_ = 0;
  size_t high_ = 0;  // the most elements held at once, but for the current size (MemoryBytes)
};

// Removes the elements for which pred is true, keeping the others in order; returns how many
// went (std::erase_if's contract).
template <class T, class Pred>
size_t erase_if(PodArray<T>& v, Pred&& pred) {
  T* out = v.begin();
  for (T* it = v.begin(); it != v.end(); ++it) {
    if (!pred(*it)) *out++ = *it;
  }
  const size_t removed = static_cast<size_t>(v.end() - out);
  v.resize(v.size() - removed);
  return removed;
}

}  // namespace tandem

#endif  // TANDEM_POD_ARRAY_H_
