// QuadricStore: the simplifier's per-vertex plane quadrics H_u (paper §2), stored compactly: the
// matrix A = Σ w n nᵀ for every vertex, and b, c and W only for those kept in full.
#ifndef TANDEM_QUADRIC_STORE_H_
#define TANDEM_QUADRIC_STORE_H_

#include <atomic>
#include <cstddef>
#include <cstdint>

#include "mesh_store.h"
#include "part_ids.h"
#include "pod_array.h"
#include "quadric.h"
#include "slot_pool.h"
#include "tandem/types.h"

namespace tandem {

// Every plane of a vertex's own triangles passes through it, so until it moves its quadric is
// its matrix A alone (b = -A v, c = vᵀ A v, w = trace A): 48 bytes a vertex, not 88, for the
// full-resolution band the time lag holds. A contraction's survivor, or a vertex about to
// move, keeps its quadric in full (Keep; docs/decisions.md 17): b, c and W beside its matrix,
// in a slot of a packed pool whose number lives in the vertex's store record (MeshStore::aux).
class QuadricStore {
 public:
  // `check`: also keep every quadric in full as it is summed, and count those read that differ
  // (SimplifierOptions::check_quadrics).
  QuadricStore(MeshStore* store, bool check) : store_(store), check_(check) {}

  size_t size() const { return planes_.size(); }  // vertex ids with a quadric
  void EnsureCapacity(size_t n);                  // ids below n have a quadric (new ones: none)
  // A new vertex (its id may be a contracted one's): no planes yet.
  void Reset(VertexId v) {
    planes_[v] = PlaneSum{};
    Drop(v);
    if (check_) eager_[v] = Quadric{};
  }
  // Adds plane quadric h of one of v's triangles (AddTriangles).
  void AddPlane(VertexId v, const Quadric& h) {
    PlaneSum& m = planes_[v];
    m.a00 += h.a00, m.a01 += h.a01, m.a02 += h.a02;
    m.a11 += h.a11, m.a12 += h.a12, m.a22 += h.a22;
    if (const uint32_t s = store_->aux(v); s != kInvalid) {
      // Kept in full (it moved): this plane need not pass through it.
      QuadricTail& t = tails_[s];
      t.b0 += h.b0, t.b1 += h.b1, t.b2 += h.b2, t.c += h.c, t.w += h.w;
    }
    if (check_) eager_[v] += h;
  }
  // Adds v's quadric to *h: Get(v) without the copy (an evaluation adds two).
  [[gnu::always_inline]] void AddTo(VertexId v, Quadric* h) const {
    if (check_) {
      *h += Get(v);  // checked there; the same sum
      return;
    }
    AddQuadricTo(v, h);
  }
  // H_a + H_b, as AddTo(a) then AddTo(b) into a zero quadric sum them (an evaluation's).
  [[gnu::always_inline]] PackedQuadric Sum(VertexId a, VertexId b) const {
    if (check_) return CheckedSum(a, b);
    PackedQuadric h;
    const PackedTail ta = PackedTailOf(a, &h);
    PackedQuadric hb;
    const PackedTail tb = PackedTailOf(b, &hb);
    h.a0 += hb.a0, h.a1 += hb.a1, h.a2 += hb.a2;
    h.b01 = ta.b01 + tb.b01;
    h.b2c = ta.b2c + tb.b2c;
    h.w = ta.w + tb.w;
    return h;
  }
  Quadric Get(VertexId v) const {
    Quadric q;
    AddQuadricTo(v, &q);
    if (check_) CheckQuadric(v, q);
    return q;
  }
  void Keep(VertexId v);  // v's quadric in full from now on (it moves, or adds another's)
  void SetQuadric(VertexId v, const Quadric& q);  // kept in full
  void Drop(VertexId v);  // v's full quadric, if kept, goes (v left the store or was reset)
  // Contraction ab -> a: H_a = H_a + H_b, kept in full (read before a moves); b's goes.
  void Merge(VertexId a, VertexId b) {
    SetQuadric(a, Sum(a, b).Unpack());  // the sum the contraction's evaluation read
    Drop(b);
    if (check_) eager_[a] += eager_[b];
  }
  // dst takes src's quadric from another store (a slab merge); `shared`: dst is the seam
  // vertex both held, each with its own triangles' planes, and the two add.
  void Adopt(const QuadricStore& from, PartVertex src, VertexId dst, bool shared);
  // Starts loading v's matrix and its full quadric's rest (v's store record must be in).
  void Prefetch(VertexId v) const {
    const char* p = reinterpret_cast<const char*>(&planes_[v]);
    __builtin_prefetch(p);
    __builtin_prefetch(p + sizeof(PlaneSum) - 1);
    if (const uint32_t s = store_->aux(v); s != kInvalid) {
      const char* t = reinterpret_cast<const char*>(&tails_[s]);
      __builtin_prefetch(t);
      __builtin_prefetch(t + sizeof(QuadricTail) - 1);
    }
  }
  // Quadrics read that differed from the full sums kept alongside (a vertex moved without Keep).
  int64_t mismatches() const { return mismatches_.load(); }
  void AddMismatches(int64_t n) { mismatches_ += n; }
  size_t MemoryBytes() const {
    return planes_.MemoryBytes() + tails_.MemoryBytes() + eager_.MemoryBytes();
  }
  static constexpr size_t VertexBytes() { return sizeof(PlaneSum); }

