#include "layer_extractor.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>
#include <utility>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "absl/strings/str_cat.h"
#include "label_extractor.h"
#include "mc_tables.h"
#include "tandem/status_macros.h"
#include "tandem/volume.h"

namespace tandem {
namespace {

constexpr int64_t kWordBits = 64;

// The n lowest bits (n clamped to [0, 64]).
uint64_t LowBits(int64_t n) {
  if (n <= 0) return 0;
  if (n >= kWordBits) return ~uint64_t{0};
  return (uint64_t{1} << n) - 1;
}

// Word w of a bit row shifted down by one bit across word boundaries: bit b = bit b+1 of
// the row, i.e. the neighbour at i+1 of voxel i (0 past the row's end).
uint64_t NextBits(const uint64_t* row, int64_t w, int64_t words) {
  return (row[w] >> 1) | (w + 1 < words ? row[w + 1] << (kWordBits - 1) : 0);
}

// Calls f(base + b) for each set bit b of `bits`, ascending.
template <typename F>
void ForEachBit(uint64_t bits, int64_t base, F&& f) {
  while (bits) {
    f(base + std::countr_zero(bits));
    bits &= bits - 1;
  }
}

// The least float t (possibly infinite) with double(t) >= iso, or NaN for a NaN iso. For a
// finite float v, Rel(v) = double(v) - iso >= 0 iff double(v) >= iso (an IEEE difference
// rounds to a number of the exact difference's sign, and is 0 only for equal operands), iff
// v >= t (t is the least such float); a NaN iso makes both false.
float InsideFrom(double iso) {
  if (std::isnan(iso)) return std::numeric_limits<float>::quiet_NaN();
  if (iso > FLT_MAX) return std::numeric_limits<float>::infinity();
  if (iso < -FLT_MAX) return -FLT_MAX;
  float t = static_cast<float>(iso);  // nearest, in range
  if (static_cast<double>(t) < iso) t = std::nextafter(t, std::numeric_limits<float>::infinity());
  return t;
}

}  // namespace

LayerExtractor::LayerExtractor(const ExtractorConfig& config, MeshStore* store)
    : config_(config), store_(store) {
  words_ = (config.nx + kWordBits - 1) / kWordBits;
  inside_from_ = InsideFrom(config.iso);
  if (config.labels.enabled) {
    labels_ = std::make_unique<LabelLayers>(config);
  }
}

LayerExtractor::~LayerExtractor() = default;

bool LayerExtractor::ComputeClosingLayer() {
  return labels_ != nullptr && labels_->ComputeClosing(this);
}

void LayerExtractor::CompactLabelPairs() {
  // At least this many pairs before the first compaction: a scan over the live triangles
  // is not worth fewer.
  constexpr size_t kMinPairs = 1024;
  if (labels_ == nullptr || store_->pairs().size() < std::max(kMinPairs, compact_pairs_at_)) {
    return;
  }
  store_->CompactPairs();
  labels_->ForgetPairs();
  compact_pairs_at_ = 2 * store_->pairs().size();
}

size_t LayerExtractor::PlaneCacheBytes(int64_t nx, int64_t ny, DType dtype) {
  const size_t n = static_cast<size_t>(nx * ny);
  const size_t words = static_cast<size_t>((nx + 63) / 64 * ny);
  const size_t value = dtype == DType::kFloat32 || !SliceValues::ScannedAsIs(dtype)
                           ? sizeof(float)
                           : sizeof(uint16_t);
  return n * 2 * value + 2 * words * sizeof(uint64_t) + 5 * words * sizeof(uint32_t);
}

size_t LayerExtractor::PlaneBytes(DType planned) const {
  if (labels_) return labels_->MemoryBytes();
  if (ze_.first.empty()) return PlaneCacheBytes(config_.nx, config_.ny, planned);
  // The values as held (the bottom plane, empty after the first slice, as the top one); the
  // sign bits and edge ranks as allocated.
  auto values = [](const Plane& p) {
    return p.f.capacity() * sizeof(float) + p.h.capacity() * sizeof(uint16_t);
  };
  const size_t words = static_cast<size_t>(words_ * config_.ny);
  return values(v_top_) + std::max(values(v_bottom_), values(v_top_)) +
         2 * words * sizeof(uint64_t) + 5 * words * sizeof(uint32_t);
}

void LayerExtractor::Plane::Prepare(DType type, size_t n) {
  dtype = type;
  if (type == DType::kFloat32) {
    std::vector<uint16_t>().swap(h);
    f.resize(n);
  } else {
    std::vector<float>().swap(f);
    h.resize(n);
  }
}

size_t LayerExtractor::EdgeIdBytes() const {
  size_t ids = 0;
  for (const CrossedEdges* e : {&xe_bottom_, &xe_top_, &ye_bottom_, &ye_top_, &ze_}) {
    ids += e->ids.capacity();
  }
  return ids * sizeof(VertexId);
}

void LayerExtractor::AllocatePlanes() {
  // On the first slice, not at construction: a session that never gets a voxel (a bare
  // config, a client that leaves) commits no memory for a grid it never sees.
  const ExtractorConfig& config = config_;
  s_bottom_.assign(static_cast<size_t>(words_ * config.ny), 0);
  s_top_ = s_bottom_;
  any_in_.resize(static_cast<size_t>(words_));
  all_in_.resize(static_cast<size_t>(words_));
  for (CrossedEdges* e : {&xe_bottom_, &xe_top_, &ye_bottom_, &ye_top_, &ze_}) {
    e->first.assign(static_cast<size_t>(words_ * config.ny), 0);
  }
}

uint64_t LayerExtractor::XCrossings(const uint64_t* signs, int64_t j, int64_t w) const {
  const uint64_t* row = signs + j * words_;
  return (row[w] ^ NextBits(row, w, words_)) & LowBits(config_.nx - 1 - w * kWordBits);
}

uint64_t LayerExtractor::YCrossings(const uint64_t* signs, int64_t j, int64_t w) const {
  return signs[j * words_ + w] ^ signs[(j + 1) * words_ + w];
}

uint64_t LayerExtractor::ZCrossings(int64_t j, int64_t w) const {
  return s_bottom_[static_cast<size_t>(j * words_ + w)] ^ s_top_[static_cast<size_t>(j * words_ + w)];
}

VertexId LayerExtractor::EdgeId(const CrossedEdges& edges, int64_t i, int64_t j,
                                uint64_t crossings) const {
  const int64_t bit = i % kWordBits;
  if (!((crossings >> bit) & 1)) return kInvalid;
  return edges.ids[edges.first[static_cast<size_t>(j * words_ + i / kWordBits)] +
                   static_cast<uint32_t>(std::popcount(crossings & LowBits(bit)))];
}

uint8_t LayerExtractor::BoxMask(double i, double j, double k) const {
  // i is a column of the whole grid; this part's faces are x_offset and x_offset + nx - 1.
  uint8_t m = 0;
  if (i == static_cast<double>(config_.x_offset)) m |= kBoxXMin;
  if (i == static_cast<double>(config_.x_offset + config_.nx - 1)) m |= kBoxXMax;
  m &= static_cast<uint8_t>(~config_.seam_faces);  // a seam is not the box
  if (j == 0) m |= kBoxYMin;
  if (j == static_cast<double>(config_.ny - 1)) m |= kBoxYMax;
  if (k == 0) m |= kBoxZMin;
  if (config_.nz > 0 && k == static_cast<double>(config_.nz - 1)) m |= kBoxZMax;
  return m;
}

void LayerExtractor::EdgePoint(double pi, double pj, double pk, int axis, double fp, double fq,
                               double offset, double idx[3]) {
  // fp and fq have different signs (one >= 0, one < 0), so the denominator is never 0 and
  // t lies in [0, 1]; t = 0 or 1 exactly when a grid value equals the iso-value, and the
  // offset keeps the point off the grid point. The cube loop recomputes points with this
  // same function, so they match bit for bit.
  double t = fp / (fp - fq);
  if (!(t >= kEdgeOffsetSpread * offset && t <= 1.0 - kEdgeOffsetSpread * offset)) {
    const double own = offset * EdgeOffsetShare(static_cast<int64_t>(pi), static_cast<int64_t>(pj),
                                                static_cast<int64_t>(pk), axis);
    t = std::clamp(t, own, 1.0 - own);
  }
  idx[0] = pi;
  idx[1] = pj;
  idx[2] = pk;
  idx[axis] += t;
}

std::array<double, 3> LayerExtractor::Offsets(int64_t k) const {
  const std::array<double, 3>& s = config_.spacing;
  const double smallest = std::min({s[0], s[1], s[2]});
  const double offset = EdgeOffset(config_.reach + static_cast<double>(k) * config_.reach_per_slice,
                                   std::max({s[0], s[1], s[2]}) / smallest) *
                        smallest;
  return {offset / s[0], offset / s[1], offset / s[2]};
}

int LayerExtractor::SeamFace(int64_t i) const {
  if (i == 0 && (config_.seam_faces & kBoxXMin)) return 0;
  if (i == config_.nx - 1 && (config_.seam_faces & kBoxXMax)) return 1;
  return -1;
}

VertexId LayerExtractor::StageVertex(const double idx[3], int seam_face) {
  const VertexId id = kPending | static_cast<VertexId>(staged_vertices_.size());
  uint8_t mask = BoxMask(idx[0], idx[1], idx[2]);
  if (seam_face >= 0) mask |= kSeam;
  staged_vertices_.push_back(
      {Physical(idx[0], idx[1], idx[2]), idx[2], mask, static_cast<int8_t>(seam_face)});
  return id;
}

absl::Status LayerExtractor::AddSlice(const float* values, std::vector<TriId>* new_tris,
                                      std::vector<VertexId>* new_verts) {
  TANDEM_RETURN_IF_ERROR(ComputeLayer(values));
  CommitLayer(new_tris, new_verts);
  return absl::OkStatus();
}

void LayerExtractor::CommitLayer(std::vector<TriId>* new_tris, std::vector<VertexId>* new_verts,
                                 std::array<std::vector<VertexId>, 2>* new_seam,
                                 std::vector<uint8_t>* new_edges) {
  if (!staged_) return;
  staged_ = false;
  store_->Reserve(staged_vertices_.size(), staged_triangles_.size());
  staged_to_store_.resize(staged_vertices_.size());
  for (size_t i = 0; i < staged_vertices_.size(); ++i) {
    const StagedVertex& sv = staged_vertices_[i];
    const VertexId v = store_->AddVertex(sv.pos, sv.height, staged_layer_, sv.box_mask);
    assert(v < kPending);
    staged_to_store_[i] = v;
    if (new_verts) new_verts->push_back(v);
    // Staging order is the canonical order: y-edges, then z-edges, by ascending y (a label
    // layer's are listed by LabelLayers::Commit).
    if (new_seam && (sv.box_mask & kSeam) && !labels_) (*new_seam)[sv.seam_face].push_back(v);
  }
  auto resolve = [this](VertexId v) { return IsPending(v) ? staged_to_store_[v & ~kPending] : v; };
  if (labels_) {
    std::vector<TriId> tris;
    tris.reserve(staged_triangles_.size());
    for (const auto& tri : staged_triangles_) {
      tris.push_back(store_->AddTriangle(resolve(tri[0]), resolve(tri[1]), resolve(tri[2])));
    }
    labels_->Commit(store_, tris, staged_to_store_, new_seam);
    if (new_edges) labels_->EdgeRules(staged_triangles_, staged_vertices_.size(), tris, new_edges);
    if (new_tris) new_tris->insert(new_tris->end(), tris.begin(), tris.end());
  } else {
    for (const auto& tri : staged_triangles_) {
      const TriId t = store_->AddTriangle(resolve(tri[0]), resolve(tri[1]), resolve(tri[2]));
      if (new_tris) new_tris->push_back(t);
    }
  }
  if (new_edges) new_edges->insert(new_edges->end(), staged_edges_.begin(), staged_edges_.end());
  // The top plane's cached ids become the next layer's bottom: store ids from now on.
  for (VertexId& v : xe_top_.ids) v = resolve(v);
  for (VertexId& v : ye_top_.ids) v = resolve(v);
  for (VertexId& v : top_plane_vertices_) v = resolve(v);
  // The staging is empty until the next layer: past 4 MiB (a closed volume's cap stages many
  // times a dense layer) it is freed, not kept at its largest for the whole session; the
  // next layer reserves what this one staged (docs/decisions.md 4).
  last_staged_ = {staged_vertices_.size(), staged_triangles_.size()};
  if (StagingBytes() > (size_t{4} << 20)) {
    std::vector<StagedVertex>().swap(staged_vertices_);
    std::vector<std::array<VertexId, 3>>().swap(staged_triangles_);
    std::vector<uint8_t>().swap(staged_edges_);
    std::vector<VertexId>().swap(staged_to_store_);
  }
  staged_vertices_.clear();
  staged_triangles_.clear();
  staged_edges_.clear();
}

size_t LayerExtractor::HeldBytes(DType dtype) const {
  return PlaneBytes(dtype) + EdgeIdBytes() + StagingBytes() +
         staged_vertices_.size() * commit_vertex_bytes_ +
         staged_triangles_.size() * commit_triangle_bytes_;
}

size_t LayerExtractor::StagingBytes() const {
  return staged_vertices_.capacity() * sizeof(StagedVertex) +
         staged_triangles_.capacity() * sizeof(staged_triangles_[0]) + staged_edges_.capacity() +
         staged_to_store_.capacity() * sizeof(VertexId);
}

bool LayerExtractor::ScanRow(const float* src, int64_t n, float* dst, uint64_t* signs) const {
  // Inside iff Rel(v) >= 0 iff v >= inside_from_ (see InsideFrom): one float compare per
  // value, 4 per SSE2 instruction, with no conversion to double.
  const float t = inside_from_;
  bool finite = true;
  int64_t i = 0;
#if defined(__SSE2__)
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  const __m128 max_finite = _mm_set1_ps(FLT_MAX), threshold = _mm_set1_ps(t);
  __m128 all_finite = _mm_castsi128_ps(_mm_set1_epi32(-1));
  for (; i + kWordBits <= n; i += kWordBits) {
    uint64_t word = 0;
    for (int b = 0; b < kWordBits; b += 4) {
      const __m128 x = _mm_loadu_ps(src + i + b);
      _mm_storeu_ps(dst + i + b, x);
      // |x| <= FLT_MAX is false for infinities and NaNs.
      all_finite = _mm_and_ps(all_finite, _mm_cmple_ps(_mm_and_ps(x, abs_mask), max_finite));
      word |= static_cast<uint64_t>(_mm_movemask_ps(_mm_cmpge_ps(x, threshold))) << b;
    }
    signs[i / kWordBits] = word;
  }
  finite = _mm_movemask_ps(all_finite) == 0xf;
#endif
  for (; i < n; i += kWordBits) {
    uint64_t word = 0;
    for (int64_t b = 0; b < kWordBits && i + b < n; ++b) {
      const float x = src[i + b];
      dst[i + b] = x;
      finite &= std::isfinite(x);
      word |= static_cast<uint64_t>(x >= t) << b;
    }
    signs[i / kWordBits] = word;
  }
  return finite;
}

template <typename T>
void LayerExtractor::ScanIntegerRow(const uint8_t* src, int64_t n, uint16_t* dst,
                                    uint64_t* signs) const {
  // An integer converts to float exactly, so float(v) >= t iff v >= ceil(t): one integer
  // compare a value (clamped: `from` past the type's range means none, at its least all).
  constexpr int32_t kLo = std::numeric_limits<T>::min(), kHi = std::numeric_limits<T>::max();
  const float t = inside_from_;
  const int32_t from = std::isnan(t)
                           ? kHi + 1
                           : static_cast<int32_t>(std::clamp(std::ceil(static_cast<double>(t)),
                                                             double{kLo}, double{kHi} + 1));
  int64_t i = 0;
#if defined(__SSE2__)
  // 16 values an iteration, compared as signed 16 bits (unsigned ones with the top bit
  // flipped); the all and none thresholds, which 16 bits cannot hold, are forced afterwards.
  const bool all = from <= kLo, none = from > kHi;
  const uint64_t keep = all || none ? 0 : ~uint64_t{0}, force = all ? ~uint64_t{0} : 0;
  const int32_t flip = std::is_signed_v<T> ? 0 : 0x8000;
  const __m128i flip_v = _mm_set1_epi16(static_cast<int16_t>(flip));
  const __m128i below = _mm_set1_epi16(
      static_cast<int16_t>(static_cast<uint16_t>(((all || none) ? kLo : from - 1) ^ flip)));
  const __m128i zero = _mm_setzero_si128();
  for (; i + kWordBits <= n; i += kWordBits) {
    uint64_t word = 0;
    for (int b = 0; b < kWordBits; b += 16) {
      __m128i lo, hi;  // values b..b+7 and b+8..b+15 as 16 bits
      if constexpr (sizeof(T) == 1) {
        const __m128i x = _mm_loadu_si128(reinterpret_cast<const __m128i*>(src + i + b));
        lo = _mm_unpacklo_epi8(x, zero);
        hi = _mm_unpackhi_epi8(x, zero);
      } else {
        lo = _mm_loadu_si128(reinterpret_cast<const __m128i*>(src + (i + b) * 2));
        hi = _mm_loadu_si128(reinterpret_cast<const __m128i*>(src + (i + b + 8) * 2));
      }
      _mm_storeu_si128(reinterpret_cast<__m128i*>(dst + i + b), lo);
      _mm_storeu_si128(reinterpret_cast<__m128i*>(dst + i + b + 8), hi);
      const __m128i in_lo = _mm_cmpgt_epi16(_mm_xor_si128(lo, flip_v), below);
      const __m128i in_hi = _mm_cmpgt_epi16(_mm_xor_si128(hi, flip_v), below);
      word |= static_cast<uint64_t>(
                  static_cast<uint32_t>(_mm_movemask_epi8(_mm_packs_epi16(in_lo, in_hi))))
              << b;
    }
    signs[i / kWordBits] = (word & keep) | force;
  }
#endif
  for (; i < n; i += kWordBits) {
    uint64_t word = 0;
    const int64_t m = std::min<int64_t>(kWordBits, n - i);
    for (int64_t b = 0; b < m; ++b) {
      T v;
      std::memcpy(&v, src + static_cast<size_t>(i + b) * sizeof(T), sizeof(T));
      dst[i + b] = static_cast<uint16_t>(v);  // a byte widened, 16 bits as they are
      word |= static_cast<uint64_t>(static_cast<int32_t>(v) >= from) << b;
    }
    signs[i / kWordBits] = word;
  }
}

absl::Status LayerExtractor::ComputeLayer(SliceValues slice) {
  const int64_t nx = config_.nx, ny = config_.ny, words = words_, xo = config_.x_offset;
  const int64_t k = slices_done_;
  if (staged_) return absl::FailedPreconditionError("CommitLayer the previous layer first");
  if (finished_ || (config_.nz > 0 && k >= config_.nz)) {
    return absl::InvalidArgumentError(
        absl::StrCat("slice ", k, " is past the end of the volume (nz = ", config_.nz, ")"));
  }
  if (labels_) return labels_->Compute(slice, this);
  if (!SliceValues::ScannedAsIs(slice.dtype)) {
    return absl::InternalError(absl::StrCat(std::string(DTypeName(slice.dtype)),
                                            " voxels reach the extractor unconverted"));
  }
  if (ze_.first.empty()) AllocatePlanes();  // ze_ last: all or nothing
  // Copy the slice and its signs into the bottom buffers (slice k-2's, no longer needed),
  // validating as we go; they become the top only if the whole slice is finite, so a bad
  // slice leaves the extractor (and the store) as it was.
  bool finite = true;
  const int64_t stride = config_.row_stride > 0 ? config_.row_stride : nx;
  const size_t row_bytes = static_cast<size_t>(stride) * DTypeSize(slice.dtype);
  v_bottom_.Prepare(slice.dtype, static_cast<size_t>(nx * ny));
  for (int64_t j = 0; j < ny; ++j) {
    const uint8_t* row = slice.bytes + static_cast<size_t>(j) * row_bytes;
    const size_t at = static_cast<size_t>(j * nx);
    uint64_t* signs = s_bottom_.data() + j * words;
    switch (slice.dtype) {
      case DType::kUInt8: ScanIntegerRow<uint8_t>(row, nx, v_bottom_.h.data() + at, signs); break;
      case DType::kUInt16: ScanIntegerRow<uint16_t>(row, nx, v_bottom_.h.data() + at, signs); break;
      case DType::kInt16: ScanIntegerRow<int16_t>(row, nx, v_bottom_.h.data() + at, signs); break;
      case DType::kFloat32:
        finite &= ScanRow(reinterpret_cast<const float*>(row), nx, v_bottom_.f.data() + at, signs);
        break;
      case DType::kInt8:
      case DType::kUInt32:
      case DType::kInt32:
      case DType::kUInt64:
      case DType::kInt64:
        break;  // refused above
    }
  }
  if (!finite) {
    const auto* values = reinterpret_cast<const float*>(slice.bytes);
    for (int64_t j = 0; j < ny; ++j) {
      for (int64_t i = 0; i < nx; ++i) {
        const float v = values[j * stride + i];
        if (!std::isfinite(v)) return NonFiniteVoxelError(i + config_.x_offset, j, v);
      }
    }
  }
  std::swap(v_bottom_, v_top_);
  std::swap(s_bottom_, s_top_);
  std::swap(xe_bottom_, xe_top_);
  std::swap(ye_bottom_, ye_top_);
  // The top lists still hold slice k-2's ids (their `first` is rewritten below, every word).
  xe_top_.ids.clear();
  ye_top_.ids.clear();
  ze_.ids.clear();

  staged_ = true;
  staged_layer_ = static_cast<int32_t>(k);
  offset_bottom_ = offset_top_;
  offset_top_ = Offsets(k);
  check_at_ = kCheckEvery;
  // Room for about what the last layer staged, at once: grown by doubling from empty, the
  // staging was copied on its way up and faulted in about twice over (tests/bench/DENSE.md;
  // CommitLayer frees it past 4 MiB).
  staged_vertices_.reserve(last_staged_.first + last_staged_.first / 16);
  staged_triangles_.reserve(last_staged_.second + last_staged_.second / 16);
  staged_edges_.reserve(last_staged_.second + last_staged_.second / 16);
  const double kz = static_cast<double>(k);
  const Plane& vb = v_bottom_;
  const Plane& vt = v_top_;
  const uint64_t* sb = s_bottom_.data();
  const uint64_t* st = s_top_.data();
  double idx3[3];
  top_plane_vertices_.clear();
  // Crossed edges are those whose two ends' sign bits differ; all loops visit them in
  // ascending (j, i) order, the order the vertices are staged in.
  // Plane vertices of slice k: x-edges (bit i vs bit i+1 of a row) then y-edges (row j vs
  // row j+1).
  for (int64_t j = 0; j < ny; ++j) {
    for (int64_t w = 0; w < words; ++w) {
      xe_top_.first[static_cast<size_t>(j * words + w)] = static_cast<uint32_t>(xe_top_.ids.size());
      ForEachBit(XCrossings(st, j, w), w * kWordBits, [&](int64_t i) {
        EdgePoint(double(i + xo), double(j), kz, 0, Rel(vt[j * nx + i]), Rel(vt[j * nx + i + 1]),
                  offset_top_[0], idx3);
        const VertexId v = StageVertex(idx3);
        xe_top_.ids.push_back(v);
        top_plane_vertices_.push_back(v);
      });
    }
    Checkpoint(slice.dtype, k);
  }
  for (int64_t j = 0; j + 1 < ny; ++j) {
    for (int64_t w = 0; w < words; ++w) {
      ye_top_.first[static_cast<size_t>(j * words + w)] = static_cast<uint32_t>(ye_top_.ids.size());
      ForEachBit(YCrossings(st, j, w), w * kWordBits, [&](int64_t i) {
        EdgePoint(double(i + xo), double(j), kz, 1, Rel(vt[j * nx + i]), Rel(vt[(j + 1) * nx + i]),
                  offset_top_[1], idx3);
        const VertexId v = StageVertex(idx3, SeamFace(i));
        ye_top_.ids.push_back(v);
        top_plane_vertices_.push_back(v);
      });
    }
    Checkpoint(slice.dtype, k);
  }
  ++slices_done_;
  if (k == 0) return absl::OkStatus();  // slice 0 has no layer below it

  // z-edges between slices k-1 and k: bottom row vs top row.
  for (int64_t j = 0; j < ny; ++j) {
    for (int64_t w = 0; w < words; ++w) {
      ze_.first[static_cast<size_t>(j * words + w)] = static_cast<uint32_t>(ze_.ids.size());
      ForEachBit(ZCrossings(j, w), w * kWordBits, [&](int64_t i) {
        const int64_t idx = j * nx + i;
        const double a = Rel(vb[idx]), b = Rel(vt[idx]);
        EdgePoint(double(i + xo), double(j), kz - 1, 2, a, b, offset_top_[2], idx3);
        ze_.ids.push_back(StageVertex(idx3, SeamFace(i)));
      });
    }
    Checkpoint(slice.dtype, k);
  }

  // Cubes of layer k. Cube (i, j) is crossed unless its 8 corners are all out or all in:
  // with `any` the OR and `all` the AND of the 4 rows j, j+1 of both slices, that is bits
  // i and i+1 of `any` both 0, or of `all` both 1.
  for (int64_t j = 0; j + 1 < ny; ++j) {
    const uint64_t *b0 = sb + j * words, *b1 = b0 + words, *t0 = st + j * words, *t1 = t0 + words;
    for (int64_t w = 0; w < words; ++w) {
      any_in_[w] = b0[w] | b1[w] | t0[w] | t1[w];
      all_in_[w] = b0[w] & b1[w] & t0[w] & t1[w];
    }
    for (int64_t w = 0; w < words; ++w) {
      const uint64_t crossed = (any_in_[w] | NextBits(any_in_.data(), w, words)) &
                               ~(all_in_[w] & NextBits(all_in_.data(), w, words)) &
                               LowBits(nx - 1 - w * kWordBits);
      ForEachBit(crossed, w * kWordBits, [&](int64_t i) { EmitCube(i, j, kz); });
    }
    Checkpoint(slice.dtype, k);
  }
  return absl::OkStatus();
}

namespace {

// The face (mc::FaceCorners' numbering: 0 x=0, 1 x=1, 2 y=0, 3 y=1, 4 z=0, 5 z=1) that cube
// edges p and q both lie on, for the pairs a loop joins (0 for the others, never asked).
constexpr auto kCommonFace = [] {
  std::array<std::array<uint8_t, 12>, 12> face{};
  for (int p = 0; p < 12; ++p) {
    for (int q = 0; q < 12; ++q) {
      const int c[4] = {mc::kEdgeCorners[p][0], mc::kEdgeCorners[p][1], mc::kEdgeCorners[q][0],
                        mc::kEdgeCorners[q][1]};
      for (int f = 0; f < 6; ++f) {
        const int axis = f / 2, bit = f % 2;
        bool all = true;
        for (int k : c) all = all && ((k >> axis) & 1) == bit;
        if (all && p != q) face[p][q] = static_cast<uint8_t>(f);
      }
    }
  }
  return face;
}();

// Bit e: cube edge e joins an in corner to an out one under this corner configuration.
constexpr auto kCrossedEdges = [] {
  std::array<uint16_t, 256> mask{};
  for (int config = 0; config < 256; ++config) {
    for (int e = 0; e < 12; ++e) {
      if (((config >> mc::kEdgeCorners[e][0]) ^ (config >> mc::kEdgeCorners[e][1])) & 1) {
        mask[config] = static_cast<uint16_t>(mask[config] | (1u << e));
      }
    }
  }
  return mask;
}();

}  // namespace

TANDEM_POPCNT_CLONES void LayerExtractor::EmitCube(int64_t i, int64_t j, double kz) {
  const int64_t nx = config_.nx;
  const Plane& vb = v_bottom_;
  const Plane& vt = v_top_;
  const int64_t p00 = j * nx + i, p10 = p00 + 1, p01 = p00 + nx, p11 = p01 + 1;
  double f[8];
  f[0] = Rel(vb[p00]); f[1] = Rel(vb[p10]); f[2] = Rel(vb[p01]); f[3] = Rel(vb[p11]);
  f[4] = Rel(vt[p00]); f[5] = Rel(vt[p10]); f[6] = Rel(vt[p01]); f[7] = Rel(vt[p11]);
  uint8_t config = 0;
  for (int c = 0; c < 8; ++c) config |= static_cast<uint8_t>((f[c] >= 0) << c);
  assert(config != 0 && config != 255);
  ++crossed_cubes_;
  uint8_t connected = 0;
  const uint8_t amb = mc::AmbiguousFaces(config);
  for (int face = 0; amb && face < 6; ++face) {
    if (!((amb >> face) & 1)) continue;
    const uint8_t* fc = mc::FaceCorners(face);
    if (mc::InCornersConnected(f[fc[0]], f[fc[1]], f[fc[2]], f[fc[3]])) {
      connected |= static_cast<uint8_t>(1u << face);
    }
  }
  const mc::CubeCase& cc = mc::Lookup(config, connected);
  // The 12 edges' ids: x-edges (i, j) and (i, j+1), y-edges (i, j) and (i+1, j) of both
  // slices, z-edges at the 4 corners (i+1 may lie in the next word).
  const uint64_t *sb = s_bottom_.data(), *st = s_top_.data();
  const int64_t w0 = i / kWordBits, w1 = (i + 1) / kWordBits;
  // Only the crossed edges, the ones the case's loops pass through, are looked up.
  VertexId ev[12];
  for (uint32_t m = kCrossedEdges[config]; m != 0; m &= m - 1) {
    const int e = std::countr_zero(m);
    switch (e) {
      case 0:
        ev[0] = EdgeId(xe_bottom_, i, j, XCrossings(sb, j, w0));
        break;
      case 1:
        ev[1] = EdgeId(xe_bottom_, i, j + 1, XCrossings(sb, j + 1, w0));
        break;
      case 2:
        ev[2] = EdgeId(xe_top_, i, j, XCrossings(st, j, w0));
        break;
      case 3:
        ev[3] = EdgeId(xe_top_, i, j + 1, XCrossings(st, j + 1, w0));
        break;
      case 4:
        ev[4] = EdgeId(ye_bottom_, i, j, YCrossings(sb, j, w0));
        break;
      case 5:
        ev[5] = EdgeId(ye_bottom_, i + 1, j, YCrossings(sb, j, w1));
        break;
      case 6:
        ev[6] = EdgeId(ye_top_, i, j, YCrossings(st, j, w0));
        break;
      case 7:
        ev[7] = EdgeId(ye_top_, i + 1, j, YCrossings(st, j, w1));
        break;
      case 8:
        ev[8] = EdgeId(ze_, i, j, ZCrossings(j, w0));
        break;
      case 9:
        ev[9] = EdgeId(ze_, i + 1, j, ZCrossings(j, w1));
        break;
      case 10:
        ev[10] = EdgeId(ze_, i, j + 1, ZCrossings(j + 1, w0));
        break;
      default:
        ev[11] = EdgeId(ze_, i + 1, j + 1, ZCrossings(j + 1, w1));
        break;
    }
  }
  // Each triangle's LayerEdges. A loop's own edges lie on the cube's faces: below (the plane
  // of slice k - 1, shared with the cube underneath but in the first layer), above (the
  // front), or on a side, shared with the neighbouring cube unless the slab ends there. Fan
  // diagonals and the edges to a centre vertex are inside the cube, each in two of its
  // triangles (a fan never joins two points of one face: those loops have a centre vertex).
  const LayerEdge side[6] = {i > 0 ? kEdgeShared : kEdgeOnce,
                             i + 2 < nx ? kEdgeShared : kEdgeOnce,
                             j > 0 ? kEdgeShared : kEdgeOnce,
                             j + 2 < config_.ny ? kEdgeShared : kEdgeOnce,
                             kz > 1.0 ? kEdgeBelow : kEdgeOnce,
                             kEdgeOnce};
  auto on_face = [&side](int p, int q) { return side[kCommonFace[p][q]]; };  // loop edge p-q
  int base = 0;
  for (int l = 0; l < cc.num_loops; ++l) {
    const int len = cc.loop_len[l];
    const uint8_t* e = cc.edges + base;
    base += len;
    if ((cc.center_mask >> l) & 1) {
      // Centroid of the loop's points, recomputed from the field (bit-identical to the
      // vertices' own positions) so this step never reads the store.
      double c[3] = {0, 0, 0};
      for (int s = 0; s < len; ++s) {
        const int c0 = mc::kEdgeCorners[e[s]][0], c1 = mc::kEdgeCorners[e[s]][1];
        const int axis = (c1 - c0) == 1 ? 0 : ((c1 - c0) == 2 ? 1 : 2);
        double p[3];
        // A z-edge, or an edge of the top slice, is this layer's; the bottom slice's are the
        // last layer's, with its offset.
        const double offset =
            (axis == 2 || ((c0 >> 2) & 1) != 0 ? offset_top_ : offset_bottom_)[axis];
        EdgePoint(double(i + config_.x_offset + (c0 & 1)), double(j + ((c0 >> 1) & 1)),
                  kz - 1 + ((c0 >> 2) & 1), axis, f[c0], f[c1], offset, p);
        const Vec3 q = Physical(p[0], p[1], p[2]);
        c[0] += q.x;
        c[1] += q.y;
        c[2] += q.z;
      }
      for (double& x : c) x *= 1.0 / len;
      const double ci[3] = {(c[0] - config_.origin[0]) / config_.spacing[0],
                            (c[1] - config_.origin[1]) / config_.spacing[1],
                            (c[2] - config_.origin[2]) / config_.spacing[2]};
      const VertexId cv = kPending | static_cast<VertexId>(staged_vertices_.size());
      staged_vertices_.push_back(
          {Vec3{c[0], c[1], c[2]}, ci[2], BoxMask(ci[0], ci[1], ci[2]), int8_t{-1}});
      for (int s = 0; s < len; ++s) {
        staged_triangles_.push_back({cv, ev[e[s]], ev[e[(s + 1) % len]]});
        staged_edges_.push_back(
            LayerEdges(kEdgeShared, on_face(e[s], e[(s + 1) % len]), kEdgeShared));
      }
    } else {
      for (int s = 1; s + 1 < len; ++s) {
        staged_triangles_.push_back({ev[e[0]], ev[e[s]], ev[e[s + 1]]});
        staged_edges_.push_back(LayerEdges(s == 1 ? on_face(e[0], e[1]) : kEdgeShared,
                                           on_face(e[s], e[s + 1]),
                                           s + 2 == len ? on_face(e[s + 1], e[0]) : kEdgeShared));
      }
    }
  }
}

void LayerExtractor::Finish() {
  if (finished_) return;
  finished_ = true;
  if (config_.nz > 0) return;  // kBoxZMax was set at creation
  if (config_.labels.close) return;  // closed: nothing lies on the box
  for (VertexId v : top_plane_vertices_) {
    if (store_->vertex_alive(v)) {
      store_->set_box_mask(v, store_->box_mask(v) | kBoxZMax);
    }
  }
}

}  // namespace tandem
