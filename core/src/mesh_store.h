// MeshStore: the mutable triangle mesh shared by the layer extractor and the simplifier.
//
// Data-oriented on purpose: flat arrays with 32-bit ids, no pointers; a vertex's fields sit in
// one 64-byte record (the simplifier reads them together at random ids, see VertexRecord),
// triangles are an array of index triples. Deletion is a flag plus a free list (the lowest
// free id comes back first: free_ids.h; a dead triangle's flag is its bit there), so ids stay
// stable while the simplifier works; compaction happens only in Snapshot(). Each vertex owns
// a slot in one pool of triangle ids (its incident triangles); slots come in size classes of
// 6 << k, aligned to their size, with a free list per class (lowest offset first, as the ids)
// and a freed slot merged with its free twin (a buddy allocator), so adding a triangle never
// allocates per element and freed slots serve any class.
#ifndef TANDEM_MESH_STORE_H_
#define TANDEM_MESH_STORE_H_

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "free_ids.h"
#include "pod_array.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"
#include "tandem/types.h"

namespace tandem {

// MeshStore::box_mask holds a vertex's flags: the faces of the grid's box it lies on
// (BoxFace) and two states that also keep it from moving (VertexFlag).
enum BoxFace : uint8_t {
  kBoxXMin = 1, kBoxXMax = 2, kBoxYMin = 4, kBoxYMax = 8, kBoxZMin = 16, kBoxZMax = 32,
};
inline constexpr uint8_t kBoxFaces = kBoxXMin | kBoxXMax | kBoxYMin | kBoxYMax | kBoxZMin | kBoxZMax;
// The axes (bit 0: x, 1: y, 2: z) whose coordinate the box faces in `box_mask` fix.
inline uint8_t FixedAxes(uint8_t box_mask) {
  uint8_t axes = 0;
  if (box_mask & (kBoxXMin | kBoxXMax)) axes |= 1;
  if (box_mask & (kBoxYMin | kBoxYMax)) axes |= 2;
  if (box_mask & (kBoxZMin | kBoxZMax)) axes |= 4;
  return axes;
}
// An axis's (0: x, 1: y, 2: z) lower face of the grid's box, and both its faces.
inline uint8_t MinFace(int axis) { return static_cast<uint8_t>(kBoxXMin << (2 * axis)); }
inline uint8_t AxisFaces(int axis) { return static_cast<uint8_t>(3u << (2 * axis)); }
// The reference point of a contraction ab (MinimizeQuadric's): the midpoint, with the
// box-fixed coordinates taken from the end on more box faces (ma, mb: their masks; one's
// faces include the other's).
inline Vec3 BoxedMidpoint(Vec3 pa, uint8_t ma, Vec3 pb, uint8_t mb) {
  const Vec3 big = ((ma & mb) == ma) ? pb : pa;
  const uint8_t fixed = FixedAxes(ma | mb);
  Vec3 ref = (pa + pb) * 0.5;
  for (int i = 0; i < 3; ++i) {
    if ((fixed >> i) & 1) ref[i] = big[i];
  }
  return ref;
}
enum VertexFlag : uint8_t {
  // On a grid edge of the plane between two slabs (slabs.h), shared with the neighbouring
  // slab. The simplifier never moves it until the slabs are merged.
  kSeam = 64,
  // Sealed (sealer.h): it never moves again and no contraction touches it; its triangles
  // leave the store once all their corners are sealed.
  kFrozen = 128,
};

// What DELAY does with an edge of a new layer's triangle, each edge of the layer queued once
// (LayerExtractor::CommitLayer lists them, Simplifier::Delay follows): kEdgeBelow, on the
// plane below, in a face the cube underneath shares, so queued with that layer; kEdgeOnce,
// this triangle's only (on the front, the box, a seam); kEdgeShared, in another triangle of
// the layer too (inside the cube, or on a face the neighbouring cube shares), queued from
// the triangle where it runs from the lower vertex id to the higher. A label layer's edge
// with a new end lies in the layer's triangles only: kEdgeOnce from the one of least id,
// kEdgeBelow from the others; its edges between two older vertices are kEdgeSearch, whose
// other triangles DELAY looks up in the store. A triangle's three (edge k joins corners k
// and k + 1) take 2 bits each, edge 0 lowest: LayerEdges.
enum LayerEdge : uint8_t { kEdgeBelow = 0, kEdgeOnce = 1, kEdgeShared = 2, kEdgeSearch = 3 };
inline uint8_t LayerEdges(LayerEdge e0, LayerEdge e1, LayerEdge e2) {
  return static_cast<uint8_t>(e0 | (e1 << 2) | (e2 << 4));
}
inline LayerEdge EdgeOf(uint8_t layer_edges, int k) {
  return static_cast<LayerEdge>((layer_edges >> (2 * k)) & 3);
}

// Which corner (0, 1, 2) of triangle `tri` is v, v being one of them. Without branches: which
// corner it is follows no pattern a branch predictor could learn.
inline int CornerOf(const std::array<VertexId, 3>& tri, VertexId v) {
  return static_cast<int>(tri[1] == v) | (static_cast<int>(tri[2] == v) << 1);
}
// The corner after and before corner i (0, 1, 2) in the triangle's order.
inline constexpr int kNextCorner[3] = {1, 2, 0};
inline constexpr int kPrevCorner[3] = {2, 0, 1};

class MeshStore {
 public:
  // Adds a vertex at physical position `pos`. `height` is its z in slice units (index
  // space), `layer` the extraction layer that created it, `box_mask` the BoxFace bits.
  VertexId AddVertex(Vec3 pos, double height, int32_t layer, uint8_t box_mask);
  // Adds triangle (a, b, c), counter-clockwise seen from outside. Vertices must be alive.
  TriId AddTriangle(VertexId a, VertexId b, VertexId c);
  // Makes room for `vertices` more vertices and `triangles` more triangles at once (a
  // layer's commit): the arrays then grow by what comes, not by double (grow.h).
  void Reserve(size_t vertices, size_t triangles);
  // Removes a triangle and unlinks it from its vertices' lists.
  void RemoveTriangle(TriId t);
  // Removes a vertex; it must have no incident triangles left.
  void RemoveVertex(VertexId v);
  // Every triangle of `from` replaces its corner `from` by `to` and joins to's list (in
  // from's list order); from's list is left empty. The contraction's last step.
  void MoveTriangles(VertexId from, VertexId to);

