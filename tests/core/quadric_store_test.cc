// QuadricStore: the compact per-vertex quadrics give the full sums of the planes, whether a
// vertex keeps only its matrix or its quadric in full, through moves, merges and adoption.
#include "quadric_store.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "mesh_store.h"
#include "quadric.h"

namespace tandem {
namespace {

// A tetrahedron's four faces around vertex 0, with an off-centre apex.
struct Fixture {
  MeshStore store;
  std::vector<VertexId> v;
  std::vector<TriId> t;
  Fixture() {
    v = {store.AddVertex({0, 0, 0}, 0, 0, 0), store.AddVertex({1, 0, 0}, 0, 0, 0),
         store.AddVertex({0, 1, 0}, 0, 0, 0), store.AddVertex({0.2, 0.3, 1}, 1, 1, 0)};
    t = {store.AddTriangle(v[0], v[2], v[1]), store.AddTriangle(v[0], v[1], v[3]),
         store.AddTriangle(v[1], v[2], v[3]), store.AddTriangle(v[2], v[0], v[3])};
  }
  Quadric Plane(TriId tri) const {
    const auto& c = store.triangle(tri);
    return PlaneQuadric(store.position(c[0]), store.position(c[1]), store.position(c[2]));
  }
  // Every triangle's plane into its corners, as AddTriangles does.
  void AddAll(QuadricStore* q) const {
    q->EnsureCapacity(store.vertex_capacity());
    for (VertexId x : v) q->Reset(x);
    for (TriId tri : t) {
      for (VertexId x : store.triangle(tri)) q->AddPlane(x, Plane(tri));
    }
  }
  Quadric Full(VertexId x) const {  // the sum of x's planes, all of H
    Quadric h;
    for (TriId tri : t) {
      for (VertexId c : store.triangle(tri)) {
        if (c == x) h += Plane(tri);
      }
    }
    return h;
  }
};

void ExpectSame(const Quadric& a, const Quadric& b) {
  for (Vec3 x : {Vec3{0, 0, 0}, Vec3{0.3, -0.2, 0.5}, Vec3{2, 1, -1}}) {
    EXPECT_NEAR(a.Evaluate(x), b.Evaluate(x), 1e-12) << x.x << " " << x.y << " " << x.z;
  }
  EXPECT_NEAR(a.w, b.w, 1e-12);
}

TEST(QuadricStore, MatrixAloneGivesTheWholeQuadricAtTheVertex) {
  Fixture f;
  QuadricStore q(&f.store, /*check=*/false);
  f.AddAll(&q);
  for (VertexId x : f.v) {
    EXPECT_EQ(f.store.aux(x), kInvalid);  // 48 bytes: no tail taken
    ExpectSame(q.Get(x), f.Full(x));
    Quadric sum;
    q.AddTo(x, &sum);
    q.AddTo(x, &sum);
    Quadric twice = f.Full(x);
    twice += f.Full(x);
    ExpectSame(sum, twice);
  }
}

TEST(QuadricStore, SumIsAddToTwiceBitForBitKeptInFullOrNot) {
  // An evaluation sums the two ends with Sum and the contraction stores Merge's sum: both
  // must be exactly what AddTo(a) then AddTo(b) gives, or ε0 ≤ E0 at the evaluation could
  // read above E0 in Error(K). Vertices 1 and 3 keep their quadric in full (3 moved).
  Fixture f;
  QuadricStore q(&f.store, /*check=*/false);
  f.AddAll(&q);
  q.Keep(f.v[1]);
  q.Keep(f.v[3]);
  f.store.set_position(f.v[3], {0.25, 0.35, 0.9});
  for (VertexId a : f.v) {
    for (VertexId b : f.v) {
      if (a == b) continue;
      Quadric want;
      q.AddTo(a, &want);
      q.AddTo(b, &want);
      const Quadric got = q.Sum(a, b).Unpack();
      const double w[11] = {want.a00, want.a01, want.a02, want.a11, want.a12, want.a22,
                            want.b0,  want.b1,  want.b2,  want.c,   want.w};
      const double g[11] = {got.a00, got.a01, got.a02, got.a11, got.a12, got.a22,
                            got.b0,  got.b1,  got.b2,  got.c,   got.w};
      for (int i = 0; i < 11; ++i) EXPECT_EQ(g[i], w[i]) << a << " " << b << " " << i;  // ±0 equal
      for (Vec3 x : {Vec3{0.1, 0.2, 0.3}, Vec3{-3, 5, 7}}) {
        EXPECT_EQ(q.Sum(a, b).Evaluate(x), want.Evaluate(x));
        EXPECT_EQ(ShapeError(q.Sum(a, b), x), ShapeError(want, x));
      }
    }
  }
}

TEST(QuadricStore, KeptInFullSurvivesAMoveAndLaterPlanes) {
  Fixture f;
  QuadricStore q(&f.store, /*check=*/true);
  q.EnsureCapacity(f.store.vertex_capacity());
  for (VertexId x : f.v) q.Reset(x);
  // Half the planes, then vertex 3 moves (kept first), then the rest: its own planes no
  // longer pass through it, so the matrix alone would be wrong.
  for (size_t i = 0; i < 2; ++i) {
    for (VertexId x : f.store.triangle(f.t[i])) q.AddPlane(x, f.Plane(f.t[i]));
  }
  const std::vector<Quadric> later = {f.Plane(f.t[2]), f.Plane(f.t[3])};
  Quadric want = f.Plane(f.t[1]);
  q.Keep(f.v[3]);
  EXPECT_NE(f.store.aux(f.v[3]), kInvalid);
  f.store.set_position(f.v[3], {0.5, 0.5, 2});
  for (size_t i = 2; i < 4; ++i) {
    for (VertexId x : f.store.triangle(f.t[i])) q.AddPlane(x, later[i - 2]);
  }
  want += later[0];
  want += later[1];
  ExpectSame(q.Get(f.v[3]), want);
  EXPECT_EQ(q.mismatches(), 0);
  // Moved without Keep: the check counts it.
  f.store.set_position(f.v[2], {0.1, 1.5, 0.4});
  (void)q.Get(f.v[2]);
  EXPECT_EQ(q.mismatches(), 1);
}

TEST(QuadricStore, MergeAddsBothAndFreesTheLosersSlot) {
  Fixture f;
  QuadricStore q(&f.store, /*check=*/false);
  f.AddAll(&q);
  q.Keep(f.v[1]);
  const uint32_t slot = f.store.aux(f.v[1]);
  ASSERT_NE(slot, kInvalid);
  Quadric want = f.Full(f.v[0]);
  want += f.Full(f.v[1]);
  q.Merge(f.v[0], f.v[1]);
  EXPECT_EQ(f.store.aux(f.v[1]), kInvalid);
  f.store.set_position(f.v[0], {0.4, 0.1, 0.2});  // the survivor moves: kept in full
  ExpectSame(q.Get(f.v[0]), want);
  // The freed slot is handed out again, lowest first.
  q.Keep(f.v[2]);
  EXPECT_EQ(f.store.aux(f.v[2]), slot);
  // Reset (an id handed to a new vertex) forgets everything.
  q.Reset(f.v[0]);
  EXPECT_EQ(f.store.aux(f.v[0]), kInvalid);
  EXPECT_EQ(q.Get(f.v[0]).w, 0);
}

TEST(QuadricStore, AdoptCopiesOrAddsAcrossStores) {
  Fixture a, b;
  QuadricStore qa(&a.store, false), qb(&b.store, false);
  a.AddAll(&qa);
  b.AddAll(&qb);
  const Quadric want3 = b.Full(b.v[3]);
  Quadric sum = a.Full(a.v[0]);
  sum += b.Full(b.v[0]);
  qb.Keep(b.v[3]);
  b.store.set_position(b.v[3], {3, 3, 3});
  qa.Adopt(qb, PartVertex{b.v[3]}, a.v[2],
           /*shared=*/false);  // a.v[2]'s record is b.v[3]'s from now
  a.store.set_position(a.v[2], {3, 3, 3});
  ExpectSame(qa.Get(a.v[2]), want3);
  qa.Adopt(qb, PartVertex{b.v[0]}, a.v[0], /*shared=*/true);
  ExpectSame(qa.Get(a.v[0]), sum);
  EXPECT_GT(qa.MemoryBytes(), 0u);
}

}  // namespace
}  // namespace tandem
