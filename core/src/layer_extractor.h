// LayerExtractor: marching cubes one layer at a time (the paper's EXTRACT(k): §2, "Surface
// extraction", and §3, "Algorithm prototype").
//
// AddSlice(k) consumes slice k and emits layer k into a MeshStore: the vertices on slice k's
// x- and y-edges, the vertices on the z-edges between slices k-1 and k, and the triangles of
// the cubes between them. Vertices on shared grid edges are created exactly once: the ids of
// the top plane's edges are kept (plane caches) and become the next layer's bottom, so the
// mesh is welded with no hashing. Memory is O(nx*ny) (values, sign bits and 4 bytes a 64-voxel
// word) plus O(crossed edges) plus the mesh.
//
// Cases come from mc_tables.h: ambiguous faces are resolved by the asymptotic decider, which
// both cubes sharing the face evaluate identically, so the union of all layers is an
// orientable 2-manifold, closed away from the grid's box. Triangles are counter-clockwise
// seen from where F < C0 (normals point from high to low values).
#ifndef TANDEM_LAYER_EXTRACTOR_H_
#define TANDEM_LAYER_EXTRACTOR_H_

#include <array>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "mesh_store.h"
#include "meter.h"
#include "tandem/geometry.h"
#include "tandem/labels.h"
#include "tandem/types.h"
#include "tandem/volume.h"

// Cloned for CPUs with POPCNT, picked once at load: a crossed edge's id is found by counting
// the crossings below it, which the baseline x86-64 target compiles to a library call. Clang
// wants the attribute on the declaration and the definition alike, and clang 14 compiles a
// call from another file as a call to the resolver (decision 68): call it from
// layer_extractor.cc only.
#if defined(__x86_64__) && defined(__ELF__)
#define TANDEM_POPCNT_CLONES __attribute__((target_clones("popcnt", "default")))
#else
#define TANDEM_POPCNT_CLONES
#endif

namespace tandem {

// A slice's values as they arrived, x fastest: float32 (4-byte aligned), or integers read as
// they are scanned (every uint8, uint16 and int16 value is exact in float). So the session's
// slices in flight hold a 16-bit scan in 2 bytes a voxel, not 4.
struct SliceValues {
  const uint8_t* bytes = nullptr;
  DType dtype = DType::kFloat32;

  // The types read as they are; TandemSession::AddSliceBytes converts any other to float32.
  static constexpr bool ScannedAsIs(DType t) {
    return t == DType::kUInt8 || t == DType::kUInt16 || t == DType::kInt16 || t == DType::kFloat32;
  }
  static SliceValues Floats(const float* values) {
    return {reinterpret_cast<const uint8_t*>(values), DType::kFloat32};
  }
  // The same slice from column x on.
  SliceValues From(int64_t x) const {
    return {bytes + static_cast<size_t>(x) * DTypeSize(dtype), dtype};
  }
};

struct ExtractorConfig {
  int64_t nx = 0, ny = 0;
  int64_t nz = 0;  // 0 when unknown (streaming): Finish() then marks the top of the box
  std::array<double, 3> spacing{1, 1, 1};
  std::array<double, 3> origin{0, 0, 0};
  double iso = 0;
  // A part of a wider grid (split sessions, tandem.h): this extractor's column i is column
  // i + x_offset of the whole grid, rows of the slices given to it are row_stride values
  // apart (0: nx), and the faces in seam_faces (kBoxXMin, kBoxXMax) are planes shared with
  // the neighbouring parts, not the box: the vertices on their y- and z-edges get kSeam
  // (listed by CommitLayer) instead of a box bit.
  int64_t x_offset = 0;
  int64_t row_stride = 0;
  uint8_t seam_faces = 0;
  // How far from 0 the written positions of slice k's points may lie, in units of the
  // smallest spacing: at most reach + k * reach_per_slice (the whole grid's, in the frame the
  // outputs are written in), which sets the edge offset (EdgeOffset, tandem/geometry.h).
  double reach = 0, reach_per_slice = 0;
  // A label session (labels.enabled): the layers come from LabelLayers (label_extractor.h),
  // through this extractor's staging and commit; `iso` and the offsets are not used.
  LabelOptions labels{};
};

class LabelLayers;

class LayerExtractor {
 public:
  // `store` must outlive the extractor.
  LayerExtractor(const ExtractorConfig& config, MeshStore* store);
  ~LayerExtractor();

