// The engine's label mode from inside (core/src): the per-label link condition against its
// definition, DELAY queueing each edge of the interface complex once, flips kept within a
// patch, and the sag correction leaving the junctions of labels where they are.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <set>
#include <vector>

#include "contraction_checks.h"
#include "degenerate.h"
#include "engine_testutil.h"
#include "label_extractor.h"
#include "layer_extractor.h"
#include "mesh_store.h"
#include "simplifier.h"
#include "simplifier_access.h"
#include "tandem/labels.h"
#include "tandem/tandem.h"

namespace tandem {
namespace {

// A 16^3 label map: two boxes side by side, a ball of a third label through both, and the
// background around them.
std::vector<uint16_t> Labels(int64_t n) {
  std::vector<uint16_t> v(static_cast<size_t>(n * n * n), 0);
  for (int64_t z = 0; z < n; ++z) {
    for (int64_t y = 0; y < n; ++y) {
      for (int64_t x = 0; x < n; ++x) {
        uint16_t l = 0;
        if (x >= 3 && x < 13 && y >= 3 && y < 13 && z >= 3 && z < 13) l = x < 8 ? 1 : 2;
        if (std::hypot(x - 8.0, y - 6.0, z - 9.0) < 3.2) l = 3;
        v[static_cast<size_t>((z * n + y) * n + x)] = l;
      }
    }
  }
  return v;
}

// A label layer's rule for edge k of its new triangle t, against the store right after the
// commit: kEdgeSearch where both ends are older; else every triangle holding the edge is
// new, and t queues it (kEdgeOnce) iff it is the one of least id.
void ExpectRuleOfTheStore(const MeshStore& s, TriId t, int k, LayerEdge rule) {
  const VertexId a = s.triangle(t)[k], b = s.triangle(t)[(k + 1) % 3];
  const int32_t layer =
      std::max({s.layer(s.triangle(t)[0]), s.layer(s.triangle(t)[1]), s.layer(s.triangle(t)[2])});
  if (s.layer(a) < layer && s.layer(b) < layer) {
    EXPECT_EQ(rule, kEdgeSearch) << a << "-" << b;
    return;
  }
  TriId least = t;
  for (TriId u : s.vertex_triangles(a)) {
    const auto& o = s.triangle(u);
    if (std::find(o.begin(), o.end(), b) == o.end()) continue;
    EXPECT_EQ(std::max({s.layer(o[0]), s.layer(o[1]), s.layer(o[2])}), layer);
    least = std::min(least, u);
  }
  EXPECT_EQ(rule, least == t ? kEdgeOnce : kEdgeBelow) << a << "-" << b << " of " << t;
}

struct LabelSweep {
  bool rules = false;     // each layer delayed with the extractor's edge rules, as the schedules do
  bool close = false;     // the volume closed at the box (the background around it)
  bool lockstep = false;  // each layer activated and simplified up to its top plane
};

// Extracts Labels(n) into `store` layer by layer (open at the box unless sweep.close); each
// layer's triangles are added to the simplifier and delayed as the tandem schedules do,
// without `rules` the store searched for each edge's other triangles. Returns how many edges
// got each LayerEdge from the extractor.
std::array<int64_t, 4> ExtractLabels(int64_t n, MeshStore* store, Simplifier* simplifier,
                                     LabelSweep sweep = {}) {
  ExtractorConfig config{n, n, n, {1, 1, 1}, {0, 0, 0}, 0};
  config.labels.enabled = true;
  config.labels.close = sweep.close;
  store->EnableLabels();
  LayerExtractor ex(config, store);
  const std::vector<uint16_t> v = Labels(n);
  std::vector<TriId> tris;
  std::vector<VertexId> verts;
  std::vector<uint8_t> edges;
  std::array<int64_t, 4> kinds{};
  auto step = [&](double front) {
    tris.clear();
    verts.clear();
    edges.clear();
    ex.CommitLayer(&tris, &verts, nullptr, sweep.rules ? &edges : nullptr);
    if (sweep.rules) {
      ASSERT_EQ(edges.size(), tris.size()) << "a rule for each triangle of the layer";
      for (size_t i = 0; i < tris.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
          const LayerEdge rule = EdgeOf(edges[i], k);
          ++kinds[rule];
          ExpectRuleOfTheStore(*store, tris[i], k, rule);
        }
      }
    }
    simplifier->AddTriangles(tris, verts);
    simplifier->Delay(tris, edges);
    if (sweep.lockstep) {
      simplifier->Activate(front);
      simplifier->Simplify();
    }
  };
  for (int64_t k = 0; k < n; ++k) {
    const auto* slice = reinterpret_cast<const uint8_t*>(v.data() + k * n * n);
    EXPECT_TRUE(ex.ComputeLayer(SliceValues{slice, DType::kUInt16}).ok());
    step(static_cast<double>(k));
  }
  if (ex.ComputeClosingLayer()) step(static_cast<double>(n));
  return kinds;
}

SimplifierOptions Options(double error = 0.5) {
  SimplifierOptions o;
  o.error = error;
  o.release = ReleaseRule::kReach;
  return o;
}

// LAMBDA(ab) per label from its definition: for every label whose surface holds a and b,
// ab is an edge of it and Lk(a) ∩ Lk(b) = Lk(ab) there, the boundary completed by a dummy
// vertex; and ab lies in at most kMaxEdgeTriangles triangles.
bool LabelLinkByDefinition(const MeshStore& s, VertexId a, VertexId b) {
  constexpr VertexId kDummy = kInvalid - 1;
  using Simplex = std::vector<VertexId>;  // sorted
  // The links involve only the triangles at a or b (and the boundary their edges).
  std::set<TriId> star(s.vertex_triangles(a).begin(), s.vertex_triangles(a).end());
  star.insert(s.vertex_triangles(b).begin(), s.vertex_triangles(b).end());
  int on_ab = 0;
  std::set<LabelId> labels;
  for (TriId t : star) {
    const auto& w = s.triangle(t);
    const bool has_a = std::count(w.begin(), w.end(), a), has_b = std::count(w.begin(), w.end(), b);
    on_ab += has_a && has_b;
    if (has_a || has_b) {
      labels.insert(s.pair_of(t).inside);
      labels.insert(s.pair_of(t).outside);
    }
  }
  if (on_ab == 0 || on_ab > kMaxEdgeTriangles) return false;
  for (LabelId l : labels) {
    std::vector<std::array<VertexId, 3>> surface;
    for (TriId t : star) {
      if (s.pair_of(t).inside == l || s.pair_of(t).outside == l) surface.push_back(s.triangle(t));
    }
    std::map<std::pair<VertexId, VertexId>, int> edges;
    for (const auto& w : surface) {
      for (int i = 0; i < 3; ++i) ++edges[std::minmax(w[i], w[(i + 1) % 3])];
    }
    for (const auto& [e, count] : edges) {  // edges at a or b: all their triangles are here
      const bool at_ab = e.first == a || e.first == b || e.second == a || e.second == b;
      if (count == 1 && at_ab) surface.push_back({e.first, e.second, kDummy});
    }
    auto link = [&surface](std::vector<VertexId> of) {
      std::set<Simplex> out;
      for (const auto& w : surface) {
        Simplex rest;
        size_t found = 0;
        for (VertexId x : w) {
          if (std::count(of.begin(), of.end(), x)) {
            ++found;
          } else {
            rest.push_back(x);
          }
        }
        if (found != of.size()) continue;
        std::sort(rest.begin(), rest.end());
        out.insert(rest);
        if (rest.size() == 2) {  // the link's vertices too
          out.insert({rest[0]});
          out.insert({rest[1]});
        }
      }
      return out;
    };
    const auto la = link({a}), lb = link({b});
    if (la.empty() || lb.empty()) continue;  // the surface holds one of them: nothing asked
    const auto lab = link({a, b});
    if (lab.empty()) return false;  // not an edge of this surface
    std::set<Simplex> both;
    std::set_intersection(la.begin(), la.end(), lb.begin(), lb.end(),
                          std::inserter(both, both.begin()));
    if (both != lab) return false;
  }
  return true;
}

// Every voxel of an n x n x depth stack its own label: three new pairs a voxel, each met in
// one layer or two. Unsealed, the store keeps every pair; the extractor's own tables (its
// PlaneBytes, pairs included) hold a layer's, so they are the same from a stack eight times
// deeper, while the store's grow with it.
TEST(LabelEngine, ExtractorPairTablesHoldALayersPairs) {
  constexpr int64_t n = 24;
  size_t plane_bytes[2] = {0, 0}, store_pairs[2] = {0, 0};
  for (int deep = 0; deep < 2; ++deep) {
    const int64_t depth = deep ? 64 : 8;
    ExtractorConfig config{n, n, depth, {1, 1, 1}, {0, 0, 0}, 0};
    config.labels.enabled = true;
    MeshStore store;
    store.EnableLabels();
    LayerExtractor ex(config, &store);
    std::vector<uint16_t> slice(static_cast<size_t>(n * n));
    uint16_t next = 1;
    for (int64_t k = 0; k < depth; ++k) {
      for (uint16_t& l : slice) l = next++;  // 24 * 24 * 64 ids fit in uint16
      ASSERT_TRUE(ex.ComputeLayer(SliceValues{reinterpret_cast<const uint8_t*>(slice.data()),
                                              DType::kUInt16})
                      .ok());
      ex.CommitLayer();
      plane_bytes[deep] = std::max(plane_bytes[deep], ex.PlaneBytes(DType::kUInt16));
    }
    store_pairs[deep] = store.pairs().size();
  }
  EXPECT_GT(store_pairs[1], 6 * store_pairs[0]);
  EXPECT_LE(plane_bytes[1], plane_bytes[0] * 5 / 4)
      << plane_bytes[0] << " bytes at 8 slices, " << plane_bytes[1] << " at 64";
}

TEST(LabelEngine, LinkConditionPerLabelMatchesItsDefinition) {
  MeshStore store;
  Simplifier simplifier(&store, Options(0.05));
  ExtractLabels(16, &store, &simplifier);
  simplifier.Activate(std::numeric_limits<double>::infinity());  // partly simplified
  simplifier.Simplify();
  const EdgeTriangles edges = CountEdgeTriangles(store);
  LinkScratch scratch;
  int junction_allowed = 0, refused = 0, checked = 0;
  for (const auto& [e, n] : edges) {
    const bool fast = LinkCondition(store, e.first, e.second, &scratch);
    ASSERT_EQ(fast, LabelLinkByDefinition(store, e.first, e.second))
        << e.first << "-" << e.second << " in " << n << " triangles";
    junction_allowed += fast && n >= 3;
    refused += !fast;
    ++checked;
  }
  EXPECT_GT(checked, 300);
  EXPECT_GT(junction_allowed, 10);  // the iso-surface's rule refuses every one of these
  // Pairs of vertices that are no edge: refused, both ways.
  EXPECT_FALSE(
      LinkCondition(store, edges.begin()->first.first, edges.rbegin()->first.second, &scratch));
  EXPECT_GT(refused, 0);
}

TEST(LabelEngine, DelayQueuesEachEdgeOfTheComplexOnce) {
  for (bool rules : {false, true}) {
    for (bool close : {false, true}) {
      MeshStore store;
      Simplifier simplifier(&store, Options());  // front at -inf: every edge waits in W
      ExtractLabels(16, &store, &simplifier, {.rules = rules, .close = close});
      const EdgeTriangles edges = CountEdgeTriangles(store);
      const auto junctions =
          std::count_if(edges.begin(), edges.end(), [](const auto& e) { return e.second >= 3; });
      EXPECT_GT(junctions, 100);
      EXPECT_EQ(SimplifierProbe::w_pushes(simplifier), static_cast<int64_t>(edges.size()))
          << (rules ? "the extractor's rules" : "the store searched") << (close ? ", closed" : "");
      EXPECT_EQ(SimplifierProbe::q_pushes(simplifier), 0);
    }
  }
}

// The extractor's rules pick the edges the store's search picks, in the same order: the same
// sweep, freed triangle ids reused by the next layers, ends in the same complex.
TEST(LabelEngine, DelayByTheExtractorsRulesSimplifiesAsTheSearch) {
  for (bool close : {false, true}) {
    MeshStore searched, ruled;
    Simplifier by_search(&searched, Options()), by_rules(&ruled, Options());
    ExtractLabels(16, &searched, &by_search, {.close = close, .lockstep = true});
    const std::array<int64_t, 4> kinds =
        ExtractLabels(16, &ruled, &by_rules, {.rules = true, .close = close, .lockstep = true});
    EXPECT_GT(kinds[kEdgeOnce], 1000);
    EXPECT_GT(kinds[kEdgeBelow], 1000);  // in another new triangle, of less id
    EXPECT_GT(kinds[kEdgeSearch], 100);  // both ends older: left to the store's search
    EXPECT_EQ(kinds[kEdgeShared], 0);
    EXPECT_EQ(SimplifierProbe::w_pushes(by_rules), SimplifierProbe::w_pushes(by_search));
    EXPECT_EQ(SimplifierProbe::contractions(by_rules), SimplifierProbe::contractions(by_search));
    EXPECT_GT(SimplifierProbe::contractions(by_rules), 500) << "ids freed for the next layers";
    ASSERT_EQ(ruled.triangle_capacity(), searched.triangle_capacity());
    for (TriId t = 0; t < ruled.triangle_capacity(); ++t) {
      ASSERT_EQ(ruled.triangle_alive(t), searched.triangle_alive(t)) << t;
      if (ruled.triangle_alive(t)) {
        ASSERT_EQ(ruled.triangle(t), searched.triangle(t)) << t;
      }
    }
  }
}

// A committed label layer by hand: edge p0-p1 in three triangles (a junction), 5-6 between two
// older vertices, the rest in one triangle each; the store's ids in staging order or not.
TEST(LabelEngine, EdgeRulesQueueEachNewEdgeFromItsTriangleOfLeastId) {
  ExtractorConfig config{4, 4, 4, {1, 1, 1}, {0, 0, 0}, 0};
  config.labels.enabled = true;
  LabelLayers layers(config);
  constexpr VertexId p0 = LayerExtractor::kPending, p1 = p0 | 1, p2 = p0 | 2, p3 = p0 | 3;
  const std::vector<std::array<VertexId, 3>> staged = {
      {p0, p1, p2}, {p1, p0, p3}, {p0, p1, 5}, {5, 6, p2}};
  const uint8_t search_once_once = LayerEdges(kEdgeSearch, kEdgeOnce, kEdgeOnce);
  const uint8_t once = LayerEdges(kEdgeOnce, kEdgeOnce, kEdgeOnce);
  const uint8_t below_once_once = LayerEdges(kEdgeBelow, kEdgeOnce, kEdgeOnce);
  std::vector<uint8_t> rules = {7};  // appended to
  layers.EdgeRules(staged, 4, std::vector<TriId>{30, 10, 20, 40}, &rules);
  EXPECT_EQ(rules,
            (std::vector<uint8_t>{7, below_once_once, once, below_once_once, search_once_once}));
  rules.clear();
  layers.EdgeRules(staged, 4, std::vector<TriId>{10, 20, 30, 40}, &rules);
  EXPECT_EQ(rules,
            (std::vector<uint8_t>{once, below_once_once, below_once_once, search_once_once}));
}

// A sliver (a, b, m), m on ab, and across ab (b, a, c): the flip mends it within one patch,
// and is refused where the two triangles separate different labels.
TEST(LabelEngine, FlipsStayWithinAPatch) {
  for (bool same : {true, false}) {
    MeshStore s;
    s.EnableLabels();
    const uint32_t p = s.PatchOf({1, 0}), q = s.PatchOf({1, 2});
    const VertexId a = s.AddVertex({0, 0, 0}, 0, 0, 0), b = s.AddVertex({2, 0, 0}, 0, 0, 0),
                   m = s.AddVertex({1, 0, 0}, 0, 0, 0), c = s.AddVertex({1, 1, 0}, 0, 0, 0),
                   d = s.AddVertex({1, -1, 0}, 0, 0, 0);
    s.set_patch(s.AddTriangle(b, a, c), same ? p : q);
    s.set_patch(s.AddTriangle(a, b, m), p);
    s.set_patch(s.AddTriangle(a, m, d), p);
    s.set_patch(s.AddTriangle(m, b, d), p);
    const DegenerateCounts n = TidyDegenerate(
        &s, 0.1, [](VertexId, Vec3) { return false; }, [](VertexId) {});
    EXPECT_EQ(n.flipped, same ? 1 : 0) << same;
    if (same) {  // the new triangles keep the patch
      for (TriId t = 0; t < s.triangle_capacity(); ++t) {
        if (s.triangle_alive(t)) {
          EXPECT_EQ(s.patch(t), p);
        }
      }
    }
  }
}

// The sag correction moves a vertex along its normal; where labels meet the triangles face
// every way, so the junctions stay where the simplification left them.
TEST(LabelEngine, SagCorrectionLeavesJunctionsInPlace) {
  // A ball cut in three labels: its junctions are curves.
  const int64_t n = 18;
  std::vector<uint16_t> v(static_cast<size_t>(n * n * n), 0);
  for (int64_t z = 0; z < n; ++z) {
    for (int64_t y = 0; y < n; ++y) {
      for (int64_t x = 0; x < n; ++x) {
        if (std::hypot(x - 8.5, y - 8.3, z - 8.6) > 7) continue;
        v[static_cast<size_t>((z * n + y) * n + x)] = x < 8 ? 1 : (y < 9 ? 2 : 3);
      }
    }
  }
  // Sealed, each vertex is corrected as it freezes, by the same rule.
  auto run = [&](double sag, bool seal) {
    VolumeInfo grid;
    grid.nx = grid.ny = grid.nz = n;
    grid.dtype = DType::kUInt16;
    SessionOptions o;
    o.labels.enabled = true;
    o.error = 0.5;
    o.sag_correction = sag;
    o.seal = seal;
    auto session = TandemSession::Create(grid, o);
    EXPECT_TRUE(session.ok());
    std::vector<SealedChunk> chunks;
    SealedChunk c;
    for (int64_t k = 0; k < n; ++k) {
      EXPECT_TRUE((*session)
                      ->AddSliceBytes(DType::kUInt16,
                                      reinterpret_cast<const uint8_t*>(v.data() + k * n * n))
                      .ok());
      while ((*session)->TakeSealed(&c)) chunks.push_back(std::move(c));
    }
    EXPECT_TRUE((*session)->Finish().ok());
    while ((*session)->TakeSealed(&c)) chunks.push_back(std::move(c));
    EXPECT_EQ((*session)->stats().sag_corrected > 0, sag > 0);  // it moved some vertices
    return seal ? WeldLabeledChunks(chunks) : (*session)->SnapshotLabeled();
  };
  // The positions of the vertices at a junction (in triangles of more than one patch) and
  // of their neighbours, whose sag estimate would read the junction's normal.
  auto junctions = [](const LabeledMesh& m) {
    std::vector<std::set<uint32_t>> patches(m.mesh.num_vertices());
    for (size_t t = 0; t < m.mesh.num_triangles(); ++t) {
      for (int c = 0; c < 3; ++c) patches[m.mesh.indices[3 * t + c]].insert(m.patch[t]);
    }
    std::set<std::array<double, 3>> out;
    for (size_t t = 0; t < m.mesh.num_triangles(); ++t) {
      const uint32_t* tri = m.mesh.indices.data() + 3 * t;
      if (patches[tri[0]].size() + patches[tri[1]].size() + patches[tri[2]].size() == 3) continue;
      for (int c = 0; c < 3; ++c) {
        const Vec3& p = m.mesh.positions[tri[c]];
        out.insert({p.x, p.y, p.z});
      }
    }
    return out;
  };
  for (bool seal : {false, true}) {
    SCOPED_TRACE(seal ? "sealed" : "whole");
    const auto without = junctions(run(0, seal)), with = junctions(run(0.3, seal));
    EXPECT_GE(without.size(), 10u);
    EXPECT_EQ(with, without);
  }
}

}  // namespace
}  // namespace tandem