 private:
  struct PlaneSum {
    double a00 = 0, a01 = 0, a02 = 0, a11 = 0, a12 = 0, a22 = 0;
  };
  struct QuadricTail {
    double b0 = 0, b1 = 0, b2 = 0, c = 0, w = 0;
  };
  // Kept in full: the tail as it is; otherwise b, c and W from A and v's position.
  [[gnu::always_inline]] void AddQuadricTo(VertexId v, Quadric* h) const {
    const PlaneSum& m = planes_[v];
    h->a00 += m.a00, h->a01 += m.a01, h->a02 += m.a02;
    h->a11 += m.a11, h->a12 += m.a12, h->a22 += m.a22;
    if (const uint32_t s = store_->aux(v); s != kInvalid) {
      const QuadricTail& t = tails_[s];
      h->b0 += t.b0, h->b1 += t.b1, h->b2 += t.b2;
      h->c += t.c;
      h->w += t.w;
      return;
    }
    const Vec3 p = store_->position(v);
    const double ax = m.a00 * p.x + m.a01 * p.y + m.a02 * p.z;
    const double ay = m.a01 * p.x + m.a11 * p.y + m.a12 * p.z;
    const double az = m.a02 * p.x + m.a12 * p.y + m.a22 * p.z;
    h->b0 -= ax, h->b1 -= ay, h->b2 -= az;
    h->c += p.x * ax + p.y * ay + p.z * az;
    h->w += m.a00 + m.a11 + m.a22;
  }
  struct PackedTail {
    V2d b01, b2c;  // (b0, b1), (b2, c)
    double w;
  };
  // v's matrix into h's, and the rest of its quadric as AddQuadricTo adds it.
  [[gnu::always_inline]] PackedTail PackedTailOf(VertexId v, PackedQuadric* h) const {
    const PlaneSum& m = planes_[v];
    __builtin_memcpy(&h->a0, &m.a00, sizeof(V2d));
    __builtin_memcpy(&h->a1, &m.a02, sizeof(V2d));
    __builtin_memcpy(&h->a2, &m.a12, sizeof(V2d));
    if (const uint32_t s = store_->aux(v); s != kInvalid) {
      const QuadricTail& t = tails_[s];
      return {V2d{t.b0, t.b1}, V2d{t.b2, t.c}, t.w};
    }
    const Vec3 p = store_->position(v);
    const V2d xy{p.x, p.y};
    const V2d axy = h->ProductXY(xy, p.z);
    const double az = h->ProductZ(xy, p.z);
    return {-axy, V2d{-az, p.x * axy[0] + p.y * axy[1] + p.z * az}, m.a00 + m.a11 + m.a22};
  }
  [[gnu::noinline]] PackedQuadric CheckedSum(VertexId a, VertexId b) const {
    Quadric q;
    AddTo(a, &q);
    AddTo(b, &q);
    return Pack(q);
  }
  void CheckQuadric(VertexId v, const Quadric& q) const;
  uint32_t TailSlot(VertexId v);  // v's slot in tails_, taken if it has none

  MeshStore* store_;
  bool check_;
  PodArray<PlaneSum> planes_;    // by vertex id
  SlotPool<QuadricTail> tails_;  // the quadrics kept in full, lowest free slot first
  PodArray<Quadric> eager_;      // check_: every quadric in full
  mutable std::atomic<int64_t> mismatches_{0};
};

}  // namespace tandem

#endif  // TANDEM_QUADRIC_STORE_H_
