// What a session counts while it runs (TandemSession::stats()): the refusals of contractions
// by reason, time per phase, and the run's statistics.
#ifndef TANDEM_STATS_H_
#define TANDEM_STATS_H_

#include <cstdint>
#include <vector>

namespace tandem {

// Contractions refused, by the check that refused them.
struct RefusalCounts {
  int64_t link = 0;        // link condition (topology would change)
  int64_t flip = 0;        // a triangle's normal would turn by more than 90 degrees
  int64_t degenerate = 0;  // a non-degenerate triangle would collapse to zero area
  int64_t box = 0;         // the vertices lie on different faces of the grid's box
  int64_t error = 0;       // conservative rule: ε0(c) > E0 although ε_α(c) <= E0
  int64_t distance = 0;    // distance guard: c too far from a reshaped triangle's plane
  int64_t total() const { return link + flip + degenerate + box + error + distance; }
  RefusalCounts& operator+=(const RefusalCounts& o) {
    link += o.link;
    flip += o.flip;
    degenerate += o.degenerate;
    box += o.box;
    error += o.error;
    distance += o.distance;
    return *this;
  }
};

struct PhaseTimes {
  // CPU time of each phase, summed over the threads that ran it (so at most the process's
  // CPU time, whatever the parts and cores).
  double extract_s = 0, simplify_s = 0;
  double total_s = 0;  // wall time spent inside AddSlice/Finish (< the sum when pipelined)
};

struct SessionStats {
  int64_t slices = 0;
  int64_t crossed_cubes = 0;
  int64_t triangles_extracted = 0;  // full-resolution triangle count
  int64_t peak_triangles = 0;       // most triangles held at once
  std::vector<int64_t> trace;       // triangles after every EXTRACT and every SIMPLIFY
  PhaseTimes time;
  RefusalCounts refusals;
  int64_t contractions = 0;
  // The simplifier's work behind them: edge evaluations (quadric solves), and the entries
  // pushed into Q (by cost) and into W (waiting for the front).
  int64_t evaluations = 0;
  int64_t q_pushes = 0;
  int64_t w_pushes = 0;
  int64_t sag_corrected = 0;        // vertices moved by the sag correction (Finish)
  // E0 as the simplification left it, physical units: SessionOptions::error, or with
  // target_triangles the E0 it rose to (0 without simplification).
  double error_reached = 0;
  double max_reach_over_front = 0;  // <= 0: no contraction's reach exceeded the front
  double max_layer_over_front = 0;  // <= -1: no contraction touched the newest layer
  int64_t sealed_triangles = 0;     // sealing: triangles handed out so far
  int64_t sealed_vertices = 0;      // sealing: global vertex ids handed out so far
  int64_t quadric_mismatches = 0;   // SessionOptions::check_quadrics: should be 0
};

}  // namespace tandem

#endif  // TANDEM_STATS_H_
