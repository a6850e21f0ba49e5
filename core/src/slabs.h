// Slabs: the grid split along x (SessionOptions::parts), each slab with its own extractor, mesh
// store and queues, so that slabs can be stepped side by side.
//
// Slab p owns cube columns [c_p, c_{p+1}) and grid columns c_p .. c_{p+1}: neighbours share the
// plane of grid column c_{p+1}. The vertices on that plane's y- and z-edges belong to both
// (kSeam) and are never contracted by a slab's own schedule, so every contraction inside a slab
// is exactly a contraction of the whole mesh (same stars, same link condition); a sealed
// session coarsens them, in both slabs at once, only as they settle (SettleSeams). At the end the
// slabs are merged into the first, the seam copies welded (their quadrics add up to the whole
// one), and the schedule goes on from the edges at the seam (schedule.h). The split is part of
// the result: parts = 1 is the paper's algorithm with nothing deferred.
#ifndef TANDEM_SLABS_H_
#define TANDEM_SLABS_H_

#include <array>
#include <functional>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "layer_extractor.h"
#include "mesh_store.h"
#include "meter.h"
#include "sealer.h"
#include "simplifier.h"
#include "tandem/mesh.h"
#include "tandem/options.h"
#include "tandem/stats.h"
#include "tandem/volume.h"

