#include "schedule.h"

#include <chrono>
#include <limits>

namespace tandem {
namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

bool Lockstep(Schedule s) { return s == Schedule::kTandem || s == Schedule::kTandemLag; }

// DELAY(k); ACTIVATE(k); SIMPLIFY(E0) for the layer extracted last, whose top plane is the
// front; sealing: then everything the front has left behind for good.
void SimplifyLayer(Slab& s) {
  const auto t0 = Clock::now();
  const double front = static_cast<double>(s.pending_front);
  s.simplifier.Delay(s.new_tris);
  s.simplifier.Activate(front);
  s.simplifier.Simplify();
  if (s.sealer) s.sealer->Seal(front);
  s.time.simplify_s += Seconds(t0, Clock::now());
  s.trace.push_back(static_cast<int64_t>(s.store.num_triangles()));
}

// The second half of EXTRACT(k): the staged layer joins the store, its triangles' quadrics
// their vertices.
void InsertLayer(Slab& s, Schedule schedule) {
  s.new_tris.clear();
  s.new_verts.clear();
  s.extractor.CommitLayer(&s.new_tris, &s.new_verts, &s.seam_log);
  s.triangles_extracted += static_cast<int64_t>(s.new_tris.size());
  if (schedule != Schedule::kNone) s.simplifier.AddTriangles(s.new_tris, s.new_verts);
  if (s.sealer) {
    s.sealer->AddVertices(s.new_verts);
    // Full resolution: nothing will change below the front plane.
    if (schedule == Schedule::kNone) s.sealer->Seal(static_cast<double>(s.extractor.slices_done() - 1));
  }
}

}  // namespace

absl::Status StepSlab(Slab& s, const float* values, Schedule schedule, const Overlap& overlap) {
  absl::Status extracted;
  double extract_s = 0;
  auto extract = [&] {  // the first half of EXTRACT(k): reads the extractor's own state only
    const auto t0 = Clock::now();
    extracted = s.extractor.ComputeLayer(values);
    extract_s = Seconds(t0, Clock::now());
  };
  if (s.simplify_pending) {
    overlap([&] { SimplifyLayer(s); }, extract);  // layer k-1's step beside EXTRACT(k)
  } else {
    extract();
  }
  s.simplify_pending = false;
  if (!extracted.ok()) return extracted;
  const auto t1 = Clock::now();
  InsertLayer(s, schedule);
  s.time.extract_s += extract_s + Seconds(t1, Clock::now());
  s.trace.push_back(static_cast<int64_t>(s.store.num_triangles()));
  if (Lockstep(schedule)) {  // DELAY(k); ACTIVATE(k); SIMPLIFY(E0): at the next step
    s.simplify_pending = true;
    s.pending_front = s.extractor.slices_done() - 1;
  }
  return absl::OkStatus();
}

void FinishSlab(Slab& s, Schedule schedule) {
  if (s.simplify_pending) SimplifyLayer(s);
  s.simplify_pending = false;
  s.extractor.Finish();
  if (schedule == Schedule::kNone) return;
  const auto t0 = Clock::now();
  if (schedule == Schedule::kClassical) {
    // INSERT every edge of the full-resolution surface, then one SIMPLIFY.
    std::vector<TriId> all;
    all.reserve(s.store.num_triangles());
    for (TriId t = 0; t < s.store.triangle_capacity(); ++t) {
      if (s.store.triangle_alive(t)) all.push_back(t);
    }
    s.simplifier.Delay(all);
  }
  s.simplifier.Activate(std::numeric_limits<double>::infinity());
  s.simplifier.Simplify();
  s.time.simplify_s += Seconds(t0, Clock::now());
}

int64_t FinishWhole(Slab& whole, const SessionOptions& options,
                    const std::vector<VertexId>* seam_vertices) {
  const bool simplify = options.schedule != Schedule::kNone;
  if (simplify && seam_vertices != nullptr) {
    // SIMPLIFY(E0) from the seam: every other edge was settled inside its slab and keeps its
    // cost; contractions here re-queue their neighbours as usual.
    const auto t0 = Clock::now();
    whole.simplifier.PushEdgesAround(*seam_vertices);
    whole.simplifier.Simplify();
    whole.time.simplify_s += Seconds(t0, Clock::now());
  }
  if (simplify && options.target_triangles > 0 &&
      static_cast<int64_t>(whole.store.num_triangles()) > options.target_triangles) {
    const auto t0 = Clock::now();
    whole.simplifier.RequeueAll();
    whole.simplifier.Simplify(options.target_triangles);
    whole.time.simplify_s += Seconds(t0, Clock::now());
  }
  int64_t sag_corrected = 0;
  const auto t0 = Clock::now();
  if (whole.sealer) {
    whole.sealer->Seal(std::numeric_limits<double>::infinity());  // the rest, sag included
    sag_corrected = whole.sealer->sag_corrected();
  } else if (simplify && options.sag_correction > 0.0) {
    sag_corrected = whole.simplifier.CorrectSag(options.sag_correction);
  } else {
    return 0;
  }
  whole.time.simplify_s += Seconds(t0, Clock::now());
  return sag_corrected;
}

}  // namespace tandem
