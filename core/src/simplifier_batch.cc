// The Simplifier's batched evaluation: DELAY's edges are collected, evaluated side by side
// (on the executor's threads, with the ends' records prefetched) and pushed in batch order, so
// the outcome is the one-at-a-time PushEdge's.
#include <cstddef>
#include <limits>

#include "run_in_ranges.h"
#include "simplifier.h"

namespace tandem {

void Simplifier::AddToBatch(VertexId a, VertexId b, bool released) {
  if (Pinned(a, b)) return;
  batch_.push_back(a < b ? BatchEdge{a, b, released} : BatchEdge{b, a, released});
  // Flushing early changes nothing (evaluations only read; pushes keep batch order) and
  // bounds the batch's memory when DELAY gets the whole mesh (classical, RequeueAll).
  if (batch_.size() >= kMaxBatch) FlushBatch();
}

void Simplifier::EvaluateBatchRange(size_t begin, size_t end) {
  // PushEdge's decisions without its pushes; reads the store and the quadrics only. The
  // ends' records are mostly out of cache (a released edge was last touched a layer or two
  // ago): their loads start kAhead edges early.
  for (size_t i = begin; i < end; ++i) {
    if (i + kAhead < end) {
      const BatchEdge& f = batch_[i + kAhead];
      PrefetchVertex(f.a);
      PrefetchVertex(f.b);
    }
    if (i + kAhead / 2 < end) {  // those records have come in by now
      const BatchEdge& f = batch_[i + kAhead / 2];
      PrefetchQuadric(f.a);
      PrefetchQuadric(f.b);
    }
    const BatchEdge e = batch_[i];
    BatchResult& r = batch_results_[i];
    r.c = Candidate{};
    r.key = -std::numeric_limits<double>::infinity();
    // An edge ACTIVATE released has not changed since its key was found <= the front, and
    // Q keeps no release data: the key need not be recomputed.
    if (opt_.release != ReleaseRule::kImmediate && !e.released) {
      r.key = ReleaseKey(e.a, e.b, &r.c);
      if (r.key > front_) {
        r.to = 0;
        continue;
      }
    }
    r.to = Evaluate(e.a, e.b, &r.c) ? 1 : 2;
  }
}

void Simplifier::FlushBatch() {
  const size_t n = batch_.size();
  if (n == 0) return;
  // Never shrunk: a resize up after a smaller batch zeroed every result again, which
  // EvaluateBatchRange writes anyway.
  if (batch_results_.size() < n) batch_results_.resize(n);
  // Below this size a thread costs more than it saves (a solve is ~1 µs).
  constexpr size_t kParallelMin = 1024;
  helper_seconds_ += RunInRanges(opt_.parallel, n, n >= kParallelMin ? 2 : 1,
                                 [this](size_t, size_t begin, size_t end) {
                                   EvaluateBatchRange(begin, end);
                                 });
  for (size_t i = 0; i < n; ++i) {
    const BatchEdge e = batch_[i];
    const BatchResult& r = batch_results_[i];
    evaluations_ += r.to != 0;
    if (r.to == 0) {
      if (!requeue_released_) {
        ++w_pushes_;
        w_.Push(WEntry{r.key, e.a, e.b, version_[e.a], version_[e.b]});
      }
    } else if (r.to == 1) {
      if (!Hold(e.a, e.b, r.c)) PushReady(e.a, e.b, r.c);
    } else {
      ++refusals_.box;
    }
  }
  batch_.clear();
  Checkpoint();
}

}  // namespace tandem
