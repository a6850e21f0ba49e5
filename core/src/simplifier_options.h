// SimplifierOptions: how a Simplifier runs (E0, α, the release rule of the schedule, and the
// policies of its units: chunked release, rise lists, parallel batches).
#ifndef TANDEM_SIMPLIFIER_OPTIONS_H_
#define TANDEM_SIMPLIFIER_OPTIONS_H_

#include <cstddef>
#include <cstdint>

#include "contraction_checks.h"
#include "tandem/executor.h"

namespace tandem {

// When an edge leaves the waiting queue W for Q (SessionOptions::schedule picks one).
enum class ReleaseRule : uint8_t {
  kImmediate,  // classical: every edge goes straight to Q
  kLayer,      // tandem without lag: key = max(layer(a), layer(b)) + 1
  kReach,      // tandem with time-lag: key = reach(c) = height(c) + rad(c)
};

struct SimplifierOptions {
  double error = 0;           // E0, physical units
  double alpha = 0;           // isotropy parameter in [0, 1]
  ReleaseRule release = ReleaseRule::kReach;
  double slice_spacing = 1;   // sz: converts lengths to slice units for rad()
  // Evaluate half of every large DELAY / ACTIVATE batch on this executor (pure work, pushed
  // in the same order: identical results); null: all on the calling thread.
  Executor* parallel = nullptr;
  double distance_guard = 0;  // K: see SessionOptions::distance_guard (0 = off)
  // kReach, the late lag: a contraction costing more than late_share x E0 over a patch at
  // least late_radius slices wide enters Q only once the front is past
  // height + (1 + late_lag) rad, not height + rad, so that a young region is simplified to
  // late_share x E0 and reaches E0 as it leaves the band (docs/decisions.md); 0: the paper's.
  double late_lag = 0;
  double late_share = 1;
  double late_radius = 0;
  // Q keeps edges costing up to keep x E0 (1: only what SIMPLIFY(E0) can pop). A target
  // triangle count raises E0 (RaiseError), and what Q kept then needs no new evaluation.
  double keep = 1;
  // E0 will rise (a target triangle count): the edges Q drops, and those SIMPLIFY refuses
  // (ε0 above E0, the link condition, the geometry checks), are listed, so that a rise
  // offers Q those it brings in reach instead of evaluating every edge of the mesh again
  // (RaiseError), and a merge hands them on (AdoptQueues).
  bool rises = false;
  // Activate: a release of more edges than this enters Q a chunk at a time
  // (2^12: 256 KiB of Q entries; docs/decisions.md).
  size_t release_chunk = size_t{1} << 12;
  // The side of the tiles of the xy plane (engine units, x and y) a chunked release is
  // ordered by, along a Z-order curve over 256 x 256 of them, so that each chunk is a compact
  // patch of the front; 0: W's order.
  double tile_x = 0, tile_y = 0;
  // Tests: keep every vertex's quadric in full as well, as the layers and contractions sum
  // it, and count those read that differ (Simplifier::quadric_mismatches).
  bool check_quadrics = false;
  // SIMPLIFY(E0) in passes: a contraction marks its survivor, whose edges are queued once Q
  // has nothing left within E0, an edge between two marked survivors once (queued at once,
  // most were overtaken by a neighbour's contraction before they popped). A target count or
  // a pass past E0 keeps the exact order.
  bool passes = true;
  OffsetEdges offset_edges;  // the extractor's (GeometryOk)
};

}  // namespace tandem

#endif  // TANDEM_SIMPLIFIER_OPTIONS_H_
