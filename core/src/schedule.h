// The paper's schedules, one slab at a time (Attali, Cohen-Steiner, Edelsbrunner, SGP 2005).
// Per slice k, with the paper's names:
//   classical:   EXTRACT(k)                              ... Finish: INSERT(all); SIMPLIFY(E0)
//   tandem:      EXTRACT(k); INSERT(k-1); SIMPLIFY(E0)   (the newest layer is never touched)
//   tandem-lag:  EXTRACT(k); DELAY(k); ACTIVATE(k); SIMPLIFY(E0)
//                                                        ... Finish: ACTIVATE(∞); SIMPLIFY(E0)
// `tandem` is the waiting queue keyed by layer + 1, `tandem-lag` keyed by the reach of the
// contracted vertex (simplifier.h); none = EXTRACT only (the full-resolution surface).
//
// Threads are not the schedule's business: the SIMPLIFY step of layer k is run at the start of
// the next step, through `overlap`, beside EXTRACT(k+1) (which reads only the extractor's own
// buffers, while the simplifier never touches the front), so an executor may run the two side by
// side; either way the store sees the same mutations in the same order.
#ifndef TANDEM_SCHEDULE_H_
#define TANDEM_SCHEDULE_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "absl/status/status.h"
#include "slabs.h"
#include "tandem/options.h"

namespace tandem {

// Runs first() and second(), possibly side by side, and returns when both are done; run one
// after the other, first() goes first.
using Overlap = std::function<void(const std::function<void()>& first,
                                   const std::function<void()>& second)>;

// One slice through one slab. A refused slice (non-finite values, past nz) leaves the slab as it
// was, apart from the deferred SIMPLIFY step, which the sequential order would have run already.
absl::Status StepSlab(Slab& slab, const float* values, Schedule schedule, const Overlap& overlap);

// The end of the stream for one slab: its last SIMPLIFY step, the top of the box, and for the
// classical schedule INSERT(all); then ACTIVATE(∞); SIMPLIFY(E0).
void FinishSlab(Slab& slab, Schedule schedule);

// The end for the whole mesh, once the slabs are merged into `whole`: SIMPLIFY(E0) from the
// welded seam vertices (null: there was one slab); toward the target triangle count if asked; then the sag correction
// (sealing: the last seal, sag included). Returns the vertices the sag correction moved.
int64_t FinishWhole(Slab& whole, const SessionOptions& options,
                    const std::vector<VertexId>* seam_vertices);

}  // namespace tandem

#endif  // TANDEM_SCHEDULE_H_
