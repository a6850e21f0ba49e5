#include "edge_queues.h"

#include <algorithm>
#include <cassert>
#include <type_traits>

namespace tandem {

void EdgeQueue::Clear() {
  for (auto& bucket : buckets_) bucket.clear();
  std::fill(heaped_.begin(), heaped_.end(), 0);
  cur_ = buckets_.empty() ? 0 : kBuckets - 1;
  size_ = 0;
  slots_.clear();
  free_.clear();
}

void EdgeQueue::Trim() {
  assert(size_ == 0);
  // A small Q keeps its memory: freeing and regrowing it every layer only fragments the heap
  // (docs/decisions.md 1).
  if (MemoryBytes() < (size_t{4} << 20)) return;
  auto trim = [](auto& v) {
    if (!Keeps(v.capacity() * sizeof(v[0]), kKeepTrimmed)) {
      std::remove_reference_t<decltype(v)>().swap(v);
    }
  };
  for (auto& bucket : buckets_) trim(bucket);
  slots_.clear();  // every slot is free
  free_.clear();
  trim(slots_);
  trim(free_);
}

size_t EdgeQueue::Bytes(bool capacity) const {
  auto of = [capacity](const auto& a) {
    return capacity ? a.capacity() * sizeof(a[0]) : a.MemoryBytes();
  };
  size_t bytes = buckets_.capacity() * sizeof(PodArray<QNode>) + heaped_.capacity() * sizeof(size_t);
  for (const auto& bucket : buckets_) bytes += of(bucket);
  return bytes + of(slots_) + of(free_);
}

void WaitingQueue::Push(const WEntry& e) {
  if (!(e.key < kFarKey)) {  // also NaN
    far_.push_back(e);
    ++size_;
    return;
  }
  const int64_t release = static_cast<int64_t>(std::ceil(e.key));
  if (buckets_.empty()) base_ = release;
  if (release < base_) {  // cannot happen for keys > front; keep it correct anyway
    if (base_ - release + static_cast<int64_t>(buckets_.size()) > kBuckets) {
      far_.push_back(e);
      ++size_;
      return;
    }
    buckets_.insert(buckets_.begin(), static_cast<size_t>(base_ - release), {});
    base_ = release;
  }
  const size_t b = static_cast<size_t>(release - base_);
  if (b >= static_cast<size_t>(kBuckets)) {
    far_.push_back(e);
    ++size_;
    return;
  }
  if (b >= buckets_.size()) buckets_.resize(b + 1);
  PushBack(buckets_[b], WEdge{e.a, e.b, e.va, e.vb});
  ++size_;
}

void WaitingQueue::TakeUpTo(double front, PodArray<WEdge>* out) {
  out->clear();
  size_t b = 0;
  for (; b < buckets_.size() && static_cast<double>(base_) + static_cast<double>(b) <= front;
       ++b) {
    size_ -= buckets_[b].size();
    if (out->empty()) {
      out->swap(buckets_[b]);
    } else {
      out->append(buckets_[b].begin(), buckets_[b].end());
    }
    buckets_[b] = {};
  }
  if (b > 0) {
    buckets_.erase(buckets_.begin(), buckets_.begin() + static_cast<std::ptrdiff_t>(b));
    base_ += static_cast<int64_t>(b);
  }
  if (!far_.empty()) {  // released ones go with the rest; the others stay, in order
    size_t kept = 0;
    for (const WEntry& e : far_) {
      if (!(e.key > front)) {
        --size_;
        out->push_back(WEdge{e.a, e.b, e.va, e.vb});
      } else {
        far_[kept++] = e;
      }
    }
    far_.resize(kept);
  }
}

size_t WaitingQueue::MemoryBytes() const {
  size_t bytes = buckets_.capacity() * sizeof(PodArray<WEdge>);
  for (const auto& bucket : buckets_) bytes += bucket.MemoryBytes();
  return bytes + far_.MemoryBytes();
}

}  // namespace tandem
