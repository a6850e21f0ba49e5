// IdIndex: where each vertex of a list sits in it (id -> index), as scratch sized to the list
// when the list is short, and to the mesh's ids only when the list is long. IdMap: values for
// the few vertex ids of a store that have one (the sealer's frozen vertices).
//
// The sag correction of a Seal looks up, for every corner of the triangles it checks, whether
// that corner is one of the few thousand vertices it moves. A 4-byte slot per vertex id would
// hold memory for the whole part between Seals for lists of a few thousand (docs/decisions.md
// 18). A short list goes into an open-addressing table at most half
// full (an IdMap, 8 bytes an entry, so 16 to 32 bytes a listed vertex); a list of a quarter of
// the ids or more (the final pass over the whole mesh) takes the slot per id, which is then
// the smaller.
#ifndef TANDEM_ID_INDEX_H_
#define TANDEM_ID_INDEX_H_

#include <algorithm>
#include <bit>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "tandem/types.h"

namespace tandem {

// A value for each of a few vertex ids, where an array by id would hold mostly nothing: the
// sealer's frozen vertices in the store, a few thousand of a part's million ids
// (docs/decisions.md 18). Open addressing, linear probing, at most half full, backward-shift
// deletion (no tombstones: the table holds what is in it). References from At and Find are
// valid until the next At or Erase.
template <typename V>
class IdMap {
 public:
  const V* Find(VertexId v) const {
    if (size_ == 0) return nullptr;
    for (uint32_t h = Hash(v);; h = (h + 1) & mask_) {
      if (slots_[h].key == v) return &slots_[h].value;
      if (slots_[h].key == kInvalid) return nullptr;
    }
  }
  V* Find(VertexId v) { return const_cast<V*>(std::as_const(*this).Find(v)); }
  // v's value, made V{} if v had none.
  V& At(VertexId v) {
    if (2 * (size_ + 1) > slots_.size()) Rehash(slots_.empty() ? 16 : 2 * slots_.size());
    uint32_t h = Hash(v);
    for (; slots_[h].key != kInvalid; h = (h + 1) & mask_) {
      if (slots_[h].key == v) return slots_[h].value;
    }
    slots_[h] = Slot{v, V{}};
    ++size_;
    return slots_[h].value;
  }
  void Erase(VertexId v) {
    if (size_ == 0) return;
    uint32_t hole = Hash(v);
    for (; slots_[hole].key != v; hole = (hole + 1) & mask_) {
      if (slots_[hole].key == kInvalid) return;
    }
    // Entries after the hole whose probe passed it move back into it.
    for (uint32_t j = (hole + 1) & mask_; slots_[j].key != kInvalid; j = (j + 1) & mask_) {
      if (((j - Hash(slots_[j].key)) & mask_) >= ((j - hole) & mask_)) {
        slots_[hole] = slots_[j];
        hole = j;
      }
    }
    slots_[hole] = Slot{};
    --size_;
  }
  // Empties the map (its capacity stays).
  void Clear() {
    if (size_ == 0) return;
    std::fill(slots_.begin(), slots_.end(), Slot{});
    size_ = 0;
  }
  size_t size() const { return size_; }
  size_t MemoryBytes() const { return slots_.capacity() * sizeof(Slot); }

 private:
  struct Slot {
    VertexId key = kInvalid;
    V value{};
  };
  // Fibonacci hashing: the product's top bits (ids of a layer are runs of consecutive ids).
  uint32_t Hash(VertexId v) const { return (v * 0x9E3779B1u) >> shift_; }
  void Rehash(size_t size) {
    std::vector<Slot> old(size);
    old.swap(slots_);
    mask_ = static_cast<uint32_t>(size - 1);
    shift_ = 32 - std::countr_zero(size);
    for (const Slot& s : old) {
      if (s.key == kInvalid) continue;
      uint32_t h = Hash(s.key);
      while (slots_[h].key != kInvalid) h = (h + 1) & mask_;
      slots_[h] = s;
    }
  }

  std::vector<Slot> slots_;
  uint32_t mask_ = 0;
  int shift_ = 32;
  size_t size_ = 0;
};

// ids[i] -> i for a list: an IdMap for a short list, a slot per id for a long one.
class IdIndex {
 public:
  // ids[i] -> i for the ids of `ids` (the last i for an id listed twice), all below `capacity`
  // (the store's vertex ids).
  void Assign(std::span<const VertexId> ids, uint32_t capacity) {
    Clear();
    if (ids.size() >= capacity / 4) {
      if (dense_.size() < capacity) dense_.resize(capacity, kInvalid);
      for (size_t i = 0; i < ids.size(); ++i) dense_[ids[i]] = static_cast<uint32_t>(i);
      dense_ids_ = ids;
      return;
    }
    for (size_t i = 0; i < ids.size(); ++i) table_.At(ids[i]) = static_cast<uint32_t>(i);
  }
  // ids[i] for the list assigned last, kInvalid for an id not in it.
  uint32_t Find(VertexId v) const {
    if (!dense_ids_.empty()) return dense_[v];
    const uint32_t* i = table_.Find(v);
    return i != nullptr ? *i : kInvalid;
  }
  // Forgets the list (the table's capacity stays for the next one).
  void Clear() {
    for (VertexId v : dense_ids_) dense_[v] = kInvalid;
    dense_ids_ = {};
    table_.Clear();
  }
  size_t MemoryBytes() const { return dense_.capacity() * sizeof(uint32_t) + table_.MemoryBytes(); }

 private:
  std::vector<uint32_t> dense_;  // per id, for a long list
  std::span<const VertexId> dense_ids_;  // the long list in dense_, to clear it
  IdMap<uint32_t> table_;
};

}  // namespace tandem

#endif  // TANDEM_ID_INDEX_H_
