#include "contraction_checks.h"

#include <algorithm>
#include <cstring>

#include "tandem/geometry.h"

// 32-byte vectors in the AVX2 versions below: every function that takes or returns one is
// always_inline (lambdas too), so none is called across the versions' instruction sets at any
// optimisation level and there is no ABI to keep. GCC warns at the file's end, so to its end.
#if defined(__clang__)
#pragma clang diagnostic ignored "-Wpsabi"
#elif defined(__GNUC__)
#pragma GCC diagnostic ignored "-Wpsabi"
#endif

namespace tandem {
namespace {

// Whether triangle tri has both c and d among its corners (the triangle x-c-d of a fan).
bool HoldsBoth(const std::array<VertexId, 3>& tri, VertexId c, VertexId d) {
  bool hc = false, hd = false;
  for (VertexId x : tri) {
    hc |= x == c;
    hd |= x == d;
  }
  return hc && hd;
}

// Whether a fan (x and y corners, unused entries kInvalid) has a triangle on edge cd, c and d
// vertices: four entries at a time, as CountOf.
template <size_t N>
bool HasEdge(const VertexId (&x)[N], const VertexId (&y)[N], VertexId c, VertexId d) {
  using fan_count::V4;
  const V4 cs = {c, c, c, c}, ds = {d, d, d, d};
  V4 any = {0, 0, 0, 0};
  for (size_t i = 0; i < N; i += 4) {
    V4 xi, yi;
    std::memcpy(&xi, x + i, sizeof(xi));
    std::memcpy(&yi, y + i, sizeof(yi));
    any |= reinterpret_cast<V4>(((xi == cs) & (yi == ds)) | ((xi == ds) & (yi == cs)));
  }
  return fan_count::Lanes(any) != 0;  // lanes of all ones or zero: a sum of ones is not 0
}

// 32-bit lanes, four (SSE2) or eight (AVX2) to a vector, and each rotated by one lane.
using V8 = uint32_t __attribute__((vector_size(32)));
[[gnu::always_inline]] inline fan_count::V4 RotateLane(fan_count::V4 r) {
  return __builtin_shufflevector(r, r, 1, 2, 3, 0);
}
[[gnu::always_inline]] inline V8 RotateLane(V8 r) {
  return __builtin_shufflevector(r, r, 1, 2, 3, 4, 5, 6, 7, 0);
}
template <typename V>
inline constexpr size_t kLanesOf = sizeof(V) / sizeof(uint32_t);

// Fan arrays as chunks of V's lanes.
template <size_t N, typename V = fan_count::V4>
struct Lanes4 {
  static constexpr size_t kW = kLanesOf<V>;
  static_assert(N % kW == 0);
  V c[N / kW];
  [[gnu::always_inline]] explicit Lanes4(const VertexId (&v)[N]) {
    for (size_t i = 0; i < N / kW; ++i) std::memcpy(&c[i], v + kW * i, sizeof(c[i]));
  }
};

// For each lane of x, all ones where its value is among y's lanes: every lane of y compared
// with every lane of x, y's chunks rotated a lane at a time (no loop exit, no branch).
template <size_t N, size_t M, typename V>
[[gnu::always_inline]] inline void FoundIn(const V (&x)[N], const V (&y)[M], V (&found)[N]) {
  for (size_t i = 0; i < N; ++i) found[i] = V{};
  for (size_t j = 0; j < M; ++j) {
    V r = y[j];
    for (size_t k = 0; k < kLanesOf<V>; ++k) {
      for (size_t i = 0; i < N; ++i) found[i] |= reinterpret_cast<V>(x[i] == r);
      r = RotateLane(r);
    }
  }
}
// The two halves' lanes, and-ed or or-ed.
[[gnu::always_inline]] inline fan_count::V4 Halves(V8 v, bool all) {
  const fan_count::V4 lo = __builtin_shufflevector(v, v, 0, 1, 2, 3);
  const fan_count::V4 hi = __builtin_shufflevector(v, v, 4, 5, 6, 7);
  return all ? (lo & hi) : (lo | hi);
}
[[gnu::always_inline]] inline bool AllOnes(fan_count::V4 v) {
  v &= __builtin_shufflevector(v, v, 2, 3, 0, 1);
  v &= __builtin_shufflevector(v, v, 1, 0, 3, 2);
  return v[0] == ~0u;
}
[[gnu::always_inline]] inline bool AnyOnes(fan_count::V4 v) {
  v |= __builtin_shufflevector(v, v, 2, 3, 0, 1);
  v |= __builtin_shufflevector(v, v, 1, 0, 3, 2);
  return v[0] != 0;
}
[[gnu::always_inline]] inline bool AllOnes(V8 v) { return AllOnes(Halves(v, true)); }
[[gnu::always_inline]] inline bool AnyOnes(V8 v) { return AnyOnes(Halves(v, false)); }

// LinkConditionFans with fan arrays of kFan entries (both fans fit). Inlined into each of
// LinkFans::Run's clones, so that its lanes take the clone's instructions.
template <size_t kFan, typename V>
[[gnu::always_inline]] inline bool LinkConditionFansOf(const MeshStore& store, VertexId a,
                                                       VertexId b) {
  // The fans of a and b as flat arrays: for each triangle at v, its corner after v (x) and
  // its corner before v (y), in the triangle's order; the caller checked they fit. Written
  // without early exits where the outcome varies from call to call: the link condition was
  // the largest source of mispredicted branches in the simplifier.
  VertexId xa[kFan], ya[kFan], xb[kFan], yb[kFan];
  // Both fans' triangles at once: each is a cache miss at a random id, and the loops below
  // would otherwise wait for them one after the other.
  store.PrefetchFan(a);
  store.PrefetchFan(b);
  for (VertexId* v : {xa, ya, xb, yb}) std::fill(v, v + kFan, kInvalid);
  int n_a = 0, n_b = 0;
  VertexId apex[4];
  int napex = 0;
  for (TriId t : store.vertex_triangles(a)) {
    const auto& tri = store.triangle(t);
    const int i = CornerOf(tri, a);
    const VertexId x = tri[kNextCorner[i]], y = tri[kPrevCorner[i]];
    store.Prefetch(x);  // GeometryOk reads every corner's position next
    xa[n_a] = x;
    ya[n_a++] = y;
    // The triangle's third corner is an apex if the triangle holds b (kept only then).
    apex[std::min(napex, 3)] = (x == b) ? y : x;
    napex += (x == b) | (y == b);
  }
  if (napex == 0) return false;  // a and b are not adjacent (any more)
  if (napex > 2) return false;   // edge in three triangles: not a manifold, refuse
  if (napex == 1) apex[1] = kInvalid;
  // An apex is a common neighbour; two equal apexes are one common neighbour for two
  // triangles on ab (the marks' version: common != napex).
  if (napex == 2 && apex[0] == apex[1]) return false;
  for (TriId t : store.vertex_triangles(b)) {
    const auto& tri = store.triangle(t);
    const int i = CornerOf(tri, b);
    store.Prefetch(tri[kNextCorner[i]]);
    xb[n_b] = tri[kNextCorner[i]];
    yb[n_b++] = tri[kPrevCorner[i]];
  }
  // Whether the x and y corners of a fan are different sets of vertices. They are whenever
  // the vertex is on the boundary (an edge (v, w) in one triangle puts w in one set only),
  // and on a consistently oriented manifold only then (an interior edge is one triangle's x
  // and the other's y). Otherwise every neighbour is an x corner. Every lane of one set
  // against every lane of the other at once (unused lanes are kInvalid in both, at the same
  // places, so they find each other).
  constexpr size_t kC = kFan / kLanesOf<V>;
  const Lanes4<kFan, V> XA(xa), YA(ya), XB(xb), YB(yb);
  V x_in_y[kC], y_in_x[kC];
  FoundIn(XB.c, YB.c, x_in_y);
  FoundIn(YB.c, XB.c, y_in_x);
  V same = x_in_y[0] & y_in_x[0];
  for (size_t i = 1; i < kC; ++i) same &= x_in_y[i] & y_in_x[i];
  const bool b_open = !AllOnes(same);
  auto in_fan_a = [&](VertexId v) { return CountOf(xa, ya, v); };
  // (1) a common neighbour that is not an apex. b's neighbours are its x corners, and its
  // y corners too where the two differ. Counted from a's side: a lane of a's fan (never a
  // itself, kInvalid where unused) found among them and not an apex.
  V a_fan[2 * kC];
  for (size_t i = 0; i < kC; ++i) {
    a_fan[i] = XA.c[i];
    a_fan[kC + i] = YA.c[i];
  }
  V common[2 * kC];
  if (b_open) {
    V b_fan[2 * kC];
    for (size_t i = 0; i < kC; ++i) {
      b_fan[i] = XB.c[i];
      b_fan[kC + i] = YB.c[i];
    }
    FoundIn(a_fan, b_fan, common);
  } else {
    FoundIn(a_fan, XB.c, common);
  }
  const V inv = V{} + kInvalid, c0 = V{} + apex[0], c1 = V{} + apex[1];
  V stray_lanes = V{};
  for (size_t i = 0; i < 2 * kC; ++i) {
    stray_lanes |=
        common[i] & reinterpret_cast<V>((a_fan[i] != inv) & (a_fan[i] != c0) & (a_fan[i] != c1));
  }
  const bool stray = AnyOnes(stray_lanes);
  if (stray) return false;
  if (napex == 1) {  // (3) boundary edge: not both ac and bc boundary edges
    const VertexId c = apex[0];
    return !(in_fan_a(c) == 1 && CountOf(xb, yb, c) == 1);
  }
  // (2) an interior edge between two boundary vertices; a vertex is on the boundary when one
  // of its edges lies in a single triangle.
  auto on_boundary = [](const VertexId(&x)[kFan], const VertexId(&y)[kFan], int n) {
    bool any = false;
    for (int i = 0; i < n; ++i) {
      any |=
          static_cast<int>(CountOf(x, y, x[i]) == 1) | static_cast<int>(CountOf(x, y, y[i]) == 1);
    }
    return any;
  };
  // Sets that do not differ mean no boundary; the exact count only where they do (rare).
  if (b_open && on_boundary(xb, yb, n_b) && on_boundary(xa, ya, n_a)) return false;
  // (3) interior: triangles a-c-d and b-c-d both present?
  const VertexId c = apex[0], d = apex[1];
  return !(HasEdge(xa, ya, c, d) && HasEdge(xb, yb, c, d));
}

}  // namespace

// LinkConditionFans's body in two versions, the one for the CPU picked once at load: eight
// lanes to a vector with AVX2 (a fan of 8 in one), four otherwise. Called from this file only
// (clang 14 calls another file's multiversioned function through its resolver).
#if defined(__x86_64__) && defined(__ELF__)
__attribute__((target("avx2"))) bool LinkFansLanes(const MeshStore& store, VertexId a, VertexId b) {
  if (store.vertex_triangles(a).size() <= 8 && store.vertex_triangles(b).size() <= 8) {
    return LinkConditionFansOf<8, V8>(store, a, b);
  }
  return LinkConditionFansOf<kFanMax, V8>(store, a, b);
}
__attribute__((target("default")))
#endif
bool LinkFansLanes(const MeshStore& store, VertexId a, VertexId b) {
  // Most fans on a dense surface hold 8 triangles or fewer: arrays of 8 halve every count.
  if (store.vertex_triangles(a).size() <= 8 && store.vertex_triangles(b).size() <= 8) {
    return LinkConditionFansOf<8, fan_count::V4>(store, a, b);
  }
  return LinkConditionFansOf<kFanMax, fan_count::V4>(store, a, b);
}

bool LinkConditionFans(const MeshStore& store, VertexId a, VertexId b) {
  return LinkFansLanes(store, a, b);
}

bool LinkConditionFansWithLanes(int lanes, const MeshStore& store, VertexId a, VertexId b) {
  const bool small = store.vertex_triangles(a).size() <= 8 && store.vertex_triangles(b).size() <= 8;
  if (lanes == 8) {
    return small ? LinkConditionFansOf<8, V8>(store, a, b)
                 : LinkConditionFansOf<kFanMax, V8>(store, a, b);
  }
  return small ? LinkConditionFansOf<8, fan_count::V4>(store, a, b)
               : LinkConditionFansOf<kFanMax, fan_count::V4>(store, a, b);
}

bool LinkConditionMarks(const MeshStore& store, VertexId a, VertexId b, LinkScratch* scratch) {
  // Lk(a) ∩ Lk(b) = Lk(ab), on the complex completed by a dummy vertex ω joined to every
  // boundary edge (Dey, Edelsbrunner, Guha, Nekhayev 1999). With manifold input it reduces
  // to: (1) the common neighbours of a and b are exactly the apexes of ab's triangles;
  // (2) ω: if a and b are both on the boundary, ab is a boundary edge; (3) no edge of both
  // links: for an interior edge with apexes c, d, not both acd and bcd are triangles; for a
  // boundary edge with apex c, not both ac and bc are boundary edges.
  // The neighbours' tallies in a table of at least twice the fans' corners, so at most half
  // full: every triangle adds at most two neighbours.
  using Mark = LinkScratch::Mark;
  const auto ta = store.vertex_triangles(a), tb = store.vertex_triangles(b);
  int bits = 4;
  while ((size_t{1} << bits) < 4 * (ta.size() + tb.size())) ++bits;
  std::vector<Mark>& table = scratch->table;
  table.assign(size_t{1} << bits, Mark{});
  const uint32_t mask = (uint32_t{1} << bits) - 1;
  auto mark = [&](VertexId x) -> Mark& {  // x's entry, made if new
    uint32_t i = (x * 2654435761u) >> (32 - bits);
    while (table[i].x != x && table[i].x != kInvalid) i = (i + 1) & mask;
    table[i].x = x;
    return table[i];
  };
  // Neighbours of a and of b, each with the number of triangles on edge (a, x) or (b, x)
  // (saturating at 127: bit 7 of count_b is the "seen" flag of the pass over b below).
  auto tally = [&](VertexId v, std::span<const TriId> fan, uint8_t Mark::*count) {
    for (TriId t : fan) {
      for (VertexId x : store.triangle(t)) {
        if (x == v) continue;
        Mark& m = mark(x);
        if (m.*count < 127) ++(m.*count);
      }
    }
  };
  tally(a, ta, &Mark::count_a);
  tally(b, tb, &Mark::count_b);
  VertexId apex[2];
  int napex = 0;
  bool a_boundary = false;
  for (TriId t : store.vertex_triangles(a)) {
    const auto& tri = store.triangle(t);
    for (VertexId x : tri) a_boundary |= (x != a && mark(x).count_a == 1);
    if (tri[0] != b && tri[1] != b && tri[2] != b) continue;
    if (napex == 2) return false;  // edge in three triangles: not a manifold, refuse
    for (VertexId x : tri) {
      if (x != a && x != b) apex[napex++] = x;
    }
  }
  if (napex == 0) return false;  // a and b are not adjacent (any more)
  // Each neighbour x of b once: (b, x) in one triangle makes b a boundary vertex; a common
  // neighbour must be an apex.
  bool b_boundary = false;
  int common = 0;
  for (TriId t : store.vertex_triangles(b)) {
    for (VertexId x : store.triangle(t)) {
      if (x == b) continue;
      Mark& m = mark(x);
      const uint8_t cb = m.count_b;
      if (cb & 0x80) continue;  // seen
      m.count_b = static_cast<uint8_t>(cb | 0x80);
      if (cb == 1) b_boundary = true;
      if (x != a && m.count_a != 0) {
        ++common;
        bool is_apex = false;
        for (int k = 0; k < napex; ++k) is_apex |= apex[k] == x;
        if (!is_apex) return false;  // (1) a common neighbour that is not an apex
        if (napex == 1 && m.count_a == 1 && cb == 1) return false;  // (3) boundary
      }
    }
  }
  if (common != napex) return false;
  if (napex == 2) {
    if (a_boundary && b_boundary) return false;  // (2) interior edge between boundaries
    // (3) interior: triangles a-c-d and b-c-d both present?
    const VertexId c = apex[0], d = apex[1];
    auto has_triangle = [&](VertexId v) {
      for (TriId t : store.vertex_triangles(v)) {
        if (HoldsBoth(store.triangle(t), c, d)) return true;
      }
      return false;
    };
    if (has_triangle(a) && has_triangle(b)) return false;
  }
  return true;
}

namespace {

using Tri = std::array<VertexId, 3>;

// The neighbours of v in its triangles `fan`, each with the number of them on edge (v, x).
void TallyNeighbours(std::span<const Tri> fan, VertexId v,
                     std::vector<std::pair<VertexId, int>>* out) {
  out->clear();
  for (const Tri& tri : fan) {
    for (VertexId x : tri) {
      if (x == v) continue;
      auto it = std::find_if(out->begin(), out->end(), [x](const auto& e) { return e.first == x; });
      if (it == out->end()) {
        out->push_back({x, 1});
      } else {
        ++it->second;
      }
    }
  }
}

int CountIn(const std::vector<std::pair<VertexId, int>>& tally, VertexId x) {
  for (const auto& [y, n] : tally) {
    if (y == x) return n;
  }
  return 0;
}

// LAMBDA(ab) in one surface, given its triangles at a and at b (the rules of
// LinkConditionMarks, on lists: a label's fans are small).
bool SurfaceLinkCondition(std::span<const Tri> fa, std::span<const Tri> fb, VertexId a, VertexId b,
                          LinkScratch* scratch) {
  VertexId apex[2];
  int napex = 0;
  for (const Tri& tri : fa) {
    if (tri[0] != b && tri[1] != b && tri[2] != b) continue;
    if (napex == 2) return false;  // an edge in three triangles of one surface
    for (VertexId x : tri) {
      if (x != a && x != b) apex[napex++] = x;
    }
  }
  if (napex == 0) return false;  // a and b both in the surface, but not joined in it
  if (napex == 2 && apex[0] == apex[1]) return false;
  auto& ta = scratch->tally_a;
  auto& tb = scratch->tally_b;
  TallyNeighbours(fa, a, &ta);
  TallyNeighbours(fb, b, &tb);
  bool a_boundary = false, b_boundary = false;
  for (const auto& [x, n] : ta) a_boundary |= n == 1;
  for (const auto& [x, n] : tb) b_boundary |= n == 1;
  int common = 0;
  for (const auto& [x, n] : tb) {
    if (x == a || CountIn(ta, x) == 0) continue;
    ++common;
    if (x != apex[0] && (napex < 2 || x != apex[1])) return false;  // (1) not an apex
  }
  if (common != napex) return false;
  if (napex == 1) {  // (3) boundary edge: not both ac and bc boundary edges
    return !(CountIn(ta, apex[0]) == 1 && CountIn(tb, apex[0]) == 1);
  }
  if (a_boundary && b_boundary) return false;  // (2) interior edge between boundaries
  const VertexId c = apex[0], d = apex[1];
  auto has_cd = [c, d](std::span<const Tri> fan) {
    return std::any_of(fan.begin(), fan.end(), [c, d](const Tri& t) { return HoldsBoth(t, c, d); });
  };
  return !(has_cd(fa) && has_cd(fb));  // (3) interior: acd and bcd both present
}

}  // namespace

bool LabelLinkCondition(const MeshStore& store, VertexId a, VertexId b, LinkScratch* scratch) {
  auto labels_at = [&store](VertexId v, std::vector<LabelId>* out) {
    out->clear();
    for (TriId t : store.vertex_triangles(v)) {
      const LabelPair& p = store.pair_of(t);
      out->push_back(p.inside);
      out->push_back(p.outside);
    }
    std::sort(out->begin(), out->end());
    out->erase(std::unique(out->begin(), out->end()), out->end());
  };
  // Inside one patch (most edges) both labels' surfaces are the stars themselves, a
  // consistently oriented manifold there: the iso-surface's test decides for both.
  const auto ta = store.vertex_triangles(a), tb = store.vertex_triangles(b);
  if (ta.empty() || tb.empty()) return false;
  const uint32_t patch = store.patch(ta[0]);
  bool one_patch = true;
  for (TriId t : ta) one_patch &= store.patch(t) == patch;
  for (TriId t : tb) one_patch &= store.patch(t) == patch;
  if (one_patch) {
    return ta.size() <= kFanMax && tb.size() <= kFanMax ? LinkConditionFans(store, a, b)
                                                        : LinkConditionMarks(store, a, b, scratch);
  }
  int on_ab = 0;
  for (TriId t : ta) {
    const auto& tri = store.triangle(t);
    on_ab += static_cast<int>(tri[0] == b) | static_cast<int>(tri[1] == b) |
             static_cast<int>(tri[2] == b);
  }
  if (on_ab == 0 || on_ab > kMaxEdgeTriangles) return false;
  labels_at(a, &scratch->labels_a);
  labels_at(b, &scratch->labels_b);
  auto fan_of = [&store](VertexId v, LabelId l, std::vector<Tri>* out) {
    out->clear();
    for (TriId t : store.vertex_triangles(v)) {
      const LabelPair& p = store.pair_of(t);
      if (p.inside == l || p.outside == l) out->push_back(store.triangle(t));
    }
  };
  for (LabelId l : scratch->labels_a) {
    if (!std::binary_search(scratch->labels_b.begin(), scratch->labels_b.end(), l)) continue;
    fan_of(a, l, &scratch->fan_a);
    fan_of(b, l, &scratch->fan_b);
    if (!SurfaceLinkCondition(scratch->fan_a, scratch->fan_b, a, b, scratch)) return false;
  }
  return true;
}

namespace {

// Whether every edge of the triangle (p with its corner at `from`, as it was) is shorter than
// the move from `from` to `pos`.
bool SmallerThanTheMove(const Vec3 (&p)[3], int corner, Vec3 from, Vec3 pos) {
  Vec3 q[3] = {p[0], p[1], p[2]};
  q[corner] = from;
  const Vec3 move = pos - from, e0 = q[1] - q[0], e1 = q[2] - q[1], e2 = q[0] - q[2];
  return std::max({Dot(e0, e0), Dot(e1, e1), Dot(e2, e2)}) < Dot(move, move);
}

// The arithmetic of GeometryOk's test for two survivors at once, a lane each: the same
// operations in the same order as the scalar expressions (TwiceAreaVector, Dot, MoveCorners,
// the guard), so each lane's values are the scalar ones bit for bit.
// Points in lanes of V (doubles), and Vec3's operations on them lane by lane.
template <typename V>
struct PointLanes {
  V x, y, z;
};
template <typename V>
[[gnu::always_inline]] inline PointLanes<V> operator-(PointLanes<V> a, PointLanes<V> b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <typename V>
[[gnu::always_inline]] inline V DotLanes(PointLanes<V> a, PointLanes<V> b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
template <typename V>
[[gnu::always_inline]] inline PointLanes<V> CrossLanes(PointLanes<V> a, PointLanes<V> b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
using V2 = double __attribute__((vector_size(16)));
using M2 = int64_t __attribute__((vector_size(16)));
using P2 = PointLanes<V2>;
[[gnu::always_inline]] inline P2 Pair(Vec3 u, Vec3 v) {
  return {V2{u.x, v.x}, V2{u.y, v.y}, V2{u.z, v.z}};
}
[[gnu::always_inline]] inline P2 Select(M2 m, P2 a, P2 b) {  // a where m is all ones, else b
  auto pick = [m](V2 x, V2 y) {
    return reinterpret_cast<V2>((reinterpret_cast<M2>(x) & m) | (reinterpret_cast<M2>(y) & ~m));
  };
  return {pick(a.x, b.x), pick(a.y, b.y), pick(a.z, b.z)};
}

// Whether either of two survivors (t0 with its moving corner c0, t1 with c1) may stop the
// contraction: the guard's distance, a collapse or a flip, in either lane. No survivor in
// lanes where neither does.
inline bool EitherSuspect(const MeshStore& store, const std::array<VertexId, 3>& t0, int c0,
                          const std::array<VertexId, 3>& t1, int c1, Vec3 pos, bool guarded,
                          double bound) {
  P2 p[3];
  for (int k = 0; k < 3; ++k) p[k] = Pair(store.position(t0[k]), store.position(t1[k]));
  const P2 n_old = CrossLanes(p[1] - p[0], p[2] - p[0]);
  const V2 old2 = DotLanes(n_old, n_old);
  const P2 at = Pair(pos, pos);
  const V2 off = DotLanes(n_old, at - p[0]);
  const V2 bb = {bound * bound, bound * bound};
  const M2 far = guarded ? (off * off > bb * old2) : M2{0, 0};
  // The moving corners' masks by 32-bit compares (SSE2 has no 64-bit one): a lane's two
  // halves hold its corner.
  using V4i = int32_t __attribute__((vector_size(16)));
  const V4i corners = {c0, c0, c1, c1};
  P2 q[3];
  for (int k = 0; k < 3; ++k) {
    q[k] = Select(reinterpret_cast<M2>(corners == V4i{k, k, k, k}), at, p[k]);
  }
  const P2 after = CrossLanes(q[1] - q[0], q[2] - q[0]);
  const V2 sse = DotLanes(q[1] - q[0], q[1] - q[0]) + DotLanes(q[2] - q[1], q[2] - q[1]) +
                 DotLanes(q[0] - q[2], q[0] - q[2]);
  const V2 ratio = {kCollapsedSquared, kCollapsedSquared}, zero = {0.0, 0.0};
  const M2 collapses = ~(DotLanes(after, after) > ratio * sse * sse);
  const M2 flips = ~(DotLanes(n_old, after) > zero);
  const M2 any = far | collapses | flips;
  return (any[0] | any[1]) != 0;
}

// The arithmetic of GeometryOk's test for four survivors at once, a lane each: the same
// operations in the same order as the scalar expressions (TwiceAreaVector, Dot, MoveCorners,
// the guard), so each lane's values are the scalar ones bit for bit (AVX2's version only).
using V4d = double __attribute__((vector_size(32)));
using M4 = int64_t __attribute__((vector_size(32)));
using P4 = PointLanes<V4d>;
[[gnu::always_inline]] inline P4 Quad(Vec3 u, Vec3 v, Vec3 w, Vec3 t) {
  const double xs[4] = {u.x, v.x, w.x, t.x}, ys[4] = {u.y, v.y, w.y, t.y},
               zs[4] = {u.z, v.z, w.z, t.z};
  P4 q;
  std::memcpy(&q.x, xs, sizeof(q.x));
  std::memcpy(&q.y, ys, sizeof(q.y));
  std::memcpy(&q.z, zs, sizeof(q.z));
  return q;
}
[[gnu::always_inline]] inline P4 Select(M4 m, P4 a,
                                        P4 b) {  // a where m is all ones, else b (a blend with AVX)
  return {m != 0 ? a.x : b.x, m != 0 ? a.y : b.y, m != 0 ? a.z : b.z};
}

// Whether any of four survivors (triangles t[i] with their moving corners c[i]) may stop the
// contraction: the guard's distance, a collapse or a flip, in any lane. No survivor in lanes
// where none does.
[[gnu::always_inline]] inline bool AnySuspect(const MeshStore& store,
                                              const std::array<VertexId, 3>* const (&t)[4],
                                              const int (&c)[4], Vec3 pos, bool guarded,
                                              double bound) {
  auto corner = [&](int k) __attribute__((always_inline)) {
    return Quad(store.position((*t[0])[k]), store.position((*t[1])[k]), store.position((*t[2])[k]),
                store.position((*t[3])[k]));
  };
  const P4 p[3] = {corner(0), corner(1), corner(2)};
  const P4 n_old = CrossLanes(p[1] - p[0], p[2] - p[0]);
  const V4d old2 = DotLanes(n_old, n_old);
  const P4 at = Quad(pos, pos, pos, pos);
  const V4d off = DotLanes(n_old, at - p[0]);
  const double b2 = bound * bound;
  const V4d bb = {b2, b2, b2, b2};
  const M4 far = guarded ? (off * off > bb * old2) : M4{0, 0, 0, 0};
  // The moving corners' masks by 32-bit compares (SSE2 has no 64-bit one): a lane's two
  // halves hold its corner.
  using V8i = int32_t __attribute__((vector_size(32)));
  const V8i corners = {c[0], c[0], c[1], c[1], c[2], c[2], c[3], c[3]};
  auto moved = [&](int k) __attribute__((always_inline)) {
    return Select(reinterpret_cast<M4>(corners == V8i{k, k, k, k, k, k, k, k}), at, p[k]);
  };
  const P4 q[3] = {moved(0), moved(1), moved(2)};
  const P4 after = CrossLanes(q[1] - q[0], q[2] - q[0]);
  const V4d sse = DotLanes(q[1] - q[0], q[1] - q[0]) + DotLanes(q[2] - q[1], q[2] - q[1]) +
                  DotLanes(q[0] - q[2], q[0] - q[2]);
  const V4d ratio = {kCollapsedSquared, kCollapsedSquared, kCollapsedSquared, kCollapsedSquared};
  const V4d zero = {0.0, 0.0, 0.0, 0.0};
  const M4 collapses = ~(DotLanes(after, after) > ratio * sse * sse);
  const M4 flips = ~(DotLanes(n_old, after) > zero);
  const M4 any = far | collapses | flips;
  return ((any[0] | any[1]) | (any[2] | any[3])) != 0;
}

// GeometryOk's body, its survivors tested kLanes at a time: 4 where the CPU has AVX2 (a
// set of lanes in one register), 2 otherwise (SSE2 pairs: four lanes in two halves cost more
// than two pairs). Instantiated in this file only, each with its target; kLanes 1 sends
// every survivor through the exact test (the tests' reference).
template <int kLanes>
[[gnu::always_inline]] inline bool GeometryOkIn(const MeshStore& store, VertexId a, VertexId b,
                                                Vec3 pos, double bound, const OffsetEdges& offsets,
                                                std::vector<Survivor>* survivors,
                                                RefusalCounts* refusals) {
  // Triangles that survive the contraction move one corner (a or b) to pos. The distance
  // guard bounds how far pos lies from each one's present plane: |n·(pos - p0)| <= K E0 |n|
  // (for a triangle smaller than the move, or how far its old corner lies from its new plane).
  // Which triangles are on ab (removed) varies from call to call: branching on it was
  // mispredicted. The survivors are gathered first (written always, kept by a count); a
  // refusal is rare and may branch, so whether the survivor was degenerate already (exact iso
  // hits: no constraint) is asked there.
  const auto ta = store.vertex_triangles(a), tb = store.vertex_triangles(b);
  if (survivors->size() < ta.size() + tb.size()) survivors->resize(ta.size() + tb.size());
  size_t n = 0;
  for (VertexId v : {a, b}) {
    const VertexId other = (v == a) ? b : a;
    for (TriId t : (v == a) ? ta : tb) {
      const auto& tri = store.triangle(t);
      (*survivors)[n] = {t, v};
      n += static_cast<size_t>((static_cast<int>(tri[0] == other) |
                                static_cast<int>(tri[1] == other) |
                                static_cast<int>(tri[2] == other)) == 0);
    }
  }
  const bool guarded = bound > 0.0;
  // The scalar test of one survivor, where the lanes found any of theirs suspect: false
  // if it refuses the contraction.
  auto survives = [&](const Survivor& s) {
    const auto [t, v] = s;
    const auto& tri = store.triangle(t);
    Vec3 p[3];
    for (int k = 0; k < 3; ++k) p[k] = store.position(tri[k]);
    const Vec3 n_old = TwiceAreaVector(p[0], p[1], p[2]);
    const double old2 = Dot(n_old, n_old);
    const double off = Dot(n_old, pos - p[0]);
    bool far = guarded && off * off > bound * bound * old2;  // guarded: fixed per run
    const int corner = CornerOf(tri, v);
    p[corner] = pos;
    const CornerMove move = MoveCorners(n_old, p[0], p[1], p[2]);
    if (!(far | move.collapses | move.flips)) return true;
    const Vec3 from = store.position(v);  // as it was
    if (far && SmallerThanTheMove(p, corner, from, pos)) {
      // Its extended plane follows the curvature, not the surface a move this long crosses:
      // it refuses only if the old corner also lies farther than the bound from the plane
      // the contraction gives it.
      const Vec3 n_new = TwiceAreaVector(p[0], p[1], p[2]);
      const double h = Dot(n_new, from - pos);
      far = h * h > bound * bound * Dot(n_new, n_new);
      if (!(far | move.collapses | move.flips)) return true;
    }
    // A survivor that was collapsed already (an exact iso hit made it: corners on one grid
    // point) has no orientation or plane to keep: the contraction is not refused for it
    // (exempting only an exactly zero area left zero-area triangles on integer scans).
    p[corner] = from;
    if (AreaAtMost(kCollapsedSquared, n_old, SumSquaredEdges(p[0], p[1], p[2]))) return true;
    // One with an offset edge stands for such a triangle: it may turn over or leave its
    // plane (else every grid point on the iso-value holds back the contractions around
    // it), but not collapse.
    if (!move.collapses) {
      const double height =
          std::max({store.height(tri[0]), store.height(tri[1]), store.height(tri[2])});
      if (offsets.Holds(p[1] - p[0], height) || offsets.Holds(p[2] - p[1], height) ||
          offsets.Holds(p[0] - p[2], height)) {
        return true;
      }
    }
    if (far) {
      ++refusals->distance;
    } else if (move.collapses) {
      ++refusals->degenerate;
    } else {
      ++refusals->flip;
    }
    return false;
  };
  // kLanes at a time (the last one repeated to fill the lanes); the scalar test, in order,
  // for those where any may refuse.
  for (size_t i = 0; i < n; i += kLanes) {
    const std::array<VertexId, 3>* t[4];
    int c[4];
    for (size_t k = 0; k < kLanes; ++k) {
      const Survivor& s = (*survivors)[std::min(i + k, n - 1)];
      t[k] = &store.triangle(s.t);
      c[k] = CornerOf(*t[k], s.v);
    }
    bool suspect = true;  // kLanes 1: every survivor
    if constexpr (kLanes == 4) {
      suspect = AnySuspect(store, t, c, pos, guarded, bound);
    } else if constexpr (kLanes == 2) {
      suspect = EitherSuspect(store, *t[0], c[0], *t[1], c[1], pos, guarded, bound);
    }
    if (suspect) [[unlikely]] {
      for (size_t k = i; k < std::min(i + kLanes, n); ++k) {
        if (!survives((*survivors)[k])) return false;
      }
    }
  }
  return true;
}

}  // namespace

// Two versions of one function, the one for the CPU picked once at load (as target_clones
// does, each with its own body): 4 lanes with AVX2, SSE2's pairs otherwise. Called from this
// file only (clang 14 calls another file's multiversioned function through its resolver).
#if defined(__x86_64__) && defined(__ELF__)
__attribute__((target("avx2"))) bool GeometryOkLanes(const MeshStore& store, VertexId a, VertexId b,
                                                     Vec3 pos, double bound,
                                                     const OffsetEdges& offsets,
                                                     std::vector<Survivor>* survivors,
                                                     RefusalCounts* refusals) {
  return GeometryOkIn<4>(store, a, b, pos, bound, offsets, survivors, refusals);
}
__attribute__((target("default")))
#endif
bool GeometryOkLanes(const MeshStore& store, VertexId a, VertexId b, Vec3 pos, double bound,
                     const OffsetEdges& offsets, std::vector<Survivor>* survivors,
                     RefusalCounts* refusals) {
  return GeometryOkIn<2>(store, a, b, pos, bound, offsets, survivors, refusals);
}

bool GeometryOk(const MeshStore& store, VertexId a, VertexId b, Vec3 pos, double bound,
                const OffsetEdges& offsets, std::vector<Survivor>* survivors,
                RefusalCounts* refusals) {
  return GeometryOkLanes(store, a, b, pos, bound, offsets, survivors, refusals);
}

bool GeometryOkWithLanes(int lanes, const MeshStore& store, VertexId a, VertexId b, Vec3 pos,
                         double bound, const OffsetEdges& offsets,
                         std::vector<Survivor>* survivors, RefusalCounts* refusals) {
  switch (lanes) {
    case 1:
      return GeometryOkIn<1>(store, a, b, pos, bound, offsets, survivors, refusals);
    case 4:
      return GeometryOkIn<4>(store, a, b, pos, bound, offsets, survivors, refusals);
    default:
      return GeometryOkIn<2>(store, a, b, pos, bound, offsets, survivors, refusals);
  }
}

}  // namespace tandem