  // Consumes the next slice (nx*ny values, x fastest): ComputeLayer then CommitLayer.
  // Appends the ids of the triangles and vertices it created to *new_tris / *new_verts when
  // given. Rejects non-finite values and slices past nz (when nz is known) with
  // InvalidArgument; the store and the extractor are then left unchanged.
  absl::Status AddSlice(const float* values, std::vector<TriId>* new_tris = nullptr,
                        std::vector<VertexId>* new_verts = nullptr);

  // The two halves of AddSlice, so extraction of layer k can run on another thread while
  // the owner simplifies layer k-1. ComputeLayer reads only the extractor's own state (it
  // never touches the store): the new layer is staged in pending buffers. CommitLayer adds
  // it to the store. Between the two, the store may be changed by anyone except in the
  // vertices of the previous top plane (the front, which the schedules never touch).
  absl::Status ComputeLayer(SliceValues values);
  absl::Status ComputeLayer(const float* values) { return ComputeLayer(SliceValues::Floats(values)); }
  // `new_seam` gets the new kSeam vertices appended of each seam face (index 0: x = 0, 1: x = nx-1)
  // in a canonical order (y-edges, then z-edges, each by ascending y): the neighbouring part
  // lists the same grid edges in the same order, which pairs the copies.
  // `new_edges` gets, per new triangle (in new_tris's order), what DELAY does with each of its
  // edges (LayerEdges, mesh_store.h): the layer's topology, which the extractor knows and the
  // queues would otherwise search the store for.
  void CommitLayer(std::vector<TriId>* new_tris = nullptr,
                   std::vector<VertexId>* new_verts = nullptr,
                   std::array<std::vector<VertexId>, 2>* new_seam = nullptr,
                   std::vector<uint8_t>* new_edges = nullptr);

  // Declares the last slice added to be the top of the box: its plane vertices get the
  // kBoxZMax bit. Called by the owner when the stream ends (a no-op beyond that).
  void Finish();
  // A label session with labels.close, once the last slice is in: stages the layer between
  // it and the background above (CommitLayer adds it). False when there is none.
  bool ComputeClosingLayer();
  // A sealed label session, between layers: once the store's label pairs have doubled since
  // the last time, drops those no live triangle holds (MeshStore::CompactPairs), and this
  // extractor's own, so that a stream of ever new labels holds the front's pairs, not all.
  void CompactLabelPairs();

  // What the plane caches of an nx x ny extractor take once the first slice has arrived: the
  // two value planes, their sign bits and the five crossed-edge indices' word counts.
  static size_t PlaneCacheBytes(int64_t nx, int64_t ny, DType dtype);
  // What this extractor's plane caches take: PlaneCacheBytes for slices of `planned` until a
  // slice came, then as they hold the slices' values (in their own type: Plane).
  size_t PlaneBytes(DType planned) const;
  // What the crossed edges' ids take (capacity): 4 bytes a crossing of the two slices' planes
  // and the layer's z-edges. Not while ComputeLayer runs on another thread.
  size_t EdgeIdBytes() const;
  // What the staged layer's arrays hold (capacity): about 64 bytes a vertex of the largest
  // recent layer. Not while ComputeLayer runs on another thread.
  size_t StagingBytes() const;

  // The owner's budget account (meter.h; null: none), reported to after every row that
  // ComputeLayer scans, with the staged layer counted as it will be once committed: `vertex`
  // and `triangle` bytes each (the store's records, the quadrics), so that a layer too large
  // for the budget stops while it is staged, not after it has grown the store.
  void set_account(Meter::Account* account, size_t vertex, size_t triangle) {
    account_ = account;
    commit_vertex_bytes_ = vertex;
    commit_triangle_bytes_ = triangle;
  }
  // What the account is told: PlaneBytes(dtype) + EdgeIdBytes() + StagingBytes() and the
  // staged layer once committed. Not while ComputeLayer runs on another thread.
  size_t HeldBytes(DType dtype) const;

