// The Simplifier's work on a settled mesh, with its quadrics: Error(K), the sag correction, the
// tidying of zero-area triangles, and the sealer's hooks (freezing, reach, normals).
#include <algorithm>
#include <cmath>
#include <functional>
#include <vector>

#include "simplifier.h"

namespace tandem {

double Simplifier::MaxShapeError() const {
  double worst = 0.0;
  for (VertexId v = 0; v < store_->vertex_capacity(); ++v) {
    if (!store_->vertex_alive(v) || v >= quadrics_.size()) continue;
    worst = std::max(worst, MeasuredShapeErrorAt(v));
  }
  return worst;
}

int64_t Simplifier::CorrectSag(double fraction, Executor* executor) {
  if (!(fraction > 0.0)) return 0;
  std::vector<VertexId> verts;
  // A label session's complex: a vertex moves only where it and its neighbours lie in one
  // patch.
  for (VertexId v = 0; v < store_->vertex_capacity(); ++v) {
    if (store_->vertex_alive(v) && (!store_->labeled() || store_->OnePatchAround(v))) {
      verts.push_back(v);
    }
  }
  std::vector<Vec3> normal(store_->vertex_capacity());
  tandem::VertexNormals(*store_, verts, normal, executor, &helper_seconds_);
  return CorrectSagAt(verts, normal, fraction, executor);
}

double Simplifier::TidySize() const {
  // A collapsed tetrahedron gets a tenth of E0 (within the bound, and far above float noise),
  // but never more than a twentieth of a slice: E0 may be huge (a target count at its floor
  // ran it to 1e6; the fuzzer put such a tetrahedron far outside the grid's box).
  return std::min(0.1 * opt_.error, 0.05 * opt_.slice_spacing);
}

bool Simplifier::TidyMayMove(VertexId v, Vec3 p) const {
  return ShapeError(quadrics_.Get(v), p) <= std::max(opt_.error, ShapeErrorAt(v));
}

DegenerateCounts Simplifier::TidyDegenerate() {
  return tandem::TidyDegenerate(
      store_, TidySize(),
      [this](VertexId v, Vec3 p) {
        const bool may = (store_->box_mask(v) & (kSeam | kFrozen)) == 0 && TidyMayMove(v, p);
        if (may) quadrics_.Keep(v);  // it moves next: its quadric in full first
        return may;
      },
      [this](VertexId v) { ++version_[v]; });
}

DegenerateCounts Simplifier::TidyDegenerateAmong(std::span<const TriId> tris,
                                                 const std::function<bool(VertexId)>& movable,
                                                 bool flips) {
  return tandem::TidyDegenerateAmong(
      store_, tris, TidySize(),
      [&](VertexId v, Vec3 p) {
        const bool may = (store_->box_mask(v) & kSeam) == 0 && movable(v) && TidyMayMove(v, p);
        if (may) quadrics_.Keep(v);  // it moves next: its quadric in full first
        return may;
      },
      [this](VertexId v) { ++version_[v]; }, flips);
}

void Simplifier::VertexNormals(std::span<const VertexId> verts, std::span<Vec3> normal) {
  tandem::VertexNormals(*store_, verts, normal);
}

bool Simplifier::EdgesReachAtMost(VertexId v, double limit) const {
  const double hv = store_->height(v), rv = store_->rad(v);
  if (hv + rv > limit) return false;
  const Vec3 pv = store_->position(v);
  for (TriId t : store_->vertex_triangles(v)) {
    for (VertexId x : store_->triangle(t)) {
      if (x == v) continue;
      // ReleaseKey's sums, in its order: height(c) + rad(c) = 0.5 (hv + hx) + 0.5 ((|v - x| /
      // s + rv) + rx). Rounding is monotone, so without the length the sum is no larger:
      // where that is already beyond, so is the reach (most vertices the sealer looks at).
      const double height = 0.5 * (hv + store_->height(x));
      const double rx = store_->rad(x);
      if (height + 0.5 * (rv + rx) > limit) return false;
      const double rad = 0.5 * (Norm(pv - store_->position(x)) / opt_.slice_spacing + rv + rx);
      if (height + rad > limit) return false;
    }
  }
  return true;
}

double Simplifier::ShapeErrorAt(VertexId v) const {
  return ShapeError(quadrics_.Get(v), store_->position(v));
}

double Simplifier::MeasuredShapeErrorAt(VertexId v) const {
  return MeasuredShapeError(quadrics_.Get(v), store_->position(v));
}

void Simplifier::Freeze(VertexId v) {
  store_->set_box_mask(v, store_->box_mask(v) | kFrozen);
  ++version_[v];
}

int64_t Simplifier::CorrectSagAt(std::span<const VertexId> verts, VertexNormalTable normal,
                                 double fraction, Executor* executor) {
  if (!(fraction > 0.0) || verts.empty()) return 0;
  EnsureVertexCapacity();
  sag_quadrics_.resize(verts.size());
  for (size_t i = 0; i < verts.size(); ++i) {
    quadrics_.Keep(verts[i]);  // it may move
    sag_quadrics_[i] = quadrics_.Get(verts[i]);
  }
  sag_moved_.clear();
  const int64_t count =
      tandem::CorrectSagAt(store_, verts, normal, sag_quadrics_, fraction, opt_.error,
                           &sag_scratch_, &sag_moved_, executor, &helper_seconds_);
  for (VertexId v : sag_moved_) ++version_[v];  // moved: entries at v go stale
  return count;
}

}  // namespace tandem
