#include "mesh_store.h"

#include <algorithm>
#include <cassert>

#include "grow.h"

namespace tandem {

// The pool is a buddy allocator: a slot of class k starts at a multiple of its size, the
// class's free list holds offset / size, and a freed slot whose twin (the other half of the
// slot of class k + 1 they make) is free too merges with it. Without merging, the slots a
// contraction's survivor left as its star grew (and the dead vertices' smallest ones) stayed
// in their own class, and dense surfaces left much of the pool as free slots of the wrong
// size (docs/decisions.md 18).
uint32_t MeshStore::AllocSlot(uint8_t size_class) {
  if (!free_slots_[size_class].empty()) {
    return free_slots_[size_class].TakeLowest() * (kMinSlot << size_class);
  }
  // Split the smallest free slot of a larger class, keeping the halves above.
  for (int c = size_class + 1; c < kNumClasses; ++c) {
    if (free_slots_[c].empty()) continue;
    uint32_t block = free_slots_[c].TakeLowest();
    for (int k = c - 1; k >= size_class; --k) {
      block *= 2;
      free_slots_[k].Release(block + 1);
    }
    return block * (kMinSlot << size_class);
  }
  // Grow the pool: up to a multiple of the slot's size (the gap goes to the free lists as the
  // largest aligned slots that fill it), then by the slot.
  const uint32_t size = kMinSlot << size_class;
  auto end = static_cast<uint32_t>(pool_.size());
  const uint32_t aligned = (end + size - 1) / size * size;
  GrowTo(pool_, aligned + size, kInvalid);
  while (end < aligned) {
    int k = 0;
    while (k + 1 < size_class && end % (kMinSlot << (k + 1)) == 0) ++k;
    FreeSlot(end, static_cast<uint8_t>(k));
    end += kMinSlot << k;
  }
  return aligned;
}

void MeshStore::FreeSlot(uint32_t offset, uint8_t size_class) {
  uint32_t block = offset / (kMinSlot << size_class);
  int k = size_class;
  while (k + 1 < kNumClasses && free_slots_[k].Contains(block ^ 1)) {
    free_slots_[k].Take(block ^ 1);
    block /= 2;
    ++k;
  }
  free_slots_[k].Release(block);
}

VertexId MeshStore::AddVertex(Vec3 pos, double height, int32_t layer, uint8_t box_mask) {
  VertexId v;
  if (!free_vertices_.empty()) {
    v = free_vertices_.TakeLowest();
  } else {
    v = static_cast<VertexId>(vtx_.size());
    PushBack(vtx_, VertexRecord{});
  }
  VertexRecord& r = vtx_[v];
  r.pos = pos;
  r.height = height;
  r.layer = layer;
  r.box = box_mask;
  r.alive = 1;
  r.rad = 1.0;
  r.aux = kInvalid;
  r.adj = AdjSlot{AllocSlot(0), 0};
  r.size_class = 0;
  ++live_vertices_;
  return v;
}

void MeshStore::Reserve(size_t vertices, size_t triangles) {
  auto beyond = [](size_t n, size_t free) { return n > free ? n - free : 0; };
  const size_t new_vertices = beyond(vertices, free_vertices_.size());
  const size_t new_triangles = beyond(triangles, free_triangles_.size());
  ReserveFor(vtx_, vtx_.size() + new_vertices);
  ReserveFor(tris_, tris_.size() + new_triangles);
  // Every new vertex takes a slot of the smallest class; the few that outgrow it take more.
  size_t free_smallest = 0;  // free slots of the smallest class, larger ones split
  for (int k = 0; k < kNumClasses; ++k) free_smallest += free_slots_[k].size() << k;
  ReserveFor(pool_, pool_.size() + beyond(vertices, free_smallest) * kMinSlot);
}

void MeshStore::LinkTriangle(VertexId v, TriId t) {
  VertexRecord& r = vtx_[v];
  ++r.star;
  AdjSlot& s = r.adj;
  const uint32_t cap = kMinSlot << r.size_class;
  if (s.count == cap) {
    // Grow into the next size class; the old slot goes back to its free list.
    assert(r.size_class + 1 < kNumClasses);
    const auto cls = static_cast<uint8_t>(r.size_class + 1);
    const uint32_t off = AllocSlot(cls);  // may reallocate pool_
    std::copy_n(pool_.begin() + s.offset, s.count, pool_.begin() + off);
    FreeSlot(s.offset, r.size_class);
    s.offset = off;
    r.size_class = cls;
  }
  pool_[s.offset + s.count++] = t;
}

void MeshStore::UnlinkTriangle(VertexId v, TriId t) {
  ++vtx_[v].star;
  AdjSlot& s = vtx_[v].adj;
  TriId* begin = pool_.data() + s.offset;
  TriId* end = begin + s.count;
  TriId* it = std::find(begin, end, t);
  assert(it != end);
  *it = *(end - 1);  // order of incident triangles is not meaningful
  --s.count;
}

TriId MeshStore::AddTriangle(VertexId a, VertexId b, VertexId c) {
  assert(vertex_alive(a) && vertex_alive(b) && vertex_alive(c));
  TriId t;
  if (!free_triangles_.empty()) {
    t = free_triangles_.TakeLowest();
    tris_[t] = {a, b, c};
  } else {
    t = static_cast<TriId>(tris_.size());
    PushBack(tris_, std::array<VertexId, 3>{a, b, c});
  }
  LinkTriangle(a, t);
  LinkTriangle(b, t);
  LinkTriangle(c, t);
  ++live_triangles_;
  return t;
}

void MeshStore::RemoveTriangle(TriId t) {
  assert(triangle_alive(t));
  for (VertexId v : tris_[t]) UnlinkTriangle(v, t);
  free_triangles_.Release(t);
  --live_triangles_;
}

void MeshStore::RemoveVertex(VertexId v) {
  assert(vertex_alive(v) && vtx_[v].adj.count == 0);
  FreeSlot(vtx_[v].adj.offset, vtx_[v].size_class);
  vtx_[v].adj = AdjSlot{};
  vtx_[v].size_class = 0;
  vtx_[v].alive = 0;
  free_vertices_.Release(v);
  --live_vertices_;
}

void MeshStore::MoveTriangles(VertexId from, VertexId to) {
  // Unlinking each triangle from `from` one by one (a search in its list each) is wasted
  // work when the whole list goes: re-point the corners, append to `to`, empty the list.
  for (uint32_t i = 0; i < vtx_[from].adj.count; ++i) {
    const TriId t = pool_[vtx_[from].adj.offset + i];  // LinkTriangle may move pool_: index it
    auto& tri = tris_[t];
    tri[CornerOf(tri, from)] = to;
    for (VertexId v : tri) ++vtx_[v].star;  // their triangle has a new corner
    LinkTriangle(to, t);
  }
  vtx_[from].adj.count = 0;
}

IndexedMesh MeshStore::Snapshot(std::vector<uint32_t>* vertex_map) const {
  IndexedMesh out;
  std::vector<uint32_t> local_map;
  std::vector<uint32_t>& map = vertex_map ? *vertex_map : local_map;
  map.assign(vtx_.size(), kInvalid);
  AppendSnapshot(&out, &map);
  return out;
}

void MeshStore::AppendSnapshot(IndexedMesh* out, std::vector<uint32_t>* vertex_map) const {
  std::vector<uint32_t>& map = *vertex_map;
  assert(map.size() >= vtx_.size());
  out->indices.reserve(out->indices.size() + live_triangles_ * 3);
  out->positions.reserve(out->positions.size() + live_vertices_);
  // Vertices in order of first use by a live triangle, triangles in id order: the result
  // depends only on the store's content, so equal runs give byte-identical snapshots.
  for (TriId t = 0; t < tris_.size(); ++t) {
    if (free_triangles_.Contains(t)) continue;
    for (VertexId v : tris_[t]) {
      if (map[v] == kInvalid) {
        map[v] = static_cast<uint32_t>(out->positions.size());
        out->positions.push_back(vtx_[v].pos);
      }
      out->indices.push_back(map[v]);
    }
  }
}

void MeshStore::set_patch(TriId t, uint32_t p) {
  if (patch_.size() <= t) patch_.resize(std::max<size_t>(t + 1, patch_.size() * 3 / 2), 0);
  patch_[t] = p;
}

uint32_t MeshStore::PatchOf(LabelPair pair) {
  const auto [it, added] =
      pair_index_.try_emplace({pair.inside, pair.outside}, static_cast<uint32_t>(pairs_.size()));
  if (added) pairs_.push_back(pair);
  return it->second;
}

void MeshStore::CompactPairs() {
  std::vector<uint32_t> renumber(pairs_.size(), kInvalid);
  for (TriId t = 0; t < tris_.size(); ++t) {
    if (!free_triangles_.Contains(t)) renumber[patch_[t]] = 0;
  }
  std::vector<LabelPair> kept;
  decltype(pair_index_) index;
  for (uint32_t p = 0; p < pairs_.size(); ++p) {
    if (renumber[p] == kInvalid) continue;
    renumber[p] = static_cast<uint32_t>(kept.size());
    index.try_emplace({pairs_[p].inside, pairs_[p].outside}, renumber[p]);
    kept.push_back(pairs_[p]);
  }
  for (TriId t = 0; t < tris_.size(); ++t) {
    if (!free_triangles_.Contains(t)) patch_[t] = renumber[patch_[t]];
  }
  pairs_ = std::move(kept);
  pair_index_ = std::move(index);
}

bool MeshStore::OnePatchAround(VertexId v) const {
  if (vertex_triangles(v).empty()) return false;
  const uint32_t p = patch_[vertex_triangles(v)[0]];
  for (TriId t : vertex_triangles(v)) {
    for (VertexId x : triangle(t)) {
      for (TriId u : vertex_triangles(x)) {
        if (patch_[u] != p) return false;
      }
    }
  }
  return true;
}

std::vector<uint32_t> MeshStore::SnapshotPatches() const {
  std::vector<uint32_t> out;
  out.reserve(live_triangles_);
  for (TriId t = 0; t < tris_.size(); ++t) {
    if (!free_triangles_.Contains(t)) out.push_back(patch_[t]);
  }
  return out;
}

size_t MeshStore::VertexBytes() { return sizeof(VertexRecord) + kMinSlot * sizeof(TriId); }
size_t MeshStore::TriangleBytes() { return sizeof(std::array<VertexId, 3>); }

size_t MeshStore::MemoryBytes() const {
  size_t b = vtx_.MemoryBytes() + free_vertices_.MemoryBytes() + tris_.MemoryBytes() +
             free_triangles_.MemoryBytes() + pool_.MemoryBytes();
  for (const auto& f : free_slots_) b += f.MemoryBytes();
  b += patch_.capacity() * sizeof(uint32_t) + pairs_.capacity() * sizeof(LabelPair) +
       pair_index_.capacity() * (sizeof(std::pair<LabelId, LabelId>) + sizeof(uint32_t) + 1);
  return b;
}

}  // namespace tandem