  int64_t slices_done() const { return slices_done_; }
  int64_t crossed_cubes() const { return crossed_cubes_; }
  const ExtractorConfig& config() const { return config_; }

  // Staged vertex ids carry this tag until CommitLayer maps them to store ids.
  static constexpr VertexId kPending = 0x80000000u;
  static bool IsPending(VertexId v) { return v != kInvalid && (v & kPending); }

 private:
  friend class LabelLayers;  // stages its layers here
  void AllocatePlanes();  // the plane caches, on the first ComputeLayer
  // After a row of ComputeLayer of slice k: once kCheckEvery more vertices and triangles are
  // staged, reports to the account (throws SessionStop). A compare a row otherwise.
  void Checkpoint(DType dtype, int64_t k) {
    const size_t staged = staged_vertices_.size() + staged_triangles_.size();
    if (account_ == nullptr || staged < check_at_) return;
    check_at_ = staged + kCheckEvery;
    account_->Hold(HeldBytes(dtype), "extracting slice", k);
  }
  static constexpr size_t kCheckEvery = 2048;  // about 150 KiB once committed

  // Index-space point on the grid edge from index point p (value fp) along `axis` to the
  // next grid point (value fq); fp, fq relative to the iso-value, exactly one >= 0; at
  // least `offset` (a fraction of the edge: Offsets) from both ends. Index space is the whole
  // grid's (x from x_offset on), so that a part computes the very positions an unsplit
  // extraction would.
  static void EdgePoint(double pi, double pj, double pk, int axis, double fp, double fq,
                        double offset, double idx[3]);
  // The edge offset of the edges in slice k and of the z-edges below it, per axis as a
  // fraction of the edge: EdgeOffset smallest spacings.
  std::array<double, 3> Offsets(int64_t k) const;
  // Stages a vertex at an index-space point; returns its pending id. seam_face: 0 or 1 for a
  // y- or z-edge on the seam face x = 0 or x = nx-1, else -1.
  VertexId StageVertex(const double idx[3], int seam_face = -1);
  uint8_t BoxMask(double i, double j, double k) const;
  int SeamFace(int64_t i) const;  // of a y- or z-edge in column i (see StageVertex)
  // Value relative to the iso-value: every edge point and face decision uses this one
  // expression, so the cubes sharing an edge or a face agree bit for bit.
  double Rel(float v) const { return static_cast<double>(v) - config_.iso; }
  // Copies the n values of a row to dst and their inside bits to signs (bits past n
  // cleared); false if a value is not finite. The integer rows (src: n values of T, not
  // necessarily aligned) are always finite.
  bool ScanRow(const float* src, int64_t n, float* dst, uint64_t* signs) const;
  template <typename T>
  void ScanIntegerRow(const uint8_t* src, int64_t n, uint16_t* dst, uint64_t* signs) const;
  // Stages the triangles (and loop centroids) of crossed cube (i, j) of the current layer,
  // whose bottom slice is at height kz - 1.
  TANDEM_POPCNT_CLONES void EmitCube(int64_t i, int64_t j, double kz);
  Vec3 Physical(double i, double j, double k) const {
    return {config_.origin[0] + i * config_.spacing[0], config_.origin[1] + j * config_.spacing[1],
            config_.origin[2] + k * config_.spacing[2]};
  }

  ExtractorConfig config_;
  MeshStore* store_;
  int64_t slices_done_ = 0;
  int64_t crossed_cubes_ = 0;
  std::array<double, 3> offset_bottom_{}, offset_top_{};  // Offsets(k - 1), Offsets(k), layer k
  bool finished_ = false;

