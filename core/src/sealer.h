// Sealer: hands out, once, the part of the mesh behind the sweep that can never change again,
// and drops it from the mesh store, so that a session holds the front, not the whole mesh.
//
// A vertex freezes when its reach, height + rad (slice units, the time-lag bookkeeping of
// simplifier.h), lies at least `margin` slices below the front: from then on no contraction
// touches it (Simplifier::Freeze), and a triangle whose three corners are frozen can never
// change. Such a triangle is sealed: appended to the pending chunk, then removed from the
// store, and so is every frozen vertex left without triangles. A vertex is sag-corrected
// (sag_correction.h, through Simplifier::CorrectSagAt) when it freezes, never after: normals
// are those of its own triangles, of unfrozen neighbours' current fans, and of frozen
// neighbours as they were when they froze.
//
// Chunks name their vertices by global ids, handed out in sealing order; a vertex shared by two
// chunks appears in both with the same id and the same coordinates, so the union of all chunks,
// welded by id (WeldChunks), is the mesh. With several slabs (slabs.h) each has a sealer, and
// slab p of P hands out the ids p, p + P, p + 2P, ...: unique without a lock, and the same
// whichever thread steps which slab. A seam vertex (kSeam) does not freeze by its reach, nor
// does a vertex next to one (so that the seam can still be coarsened): the triangles around
// them stay in the slab until the merge, where the schedule goes on from the seam (slabs.h);
// then the merged sealer (Absorb) seals them. Far enough behind the front the session
// coarsens the seams and freezes their vertices in both slabs at once (SettleSeams,
// FreezeShared), so that a deep stream's seams do not pile up.
#ifndef TANDEM_SEALER_H_
#define TANDEM_SEALER_H_

#include <cstdint>
#include <span>
#include <vector>

#include "tandem/mesh.h"
#include "id_index.h"
#include "mesh_store.h"
#include "part_ids.h"
#include "pod_array.h"
#include "sag_correction.h"
#include "simplifier.h"
#include "slot_pool.h"
#include "tandem/types.h"

namespace tandem {

// One chunk of `pieces` (the slabs' chunks of one moment): vertices in increasing id, each
// once (a shared seam vertex may be in two), triangles and retired ids in the pieces' order.
SealedChunk JoinChunks(std::vector<SealedChunk> pieces);
// A label session's chunks: each one's triangles' pairs appended to *patch, as indices into
// *pairs, which gets every pair they hold, in increasing (inside, outside), each once.
void JoinPairs(std::span<const SealedChunk> chunks, std::vector<uint32_t>* patch,
               std::vector<LabelPair>* pairs);

class Sealer {
 public:
  // simplifier == nullptr: a full-resolution session (nothing is contracted; no sag).
  // Global ids first, first + stride, first + 2 stride, ...
  Sealer(MeshStore* store, Simplifier* simplifier, double margin, double sag_fraction,
         uint32_t id_first = 0, uint32_t id_stride = 1);

  // Vertices made by the last EXTRACT (unfrozen).
  void AddVertices(std::span<const VertexId> verts);
  // Freezes the vertices whose reach is at least `margin` below the front (every vertex when
  // front = +inf, the end of the stream) and seals what that completes; with an executor, a
  // large sag correction in ranges side by side (the same result).
  void Seal(double front, Executor* executor = nullptr);
  // Moves the triangles sealed since the last call into *out (false: none). out->index
  // counts this sealer's chunks.
  bool TakeChunk(SealedChunk* out);
  // Takes over the sealing state of `other`, whose store's vertices were copied into this
  // sealer's store (MergeSlabs): vertex v there is map[v] here. Its pending chunk joins this
  // one; its unfrozen vertices stay unfrozen. `welded`: its seam copies that were welded to
  // vertices of this store, which keep their own state.
  void Absorb(const Sealer& other, const PartVertexMap& map, std::span<const PartVertex> welded);
  // Freezes seam vertex v as it is, with the global id `id` that its copy in the neighbouring
  // slab gets too (the session hands these out, in an id space of its own); its triangles
  // are sealed as their other corners freeze. Its retirement, like any, is listed in a chunk:
  // the id is retired once both copies are (TandemSession::TakeSealed counts them).
  // `shape_error`: ε0 of the welded vertex (both sides' quadrics), for max_shape_error.
  void FreezeShared(VertexId v, GlobalId id, double shape_error);
  // Forgets the unfrozen vertices contracted away outside SIMPLIFY (CoarsenSettlingSeam),
  // whose ids the next EXTRACT may hand out again.
  void DropDead();
  // v's global id; kNoGlobalId before one was handed out.
  GlobalId id(VertexId v) const {
    const Kept* k = kept_.Find(v);
    return k != nullptr ? k->id : kNoGlobalId;
  }

