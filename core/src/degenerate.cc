#include "degenerate.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <utility>
#include <vector>

#include "tandem/geometry.h"

namespace tandem {
namespace {

// Degenerate as written (IsDegenerateTriangle takes 2e-12: exact zeros only).
bool Degenerate(Vec3 a, Vec3 b, Vec3 c) { return IsWrittenDegenerate(a, b, c); }
bool Degenerate(const MeshStore& s, TriId t) {
  const auto& tri = s.triangle(t);
  return Degenerate(s.position(tri[0]), s.position(tri[1]), s.position(tri[2]));
}
// Two corners of a degenerate triangle at one point, as written: their edge under 1e-4 of the
// longest one.
bool Close(Vec3 p, Vec3 q, double longest_squared) {
  const Vec3 d = p - q;
  return Dot(d, d) <= 1e-8 * longest_squared;
}

Vec3 TwiceArea(const MeshStore& s, const std::array<VertexId, 3>& tri) {
  return TwiceAreaVector(s.position(tri[0]), s.position(tri[1]), s.position(tri[2]));
}

// The triangle holding the half-edge from -> to, or kInvalid (the box's boundary).
TriId WithHalfEdge(const MeshStore& s, VertexId from, VertexId to) {
  for (TriId u : s.vertex_triangles(from)) {
    const auto& o = s.triangle(u);
    for (int j = 0; j < 3; ++j) {
      if (o[j] == from && o[(j + 1) % 3] == to) return u;
    }
  }
  return kInvalid;
}

// The way a degenerate triangle should face once mended: as its neighbours across its edges
// do (their summed normals), or `otherwise` when they are degenerate too. Where two sheets
// touch at a vertex, the sum over the vertex's triangles mixes the two sheets' sides, and
// with it as the reference more stayed unmended (docs/decisions.md 26).
Vec3 Across(const MeshStore& s, const std::array<VertexId, 3>& tri, Vec3 otherwise) {
  Vec3 sum{0, 0, 0};
  for (int j = 0; j < 3; ++j) {
    const TriId o = WithHalfEdge(s, tri[(j + 1) % 3], tri[j]);
    if (o != kInvalid && !Degenerate(s, o)) sum = sum + TwiceArea(s, s.triangle(o));
  }
  return Dot(sum, sum) > 0 ? sum : otherwise;
}

bool HasEdge(const MeshStore& s, VertexId a, VertexId b) {
  for (TriId u : s.vertex_triangles(a)) {
    for (VertexId x : s.triangle(u)) {
      if (x == b) return true;
    }
  }
  return false;
}

// The longest edge of tri, tri[k] -> tri[k + 1], and its squared length.
std::pair<int, double> LongestEdge(const MeshStore& s, const std::array<VertexId, 3>& tri) {
  int k = 0;
  double longest = 0;
  for (int i = 0; i < 3; ++i) {
    const Vec3 e = s.position(tri[(i + 1) % 3]) - s.position(tri[i]);
    if (Dot(e, e) > longest) {
      longest = Dot(e, e);
      k = i;
    }
  }
  return {k, longest};
}

// t's corners on one line: flips its longest edge ab to m c (see degenerate.h).
bool TryFlip(MeshStore* s, TriId t) {
  const std::array<VertexId, 3> tri = s->triangle(t);
  const auto [k, longest] = LongestEdge(*s, tri);
  const VertexId a = tri[k], b = tri[(k + 1) % 3], m = tri[(k + 2) % 3];
  if (Close(s->position(m), s->position(a), longest) ||
      Close(s->position(m), s->position(b), longest)) {
    return false;  // corners at one point: not a flip's case
  }
  const TriId u = WithHalfEdge(*s, b, a);
  if (u == kInvalid) return false;
  const std::array<VertexId, 3> o = s->triangle(u);
  const VertexId c = o[0] != a && o[0] != b ? o[0] : (o[1] != a && o[1] != b ? o[1] : o[2]);
  if (c == m || HasEdge(*s, m, c)) return false;
  if (s->labeled()) {
    // The complex of a label session: a flip keeps within one patch, on an edge of two
    // triangles (where labels meet it would cut one label's surface from another's).
    int on_ab = 0;
    for (TriId x : s->vertex_triangles(a)) {
      const auto& w = s->triangle(x);
      on_ab += (w[0] == b) | (w[1] == b) | (w[2] == b);
    }
    if (on_ab != 2 || s->patch(t) != s->patch(u)) return false;
  }
  // m inside ab: (m, a, c) and (m, c, b) tile u and keep its orientation; otherwise one turns.
  const Vec3 before = TwiceArea(*s, o);
  const std::array<VertexId, 3> n1{m, a, c}, n2{m, c, b};
  for (const auto& n : {n1, n2}) {
    const Vec3 p0 = s->position(n[0]), p1 = s->position(n[1]), p2 = s->position(n[2]);
    if (Degenerate(p0, p1, p2) || !MovedCornerKeepsOrientation(before, p0, p1, p2)) {
      return false;
    }
  }
  const uint32_t patch = s->labeled() ? s->patch(t) : 0;
  s->RemoveTriangle(t);
  s->RemoveTriangle(u);
  const TriId t1 = s->AddTriangle(m, a, c), t2 = s->AddTriangle(m, c, b);
  if (s->labeled()) {
    s->set_patch(t1, patch);
    s->set_patch(t2, patch);
  }
  return true;
}

// The way v's star faces: the sum of its non-degenerate triangles' twice-area vectors. When
// every triangle of v is degenerate (a strip of them flat along an edge of the grid's box, at
// a settled seam vertex: the quantised tangles sealed kept 4 so), the way the nearest
// non-degenerate ones face, found ring by ring across the degenerate triangles' edges (up
// to kFacingRings out); zero if there are none.
constexpr int kFacingRings = 4;
Vec3 StarFacing(const MeshStore& s, VertexId v) {
  Vec3 facing{0, 0, 0};
  for (TriId u : s.vertex_triangles(v)) {
    if (!Degenerate(s, u)) facing = facing + TwiceArea(s, s.triangle(u));
  }
  if (Dot(facing, facing) > 0) return facing;
  std::vector<TriId> ring(s.vertex_triangles(v).begin(), s.vertex_triangles(v).end());
  std::vector<TriId> seen = ring, next;
  for (int depth = 0; depth < kFacingRings && !ring.empty(); ++depth) {
    next.clear();
    for (TriId u : ring) {
      const auto& w = s.triangle(u);
      for (int j = 0; j < 3; ++j) {
        const TriId o = WithHalfEdge(s, w[(j + 1) % 3], w[j]);
        if (o == kInvalid || std::find(seen.begin(), seen.end(), o) != seen.end()) continue;
        seen.push_back(o);
        if (Degenerate(s, o)) {
          next.push_back(o);
        } else {
          facing = facing + TwiceArea(s, s.triangle(o));
        }
      }
    }
    if (Dot(facing, facing) > 0) return facing;
    ring.swap(next);
  }
  return facing;
}

// Whether v at q keeps every triangle around it facing as it does, none collapsing, and the
// degenerate ones facing as their neighbours across their edges do (else `facing`, v's star).
bool KeepsFacing(const MeshStore& s, VertexId v, Vec3 q, Vec3 facing) {
  for (TriId u : s.vertex_triangles(v)) {
    const auto& w = s.triangle(u);
    Vec3 c[3];
    for (int j = 0; j < 3; ++j) c[j] = w[j] == v ? q : s.position(w[j]);
    if (Degenerate(s, u)) {
      // Parting sheets that touch can fold a sliver back, a sharp fold worse than the zero
      // area it mends (docs/decisions.md 26): left as it is instead.
      if (!MovedCornerKeepsOrientation(Across(s, w, facing), c[0], c[1], c[2])) return false;
    } else if (!MovedCornerKeepsOrientation(TwiceArea(s, w), c[0], c[1], c[2])) {
      return false;
    }
  }
  return true;
}

// Moves v apart by kApart of the way toward the centroid of its neighbours not at its point,
// along its box faces if it is on the grid's box, unless a triangle turns over or collapses
// (the degenerate ones around it must come out facing as their neighbours across their edges
// do: Across) or may_move refuses. When that direction turns a degenerate triangle the wrong
// way, the same length is tried across each degenerate triangle's long edge, to the side
// that makes it face as v's triangles do, then along the sum of those steps (where two
// sheets touch, the last zero-area triangles part only so).
bool MoveApart(MeshStore* s, VertexId v, double longest,
               const std::function<bool(VertexId, Vec3)>& may_move) {
  const Vec3 p = s->position(v);
  const Vec3 facing = StarFacing(*s, v);
  Vec3 sum{0, 0, 0};
  int n = 0;
  for (TriId u : s->vertex_triangles(v)) {
    for (VertexId x : s->triangle(u)) {
      if (x != v && !Close(s->position(x), p, longest)) {
        sum = sum + s->position(x);
        ++n;
      }
    }
  }
  if (n == 0) return false;
  const uint8_t box = s->box_mask(v);
  auto on_box = [box](Vec3 step) {
    if (box & (kBoxXMin | kBoxXMax)) step.x = 0;
    if (box & (kBoxYMin | kBoxYMax)) step.y = 0;
    if (box & (kBoxZMin | kBoxZMax)) step.z = 0;
    return step;
  };
  auto keeps_facing = [&](Vec3 q) { return KeepsFacing(*s, v, q, facing); };
  auto try_step = [&](Vec3 step) {
    step = on_box(step);
    const Vec3 q = p + step;
    if (Dot(step, step) == 0 || !keeps_facing(q) || !may_move(v, q)) return false;
    s->set_position(v, q);
    return true;
  };
  const Vec3 toward = kApart * (sum * (1.0 / n) - p);
  if (try_step(toward)) return true;
  const double length = Norm(toward);
  if (!(length > 0) || !(Dot(facing, facing) > 0)) return false;
  Vec3 all{0, 0, 0};
  for (TriId u : s->vertex_triangles(v)) {
    if (!Degenerate(*s, u)) continue;
    // The corner of u farthest from v: moving v by d turns u's normal to about
    // (far - p) x d, which faces as the others do for d along facing x (far - p).
    Vec3 far = p;
    for (VertexId x : s->triangle(u)) {
      const Vec3 d = s->position(x) - p;
      if (Dot(d, d) > Dot(far - p, far - p)) far = s->position(x);
    }
    const Vec3 across = on_box(Cross(facing, far - p));
    const double norm = Norm(across);
    if (!(norm > 0)) continue;
    const Vec3 step = across * (length / norm);
    all = all + step;
    if (try_step(step)) return true;
  }
  const double norm = Norm(all);
  if (norm > 0 && try_step(all * (length / norm))) return true;
  // Exactly: moving v by d adds d x (next - prev) to each of its triangles' twice-area
  // vectors (next, prev: the corners after and before v), so a degenerate u comes out facing
  // n_u = Across(u) for d . ((next - prev) x n_u) > 0. Where two sheets touch along a
  // zero-length edge, each sheet's sliver asks for its own side, which the directions above
  // (built on v's own facing) can both miss; the sum of the two unit directions meets both
  // half-spaces unless they are opposite.
  Vec3 exact{0, 0, 0};
  for (TriId u : s->vertex_triangles(v)) {
    if (!Degenerate(*s, u)) continue;
    const auto& w = s->triangle(u);
    const int i = w[0] == v ? 0 : w[1] == v ? 1 : 2;
    const Vec3 a = on_box(Cross(s->position(w[(i + 1) % 3]) - s->position(w[(i + 2) % 3]),
                                Across(*s, w, facing)));
    const double an = Norm(a);
    if (an > 0) exact = exact + a * (1 / an);
  }
  const double en = Norm(exact);
  if (en > 0 && try_step(exact * (length / en))) return true;
  // On an edge of the grid's box (faces of two axes), every step above stays on the edge's
  // line, where a corner between two others on it cannot leave (the quantised tangles: a
  // boundary triangle with its three corners along x = 0, y = max). It may leave one of its
  // faces, straight into the box, and stay on the other: the triangle then lies in that
  // other face, and keeps_facing picks the face where it turns as its neighbours do.
  if (std::popcount(FixedAxes(box)) < 2) return false;
  for (int a = 0; a < 3; ++a) {
    if (!(box & AxisFaces(a))) continue;
    Vec3 step{0, 0, 0};
    step[a] = (box & MinFace(a)) ? length : -length;
    const Vec3 q = p + step;
    if (!keeps_facing(q) || !may_move(v, q)) continue;
    s->set_position(v, q);
    s->set_box_mask(v, static_cast<uint8_t>(s->box_mask(v) & ~AxisFaces(a)));
    return true;
  }
  return false;
}

// t's corners at one point, or on one line where no flip could mend it (on the box): each
// corner at another's point, else the middle one, moves apart (MoveApart).
int64_t TryApart(MeshStore* s, TriId t, const std::function<bool(VertexId, Vec3)>& may_move,
                 const std::function<void(VertexId)>& moved) {
  const std::array<VertexId, 3> tri = s->triangle(t);
  const auto [k, longest] = LongestEdge(*s, tri);
  std::array<bool, 3> move{};
  bool coincident = false;
  for (int i = 0; i < 3; ++i) {
    const Vec3 p = s->position(tri[i]);
    move[i] = Close(s->position(tri[(i + 1) % 3]), p, longest) ||
              Close(s->position(tri[(i + 2) % 3]), p, longest);
    coincident |= move[i];
  }
  if (!coincident) move[(k + 2) % 3] = true;  // collinear: the corner between the other two
  int64_t count = 0;
  for (int i = 0; i < 3; ++i) {
    if (move[i] && MoveApart(s, tri[i], longest, may_move)) {
      moved(tri[i]);
      ++count;
    }
  }
  return count;
}

// t in a closed component of four triangles with every corner at one point (a voxel exactly
// at the iso-value, alone inside: the link condition keeps a tetrahedron of it): its corners
// move to a regular tetrahedron of circumradius `size` around the point, facing out.
int64_t TryInflate(MeshStore* s, TriId t, double size,
                   const std::function<bool(VertexId, Vec3)>& may_move,
                   const std::function<void(VertexId)>& moved) {
  const std::array<VertexId, 3> tri = s->triangle(t);
  const Vec3 p = s->position(tri[0]);
  const double tolerance = 1e-6 * size * size;  // squared: a thousandth of the size
  auto at_p = [&](VertexId x) {
    const Vec3 d = s->position(x) - p;
    return Dot(d, d) <= tolerance;
  };
  std::array<VertexId, 4> v{tri[0], tri[1], tri[2], kInvalid};
  std::vector<TriId> faces;
  for (VertexId x : tri) {
    // On the grid's box a corner must stay on its faces: not a lone voxel's tetrahedron.
    if (!at_p(x) || s->vertex_triangles(x).size() != 3 || (s->box_mask(x) & kBoxFaces)) return 0;
    for (TriId u : s->vertex_triangles(x)) {
      if (std::find(faces.begin(), faces.end(), u) == faces.end()) faces.push_back(u);
      for (VertexId y : s->triangle(u)) {
        if (y != v[0] && y != v[1] && y != v[2]) {
          if (v[3] != kInvalid && v[3] != y) return 0;
          v[3] = y;
        }
      }
    }
  }
  if (faces.size() != 4 || v[3] == kInvalid || !at_p(v[3]) ||
      s->vertex_triangles(v[3]).size() != 3 || (s->box_mask(v[3]) & kBoxFaces)) {
    return 0;
  }
  const double d = size / std::sqrt(3.0);
  std::array<Vec3, 4> q{p + Vec3{d, d, d}, p + Vec3{d, -d, -d}, p + Vec3{-d, d, -d},
                        p + Vec3{-d, -d, d}};
  auto volume = [&] {  // six times the signed volume the faces enclose, positive facing out
    double sum = 0;
    for (TriId u : faces) {
      const auto& w = s->triangle(u);
      Vec3 c[3];
      for (int j = 0; j < 3; ++j) c[j] = q[std::find(v.begin(), v.end(), w[j]) - v.begin()];
      sum += Dot(c[0], Cross(c[1], c[2]));
    }
    return sum;
  };
  if (volume() < 0) std::swap(q[0], q[1]);
  for (int i = 0; i < 4; ++i) {
    if (!may_move(v[i], q[i])) return 0;
  }
  for (int i = 0; i < 4; ++i) {
    s->set_position(v[i], q[i]);
    moved(v[i]);
  }
  return 4;
}

// t alone in its component (each corner in t only) and flat on the grid's box (a voxel at
// the iso-value on the box, its surface cut down to a point or a line there): its corners
// part to a triangle of circumradius `size` (all at one point) or a corner moves `size` off
// the line, facing into the box, as that voxel's surface does. On one face they part within
// it. On an edge of the box (two faces) they part within one of the two, the moved corners
// leaving the other straight into the box; of the two ways, the one that faces into the box.
int64_t TryInflateOnBox(MeshStore* s, TriId t, double size,
                        const std::function<bool(VertexId, Vec3)>& may_move,
                        const std::function<void(VertexId)>& moved) {
  const std::array<VertexId, 3> tri = s->triangle(t);
  uint8_t face = kBoxFaces;
  for (VertexId x : tri) {
    if (s->vertex_triangles(x).size() != 1) return 0;
    face &= s->box_mask(x);
  }
  std::array<int, 2> axes{};
  std::array<double, 3> inward{};
  int on = 0;
  for (int a = 0; a < 3; ++a) {
    if (face & AxisFaces(a)) {
      if (on == 2) return 0;  // a corner of the box
      axes[on++] = a;
      inward[a] = (face & MinFace(a)) ? 1 : -1;
    }
  }
  if (on == 0) return 0;
  auto unit = [](int a, double sign) {
    Vec3 e{0, 0, 0};
    e[a] = sign;
    return e;
  };
  const std::array<Vec3, 3> p{s->position(tri[0]), s->position(tri[1]), s->position(tri[2])};
  const auto [k, longest] = LongestEdge(*s, tri);
  const Vec3 a = p[k], b = p[(k + 1) % 3];
  const bool point = longest <= 1e-8 * size * size;
  for (int way = 0; way < on; ++way) {
    const int stay = axes[way], leave = on == 2 ? axes[1 - way] : -1;
    const Vec3 n = unit(stay, inward[stay]);
    std::array<Vec3, 3> q = p;
    if (point) {  // a small triangle at it
      if (leave >= 0) {  // a corner, one step into the box, one along the edge
        q[1] = a + unit(leave, inward[leave]) * size;
        q[2] = a + unit(3 - stay - leave, 1) * size;
        q[0] = a;
      } else {  // around it
        const Vec3 e1 = stay == 0 ? Vec3{0, 1, 0} : Vec3{1, 0, 0};
        const Vec3 e2 = Cross(n, e1);
        for (int i = 0; i < 3; ++i) {
          const double angle = 2.0943951023931953 * i;  // 120 degrees apart
          q[i] = a + (e1 * std::cos(angle) + e2 * std::sin(angle)) * size;
        }
      }
      if (Dot(TwiceAreaVector(q[0], q[1], q[2]), n) < 0) std::swap(q[1], q[2]);
    } else {  // a line: the corner off the longest edge leaves it
      const int m = (k + 2) % 3;
      if (leave >= 0) {
        q[m] = p[m] + unit(leave, inward[leave]) * size;
        if (Dot(TwiceAreaVector(q[0], q[1], q[2]), n) < 0) continue;  // the other way
      } else {
        const Vec3 d = Cross(n, b - a);
        q[m] = p[m] + d * (size / Norm(d));
        if (Dot(TwiceAreaVector(q[0], q[1], q[2]), n) < 0) q[m] = p[m] - (q[m] - p[m]);
      }
    }
    bool may = true;
    for (int i = 0; i < 3; ++i) may = may && (q[i] == p[i] || may_move(tri[i], q[i]));
    if (!may) continue;
    int64_t count = 0;
    for (int i = 0; i < 3; ++i) {
      if (q[i] == p[i]) continue;
      s->set_position(tri[i], q[i]);
      if (leave >= 0 && q[i][leave] != p[i][leave]) {  // a corner off the face it left
        s->set_box_mask(tri[i], static_cast<uint8_t>(s->box_mask(tri[i]) & ~AxisFaces(leave)));
      }
      moved(tri[i]);
      ++count;
    }
    return count;
  }
  return 0;
}

}  // namespace

bool MoveKeepsFacing(const MeshStore& store, VertexId v, Vec3 q, Vec3 otherwise) {
  const Vec3 facing = StarFacing(store, v);
  return KeepsFacing(store, v, q, Dot(facing, facing) > 0 ? facing : otherwise);
}

Vec3 VertexFacing(const MeshStore& store, VertexId v) { return StarFacing(store, v); }

DegenerateCounts TidyDegenerateAmong(MeshStore* store, std::span<const TriId> tris, double size,
                                     const std::function<bool(VertexId, Vec3)>& may_move,
                                     const std::function<void(VertexId)>& moved, bool flips) {
  DegenerateCounts counts;
  std::vector<TriId> bad;
  for (TriId t : tris) {
    if (store->triangle_alive(t) && Degenerate(*store, t)) bad.push_back(t);
  }
  // An id a flip freed may come back as one of its new triangles: those are not degenerate.
  for (TriId t : bad) {
    if (!store->triangle_alive(t) || !Degenerate(*store, t)) continue;
    if (flips && TryFlip(store, t)) {
      ++counts.flipped;
    } else if (const int64_t n = TryInflate(store, t, size, may_move, moved); n > 0) {
      counts.moved += n;
    } else if (const int64_t m = TryInflateOnBox(store, t, size, may_move, moved); m > 0) {
      counts.moved += m;
    } else {
      counts.moved += TryApart(store, t, may_move, moved);
    }
  }
  for (TriId t : bad) {
    counts.left += store->triangle_alive(t) && Degenerate(*store, t);
  }
  return counts;
}

DegenerateCounts TidyDegenerate(MeshStore* store, double size,
                                const std::function<bool(VertexId, Vec3)>& may_move,
                                const std::function<void(VertexId)>& moved) {
  std::vector<TriId> all;
  for (TriId t = 0; t < store->triangle_capacity(); ++t) {
    if (store->triangle_alive(t)) all.push_back(t);
  }
  return TidyDegenerateAmong(store, all, size, may_move, moved);
}

}  // namespace tandem
