#include "tandem/mesh_store.h"

#include <algorithm>
#include <cassert>

namespace tandem {

uint32_t MeshStore::AllocSlot(uint8_t size_class) {
  auto& free_list = free_slots_[size_class];
  if (!free_list.empty()) {
    uint32_t off = free_list.back();
    free_list.pop_back();
    return off;
  }
  const uint32_t cap = kMinSlot << size_class;
  const uint32_t off = static_cast<uint32_t>(pool_.size());
  pool_.resize(pool_.size() + cap, kInvalid);
  return off;
}

void MeshStore::FreeSlot(uint32_t offset, uint8_t size_class) {
  free_slots_[size_class].push_back(offset);
}

VertexId MeshStore::AddVertex(Vec3 pos, double height, int32_t layer, uint8_t box_mask) {
  VertexId v;
  if (!free_vertices_.empty()) {
    v = free_vertices_.back();
    free_vertices_.pop_back();
    pos_[v] = pos;
    height_[v] = height;
    layer_[v] = layer;
    box_[v] = box_mask;
    vtx_alive_[v] = 1;
  } else {
    v = static_cast<VertexId>(pos_.size());
    pos_.push_back(pos);
    height_.push_back(height);
    layer_.push_back(layer);
    box_.push_back(box_mask);
    vtx_alive_.push_back(1);
    adj_.emplace_back();
  }
  adj_[v] = AdjSlot{AllocSlot(0), 0, 0};
  ++live_vertices_;
  return v;
}

void MeshStore::LinkTriangle(VertexId v, TriId t) {
  AdjSlot& s = adj_[v];
  const uint32_t cap = kMinSlot << s.size_class;
  if (s.count == cap) {
    // Grow into the next size class; the old slot goes back to its free list.
    assert(s.size_class + 1 < kNumClasses);
    const uint8_t cls = static_cast<uint8_t>(s.size_class + 1);
    const uint32_t off = AllocSlot(cls);  // may reallocate pool_
    std::copy_n(pool_.begin() + s.offset, s.count, pool_.begin() + off);
    FreeSlot(s.offset, s.size_class);
    s.offset = off;
    s.size_class = cls;
  }
  pool_[s.offset + s.count++] = t;
}

void MeshStore::UnlinkTriangle(VertexId v, TriId t) {
  AdjSlot& s = adj_[v];
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
    t = free_triangles_.back();
    free_triangles_.pop_back();
    tris_[t] = {a, b, c};
    tri_alive_[t] = 1;
  } else {
    t = static_cast<TriId>(tris_.size());
    tris_.push_back({a, b, c});
    tri_alive_.push_back(1);
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
  tri_alive_[t] = 0;
  free_triangles_.push_back(t);
  --live_triangles_;
}

void MeshStore::RemoveVertex(VertexId v) {
  assert(vertex_alive(v) && adj_[v].count == 0);
  FreeSlot(adj_[v].offset, adj_[v].size_class);
  adj_[v] = AdjSlot{};
  vtx_alive_[v] = 0;
  free_vertices_.push_back(v);
  --live_vertices_;
}

void MeshStore::MoveTriangles(VertexId from, VertexId to) {
  // Unlinking each triangle from `from` one by one (a search in its list each) is wasted
  // work when the whole list goes: re-point the corners, append to `to`, empty the list.
  for (uint32_t i = 0; i < adj_[from].count; ++i) {
    const TriId t = pool_[adj_[from].offset + i];  // LinkTriangle may move pool_: index it
    for (VertexId& v : tris_[t]) {
      if (v == from) {
        v = to;
        break;
      }
    }
    LinkTriangle(to, t);
  }
  adj_[from].count = 0;
}

Vec3 MeshStore::TriangleNormalTimesTwoArea(TriId t) const {
  const auto& tri = tris_[t];
  const Vec3 a = pos_[tri[0]];
  return Cross(pos_[tri[1]] - a, pos_[tri[2]] - a);
}

IndexedMesh MeshStore::Snapshot(std::vector<uint32_t>* vertex_map) const {
  IndexedMesh out;
  std::vector<uint32_t> local_map;
  std::vector<uint32_t>& map = vertex_map ? *vertex_map : local_map;
  map.assign(pos_.size(), kInvalid);
  AppendSnapshot(&out, &map);
  return out;
}

void MeshStore::AppendSnapshot(IndexedMesh* out, std::vector<uint32_t>* vertex_map) const {
  std::vector<uint32_t>& map = *vertex_map;
  assert(map.size() >= pos_.size());
  out->indices.reserve(out->indices.size() + live_triangles_ * 3);
  out->positions.reserve(out->positions.size() + live_vertices_);
  // Vertices in order of first use by a live triangle, triangles in id order: the result
  // depends only on the store's content, so equal runs give byte-identical snapshots.
  for (TriId t = 0; t < tris_.size(); ++t) {
    if (!tri_alive_[t]) continue;
    for (VertexId v : tris_[t]) {
      if (map[v] == kInvalid) {
        map[v] = static_cast<uint32_t>(out->positions.size());
        out->positions.push_back(pos_[v]);
      }
      out->indices.push_back(map[v]);
    }
  }
}

size_t MeshStore::MemoryBytes() const {
  size_t b = pos_.capacity() * sizeof(Vec3) + height_.capacity() * sizeof(double) +
             layer_.capacity() * sizeof(int32_t) + box_.capacity() + vtx_alive_.capacity() +
             adj_.capacity() * sizeof(AdjSlot) + free_vertices_.capacity() * sizeof(VertexId) +
             tris_.capacity() * sizeof(tris_[0]) + tri_alive_.capacity() +
             free_triangles_.capacity() * sizeof(TriId) + pool_.capacity() * sizeof(TriId);
  for (const auto& f : free_slots_) b += f.capacity() * sizeof(uint32_t);
  return b;
}

}  // namespace tandem