  bool vertex_alive(VertexId v) const { return v < vtx_.size() && vtx_[v].alive; }
  bool triangle_alive(TriId t) const { return t < tris_.size() && !free_triangles_.Contains(t); }
  const std::array<VertexId, 3>& triangle(TriId t) const { return tris_[t]; }
  std::span<const TriId> vertex_triangles(VertexId v) const {
    return {pool_.data() + vtx_[v].adj.offset, vtx_[v].adj.count};
  }

  Vec3 position(VertexId v) const { return vtx_[v].pos; }
  void set_position(VertexId v, Vec3 p) { vtx_[v].pos = p; }
  double height(VertexId v) const { return vtx_[v].height; }
  void set_height(VertexId v, double h) { vtx_[v].height = h; }
  int32_t layer(VertexId v) const { return vtx_[v].layer; }
  void set_layer(VertexId v, int32_t l) { vtx_[v].layer = l; }
  uint8_t box_mask(VertexId v) const { return vtx_[v].box; }
  // The time-lag's radius of the vertex's patch (slice units; 1 for a new vertex): the
  // simplifier's bookkeeping, kept here beside height and layer, which it reads with it.
  double rad(VertexId v) const { return vtx_[v].rad; }
  // Starts loading v's record (a hint for loops that know which vertices come next).
  void Prefetch(VertexId v) const { __builtin_prefetch(&vtx_[v]); }
  // v's list of triangles, and the triangles on it (the record, and for PrefetchFan the list,
  // must be in cache already, or these wait for them).
  void PrefetchStar(VertexId v) const { __builtin_prefetch(pool_.data() + vtx_[v].adj.offset); }
  void PrefetchFan(VertexId v) const {
    for (TriId t : vertex_triangles(v)) __builtin_prefetch(&tris_[t]);
  }
  void set_rad(VertexId v, double r) { vtx_[v].rad = r; }
  void set_box_mask(VertexId v, uint8_t m) { vtx_[v].box = m; }

  // Changes whenever a triangle around v is added or removed or one of its corners changes
  // (MoveTriangles): while it stays, v's star has the same triangles with the same corners,
  // so a link condition at v decides as it did (Simplifier: link refusals wait for it).
  // Positions are not covered.
  uint32_t star_stamp(VertexId v) const { return vtx_[v].star; }
  // A 32-bit value of the store's user, in the vertex's record (kInvalid when the vertex is
  // made): the simplifier keeps there where v's quadric is kept in full (simplifier.h), read
  // with the position, not at another random address first.
  uint32_t aux(VertexId v) const { return vtx_[v].aux; }
  void set_aux(VertexId v, uint32_t x) { vtx_[v].aux = x; }

  // One past the largest id ever handed out (ids below may be dead).
  uint32_t vertex_capacity() const { return static_cast<uint32_t>(vtx_.size()); }
  uint32_t triangle_capacity() const { return static_cast<uint32_t>(tris_.size()); }
  size_t num_vertices() const { return live_vertices_; }
  size_t num_triangles() const { return live_triangles_; }