  // Bottom (k-1) and top (k) slices: their values as given, and their signs bit-packed per
  // row (words_ words of 64 voxels; bit i of row j is set iff voxel (i, j) is inside,
  // Rel(value) >= 0). Whole words of these masks find the crossed edges and cubes, so the
  // per-voxel work is one float compare and the rest is spent where the surface passes.
  int64_t words_ = 0;
  float inside_from_ = 0;  // for finite v: Rel(v) >= 0 iff v >= inside_from_
  // A slice's values in its own type: floats for float input, and 16 bits for 8- and 16-bit
  // integers (a 16-bit value's bits; a byte widened), read back as the float it converts to
  // exactly, since floats for every type would double the planes of a 16-bit stream
  // (docs/decisions.md 18).
  struct Plane {
    DType dtype = DType::kFloat32;
    std::vector<float> f;      // kFloat32
    std::vector<uint16_t> h;   // kUInt8, kUInt16, kInt16
    void Prepare(DType type, size_t n);  // for n values of `type`
    float operator[](size_t i) const {
      switch (dtype) {
        case DType::kUInt8:
        case DType::kUInt16: return static_cast<float>(h[i]);
        case DType::kInt16: return static_cast<float>(static_cast<int16_t>(h[i]));
        case DType::kFloat32:
        case DType::kInt8:
        case DType::kUInt32:
        case DType::kInt32:
        case DType::kUInt64:
        case DType::kInt64:
          break;  // held as float32 (SliceValues::ScannedAsIs)
      }
      return f[i];
    }
  };
  Plane v_bottom_, v_top_;
  std::vector<uint64_t> s_bottom_, s_top_;
  std::vector<uint64_t> any_in_, all_in_;  // scratch: OR and AND of a row pair's 4 rows
  // The vertex ids of a family of crossed grid edges: x- or y-edges of the bottom (k-1) or
  // top (k) slice, z-edges of the current layer. Only crossed edges have a vertex, so only
  // they are listed, in ascending (j, i) order (the order they are staged in); edge (i, j)
  // is found by its rank, the crossings of its row's earlier words (first) plus those below
  // it in its word, which the slices' sign bits give again (XCrossings, YCrossings,
  // ZCrossings). 4 bytes a crossing and 4 a word, where a dense cache took 4 a grid edge: 20
  // MB a 512 x 2048 part, most of them kInvalid even on a dense surface.
  struct CrossedEdges {
    std::vector<uint32_t> first;  // per row j and word w, at j * words_ + w
    std::vector<VertexId> ids;
  };
  CrossedEdges xe_bottom_, xe_top_, ye_bottom_, ye_top_, ze_;
  // The crossed x- and y-edges of a slice in word w of row j (signs: the slice's bit rows),
  // the crossed z-edges between two slices.
  uint64_t XCrossings(const uint64_t* signs, int64_t j, int64_t w) const;
  uint64_t YCrossings(const uint64_t* signs, int64_t j, int64_t w) const;
  uint64_t ZCrossings(int64_t j, int64_t w) const;
  // The id of edge (i, j) of a family whose crossings in word i / 64 of row j are `crossings`
  // (kInvalid if it is not crossed).
  VertexId EdgeId(const CrossedEdges& edges, int64_t i, int64_t j, uint64_t crossings) const;
  std::vector<VertexId> top_plane_vertices_;  // for Finish()

  // Staged layer (ComputeLayer -> CommitLayer).
  struct StagedVertex {
    Vec3 pos;
    double height;
    uint8_t box_mask;
    int8_t seam_face;  // see StageVertex
  };
  std::vector<StagedVertex> staged_vertices_;
  std::vector<std::array<VertexId, 3>> staged_triangles_;
  std::vector<uint8_t> staged_edges_;  // per staged triangle: its LayerEdges
  std::vector<VertexId> staged_to_store_;
  std::pair<size_t, size_t> last_staged_{0, 0};  // the last layer's vertices and triangles
  int32_t staged_layer_ = 0;
  bool staged_ = false;
  Meter::Account* account_ = nullptr;
  size_t commit_vertex_bytes_ = 0, commit_triangle_bytes_ = 0;
  size_t check_at_ = 0;  // staged elements at the next Checkpoint
  std::unique_ptr<LabelLayers> labels_;  // a label session's layers (null: iso-surface)
  size_t compact_pairs_at_ = 0;          // CompactLabelPairs: the store's pairs, at the next
};

}  // namespace tandem

#endif  // TANDEM_LAYER_EXTRACTOR_H_
