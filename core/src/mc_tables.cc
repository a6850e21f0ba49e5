#include "mc_tables.h"

#include <array>
#include <cassert>
#include <vector>

namespace tandem::mc {
namespace {

struct Tables {
  uint8_t face_corners[6][4];
  uint8_t face_edges[6][4];  // edge between face_corners[i] and [i+1]
  uint8_t ambiguous[256];
  std::vector<CubeCase> cases;  // 256 * 64
};

int EdgeBetween(int a, int b) {
  for (int e = 0; e < 12; ++e) {
    if ((kEdgeCorners[e][0] == a && kEdgeCorners[e][1] == b) ||
        (kEdgeCorners[e][0] == b && kEdgeCorners[e][1] == a)) {
      return e;
    }
  }
  return -1;
}

void CornerPos(int c, int p[3]) {
  p[0] = c & 1;
  p[1] = (c >> 1) & 1;
  p[2] = (c >> 2) & 1;
}

// Orders each face's corners cyclically and counter-clockwise around the outward normal.
void BuildFaces(Tables& t) {
  for (int f = 0; f < 6; ++f) {
    const int axis = f / 2, side = f % 2;
    int corners[4], n = 0;
    for (int c = 0; c < 8; ++c) {
      int p[3];
      CornerPos(c, p);
      if (p[axis] == side) corners[n++] = c;
    }
    // Cyclic order: corners[0], its edge-neighbour, the opposite, the other neighbour.
    int cyc[4] = {corners[0], -1, -1, -1};
    int nb[2], k = 0, opp = -1;
    for (int i = 1; i < 4; ++i) {
      if (EdgeBetween(corners[0], corners[i]) >= 0) nb[k++] = corners[i];
      else opp = corners[i];
    }
    cyc[1] = nb[0];
    cyc[2] = opp;
    cyc[3] = nb[1];
    int p0[3], p1[3], p3[3];
    CornerPos(cyc[0], p0);
    CornerPos(cyc[1], p1);
    CornerPos(cyc[3], p3);
    const int u[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
    const int v[3] = {p3[0] - p0[0], p3[1] - p0[1], p3[2] - p0[2]};
    const int cr[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                       u[0] * v[1] - u[1] * v[0]};
    const int outward = side ? 1 : -1;
    if (cr[axis] * outward < 0) std::swap(cyc[1], cyc[3]);
    for (int i = 0; i < 4; ++i) {
      t.face_corners[f][i] = static_cast<uint8_t>(cyc[i]);
      t.face_edges[f][i] = static_cast<uint8_t>(EdgeBetween(cyc[i], cyc[(i + 1) % 4]));
    }
  }
}

CubeCase BuildCase(const Tables& t, int config, int connected) {
  auto in = [config](int c) { return (config >> c) & 1; };
  int next[12];
  for (int& e : next) e = -1;
  for (int f = 0; f < 6; ++f) {
    const bool join = ((t.ambiguous[config] >> f) & 1) && ((connected >> f) & 1);
    for (int i = 0; i < 4; ++i) {
      const int a = t.face_corners[f][i], b = t.face_corners[f][(i + 1) % 4];
      if (in(a) || !in(b)) continue;  // not an out->in crossing
      for (int s = 1; s < 4; ++s) {
        const int j = join ? (i - s + 4) % 4 : (i + s) % 4;
        const int c = t.face_corners[f][j], d = t.face_corners[f][(j + 1) % 4];
        if (in(c) && !in(d)) {
          next[t.face_edges[f][i]] = t.face_edges[f][j];
          break;
        }
      }
    }
  }
  CubeCase cc;
  bool seen[12] = {};
  int pos = 0;
  for (int start = 0; start < 12; ++start) {
    if (next[start] < 0 || seen[start]) continue;
    const int first = pos;
    for (int e = start; !seen[e]; e = next[e]) {
      assert(e >= 0);
      seen[e] = true;
      cc.edges[pos++] = static_cast<uint8_t>(e);
    }
    const int len = pos - first;
    const int l = cc.num_loops++;
    cc.loop_len[l] = static_cast<uint8_t>(len);
    for (int f = 0; f < 6; ++f) {
      if (!((t.ambiguous[config] >> f) & 1)) continue;
      int on_face = 0;
      for (int i = first; i < pos; ++i) {
        for (int k = 0; k < 4; ++k) on_face += cc.edges[i] == t.face_edges[f][k];
      }
      if (on_face == 4) cc.center_mask |= static_cast<uint8_t>(1u << l);
    }
  }
  return cc;
}

const Tables& GetTables() {
  static const Tables* tables = [] {
    auto* t = new Tables;
    BuildFaces(*t);
    for (int config = 0; config < 256; ++config) {
      uint8_t amb = 0;
      for (int f = 0; f < 6; ++f) {
        const uint8_t* c = t->face_corners[f];
        const int s0 = (config >> c[0]) & 1, s1 = (config >> c[1]) & 1;
        const int s2 = (config >> c[2]) & 1, s3 = (config >> c[3]) & 1;
        if (s0 == s2 && s1 == s3 && s0 != s1) amb |= static_cast<uint8_t>(1u << f);
      }
      t->ambiguous[config] = amb;
    }
    // Only the bits of ambiguous faces matter: build each distinct case once (656 of
    // the 16,384 slots; building all of them slowed every start, docs/decisions.md 41) and copy
    // it to the slots that differ in the other bits. conn & amb <= conn, so it is built.
    t->cases.resize(256 * 64);
    for (int config = 0; config < 256; ++config) {
      const int amb = t->ambiguous[config];
      for (int conn = 0; conn < 64; ++conn) {
        CubeCase& c = t->cases[config * 64 + conn];
        c = (conn & amb) == conn ? BuildCase(*t, config, conn)
                                 : t->cases[config * 64 + (conn & amb)];
      }
    }
    return t;
  }();
  return *tables;
}

}  // namespace

const uint8_t (&FaceCorners(int f))[4] { return GetTables().face_corners[f]; }

uint8_t AmbiguousFaces(uint8_t config) { return GetTables().ambiguous[config]; }

const CubeCase& Lookup(uint8_t config, uint8_t connected) {
  const Tables& t = GetTables();
  return t.cases[config * 64 + (connected & t.ambiguous[config])];
}

}  // namespace tandem::mc