  // Compacted copy of the live mesh. If vertex_map is given, it receives for every live
  // store vertex its index in the snapshot (kInvalid for dead ones). Vertices without
  // triangles are dropped.
  IndexedMesh Snapshot(std::vector<uint32_t>* vertex_map = nullptr) const;
  // Appends the live triangles to *out as Snapshot orders them. (*vertex_map)[v] (sized to
  // vertex_capacity()) is the output index of vertex v: entries other than kInvalid are
  // used as given (a vertex already in *out, e.g. welded), the others are filled in.
  void AppendSnapshot(IndexedMesh* out, std::vector<uint32_t>* vertex_map) const;

  // Label mode (SessionOptions::labels): each triangle's patch, an index into pairs(), the
  // two labels it separates. Kept beside the triangles only once EnableLabels is called, so
  // an iso-surface store carries nothing for it.
  void EnableLabels() { labeled_ = true; }
  bool labeled() const { return labeled_; }
  uint32_t patch(TriId t) const { return patch_[t]; }
  void set_patch(TriId t, uint32_t p);
  const std::vector<LabelPair>& pairs() const { return pairs_; }
  const LabelPair& pair_of(TriId t) const { return pairs_[patch_[t]]; }
  uint32_t PatchOf(LabelPair pair);  // its index in pairs(), added if new
  // Whether v has triangles, and they and its neighbours' all lie in one patch (where labels
  // meet, the triangles face every way and a vertex normal means nothing).
  bool OnePatchAround(VertexId v) const;
  // Keeps only the pairs of live triangles, in the order of their first patch index, and
  // renumbers the patches.
  void CompactPairs();
  // The patches of the live triangles in Snapshot's order (triangle id order).
  std::vector<uint32_t> SnapshotPatches() const;

  // Bytes the store's arrays take in memory (PodArray::MemoryBytes: capacity, but for a
  // mapped array only the pages written): for memory figures and the session budget.
  size_t MemoryBytes() const;
  // What a vertex and a triangle take that need a new id (their records, a vertex's
  // smallest slot of the incidence pool).
  static size_t VertexBytes();
  static size_t TriangleBytes();
  // The incidence pool's share of MemoryBytes (for tests of its allocator).
  size_t IncidenceBytes() const { return pool_.MemoryBytes(); }

 private:
  struct AdjSlot {  // capacity = kMinSlot << VertexRecord::size_class
    uint32_t offset = 0;
    uint32_t count = 0;
  };
  // Most vertices have at most 6 triangles: a smallest slot of 8 left much of the pool empty
  // (docs/decisions.md 15).
  static constexpr uint32_t kMinSlot = 6;
  static constexpr int kNumClasses = 24;

  uint32_t AllocSlot(uint8_t size_class);
  void FreeSlot(uint32_t offset, uint8_t size_class);
  void LinkTriangle(VertexId v, TriId t);
  void UnlinkTriangle(VertexId v, TriId t);

  // Vertices: one record each, all of a vertex in one cache line: the simplifier reads a
  // neighbour's position, height, rad, layer, box faces and triangle list together, at
  // random ids (ids are recycled). docs/decisions.md: why one record.
  struct alignas(64) VertexRecord {
    Vec3 pos;
    double height = 0;
    AdjSlot adj;
    int32_t layer = 0;
    uint8_t box = 0;
    uint8_t alive = 0;
    uint8_t size_class = 0;  // of adj
    uint32_t star = 0;  // star_stamp (in what was padding)
    uint32_t aux = kInvalid;  // aux() (in what was padding too)
    double rad = 1.0;
  };
  static_assert(sizeof(VertexRecord) == 64);
  PodArray<VertexRecord> vtx_;
  FreeIds free_vertices_;  // handed out lowest first (free_ids.h)
  size_t live_vertices_ = 0;

  // Triangles.
  PodArray<std::array<VertexId, 3>> tris_;
  FreeIds free_triangles_;  // also the dead ones' flags: a bit a triangle, not a byte
  size_t live_triangles_ = 0;

  // Label mode: patch per triangle id, the pairs and their index.
  bool labeled_ = false;
  std::vector<uint32_t> patch_;
  std::vector<LabelPair> pairs_;
  absl::flat_hash_map<std::pair<LabelId, LabelId>, uint32_t> pair_index_;

  // Incidence pool and its per-size-class free lists.
  PodArray<TriId> pool_;
  std::array<FreeIds, kNumClasses> free_slots_;
};

}  // namespace tandem

#endif  // TANDEM_MESH_STORE_H_
