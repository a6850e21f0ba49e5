// The ids that cross stores: a merged part's vertex ids and their map into the merged store
// (MergeSlabs), and the sealed output's global ids (Sealer). Zero-cost types, so that one
// store's id cannot be passed where another store's, or a global one, is expected.
#ifndef TANDEM_PART_IDS_H_
#define TANDEM_PART_IDS_H_

#include <cstddef>
#include <cstdint>
#include <vector>

#include "tandem/types.h"

namespace tandem {

// A vertex id of another part's store (a slab being merged into this one): an index there,
// never here.
enum class PartVertex : uint32_t {};
// v's index in its own (the part's) store.
inline constexpr VertexId InPart(PartVertex v) { return static_cast<VertexId>(v); }

// A part's vertex ids -> the merged store's (kInvalid: not copied).
class PartVertexMap {
 public:
  // Every id of a part whose store has `capacity` vertex ids maps to kInvalid.
  void Reset(size_t capacity) { to_.assign(capacity, kInvalid); }
  size_t size() const { return to_.size(); }
  VertexId operator[](PartVertex v) const { return to_[InPart(v)]; }
  VertexId& operator[](PartVertex v) { return to_[InPart(v)]; }
  void swap(PartVertexMap& other) { to_.swap(other.to_); }

 private:
  std::vector<VertexId> to_;
};

// A vertex's id in the sealed output (SealedChunk::ids), handed out by the sealers: the
// same in every chunk that holds the vertex, and an index of no store.
enum class GlobalId : uint32_t {};
inline constexpr GlobalId kNoGlobalId{kInvalid};
inline constexpr uint32_t Value(GlobalId id) { return static_cast<uint32_t>(id); }

}  // namespace tandem

#endif  // TANDEM_PART_IDS_H_