namespace tandem {

class TargetControl;

struct Slab {
  // `meter`: the session's (meter.h), which must outlive the slab.
  Slab(const ExtractorConfig& ec, const SimplifierOptions& so, Meter* meter);
  // The session's budget: what the extractor holds, its staged layer counted as committed
  // (reported by the extractor as it scans a slice), and what the rest of the slab holds
  // (HoldingBytes, reported by CheckHolding: by the simplifier as it queues and contracts,
  // and by the schedule after each layer's commit and SIMPLIFY step).
  Meter* meter;
  Meter::Account extraction{meter}, holding{meter};
  size_t HoldingBytes() const;
  // Reports HoldingBytes while `doing` slice `slice`; throws SessionStop when the session
  // must stop.
  void CheckHolding(const char* doing, int64_t slice) {
    holding.Hold(HoldingBytes(), doing, slice);
  }
  MeshStore store;
  LayerExtractor extractor;
  Simplifier simplifier;
  std::unique_ptr<Sealer> sealer;  // SessionOptions::seal
  int64_t x0 = 0;                  // first grid column
  size_t index = 0;                // in the session's slabs
  // The layer last extracted (the next SIMPLIFY step's DELAY) and this slab's seam vertices
  // not yet paired with the neighbour's copies, per seam face, in order.
  std::vector<TriId> new_tris;
  std::vector<uint8_t> new_edges;  // the extractor's LayerEdges of new_tris
  std::vector<VertexId> new_verts;
  std::array<std::vector<VertexId>, 2> seam_log;
  std::vector<int64_t> trace;  // this slab's triangles after every step
  PhaseTimes time;
  int64_t triangles_extracted = 0;
  // The tandem schedules simplify layer k while layer k+1 is extracted (schedule.h).
  bool simplify_pending = false;
  int64_t pending_front = 0;
  // SessionOptions::target_triangles: E0 follows the session's control (schedule.h; null:
  // no target); the triangle counts of the last layers as extracted, newest last; and who
  // to call when this slab's report completed a decision (slabs waiting for it may go on).
  TargetControl* target = nullptr;
  std::vector<int64_t> recent_layers;
  std::function<void()> waker;
  int64_t seam_vertices = 0;  // made so far
};

// One vertex of the plane two slabs share, made by both from the same grid edge: its copy
// in each slab's store (ids of two stores, never one vertex pair of a store).
struct SeamVertex {
  VertexId left;   // in slab s
  VertexId right;  // in slab s+1
};
// seams[s]: the vertices slabs s and s+1 share, not settled yet, as the slabs made them.
using Seams = std::vector<std::vector<SeamVertex>>;

// The number of slabs a session with these options uses over `grid` (SessionOptions::parts).
int SlabCount(const VolumeInfo& grid, const SessionOptions& options);

// The slabs of `grid` in the engine frame (spacing divided by `scale`), ready for slice 0;
// `batches`: where the simplifiers evaluate half of their large batches (null: in place);
// `meter`: the session's budget, told what the slabs hold as planned.
std::vector<std::unique_ptr<Slab>> MakeSlabs(const VolumeInfo& grid, const SessionOptions& options,
                                             double scale, int count, Executor* batches,
                                             Meter* meter);

// Sealing with `count` slabs: slab p's sealer hands out ids p + k * stride, and with several
// slabs the ids k * stride + count are the settled seam vertices' (SettleSeams).
inline uint32_t SealerIdStride(int count) {
  return count == 1 ? 1u : static_cast<uint32_t>(count) + 1u;
}

// Sealing: seam vertices `settle_slices` (SessionOptions::seam_settle_slices) or more below
// the front freeze, in both slabs (Sealer::FreezeShared), and leave `seams`; so do a seam's
// oldest past its newest `hold_vertices` (SessionOptions::seam_hold_vertices), but none within
// kSeamSettleFloor slices of the front. `seam_ids` counts the ids handed out. So the
// triangles at the seams that wait for the merge follow the front, not the depth. With `coarsen` (a simplifying session) the settling part of each
// seam is first coarsened along itself (CoarsenSettlingSeam), and its copies left at one
// point are moved apart (MendSettlingSeam); what a settled seam vertex gives up is a
// contraction off the seam's plane at the merge.
void SettleSeams(const std::vector<std::unique_ptr<Slab>>& slabs, Seams* seams, double front,
                 int64_t settle_slices, int64_t hold_vertices, bool coarsen, int64_t* seam_ids);
// Seam vertices this close to the front wait, however many a seam holds: their neighbours in
// the slabs are still being simplified.
inline constexpr int64_t kSeamSettleFloor = 64;

// Contracts edges of the seam between `left` and `right` whose ends are both at height
// <= limit, in both slabs at once: cheapest first, each to the point of the seam's plane
// that minimises both sides' quadrics, while that costs at most E0 and passes the link
// condition of the welded mesh, each slab's own and the geometry checks on both sides.
// Seam vertices on the grid's box keep to its faces (two on different faces stay, as in
// Simplifier::Evaluate), and a slab's own vertices on it stay. Returns the number of
// contractions; the contracted-away pairs are dead in both stores (the caller drops them
// from `pairs`).
int64_t CoarsenSettlingSeam(Slab& left, Slab& right, const std::vector<SeamVertex>& pairs,
                            double limit);

// Mends the zero-area triangles at the seam vertices of `pairs` at height <= limit (alive),
// which are about to settle: they move apart within the seam's plane, both copies at once
// (see MendSettlingSeamSide in slabs.cc). Run after CoarsenSettlingSeam.
void MendSettlingSeam(Slab& left, Slab& right, const std::vector<SeamVertex>& pairs, double limit);

// Moves the slabs' new seam vertices into `seams` (both sides list the same grid edges in the
// same order). INTERNAL if two neighbours disagree.
absl::Status PairSeams(const std::vector<std::unique_ptr<Slab>>& slabs, Seams* seams);

// Appends the slabs' meshes to *out, each seam vertex once (the index of its first copy).
void AppendWeldedSnapshot(const std::vector<std::unique_ptr<Slab>>& slabs, const Seams& seams,
                          IndexedMesh* out);

// A label session's: the patches of the triangles AppendWeldedSnapshot appends, in its order,
// appended to *patch as indices into *pairs, which gets the slabs' pairs it lacks.
void AppendWeldedPatches(const std::vector<std::unique_ptr<Slab>>& slabs,
                         std::vector<uint32_t>* patch, std::vector<LabelPair>* pairs);

// What the slabs merged away had counted.
struct MergedCounts {
  int64_t crossed_cubes = 0, triangles_extracted = 0;
  PhaseTimes time;
};

// Merges every slab into the first (the others are freed one by one as they are copied) and
// welds the seams. Returns the welded seam vertices (ids in the first slab), from which the
// schedule goes on.
std::vector<VertexId> MergeSlabs(std::vector<std::unique_ptr<Slab>>* slabs, Seams* seams,
                                 bool simplify, MergedCounts* merged);

}  // namespace tandem

#endif  // TANDEM_SLABS_H_
