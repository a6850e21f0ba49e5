// ChunkedRelease: ACTIVATE's policy for a large release: W's edges for the front enter Q a chunk
// at a time, in compact patches of the front, each chunk simplified before the next enters.
#ifndef TANDEM_CHUNKED_RELEASE_H_
#define TANDEM_CHUNKED_RELEASE_H_

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "edge_queues.h"
#include "mesh_store.h"
#include "pod_array.h"
#include "tandem/types.h"

namespace tandem {

// A vertex is ready once the chunk holding the last of its released edges is in; an edge
// enters Q with the chunk that makes both its ends ready, and a contraction's edge to a vertex
// that is not ready yet waits for that vertex's chunk (Defer). So SIMPLIFY never reaches past
// the chunks taken: where it did, Q held only the edges contractions had pushed there, and on
// a flat cap (every cost 0) one survivor swallowed the next chunk's vertices one by one into a
// fan (docs/decisions.md).
class ChunkedRelease {
 public:
  // `version`: the simplifier's vertex stamps (stale edges are no edges); `chunk`: a release
  // of more edges enters in chunks (0: never); tile_x, tile_y: the xy tiles a chunked release
  // is ordered by along a Z-order curve (0: W's order).
  ChunkedRelease(const MeshStore* store, const PodArray<uint32_t>* version, size_t chunk,
                 double tile_x, double tile_y)
      : store_(store), version_(version), chunk_(chunk), tile_x_(tile_x), tile_y_(tile_y) {}

  // Takes W's entries with key <= front, live ones only, and returns the number of chunks
  // (1: the release enters Q whole; 0: nothing released).
  size_t Take(WaitingQueue* w, double front);
  // The edges chunk g brings in, in order (g = 0, 1, ... after Take): what earlier chunks
  // left for it (their edges in W's order, then what their contractions deferred), then its
  // own edges that it makes ready; the others wait for their chunk. Each taken chunk's
  // memory goes back as it is cut off the release.
  template <typename Enter>
  void ForEachIn(size_t g, Enter&& enter);
  // After a chunk's SIMPLIFY (the last one's too, after Done): W and the later chunks'
  // deferred edges lose their stale entries once they have grown by half since their last
  // sweep.
  void Sweep(WaitingQueue* w);
  // Frees the release (between steps nothing stays allocated).
  void Done();
  // An edge a contraction pushes during chunk g: true if an end waits for a later chunk,
  // where the edge now waits too.
  bool Defer(VertexId a, VertexId b) {
    const uint32_t g = std::max(ReadyGroup(a), ReadyGroup(b));
    if (g <= group_) return false;
    groups_[g].push_back(WEdge{a, b, (*version_)[a], (*version_)[b]});
    ++deferred_;
    return true;
  }
  size_t size() const { return n_; }           // edges taken by the last Take
  size_t chunk() const { return chunk_now_; }  // edges a chunk of it
  // Edges held back for a later chunk so far: the chunks' borders.
  int64_t deferred() const { return deferred_; }
  size_t MemoryBytes() const;

 private:
  template <typename E>
  bool Stale(const E& e) const {
    return (((*version_)[e.a] ^ e.va) | ((*version_)[e.b] ^ e.vb)) != 0;
  }
  uint32_t ReadyGroup(VertexId v) const { return v < ready_.size() ? ready_[v] : 0; }
  void OrderRelease();  // in tiles along a Z-order curve

  const MeshStore* store_;
  const PodArray<uint32_t>* version_;
  size_t chunk_;
  double tile_x_, tile_y_;
  size_t n_ = 0, chunk_now_ = 0, groups_count_ = 0;
  PodArray<WEdge> released_;  // W's bucket; chunked: last edge first, cut as chunks are taken
  PodArray<uint16_t> ready_;  // chunked: per vertex id, the chunk that makes it ready
  std::vector<PodArray<WEdge>> groups_;  // per chunk, the edges left for it
  uint32_t group_ = 0;                   // the chunk being simplified
  size_t swept_ = 0, waiting_ = 0;       // W's size and the groups' after their last sweeps
  int64_t deferred_ = 0;
};

template <typename Enter>
void ChunkedRelease::ForEachIn(size_t g, Enter&& enter) {
  if (groups_count_ <= 1) {
    for (const WEdge& e : released_) enter(e);
    released_ = {};
    return;
  }
  group_ = static_cast<uint32_t>(g);
  PodArray<WEdge> left;
  left.swap(groups_[g]);
  for (const WEdge& e : left) {
    if (!Stale(e)) enter(e);
  }
  left = {};
  const size_t end = std::min(n_, (g + 1) * chunk_now_);
  for (size_t i = g * chunk_now_; i < end; ++i) {
    const WEdge& e = released_[n_ - 1 - i];
    if (const uint32_t r = std::max(ready_[e.a], ready_[e.b]); r > group_) {
      groups_[r].push_back(e);
      ++deferred_;
    } else if (!Stale(e)) {
      enter(e);
    }
  }
  released_.resize(n_ - end);
  released_.shrink_to_fit();
}

}  // namespace tandem

#endif  // TANDEM_CHUNKED_RELEASE_H_
