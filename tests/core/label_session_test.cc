// Label sessions (SessionOptions::labels): every label's surface from one sweep, on label
// volumes made here. Each label's surface (SplitByLabel) must be an oriented 2-manifold,
// closed or open only on the grid's box, with the topology of the unsimplified surface; the
// interfaces are the same triangles in both labels' surfaces; the error stays within E0.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"
#include "tandem/eval/topology.h"
#include "tandem/geometry.h"
#include "tandem/labels.h"
#include "tandem/tandem.h"
#include "testutil/triangle_key.h"

namespace tandem {
namespace {

struct Volume {
  int64_t nx, ny, nz;
  std::vector<uint16_t> v;
  Volume(int64_t x, int64_t y, int64_t z, uint16_t fill = 0)
      : nx(x), ny(y), nz(z), v(static_cast<size_t>(x * y * z), fill) {}
  uint16_t& at(int64_t x, int64_t y, int64_t z) {
    return v[static_cast<size_t>((z * ny + y) * nx + x)];
  }
  // Label l in the voxels [x0, x1) x [y0, y1) x [z0, z1).
  void Box(std::array<int64_t, 3> lo, std::array<int64_t, 3> hi, uint16_t l) {
    for (int64_t z = lo[2]; z < hi[2]; ++z) {
      for (int64_t y = lo[1]; y < hi[1]; ++y) {
        for (int64_t x = lo[0]; x < hi[0]; ++x) at(x, y, z) = l;
      }
    }
  }
};

struct Meshed {
  absl::Status status;
  LabeledMesh mesh;
  double max_error = 0;
  // Sealing: the chunks taken, those taken before Finish, their triangles, and the most
  // triangles the session held after a slice.
  int64_t chunks = 0, early_chunks = 0, early_triangles = 0, peak_held = 0;
  size_t peak_bytes = 0;  // MemoryBytes after a slice, at its most
  int parts = 0;          // the session's slabs
};

SessionOptions LabelOptionsFor(Schedule schedule, bool close = false) {
  SessionOptions o;
  o.labels.enabled = true;
  o.labels.close = close;
  o.schedule = schedule;
  o.error = 0.5;
  return o;
}

// `declare_nz` false: a stream whose depth is not known until it ends.
Meshed Mesh(const Volume& vol, const SessionOptions& options,
            std::array<double, 3> spacing = {1, 1, 1}, bool declare_nz = true) {
  Meshed r;
  VolumeInfo grid;
  grid.spacing = spacing;
  grid.nx = vol.nx;
  grid.ny = vol.ny;
  grid.nz = declare_nz ? vol.nz : 0;
  grid.dtype = DType::kUInt16;
  auto session = TandemSession::Create(grid, options);
  if (!session.ok()) {
    r.status = session.status();
    return r;
  }
  r.parts = (*session)->num_parts();
  const size_t slice = static_cast<size_t>(vol.nx * vol.ny);
  std::vector<SealedChunk> chunks;
  // Sealing: every chunk a label session hands out has a pair for each triangle, its pairs
  // listed once each, in order.
  auto take = [&] {
    SealedChunk c;
    while ((*session)->TakeSealed(&c)) {
      EXPECT_EQ(c.patch.size(), c.num_triangles());
      for (uint32_t p : c.patch) EXPECT_LT(p, c.pairs.size());
      for (size_t i = 1; i < c.pairs.size(); ++i) {
        EXPECT_LT(std::tie(c.pairs[i - 1].inside, c.pairs[i - 1].outside),
                  std::tie(c.pairs[i].inside, c.pairs[i].outside));
      }
      chunks.push_back(std::move(c));
    }
  };
  for (int64_t z = 0; z < vol.nz; ++z) {
    r.status = (*session)->AddSliceBytes(
        DType::kUInt16, reinterpret_cast<const uint8_t*>(vol.v.data() + z * slice));
    if (!r.status.ok()) return r;
    if (options.seal) take();
    r.peak_held = std::max(r.peak_held, (*session)->num_triangles());
    r.peak_bytes = std::max(r.peak_bytes, (*session)->MemoryBytes());
  }
  r.early_chunks = static_cast<int64_t>(chunks.size());
  for (const SealedChunk& c : chunks) r.early_triangles += static_cast<int64_t>(c.num_triangles());
  r.status = (*session)->Finish();
  r.max_error = (*session)->MaxShapeError();
  if (!options.seal) {
    r.mesh = (*session)->SnapshotLabeled();
    return r;
  }
  take();
  r.chunks = static_cast<int64_t>(chunks.size());
  EXPECT_EQ((*session)->SnapshotLabeled().mesh.num_triangles(), 0u);  // all sealed
  r.mesh = WeldLabeledChunks(chunks);
  return r;
}

// Whether p lies on the grid's box (spacing 1, origin 0).
bool OnBox(const Vec3& p, const Volume& vol) {
  return p.x == 0 || p.y == 0 || p.z == 0 || p.x == static_cast<double>(vol.nx - 1) ||
         p.y == static_cast<double>(vol.ny - 1) || p.z == static_cast<double>(vol.nz - 1);
}

struct LabelTopology {
  int64_t euler = 0;
  size_t components = 0, triangles = 0;
};

// Checks every label's surface of `run` and returns its topology by label: an oriented
// 2-manifold, each triangle once, boundary edges only on the grid's box (none when
// `closed`); and the interfaces: each triangle between two labels is in the first one's
// surface as it is and in the second's reversed, at the same positions.
std::map<LabelId, LabelTopology> CheckSurfaces(const Meshed& run, const Volume& vol, bool closed,
                                               LabelId background = 0) {
  std::map<LabelId, LabelTopology> out;
  const LabeledMesh& m = run.mesh;
  EXPECT_EQ(m.patch.size(), m.mesh.num_triangles());
  std::map<LabelId, std::multiset<testing::TriangleKey>> sides;
  for (const auto& [label, surface] : SplitByLabel(m, background)) {
    const eval::TopologyReport t = eval::AnalyzeTopology(surface);
    SCOPED_TRACE("label " + std::to_string(label));
    EXPECT_TRUE(t.IsManifold()) << t.nonmanifold_edges << " non-manifold edges, "
                                << t.nonmanifold_vertices << " non-manifold vertices, "
                                << t.misoriented_edges << " misoriented edges, "
                                << t.repeated_index_triangles << " repeated indices";
    if (closed) {
      EXPECT_EQ(t.boundary_edges, 0u);
    }
    // An open surface's boundary lies on the box: each boundary edge's ends.
    std::map<std::pair<uint32_t, uint32_t>, int> edges;
    for (size_t i = 0; i < surface.num_triangles(); ++i) {
      for (int c = 0; c < 3; ++c) {
        uint32_t a = surface.indices[3 * i + c], b = surface.indices[3 * i + (c + 1) % 3];
        ++edges[{std::min(a, b), std::max(a, b)}];
      }
      sides[label].insert(testing::KeyOfTriangle(surface, i, false));
    }
    for (const auto& [e, n] : edges) {
      if (n == 1) {
        EXPECT_TRUE(OnBox(surface.positions[e.first], vol) &&
                    OnBox(surface.positions[e.second], vol));
      }
    }
    out[label] = {t.euler, t.components, t.triangles};
  }
  for (size_t i = 0; i < m.mesh.num_triangles(); ++i) {
    const LabelPair& p = m.pairs[m.patch[i]];
    EXPECT_NE(p.inside, p.outside);
    EXPECT_NE(p.inside, background);  // the background is never inside
    EXPECT_EQ(sides[p.inside].count(testing::KeyOfTriangle(m.mesh, i, false)), 1u);
    if (p.outside != background) {
      EXPECT_EQ(sides[p.outside].count(testing::KeyOfTriangle(m.mesh, i, true)), 1u);
    }
  }
  return out;
}

// The volume stretched along x (each column repeated) until a session splits it into
// `parts` slabs (at least 16 cube columns each): every label keeps its topology, and the
// seams cut through the labels.
Volume Widen(const Volume& vol, int parts) {
  const int64_t f = (16 * parts + vol.nx) / vol.nx;  // nx * f >= 16 parts + 1
  Volume wide(vol.nx * f, vol.ny, vol.nz);
  for (int64_t z = 0; z < vol.nz; ++z) {
    for (int64_t y = 0; y < vol.ny; ++y) {
      for (int64_t x = 0; x < wide.nx; ++x) {
        wide.at(x, y, z) = vol.v[static_cast<size_t>((z * vol.ny + y) * vol.nx + x / f)];
      }
    }
  }
  return wide;
}

void ExpectSameTopology(const std::map<LabelId, LabelTopology>& topology,
                        const std::map<LabelId, LabelTopology>& reference) {
  EXPECT_EQ(topology.size(), reference.size());
  for (const auto& [label, ref] : reference) {
    SCOPED_TRACE("label " + std::to_string(label));
    if (!topology.count(label)) {
      ADD_FAILURE() << "no surface";
      continue;
    }
    EXPECT_EQ(topology.at(label).euler, ref.euler);
    EXPECT_EQ(topology.at(label).components, ref.components);
  }
}

// The labels' topology of the full-resolution surface and of every simplifying schedule
// agree, the simplified ones within E0 and with far fewer triangles; so do the lock-step
// schedules' and the full resolution's sealed (the chunks welded). All with base.parts slabs
// (checked); split and sealed, tandem-lag's seams settle behind the front. Returns the
// full-resolution topology.
std::map<LabelId, LabelTopology> CheckSchedulesIn(const Volume& vol, bool closed,
                                                  SessionOptions base, double reduction) {
  base.schedule = Schedule::kNone;
  const Meshed full = Mesh(vol, base);
  EXPECT_TRUE(full.status.ok()) << full.status;
  EXPECT_EQ(full.parts, base.parts);
  const auto reference = CheckSurfaces(full, vol, closed, base.labels.background);
  base.seal = true;
  const Meshed sealed_full = Mesh(vol, base);
  EXPECT_TRUE(sealed_full.status.ok()) << sealed_full.status;
  {
    SCOPED_TRACE("sealed full resolution");
    const auto topology = CheckSurfaces(sealed_full, vol, closed, base.labels.background);
    EXPECT_EQ(sealed_full.mesh.mesh.num_triangles(), full.mesh.mesh.num_triangles());
    EXPECT_EQ(topology.size(), reference.size());
    for (const auto& [label, ref] : reference) {
      EXPECT_EQ(topology.count(label) ? topology.at(label).euler : -999, ref.euler) << label;
    }
  }
  for (auto [s, seal] : {std::pair{Schedule::kClassical, false}, {Schedule::kTandem, false},
                         {Schedule::kTandemLag, false}, {Schedule::kTandem, true},
                         {Schedule::kTandemLag, true}}) {
    SCOPED_TRACE(std::string(ScheduleName(s)) + (seal ? " sealed" : ""));
    base.schedule = s;
    base.seal = seal;
    SessionOptions o = base;
    if (seal && s == Schedule::kTandemLag) o.seam_settle_slices = 4;
    const Meshed run = Mesh(vol, o);
    EXPECT_TRUE(run.status.ok()) << run.status;
    EXPECT_EQ(run.parts, base.parts);
    ExpectSameTopology(CheckSurfaces(run, vol, closed, base.labels.background), reference);
    EXPECT_LE(run.max_error, base.error * (1 + 1e-9));
    size_t degenerate = 0;  // zero-area triangles (tidied at the end)
    const IndexedMesh& mesh = run.mesh.mesh;
    for (size_t t = 0; t < mesh.num_triangles(); ++t) {
      degenerate += IsDegenerateTriangle(mesh.positions[mesh.indices[3 * t]],
                                         mesh.positions[mesh.indices[3 * t + 1]],
                                         mesh.positions[mesh.indices[3 * t + 2]]);
    }
    EXPECT_EQ(degenerate, 0u);
    EXPECT_LT(static_cast<double>(run.mesh.mesh.num_triangles()),
              reduction * static_cast<double>(full.mesh.mesh.num_triangles()));
  }
  return reference;
}

// CheckSchedulesIn with one slab; then on the volume widened for 2 and 3 slabs, with those
// (every label's topology as one slab's full resolution of the widened volume). Returns the
// one slab's full-resolution topology of `vol`.
std::map<LabelId, LabelTopology> CheckSchedules(const Volume& vol, bool closed, SessionOptions base,
                                                double reduction = 0.5) {
  base.parts = 1;
  const auto reference = CheckSchedulesIn(vol, closed, base, reduction);
  for (int parts : {2, 3}) {
    SCOPED_TRACE(std::to_string(parts) + " parts");
    const Volume wide = Widen(vol, parts);
    base.parts = 1;
    base.schedule = Schedule::kNone;
    const Meshed one = Mesh(wide, base);
    EXPECT_TRUE(one.status.ok()) << one.status;
    const auto wide_reference = CheckSurfaces(one, wide, closed, base.labels.background);
    EXPECT_EQ(wide_reference.size(), reference.size());
    base.parts = parts;
    ExpectSameTopology(CheckSchedulesIn(wide, closed, base, reduction), wide_reference);
  }
  return reference;
}

TEST(LabelSession, TwoTouchingBoxesAreTwoClosedSpheresSharingTheirInterface) {
  Volume vol(20, 20, 20);
  vol.Box({4, 4, 4}, {10, 16, 16}, 1);
  vol.Box({10, 4, 4}, {16, 16, 16}, 2);
  const auto topology = CheckSchedules(vol, /*closed=*/true, LabelOptionsFor(Schedule::kNone));
  ASSERT_EQ(topology.size(), 2u);
  for (const auto& [label, t] : topology) {
    EXPECT_EQ(t.euler, 2) << label;
    EXPECT_EQ(t.components, 1u) << label;
  }
  // The full-resolution complex has an edge in 3 triangles where 1, 2 and the background
  // meet; the interface between the boxes is one patch of the pair (1, 2).
  const Meshed full = Mesh(vol, LabelOptionsFor(Schedule::kNone));
  EXPECT_FALSE(eval::AnalyzeTopology(full.mesh.mesh).IsManifold());
  EXPECT_NE(std::find(full.mesh.pairs.begin(), full.mesh.pairs.end(), LabelPair{1, 2}),
            full.mesh.pairs.end());
}

TEST(LabelSession, NestedSpheresKeepTheirShells) {
  Volume vol(26, 26, 26);
  for (int64_t z = 0; z < 26; ++z) {
    for (int64_t y = 0; y < 26; ++y) {
      for (int64_t x = 0; x < 26; ++x) {
        const double r = std::hypot(x - 12.5, y - 12.5, z - 12.5);
        vol.at(x, y, z) = r < 4 ? 3 : r < 7.5 ? 2 : r < 11 ? 1 : 0;
      }
    }
  }
  const auto topology = CheckSchedules(vol, true, LabelOptionsFor(Schedule::kNone));
  ASSERT_EQ(topology.size(), 3u);
  EXPECT_EQ(topology.at(3).euler, 2);  // a ball
  EXPECT_EQ(topology.at(3).components, 1u);
  for (LabelId shell : {1, 2}) {  // two spheres each
    EXPECT_EQ(topology.at(shell).euler, 4) << shell;
    EXPECT_EQ(topology.at(shell).components, 2u) << shell;
  }
}

// About 30 cells of a Voronoi diagram with random 16-bit ids, inside a ball (open: also
// filling the whole box).
Volume Voronoi(bool ball, uint32_t seed) {
  Volume vol(30, 28, 26);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> pos(0, 1);
  std::uniform_int_distribution<int> id(1, 65535);
  std::vector<std::array<double, 3>> seeds;
  std::vector<uint16_t> ids;
  std::set<uint16_t> used;
  while (seeds.size() < 30) {
    const auto l = static_cast<uint16_t>(id(rng));
    if (!used.insert(l).second) continue;
    seeds.push_back({pos(rng) * 30, pos(rng) * 28, pos(rng) * 26});
    ids.push_back(l);
  }
  for (int64_t z = 0; z < vol.nz; ++z) {
    for (int64_t y = 0; y < vol.ny; ++y) {
      for (int64_t x = 0; x < vol.nx; ++x) {
        if (ball && std::hypot(x - 14.5, y - 13.5, z - 12.5) > 11.5) continue;
        size_t best = 0;
        double d = 1e30;
        for (size_t s = 0; s < seeds.size(); ++s) {
          const double e = std::hypot(x - seeds[s][0], y - seeds[s][1], z - seeds[s][2]);
          if (e < d) {
            d = e;
            best = s;
          }
        }
        vol.at(x, y, z) = ids[best];
      }
    }
  }
  return vol;
}

// Voronoi cells of an EM-like stack, `depth` slices: 24 cells every 16 slices, each with ids
// of its own (1 + 32 p + i for the i-th seed of period p), so that the labels go on with the
// depth as a deep segmentation's do.
Volume DeepVoronoi(int64_t depth) {
  constexpr int64_t kPeriod = 16, kCells = 24;
  Volume vol(36, 32, depth);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> pos(0, 1);
  const int64_t periods = (depth + kPeriod - 1) / kPeriod + 1;
  std::vector<std::array<double, 3>> seeds;
  for (int64_t p = 0; p < periods; ++p) {
    for (int64_t i = 0; i < kCells; ++i) {
      seeds.push_back({pos(rng) * 36, pos(rng) * 32, static_cast<double>(p * kPeriod) +
                                                         pos(rng) * kPeriod});
    }
  }
  for (int64_t z = 0; z < vol.nz; ++z) {
    const int64_t p0 = std::max<int64_t>(0, z / kPeriod - 1);
    const int64_t p1 = std::min<int64_t>(periods - 1, z / kPeriod + 1);
    for (int64_t y = 0; y < vol.ny; ++y) {
      for (int64_t x = 0; x < vol.nx; ++x) {
        double d = 1e30;
        int64_t best = 0;
        for (int64_t s = p0 * kCells; s < (p1 + 1) * kCells; ++s) {
          const double e = std::hypot(x - seeds[s][0], y - seeds[s][1], z - seeds[s][2]);
          if (e < d) {
            d = e;
            best = s;
          }
        }
        vol.at(x, y, z) = static_cast<uint16_t>(1 + (best / kCells) * 32 + best % kCells);
      }
    }
  }
  return vol;
}

// Sealed, a label session holds the front, not the mesh: from a stack eight times deeper
// (eight times the labels and triangles), the most triangles it holds after a slice and its
// peak memory (the store's label pairs included) stay within 1.2x; unsealed, they grow with
// the depth. The welded chunks keep every label's topology.
TEST(LabelSession, SealedMemoryIsFlatInDepth) {
  constexpr int64_t kDepth = 64;
  int64_t held[2] = {0, 0}, triangles[2] = {0, 0}, unsealed_held[2] = {0, 0};
  size_t bytes[2] = {0, 0};
  for (int deep = 0; deep < 2; ++deep) {
    const Volume vol = DeepVoronoi(deep ? 8 * kDepth : kDepth);
    SessionOptions o = LabelOptionsFor(Schedule::kTandemLag);
    o.seal = true;
    const Meshed run = Mesh(vol, o);
    ASSERT_TRUE(run.status.ok()) << run.status;
    held[deep] = run.peak_held;
    bytes[deep] = run.peak_bytes;
    triangles[deep] = static_cast<int64_t>(run.mesh.mesh.num_triangles());
    EXPECT_GT(2 * run.early_triangles, triangles[deep]);  // most sealed before Finish
    EXPECT_LE(run.max_error, o.error * (1 + 1e-9));
    if (!deep) {
      o.seal = false;
      const Meshed whole = Mesh(vol, o);
      o.schedule = Schedule::kNone;
      const auto reference = CheckSurfaces(Mesh(vol, o), vol, false);
      const auto topology = CheckSurfaces(run, vol, false);
      ASSERT_EQ(topology.size(), reference.size());
      for (const auto& [label, ref] : reference) {
        EXPECT_EQ(topology.at(label).euler, ref.euler) << label;
        EXPECT_EQ(topology.at(label).components, ref.components) << label;
      }
      unsealed_held[0] = whole.peak_held;
    } else {
      o.seal = false;
      unsealed_held[1] = Mesh(vol, o).peak_held;
    }
  }
  EXPECT_GT(triangles[1], 6 * triangles[0]);
  EXPECT_LE(held[1], held[0] * 6 / 5) << held[0] << " triangles held at " << kDepth
                                      << " slices, " << held[1] << " at " << 8 * kDepth;
  EXPECT_LE(bytes[1], bytes[0] * 6 / 5) << bytes[0] << " bytes at " << kDepth << " slices, "
                                        << bytes[1] << " at " << 8 * kDepth;
  EXPECT_GT(unsealed_held[1], 4 * unsealed_held[0]);
}

// Split in two, sealed, the seams settle behind the front (seam_settle_slices), so what the
// session holds stays within 1.25x from a stack eight times deeper too, and every label keeps
// its topology across the settled seams.
TEST(LabelSession, SplitSealedMemoryIsFlatInDepth) {
  constexpr int64_t kDepth = 64;
  int64_t held[2] = {0, 0};
  size_t bytes[2] = {0, 0};
  for (int deep = 0; deep < 2; ++deep) {
    const Volume vol = DeepVoronoi(deep ? 8 * kDepth : kDepth);
    SessionOptions o = LabelOptionsFor(Schedule::kTandemLag);
    o.seal = true;
    o.parts = 2;
    o.seam_settle_slices = 32;
    const Meshed run = Mesh(vol, o);
    ASSERT_TRUE(run.status.ok()) << run.status;
    EXPECT_EQ(run.parts, 2);
    held[deep] = run.peak_held;
    bytes[deep] = run.peak_bytes;
    EXPECT_GT(2 * run.early_triangles, static_cast<int64_t>(run.mesh.mesh.num_triangles()));
    EXPECT_LE(run.max_error, o.error * (1 + 1e-9));
    if (!deep) {
      o.seal = false;
      o.parts = 1;
      o.schedule = Schedule::kNone;
      ExpectSameTopology(CheckSurfaces(run, vol, false), CheckSurfaces(Mesh(vol, o), vol, false));
    }
  }
  EXPECT_LE(held[1], held[0] * 5 / 4) << held[0] << " triangles held at " << kDepth << " slices, "
                                      << held[1] << " at " << 8 * kDepth;
  EXPECT_LE(bytes[1], bytes[0] * 5 / 4)
      << bytes[0] << " bytes at " << kDepth << " slices, " << bytes[1] << " at " << 8 * kDepth;
}

// At full resolution a split changes nothing: after every slice and at the end, the parts'
// welded SnapshotLabeled holds one part's triangles (at the same positions, each once) with
// the same label pair each, open or closed at the box.
TEST(LabelSession, SplitFullResolutionIsOnePartsComplexAfterEverySlice) {
  const Volume vol = Widen(Voronoi(false, 11), 3);
  // The triangles as keys with their pairs, sorted.
  auto keyed = [](const LabeledMesh& m) {
    std::vector<std::pair<testing::TriangleKey, std::pair<LabelId, LabelId>>> out;
    EXPECT_EQ(m.patch.size(), m.mesh.num_triangles());
    for (size_t t = 0; t < m.mesh.num_triangles(); ++t) {
      const LabelPair& p = m.pairs[m.patch[t]];
      out.push_back({testing::KeyOfTriangle(m.mesh, t, false), {p.inside, p.outside}});
    }
    std::sort(out.begin(), out.end());
    return out;
  };
  for (bool close : {false, true}) {
    SCOPED_TRACE(close ? "closed" : "open");
    VolumeInfo grid;
    grid.nx = vol.nx;
    grid.ny = vol.ny;
    grid.nz = vol.nz;
    grid.dtype = DType::kUInt16;
    std::unique_ptr<TandemSession> sessions[2];
    for (int split = 0; split < 2; ++split) {
      SessionOptions o = LabelOptionsFor(Schedule::kNone, close);
      o.parts = split ? 3 : 1;
      auto s = TandemSession::Create(grid, o);
      ASSERT_TRUE(s.ok()) << s.status();
      EXPECT_EQ((*s)->num_parts(), o.parts);
      sessions[split] = *std::move(s);
    }
    const size_t slice = static_cast<size_t>(vol.nx * vol.ny);
    for (int64_t z = 0; z < vol.nz; ++z) {
      for (auto& s : sessions) {
        ASSERT_TRUE(s->AddSliceBytes(DType::kUInt16,
                                     reinterpret_cast<const uint8_t*>(vol.v.data() + z * slice))
                        .ok());
      }
      const LabeledMesh one = sessions[0]->SnapshotLabeled(),
                        split = sessions[1]->SnapshotLabeled();
      EXPECT_EQ(split.mesh.num_vertices(), one.mesh.num_vertices()) << "slice " << z;
      EXPECT_TRUE(keyed(split) == keyed(one)) << "slice " << z;
    }
    for (auto& s : sessions) ASSERT_TRUE(s->Finish().ok());
    const LabeledMesh one = sessions[0]->SnapshotLabeled(), split = sessions[1]->SnapshotLabeled();
    EXPECT_GT(one.mesh.num_triangles(), 0u);
    EXPECT_EQ(split.mesh.num_vertices(), one.mesh.num_vertices());
    EXPECT_TRUE(keyed(split) == keyed(one));
  }
}

TEST(LabelSession, VoronoiCellsInABallAreClosedManifolds) {
  const auto topology = CheckSchedules(Voronoi(true, 7), true, LabelOptionsFor(Schedule::kNone));
  EXPECT_GE(topology.size(), 20u);
}

TEST(LabelSession, VoronoiCellsFillingTheBoxAreOpenThereOrClosed) {
  const Volume vol = Voronoi(false, 11);
  const auto open = CheckSchedules(vol, false, LabelOptionsFor(Schedule::kNone));
  EXPECT_GE(open.size(), 25u);
  const auto closed = CheckSchedules(vol, true, LabelOptionsFor(Schedule::kNone, true));
  EXPECT_EQ(closed.size(), open.size());
  for (const auto& [label, t] : closed) EXPECT_EQ(t.euler, 2 * static_cast<int64_t>(t.components));
}

TEST(LabelSession, IsotropyATargetCountAndAnisotropicVoxelsKeepEachLabel) {
  const Volume ball = Voronoi(true, 5);
  for (int parts : {1, 2}) {  // two: the ball widened
    SCOPED_TRACE(std::to_string(parts) + " parts");
    const Volume vol = parts == 1 ? ball : Widen(ball, parts);
    SessionOptions o = LabelOptionsFor(Schedule::kNone);
    o.parts = 1;
    const auto reference = CheckSurfaces(Mesh(vol, o), vol, true);
    o.parts = parts;
    o.schedule = Schedule::kTandemLag;
    o.alpha = 0.5;
    const Meshed isotropic = Mesh(vol, o);
    ASSERT_TRUE(isotropic.status.ok()) << isotropic.status;
    EXPECT_EQ(isotropic.parts, parts);
    ExpectSameTopology(CheckSurfaces(isotropic, vol, true), reference);
    EXPECT_LE(isotropic.max_error, o.error * (1 + 1e-9));
    o.alpha = 0;
    o.target_triangles = 700;
    const Meshed target = Mesh(vol, o);
    ASSERT_TRUE(target.status.ok()) << target.status;
    ExpectSameTopology(CheckSurfaces(target, vol, true), reference);
    EXPECT_LE(target.mesh.mesh.num_triangles(), 770u);
    o.target_triangles = 0;
    o.error = 1.2;  // voxels 1 x 1 x 3: E0 in physical units
    const Meshed thick = Mesh(vol, o, {1, 1, 3});
    ASSERT_TRUE(thick.status.ok()) << thick.status;
    ExpectSameTopology(CheckSurfaces(thick, vol, true), reference);
    EXPECT_LE(thick.max_error, o.error * (1 + 1e-9));
  }
}

TEST(LabelSession, OneVoxelLabelIsAClosedSphere) {
  Volume vol(12, 12, 12);
  vol.Box({2, 2, 2}, {10, 10, 10}, 1);
  vol.at(5, 5, 5) = 9;    // inside label 1
  vol.at(0, 11, 11) = 4;  // alone, in a corner of the box (closed with close)
  const auto topology = CheckSchedules(vol, true, LabelOptionsFor(Schedule::kNone, true));
  for (LabelId l : {4, 9}) {
    EXPECT_EQ(topology.at(l).euler, 2) << l;
    EXPECT_EQ(topology.at(l).components, 1u) << l;
  }
  EXPECT_EQ(topology.at(1).euler, 4);  // a box with a one-voxel cavity
}

TEST(LabelSession, LabelsMeetingAtAnEdgeOrACornerStayManifold) {
  Volume edge(16, 16, 16);
  edge.Box({3, 3, 3}, {8, 8, 13}, 1);
  edge.Box({8, 8, 3}, {13, 13, 13}, 2);
  const auto e = CheckSchedules(edge, true, LabelOptionsFor(Schedule::kNone));
  Volume corner(16, 16, 16);
  corner.Box({3, 3, 3}, {8, 8, 8}, 1);
  corner.Box({8, 8, 8}, {13, 13, 13}, 2);
  corner.Box({9, 2, 2}, {12, 5, 5}, 4);  // label 4 touching itself at a corner only
  corner.Box({12, 5, 5}, {15, 8, 8}, 4);
  const auto c = CheckSchedules(corner, true, LabelOptionsFor(Schedule::kNone));
  EXPECT_EQ(e.at(1).components, 1u);
  EXPECT_EQ(e.at(2).components, 1u);
  EXPECT_EQ(e.at(1).euler, 2);
  EXPECT_EQ(c.at(1).euler, 2);
  EXPECT_EQ(c.at(2).euler, 2);
  EXPECT_EQ(c.at(4).euler, 2 * static_cast<int64_t>(c.at(4).components));
}

TEST(LabelSession, LabelsTouchingTheBoxAreOpenThereUnlessClosed) {
  Volume vol(14, 12, 10);
  vol.Box({0, 0, 0}, {6, 12, 10}, 1);  // a whole side of the box
  vol.Box({6, 3, 0}, {10, 9, 5}, 2);   // the bottom face
  const auto open = CheckSchedules(vol, false, LabelOptionsFor(Schedule::kNone));
  EXPECT_EQ(open.at(2).components, 1u);
  const auto closed = CheckSchedules(vol, true, LabelOptionsFor(Schedule::kNone, true));
  EXPECT_EQ(closed.at(1).euler, 2);
  EXPECT_EQ(closed.at(2).euler, 2);
  // Open, the surfaces end on the box: a disk each (one boundary loop, χ = 1).
  EXPECT_EQ(open.at(2).euler, 1);
  // A stream of unknown depth finds the top of the box when it ends: the same meshes, in one
  // part or two (the volume widened).
  const Volume wide = Widen(vol, 2);
  for (bool close : {false, true}) {
    for (int parts : {1, 2}) {
      SessionOptions o = LabelOptionsFor(Schedule::kTandemLag, close);
      o.parts = parts;
      const Volume& v = parts == 1 ? vol : wide;
      const Meshed known = Mesh(v, o), streamed = Mesh(v, o, {1, 1, 1}, false);
      ASSERT_TRUE(streamed.status.ok()) << streamed.status;
      EXPECT_EQ(streamed.parts, parts);
      EXPECT_EQ(streamed.mesh.mesh.indices, known.mesh.mesh.indices) << close;
      EXPECT_EQ(streamed.mesh.patch, known.mesh.patch) << close;
    }
  }
}

TEST(LabelSession, OneLabelEverywhereIsNoSurfaceOrTheClosedBox) {
  const Volume vol(9, 8, 7, 3);
  const Meshed open = Mesh(vol, LabelOptionsFor(Schedule::kTandemLag));
  ASSERT_TRUE(open.status.ok()) << open.status;
  EXPECT_EQ(open.mesh.mesh.num_triangles(), 0u);
  const auto closed = CheckSchedules(vol, true, LabelOptionsFor(Schedule::kNone, true));
  ASSERT_EQ(closed.size(), 1u);
  EXPECT_EQ(closed.at(3).euler, 2);
  EXPECT_EQ(closed.at(3).components, 1u);
}

TEST(LabelSession, OnlyAndBackgroundChooseTheLabels) {
  Volume vol(16, 16, 16, 7);  // 7 is the background here
  vol.Box({3, 3, 3}, {8, 12, 12}, 1);
  vol.Box({8, 3, 3}, {13, 12, 12}, 2);
  vol.Box({5, 5, 5}, {7, 7, 7}, 0);  // 0 is a label like any other
  SessionOptions o = LabelOptionsFor(Schedule::kNone);
  o.labels.background = 7;
  const auto all = CheckSchedules(vol, true, o);
  EXPECT_EQ(all.size(), 3u);
  EXPECT_TRUE(all.count(0));
  o.labels.only = {2};
  const auto two = CheckSchedules(vol, true, o);
  ASSERT_EQ(two.size(), 1u);
  EXPECT_EQ(two.at(2).euler, 2);
  // Only label 2's surface: every triangle separates 2 from the background.
  o.schedule = Schedule::kTandemLag;
  const Meshed run = Mesh(vol, o);
  ASSERT_TRUE(run.status.ok()) << run.status;
  for (uint32_t p : run.mesh.patch) EXPECT_EQ(run.mesh.pairs[p], (LabelPair{2, 7}));
}

TEST(LabelSession, OptionsAreValidated) {
  SessionOptions o = LabelOptionsFor(Schedule::kTandemLag);
  o.labels.only = {3, 2};
  EXPECT_NE(o.Validate().message().find("labels.only"), std::string::npos);
  o.labels.only = {2, 2};
  EXPECT_FALSE(o.Validate().ok());
  o.labels.only = {0, 2};
  EXPECT_NE(o.Validate().message().find("labels.background"), std::string::npos);
  o.labels.only = {2};
  EXPECT_TRUE(o.Validate().ok());
  o.seal = true;  // sealed chunks carry their triangles' pairs
  EXPECT_TRUE(o.Validate().ok());
  o.seal = false;
  o.parts = 2;
  EXPECT_TRUE(o.Validate().ok());
  o.parts = 0;  // automatic: as an iso-surface's, 4 parts on a grid 256 wide or more
  VolumeInfo grid;
  grid.nx = 300;
  grid.ny = 4;
  grid.nz = 2;
  grid.dtype = DType::kFloat32;
  const absl::Status floats = TandemSession::Create(grid, o).status();
  EXPECT_NE(floats.message().find("float32"), std::string::npos) << floats;
  grid.dtype = DType::kUInt16;
  auto session = TandemSession::Create(grid, o);
  ASSERT_TRUE(session.ok()) << session.status();
  EXPECT_EQ((*session)->num_parts(), 4);
  // The label planes are counted before the first slice: two padded planes of 64-bit labels
  // (the parts' together at least the grid's).
  EXPECT_GE((*session)->MemoryBytes(), 2u * 302 * 6 * sizeof(LabelId));
}

TEST(LabelSession, FloatAndNegativeValuesAreRefused) {
  VolumeInfo grid;
  grid.nx = 4;
  grid.ny = 4;
  grid.nz = 3;
  grid.dtype = DType::kInt16;
  auto session = TandemSession::Create(grid, LabelOptionsFor(Schedule::kTandemLag));
  ASSERT_TRUE(session.ok());
  std::vector<float> f(16, 1.0f);
  const absl::Status st = (*session)->AddSlice(f.data());
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(st.message().find("float32"), std::string::npos) << st;
  std::vector<int16_t> s(16, 1);
  s[6] = -3;
  const absl::Status neg =
      (*session)->AddSliceBytes(DType::kInt16, reinterpret_cast<const uint8_t*>(s.data()));
  EXPECT_NE(neg.message().find("voxel (2, 1, 0)"), std::string::npos) << neg;
  EXPECT_NE(neg.message().find("-3"), std::string::npos) << neg;
  s[6] = 1;  // the session goes on
  for (int z = 0; z < 3; ++z) {
    ASSERT_TRUE(
        (*session)->AddSliceBytes(DType::kInt16, reinterpret_cast<const uint8_t*>(s.data())).ok());
  }
  EXPECT_TRUE((*session)->Finish().ok());
}

// Split, a slice is refused before any part moves: a negative label in either part's columns
// names its voxel in the whole grid, and the session goes on to the mesh of a session that
// never saw it, queued or stepped in turn.
TEST(LabelSession, ASplitSessionRefusesANegativeLabelBeforeAnyPartMoves) {
  VolumeInfo grid;
  grid.nx = 40;
  grid.ny = 5;
  grid.nz = 4;
  grid.dtype = DType::kInt16;
  std::vector<int16_t> good(static_cast<size_t>(grid.nx * grid.ny));
  for (size_t i = 0; i < good.size(); ++i) good[i] = static_cast<int16_t>(1 + (i % 40) / 7 % 3);
  auto bytes = [](const std::vector<int16_t>& v) {
    return reinterpret_cast<const uint8_t*>(v.data());
  };
  for (bool pipeline : {true, false}) {
    SCOPED_TRACE(pipeline ? "queued" : "stepped");
    SessionOptions o = LabelOptionsFor(Schedule::kTandemLag);
    o.parts = 2;
    o.pipeline = pipeline;
    auto clean = TandemSession::Create(grid, o);
    auto session = TandemSession::Create(grid, o);
    ASSERT_TRUE(clean.ok() && session.ok());
    EXPECT_EQ((*session)->num_parts(), 2);
    for (int64_t z = 0; z < grid.nz; ++z) {
      for (int64_t x : {5, 30}) {  // in the first part's columns, then the second's
        std::vector<int16_t> bad = good;
        bad[static_cast<size_t>(2 * grid.nx + x)] = -3;
        const absl::Status st = (*session)->AddSliceBytes(DType::kInt16, bytes(bad));
        EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument);
        EXPECT_NE(st.message().find(absl::StrCat("voxel (", x, ", 2, ", z, ")")), std::string::npos)
            << st;
      }
      ASSERT_TRUE((*session)->AddSliceBytes(DType::kInt16, bytes(good)).ok());
      ASSERT_TRUE((*clean)->AddSliceBytes(DType::kInt16, bytes(good)).ok());
    }
    ASSERT_TRUE((*session)->Finish().ok());
    ASSERT_TRUE((*clean)->Finish().ok());
    const LabeledMesh a = (*session)->SnapshotLabeled(), b = (*clean)->SnapshotLabeled();
    EXPECT_GT(a.mesh.num_triangles(), 0u);
    EXPECT_EQ(a.mesh.indices, b.mesh.indices);
    EXPECT_EQ(a.patch, b.patch);
  }
}

TEST(LabelSession, SplitByLabelOrientsEachSurfaceOutward) {
  LabeledMesh m;
  m.mesh.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  m.mesh.indices = {0, 1, 2, 0, 1, 3};
  m.pairs = {{5, 0}, {5, 8}};
  m.patch = {0, 1};
  const auto split = SplitByLabel(m, 0);
  ASSERT_EQ(split.size(), 2u);
  EXPECT_EQ(split[0].first, 5u);
  EXPECT_EQ(split[0].second.num_triangles(), 2u);
  EXPECT_EQ(split[1].first, 8u);
  ASSERT_EQ(split[1].second.num_triangles(), 1u);
  const IndexedMesh& s8 = split[1].second;  // reversed: 0 3 1
  EXPECT_EQ(s8.positions[s8.indices[1]].z, 1.0);
  EXPECT_EQ(s8.positions[s8.indices[2]].x, 1.0);
  // An iso-surface session has no labeled mesh.
  VolumeInfo grid;
  grid.nx = grid.ny = grid.nz = 4;
  SessionOptions iso;
  iso.schedule = Schedule::kNone;
  auto session = TandemSession::Create(grid, iso);
  ASSERT_TRUE(session.ok());
  EXPECT_TRUE((*session)->SnapshotLabeled().patch.empty());
}

}  // namespace
}  // namespace tandem
