#include "label_extractor.h"

#include <algorithm>
#include <cassert>
#include <cstring>
#include <type_traits>
#include <utility>

#include "absl/strings/str_cat.h"
#include "layer_extractor.h"

namespace tandem {
namespace {

// Twelfths of a voxel: every edge midpoint (halves), face centroid (thirds) and tetrahedron
// centroid (quarters) of the subdivision is a whole number of them.
constexpr int64_t kUnit = 12;

// The 6 tetrahedra of a cube (corner c at (c & 1, c >> 1 & 1, c >> 2 & 1)): the paths from
// corner 0 to corner 7 along the axes in each order.
constexpr auto kTets = [] {
  std::array<std::array<int, 4>, 6> tets{};
  const int order[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  for (int t = 0; t < 6; ++t) {
    const int a = 1 << order[t][0], b = a | (1 << order[t][1]);
    tets[t] = {0, a, b, 7};
  }
  return tets;
}();

using Point = std::array<int64_t, 3>;

Point Corner(int c) { return {kUnit * (c & 1), kUnit * ((c >> 1) & 1), kUnit * ((c >> 2) & 1)}; }
Point Mid(int u, int w) {
  const Point a = Corner(u), b = Corner(w);
  return {(a[0] + b[0]) / 2, (a[1] + b[1]) / 2, (a[2] + b[2]) / 2};
}
Point Centroid(std::initializer_list<int> corners) {
  Point s{0, 0, 0};
  for (int c : corners) {
    const Point p = Corner(c);
    for (int k = 0; k < 3; ++k) s[k] += p[k];
  }
  const auto n = static_cast<int64_t>(corners.size());
  return {s[0] / n, s[1] / n, s[2] / n};
}

}  // namespace

namespace {
template <typename T>
bool LabelOf(const uint8_t* bytes, size_t i, LabelId* out, int64_t* refused) {
  T v;
  std::memcpy(&v, bytes + i * sizeof(v), sizeof(v));
  *out = static_cast<LabelId>(v);
  if constexpr (std::is_signed_v<T>) {
    *refused = static_cast<int64_t>(v);
    return v >= 0;
  }
  return true;
}
}  // namespace

bool LabelOfVoxel(DType dtype, const uint8_t* bytes, size_t i, LabelId* out, int64_t* refused) {
  switch (dtype) {
    case DType::kUInt8: return LabelOf<uint8_t>(bytes, i, out, refused);
    case DType::kInt8: return LabelOf<int8_t>(bytes, i, out, refused);
    case DType::kUInt16: return LabelOf<uint16_t>(bytes, i, out, refused);
    case DType::kInt16: return LabelOf<int16_t>(bytes, i, out, refused);
    case DType::kUInt32: return LabelOf<uint32_t>(bytes, i, out, refused);
    case DType::kInt32: return LabelOf<int32_t>(bytes, i, out, refused);
    case DType::kUInt64: return LabelOf<uint64_t>(bytes, i, out, refused);
    case DType::kInt64: return LabelOf<int64_t>(bytes, i, out, refused);
    case DType::kFloat32: break;
  }
  return false;
}

namespace {
absl::Status NoLabelError(int64_t i, int64_t j, int64_t k, int64_t v) {
  return absl::InvalidArgumentError(absl::StrCat("voxel (", i, ", ", j, ", ", k,
                                                 ") of the label volume is ", v,
                                                 ": labels must be whole numbers >= 0"));
}
}  // namespace

absl::Status CheckLabelSlice(SliceValues slice, int64_t nx, int64_t ny, int64_t stride, int64_t k) {
  const DType t = slice.dtype;
  if (t != DType::kInt8 && t != DType::kInt16 && t != DType::kInt32 && t != DType::kInt64) {
    return absl::OkStatus();  // every unsigned value is a label (float32: refused before)
  }
  for (int64_t j = 0; j < ny; ++j) {
    for (int64_t i = 0; i < nx; ++i) {
      LabelId l = 0;
      int64_t v = 0;
      if (!LabelOfVoxel(t, slice.bytes, static_cast<size_t>(j * stride + i), &l, &v)) {
        return NoLabelError(i, j, k, v);
      }
    }
  }
  return absl::OkStatus();
}

LabelLayers::LabelLayers(const ExtractorConfig& config)
    : nx_(config.nx),
      ny_(config.ny),
      nz_(config.nz),
      x_offset_(config.x_offset),
      row_stride_(config.row_stride > 0 ? config.row_stride : config.nx),
      seam_faces_(config.seam_faces),
      labels_(config.labels) {}

LabelId LabelLayers::Filter(LabelId l) const {
  const auto& only = labels_.only;
  if (only.empty() || std::binary_search(only.begin(), only.end(), l)) return l;
  return labels_.background;
}

void LabelLayers::ReadSlice(SliceValues slice, std::vector<LabelId>* plane, int64_t k,
                            absl::Status* status) const {
  // A slice is mostly runs of one label: the last value's filtered label is kept.
  LabelId last_raw = 0, last = Filter(0);
  for (int64_t j = 0; j < ny_; ++j) {
    for (int64_t i = 0; i < nx_; ++i) {
      LabelId raw = 0;
      int64_t v = 0;
      if (!LabelOfVoxel(slice.dtype, slice.bytes, static_cast<size_t>(j * row_stride_ + i), &raw,
                        &v)) {
        *status = NoLabelError(i + x_offset_, j, k, v);
        return;
      }
      if (raw != last_raw) {
        last_raw = raw;
        last = Filter(raw);
      }
      (*plane)[Index(i, j)] = last;
    }
  }
}

absl::Status LabelLayers::Compute(SliceValues slice, LayerExtractor* ex) {
  const int64_t k = ex->slices_done_;
  if (slice.dtype == DType::kFloat32) {
    return absl::InvalidArgumentError(
        absl::StrCat("slice ", k,
                     " has float32 values, which are not labels: a label volume needs integer "
                     "voxels (uint8, uint16, int16, ...)"));
  }
  if (top_.empty()) {  // on the first slice, as the iso-surface's planes
    const size_t n = static_cast<size_t>((nx_ + 2) * (ny_ + 2));
    bottom_.assign(n, labels_.background);
    top_.assign(n, labels_.background);
  }
  absl::Status status;
  ReadSlice(slice, &bottom_, k, &status);  // slice k-2's plane, no longer needed
  if (!status.ok()) return status;
  std::swap(bottom_, top_);
  if (k == 0) std::fill(bottom_.begin(), bottom_.end(), labels_.background);
  ex->staged_ = true;
  ex->staged_layer_ = static_cast<int32_t>(k);
  ex->check_at_ = LayerExtractor::kCheckEvery;
  ex->top_plane_vertices_.clear();
  ++ex->slices_done_;
  std::swap(plane_bottom_, plane_top_);
  plane_top_.clear();
  inside_.clear();
  if (k == 0 && !labels_.close) return absl::OkStatus();  // no layer below slice 0
  EmitLayer(k - 1, ex);
  return absl::OkStatus();
}

bool LabelLayers::ComputeClosing(LayerExtractor* ex) {
  if (!labels_.close || closed_ || ex->slices_done_ == 0 || ex->staged_) return false;
  closed_ = true;
  std::swap(bottom_, top_);
  std::fill(top_.begin(), top_.end(), labels_.background);
  ex->staged_ = true;
  ex->staged_layer_ = static_cast<int32_t>(ex->slices_done_);
  ex->check_at_ = LayerExtractor::kCheckEvery;
  ex->top_plane_vertices_.clear();
  std::swap(plane_bottom_, plane_top_);
  plane_top_.clear();
  inside_.clear();
  EmitLayer(ex->slices_done_ - 1, ex);
  return true;
}

void LabelLayers::EmitLayer(int64_t zb, LayerExtractor* ex) {
  // Open, the cubes of the grid; closed, those of the grid padded with background. A part's
  // seam is no side of the box: the padding beyond it is its neighbour's columns.
  const int64_t lo = labels_.close ? -1 : 0;
  const int64_t lo_x = (seam_faces_ & kBoxXMin) ? 0 : lo;
  const int64_t hi_x = labels_.close && !(seam_faces_ & kBoxXMax) ? nx_ - 1 : nx_ - 2;
  const int64_t hi_y = labels_.close ? ny_ - 1 : ny_ - 2;
  const size_t dx = 1, dy = static_cast<size_t>(nx_ + 2);
  for (int64_t j = lo; j <= hi_y; ++j) {
    for (int64_t i = lo_x; i <= hi_x; ++i) {
      const size_t at = Index(i, j);
      const LabelId l[8] = {bottom_[at], bottom_[at + dx], bottom_[at + dy], bottom_[at + dx + dy],
                            top_[at],    top_[at + dx],    top_[at + dy],    top_[at + dx + dy]};
      bool uniform = true;
      for (int c = 1; c < 8; ++c) uniform &= l[c] == l[0];
      if (uniform) continue;
      EmitCube(i, j, zb, l, ex);
    }
    ex->Checkpoint(DType::kUInt16, zb + 1);
  }
}

void LabelLayers::EmitCube(int64_t i, int64_t j, int64_t zb, const LabelId (&l)[8],
                           LayerExtractor* ex) {
  ++ex->crossed_cubes_;
  ox_ = kUnit * i;
  oy_ = kUnit * j;
  oz_ = kUnit * zb;
  for (const auto& tet : kTets) {
    const LabelId tl[4] = {l[tet[0]], l[tet[1]], l[tet[2]], l[tet[3]]};
    int distinct = 1;
    for (int a = 1; a < 4; ++a) {
      bool seen = false;
      for (int b = 0; b < a; ++b) seen |= tl[a] == tl[b];
      distinct += !seen;
    }
    if (distinct == 1) continue;
    if (distinct == 2) {
      // Marching tetrahedra: the corners with tet[0]'s label against the others.
      int same[4], other[4], ns = 0, no = 0;
      for (int a = 0; a < 4; ++a) {
        if (tl[a] == tl[0]) {
          same[ns++] = tet[a];
        } else {
          other[no++] = tet[a];
        }
      }
      if (ns == 2) {  // 2-2: the parallelogram of the 4 crossed edges' midpoints
        const int p = same[0], q = same[1], r = other[0], s = other[1];
        Emit(Mid(p, r), Mid(p, s), Mid(q, s), p, r, l, ex);
        Emit(Mid(p, r), Mid(q, s), Mid(q, r), p, r, l, ex);
      } else {  // 1-3: the lone corner cut off
        const int lone = ns == 1 ? same[0] : other[0];
        int rest[3], n = 0;
        for (int c : tet) {
          if (c != lone) rest[n++] = c;
        }
        Emit(Mid(lone, rest[0]), Mid(lone, rest[1]), Mid(lone, rest[2]), lone, rest[0], l, ex);
      }
      continue;
    }
    // Three or four labels: the cone from the centroid over the faces' interface segments.
    const Point centre = Centroid({tet[0], tet[1], tet[2], tet[3]});
    for (int omit = 0; omit < 4; ++omit) {
      int f[3], n = 0;
      for (int a = 0; a < 4; ++a) {
        if (a != omit) f[n++] = tet[a];
      }
      const LabelId la = l[f[0]], lb = l[f[1]], lc = l[f[2]];
      if (la == lb && lb == lc) continue;
      if (la != lb && lb != lc && la != lc) {
        const Point fc = Centroid({f[0], f[1], f[2]});
        for (int e = 0; e < 3; ++e) {
          const int u = f[e], w = f[(e + 1) % 3];
          Emit(centre, fc, Mid(u, w), u, w, l, ex);
        }
        continue;
      }
      // Two labels on the face: the lone corner's two edges' midpoints.
      const int lone = la == lb ? f[2] : (la == lc ? f[1] : f[0]);
      int rest[2], m = 0;
      for (int c : f) {
        if (c != lone) rest[m++] = c;
      }
      Emit(centre, Mid(lone, rest[0]), Mid(lone, rest[1]), lone, rest[0], l, ex);
    }
  }
}

void LabelLayers::Emit(Point a, Point b, Point c, int u, int w, const LabelId (&l)[8],
                       LayerExtractor* ex) {
  LabelId in = l[u], out = l[w];
  if (in == labels_.background || (out != labels_.background && out < in)) std::swap(in, out);
  // From the inside corner to the outside one: the normal must point that way. u and w lie
  // strictly on either side of the triangle's plane (docs/decisions.md), and the arithmetic
  // is exact.
  const Point cu = Corner(u), cw = Corner(w);
  const int64_t sign = l[u] == in ? 1 : -1;
  const Point d{sign * (cw[0] - cu[0]), sign * (cw[1] - cu[1]), sign * (cw[2] - cu[2])};
  const Point e1{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2{c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  const Point n{e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0]};
  const int64_t facing = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
  assert(facing != 0);
  if (facing < 0) std::swap(b, c);
  const VertexId va = Vertex(a, ex), vb = Vertex(b, ex), vc = Vertex(c, ex);
  ex->staged_triangles_.push_back({va, vb, vc});
  const auto [it, added] = pair_index_.try_emplace({in, out}, static_cast<uint32_t>(pairs_.size()));
  if (added) pairs_.push_back({in, out});
  staged_patch_.push_back(it->second);
}

VertexId LabelLayers::Vertex(const Point& p, LayerExtractor* ex) {
  const int64_t x = ox_ + p[0], y = oy_ + p[1], dz = p[2];
  // x and y from -12 on (the closed volume's padding), dz in [0, 12]; a plane's points
  // without dz, so that the top plane's keys are the next layer's bottom's.
  const bool plane = dz == 0 || dz == kUnit;
  const uint64_t key = (static_cast<uint64_t>(x + kUnit) << 40) |
                       (static_cast<uint64_t>(y + kUnit) << 8) |
                       static_cast<uint64_t>(plane ? 0 : dz);
  auto& map = dz == 0 ? plane_bottom_ : (dz == kUnit ? plane_top_ : inside_);
  const auto [it, added] = map.try_emplace(key, kInvalid);
  if (!added) return it->second;
  const int64_t z = oz_ + dz;
  // On a seam face (0: x = 0, 1: x = nx - 1), shared with the neighbouring part.
  const int seam = x == 0 && (seam_faces_ & kBoxXMin)                   ? 0
                   : x == kUnit * (nx_ - 1) && (seam_faces_ & kBoxXMax) ? 1
                                                                        : -1;
  uint8_t mask = seam >= 0 ? kSeam : 0;
  if (!labels_.close) {  // open: a point on the grid's box keeps to its faces
    if (x == 0 && seam < 0) mask |= kBoxXMin;
    if (x == kUnit * (nx_ - 1) && seam < 0) mask |= kBoxXMax;
    if (y == 0) mask |= kBoxYMin;
    if (y == kUnit * (ny_ - 1)) mask |= kBoxYMax;
    if (z == 0) mask |= kBoxZMin;
    if (nz_ > 0 && z == kUnit * (nz_ - 1)) mask |= kBoxZMax;
  }
  // The whole grid's x, divided once: a part's points are one part's bit for bit.
  const double ix = static_cast<double>(x + kUnit * x_offset_) / kUnit,
               iy = static_cast<double>(y) / kUnit, iz = static_cast<double>(z) / kUnit;
  const auto staged = static_cast<uint32_t>(ex->staged_vertices_.size());
  const VertexId id = LayerExtractor::kPending | staged;
  if (seam >= 0) seam_[static_cast<size_t>(seam)].push_back({z, y, staged});
  ex->staged_vertices_.push_back({ex->Physical(ix, iy, iz), iz, mask, static_cast<int8_t>(seam)});
  if (dz == kUnit && !labels_.close) ex->top_plane_vertices_.push_back(id);  // Finish: kBoxZMax
  it->second = id;
  return id;
}

void LabelLayers::Commit(MeshStore* store, std::span<const TriId> tris,
                         std::span<const VertexId> staged_to_store,
                         std::array<std::vector<VertexId>, 2>* new_seam) {
  for (size_t f = 0; f < 2; ++f) {
    std::vector<SeamPoint>& points = seam_[f];
    std::sort(points.begin(), points.end(), [](const SeamPoint& a, const SeamPoint& b) {
      return a.z != b.z ? a.z < b.z : a.y < b.y;
    });
    if (new_seam) {
      for (const SeamPoint& p : points) (*new_seam)[f].push_back(staged_to_store[p.staged]);
    }
    points.clear();
  }
  assert(tris.size() == staged_patch_.size());
  store_patch_.resize(pairs_.size(), kInvalid);
  for (size_t i = 0; i < tris.size(); ++i) {
    uint32_t& p = store_patch_[staged_patch_[i]];
    if (p == kInvalid) p = store->PatchOf(pairs_[staged_patch_[i]]);
    store->set_patch(tris[i], p);
  }
  staged_patch_.clear();
  // The store holds every pair met; the next layer's lookups need only its own, so that this
  // table is a layer's pairs, not the whole sweep's (a million ids: three million pairs).
  pairs_.clear();
  pair_index_.clear();
  store_patch_.clear();
  for (auto& [key, v] : plane_top_) {
    if (v & LayerExtractor::kPending) v = staged_to_store[v & ~LayerExtractor::kPending];
  }
}

void LabelLayers::EdgeRules(std::span<const std::array<VertexId, 3>> staged, size_t vertices,
                            std::span<const TriId> tris, std::vector<uint8_t>* rules) {
  // An edge with a new end lies in this layer's triangles only (the store's triangles at a
  // new vertex are the layer's), all of this layer: the one of least id queues it. Each such
  // edge is listed at its end of larger id (pending ids are above store ids, so that is a new
  // end), with the triangle edge that queues it as far as the triangles met so far say.
  auto is_new = [](VertexId v) { return (v & LayerExtractor::kPending) != 0; };  // no kInvalid
  auto staged_index = [](VertexId v) { return v & ~LayerExtractor::kPending; };
  listed_at_.assign(vertices + 1, 0);
  for (const auto& tri : staged) {
    for (int k = 0; k < 3; ++k) {
      const VertexId end = std::max(tri[k], tri[kNextCorner[k]]);
      if (is_new(end)) ++listed_at_[staged_index(end) + 1];
    }
  }
  for (size_t v = 1; v <= vertices; ++v) listed_at_[v] += listed_at_[v - 1];
  listed_end_.assign(listed_at_.begin(), listed_at_.end() - 1);
  listed_.resize(listed_at_[vertices]);
  const size_t first = rules->size();
  rules->resize(first + staged.size());
  for (size_t i = 0; i < staged.size(); ++i) {
    uint8_t rule = 0;  // kEdgeBelow where not set
    for (int k = 0; k < 3; ++k) {
      const VertexId a = staged[i][k], b = staged[i][kNextCorner[k]];
      const VertexId end = std::max(a, b), other = std::min(a, b);
      if (!is_new(end)) {
        rule |= kEdgeSearch << (2 * k);
        continue;
      }
      const auto edge = static_cast<uint32_t>(3 * i + k);
      const uint32_t v = staged_index(end);
      ListedEdge* e = listed_.data() + listed_at_[v];
      ListedEdge* const last = listed_.data() + listed_end_[v];
      while (e != last && e->other != other) ++e;
      if (e == last) {
        *e = {other, edge};
        ++listed_end_[v];
      } else if (tris[e->edge / 3] > tris[i]) {  // the store handed out ids out of order
        (*rules)[first + e->edge / 3] &= static_cast<uint8_t>(~(3 << (2 * (e->edge % 3))));
        e->edge = edge;
      } else {
        continue;
      }
      rule |= kEdgeOnce << (2 * k);
    }
    (*rules)[first + i] = rule;
  }
  // As the extractor's staging: a cap's lists are not kept for the whole session.
  if (EdgeListBytes() > (size_t{4} << 20)) {
    std::vector<uint32_t>().swap(listed_at_);
    std::vector<uint32_t>().swap(listed_end_);
    std::vector<ListedEdge>().swap(listed_);
  }
}

size_t LabelLayers::EdgeListBytes() const {
  return (listed_at_.capacity() + listed_end_.capacity()) * sizeof(uint32_t) +
         listed_.capacity() * sizeof(ListedEdge);
}

void LabelLayers::ForgetPairs() {
  assert(staged_patch_.empty());
  pairs_ = {};
  pair_index_ = {};
  store_patch_ = {};
}

size_t LabelLayers::MemoryBytes() const {
  auto map_bytes = [](const absl::flat_hash_map<uint64_t, VertexId>& m) {
    return m.capacity() * (sizeof(uint64_t) + sizeof(VertexId) + 1);
  };
  // The two planes as planned until the first slice allocates them (a budget checked before
  // any voxel counts them).
  const size_t planes = top_.empty() ? 2 * static_cast<size_t>((nx_ + 2) * (ny_ + 2))
                                     : bottom_.capacity() + top_.capacity();
  return planes * sizeof(LabelId) + map_bytes(plane_bottom_) + map_bytes(plane_top_) +
         map_bytes(inside_) + staged_patch_.capacity() * sizeof(uint32_t) +
         pairs_.capacity() * sizeof(LabelPair) + store_patch_.capacity() * sizeof(uint32_t) +
         pair_index_.capacity() * (sizeof(std::pair<LabelId, LabelId>) + sizeof(uint32_t) + 1) +
         (seam_[0].capacity() + seam_[1].capacity()) * sizeof(SeamPoint) + EdgeListBytes();
}

}  // namespace tandem
