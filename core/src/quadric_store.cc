#include "quadric_store.h"

#include <cmath>

#include "grow.h"

namespace tandem {

void QuadricStore::EnsureCapacity(size_t n) {
  if (planes_.size() >= n) return;
  GrowTo(planes_, n);
  if (check_) GrowTo(eager_, n);
}

void QuadricStore::CheckQuadric(VertexId v, const Quadric& q) const {
  // The sum kept in full and this one: the same planes, the same error (to rounding) near v.
  const Quadric& e = eager_[v];
  const Vec3 p = store_->position(v);
  const double scale = std::abs(e.w) + std::abs(e.a00) + std::abs(e.a11) + std::abs(e.a22);
  for (const Vec3 d : {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, 0, 1}, Vec3{1, 1, 1}}) {
    const Vec3 x = p + d;
    const double tolerance = 1e-9 * scale * (1 + Dot(p, p));
    if (!(std::abs(q.Evaluate(x) - e.Evaluate(x)) <= tolerance)) {
      mismatches_.fetch_add(1, std::memory_order_relaxed);
      return;
    }
  }
}

uint32_t QuadricStore::TailSlot(VertexId v) {
  uint32_t s = store_->aux(v);
  if (s == kInvalid) {
    s = tails_.Take();
    store_->set_aux(v, s);
  }
  return s;
}

void QuadricStore::SetQuadric(VertexId v, const Quadric& q) {
  planes_[v] = PlaneSum{q.a00, q.a01, q.a02, q.a11, q.a12, q.a22};
  tails_[TailSlot(v)] = QuadricTail{q.b0, q.b1, q.b2, q.c, q.w};
}

void QuadricStore::Keep(VertexId v) {
  if (store_->aux(v) == kInvalid) SetQuadric(v, Get(v));
}

void QuadricStore::Drop(VertexId v) {
  const uint32_t s = store_->aux(v);
  if (s == kInvalid) return;
  tails_.Release(s);
  store_->set_aux(v, kInvalid);
}

void QuadricStore::Adopt(const QuadricStore& from, PartVertex part_src, VertexId dst,
                         bool shared) {
  const VertexId src = InPart(part_src);  // an index of from's arrays only
  if (shared) {
    Quadric q;  // a seam vertex: each part saw its own triangles
    AddTo(dst, &q);
    from.AddTo(src, &q);
    SetQuadric(dst, q);
    if (check_) eager_[dst] += from.eager_[src];
    return;
  }
  // At src's position: its planes' matrix, and the rest of its quadric kept in full.
  planes_[dst] = from.planes_[src];
  Drop(dst);
  if (const uint32_t s = from.store_->aux(src); s != kInvalid) {
    tails_[TailSlot(dst)] = from.tails_[s];
  }
  if (check_) eager_[dst] = from.eager_[src];
}

}  // namespace tandem
