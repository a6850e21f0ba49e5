#include "sag_correction.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "run_in_ranges.h"
#include "tandem/geometry.h"

namespace tandem {
namespace {

// The triangles of a fan in increasing id: every sum over them is then taken in the order of
// a pass over all triangles, whichever vertex asks.
void SortedFan(const MeshStore& store, VertexId v, std::vector<TriId>* fan) {
  const auto tris = store.vertex_triangles(v);
  fan->assign(tris.begin(), tris.end());
  std::sort(fan->begin(), fan->end());
}

// Ranges for a pass over n vertices: one per thread of the executor and one for the caller,
// from 16,384 vertices on (below, a task costs more than it saves).
size_t Pieces(Executor* executor, size_t n) {
  constexpr size_t kParallelMin = 16384;
  if (executor == nullptr || n < kParallelMin) return 1;
  return static_cast<size_t>(executor->threads()) + 1;
}

}  // namespace

Vec3 VertexNormal(const MeshStore& store, VertexId v, std::vector<TriId>* fan) {
  SortedFan(store, v, fan);
  Vec3 n{};
  for (TriId t : *fan) {
    const auto& tri = store.triangle(t);
    n = n + TwiceAreaVector(store.position(tri[0]), store.position(tri[1]),
                            store.position(tri[2]));
  }
  const double len = Norm(n);
  return len > 0.0 ? n * (1.0 / len) : Vec3{};
}

void VertexNormals(const MeshStore& store, std::span<const VertexId> verts, std::span<Vec3> normal,
                   Executor* executor, double* helper_seconds) {
  const double helpers =
      RunInRanges(executor, verts.size(), Pieces(executor, verts.size()),
                  [&](size_t, size_t begin, size_t end) {
                    std::vector<TriId> fan;
                    for (size_t i = begin; i < end; ++i) {
                      normal[verts[i]] = VertexNormal(store, verts[i], &fan);
                    }
                  });
  if (helper_seconds != nullptr) *helper_seconds += helpers;
}

int64_t CorrectSagAt(MeshStore* store, std::span<const VertexId> verts,
                     VertexNormalTable normal, std::span<const Quadric> quadric, double fraction,
                     double error, SagScratch* scratch, std::vector<VertexId>* moved_ids,
                     Executor* executor, double* helper_seconds) {
  if (!(fraction > 0.0) || verts.empty()) return 0;
  // Near a crease the vertex normal averages faces that meet at an angle: the sag estimate
  // measures the crease, not a curvature, and moving the vertex would cut the edge. A vertex
  // with a triangle whose normal is more than kSagCreaseDegrees from its own stays
  // (docs/decisions.md: why 25).
  constexpr double kSagCreaseDegrees = 25.0;
  const double cos_crease = std::cos(kSagCreaseDegrees * std::numbers::pi / 180.0);
  scratch->slot.Assign(verts, store->vertex_capacity());
  std::vector<Vec3> moved(verts.size());
  std::vector<uint8_t> moving(verts.size(), 0);
  std::vector<TriId>& checks = scratch->checks;
  checks.clear();
  auto corners = [&](TriId t, Vec3 p[3]) {
    const auto& tri = store->triangle(t);
    for (int k = 0; k < 3; ++k) p[k] = store->position(tri[k]);
  };
  // The step of each vertex, limited so that ε0 <= max(E0, ε0 now): its triangles' mean sag
  // (Σ w·s/24 over area) along its normal, unless it is on the box or at a crease. Each step
  // reads the mesh as it is and writes its own moved[i], moving[i]: the ranges are
  // independent, and their triangles to check are sorted below, so the result does not depend
  // on how many there are.
  auto step_of = [&](size_t i, std::vector<TriId>* fan_scratch, std::vector<TriId>* to_check) {
    const VertexId v = verts[i];
    moved[i] = store->position(v);
    if ((store->box_mask(v) & ~kFrozen) != 0) return;
    std::vector<TriId>& fan = *fan_scratch;
    SortedFan(*store, v, &fan);
    double sag = 0.0, area = 0.0;
    bool crease = false;
    for (TriId t : fan) {
      const auto& tri = store->triangle(t);
      Vec3 p[3];
      corners(t, p);
      const Vec3 fn = TwiceAreaVector(p[0], p[1], p[2]);  // 2·area·unit normal
      const double w = 0.5 * Norm(fn);
      if (w > 0.0) crease |= Dot(fn, normal[v]) < cos_crease * 2.0 * w;
      double s = 0.0;
      for (int k = 0; k < 3; ++k) {
        const int j = (k + 1) % 3;
        s += Dot(normal[tri[j]] - normal[tri[k]], p[j] - p[k]);
      }
      sag += w * s / 24.0;
      area += w;
    }
    const Quadric& q = quadric[i];
    const Vec3 n = normal[v];
    if (area <= 0.0 || crease || q.w <= 0.0 || Dot(n, n) == 0.0) return;
    const double step = fraction * sag / area;
    const Vec3 d = step < 0.0 ? n * -1.0 : n;  // t >= 0 along d
    const Vec3 x = moved[i];
    const double t =
        StepWithinError(q, x, d, std::abs(step), std::max(error, ShapeError(q, x)));
    if (!(t > 0.0)) return;
    moved[i] = x + d * t;
    moving[i] = 1;
    to_check->insert(to_check->end(), fan.begin(), fan.end());
  };
  const size_t pieces = Pieces(executor, verts.size());
  std::vector<std::vector<TriId>> piece_checks(pieces);
  const double helpers =
      RunInRanges(executor, verts.size(), pieces, [&](size_t piece, size_t begin, size_t end) {
        std::vector<TriId> local_fan;
        std::vector<TriId>* fan = piece == 0 ? &scratch->fan : &local_fan;
        std::vector<TriId>* to_check = piece == 0 ? &checks : &piece_checks[piece];
        for (size_t i = begin; i < end; ++i) step_of(i, fan, to_check);
      });
  if (helper_seconds != nullptr) *helper_seconds += helpers;
  for (const auto& more : piece_checks) checks.insert(checks.end(), more.begin(), more.end());
  // No triangle may turn over or collapse: put the corners of any that would back, until
  // none does (each round puts at least one vertex back, and the mesh as it was is valid).
  std::sort(checks.begin(), checks.end());
  checks.erase(std::unique(checks.begin(), checks.end()), checks.end());
  auto is_moving = [&](VertexId v) {
    const uint32_t i = scratch->slot.Find(v);
    return i != kInvalid && moving[i];
  };
  auto now = [&](VertexId v) {
    const uint32_t i = scratch->slot.Find(v);
    return i != kInvalid && moving[i] ? moved[i] : store->position(v);
  };
  for (bool again = true; again;) {
    again = false;
    for (TriId t : checks) {
      const auto& tri = store->triangle(t);
      if (!(is_moving(tri[0]) | is_moving(tri[1]) | is_moving(tri[2]))) continue;
      Vec3 p[3];
      corners(t, p);
      const Vec3 n_old = TwiceAreaVector(p[0], p[1], p[2]);
      if (Dot(n_old, n_old) == 0.0) continue;  // already degenerate: no orientation to keep
      if (MovedCornerKeepsOrientation(n_old, now(tri[0]), now(tri[1]), now(tri[2]))) continue;
      for (VertexId v : tri) {
        if (const uint32_t i = scratch->slot.Find(v); i != kInvalid && moving[i]) {
          moving[i] = 0;
          again = true;
        }
      }
    }
  }
  int64_t count = 0;
  for (size_t i = 0; i < verts.size(); ++i) {
    const VertexId v = verts[i];
    if (!moving[i]) continue;
    store->set_position(v, moved[i]);
    moved_ids->push_back(v);
    ++count;
  }
  scratch->slot.Clear();
  return count;
}

}  // namespace tandem