  int64_t sealed_triangles() const { return sealed_triangles_; }
  int64_t pending_triangles() const { return static_cast<int64_t>(pend_tris_.size() / 3); }
  int64_t sealed_vertices() const { return handed_out_; }
  int64_t sag_corrected() const { return sag_corrected_; }
  double max_shape_error() const { return max_shape_error_; }  // over frozen vertices
  size_t MemoryBytes() const;

 private:
  // tris_ = the live triangles around `around` (`every`: in the store) whose three corners
  // are frozen, by id.
  void GatherSealable(std::span<const VertexId> around, bool every = false);
  struct Kept;
  Kept& HandOut(VertexId v);  // its global id (Kept::id), handed out on first use
  void TakePairs(SealedChunk* out) const;  // the pending triangles' patch and pairs
  void SetNormal(VertexId v, Vec3 n);  // normals_[its slot] = n, taking a slot
  void ReleaseNormal(VertexId v);      // its slot, if it has one, is free again
  VertexNormalTable Normals() const { return {normals_.values(), &normal_slot_}; }
  bool NextToSeam(VertexId v) const;  // some triangle at v has a seam vertex

  struct PendingVertex {
    GlobalId id;
    double height;
    Vec3 pos;
  };
  MeshStore* store_;
  Simplifier* simplifier_;
  double margin_, sag_fraction_;
  std::vector<VertexId> active_;  // unfrozen vertices (dead ones are dropped by Seal)
  // What the sealer keeps of a vertex, for the few in the store that have any: a frozen
  // vertex's global id (none before its first sealed triangle) and the pending chunk it was
  // last added to; and the slot of the normal it froze with, which it keeps while it is in
  // the store (its unfrozen neighbours' sag reads it; theirs are found again at each Seal and
  // let go). Kept per listed vertex, not by vertex id, since arrays by id would cost every
  // vertex of the part for a few thousand frozen ones (docs/decisions.md 18).
  struct Kept {
    GlobalId id = kNoGlobalId;
    uint32_t stamp = 0;
  };
  IdMap<Kept> kept_;
  IdMap<uint32_t> normal_slot_;
  SlotPool<Vec3> normals_;
  std::vector<TriId> fan_;  // VertexNormal's scratch
  // Scratch.
  std::vector<VertexId> freeze_, need_, drop_, sag_;
  std::vector<VertexId> shared_;  // frozen by FreezeShared since the last Seal
  std::vector<TriId> tris_;
  std::vector<TriId> later_;  // Seal's scratch: the triangles around the corners handed out
  // The pending chunk.
  std::vector<PendingVertex> pend_verts_;
  std::vector<GlobalId> pend_tris_;  // 3 per triangle
  std::vector<LabelPair> pend_pairs_;  // a label session's: the pair of each
  std::vector<GlobalId> pend_retired_;
  uint32_t chunk_stamp_ = 1;
  uint32_t next_id_ = 0;  // the next id handed out
  uint32_t id_stride_ = 1;
  int64_t handed_out_ = 0;  // ids handed out (absorbed sealers' included)
  int64_t chunks_ = 0;
  int64_t sealed_triangles_ = 0;
  int64_t sag_corrected_ = 0;
  double max_shape_error_ = 0;
};

}  // namespace tandem

#endif  // TANDEM_SEALER_H_
