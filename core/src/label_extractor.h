// LabelLayers: EXTRACT(k) of a label session (SessionOptions::labels): the interfaces between
// the labels of layer k, by multi-label marching tetrahedra on the Kuhn (Freudenthal)
// subdivision (docs/decisions.md, "Label volumes").
//
// Every grid cube is split into the 6 tetrahedra around its diagonal (0,0,0)-(1,1,1), one per
// order of the axes; the split is the same in every cube, so a cube face (and the plane z = k,
// seen by layers k and k+1) is cut the same way from both sides. A tetrahedron edge whose ends
// carry different labels has a vertex at its midpoint. A tetrahedron with two labels gets the
// marching-tetrahedra piece through those midpoints (1 triangle, or 2 for a 2-2 split); one
// with three or four gets a vertex at its centroid and the cone from it over the interface
// segments of its 4 faces: a face with two labels has the segment between its two midpoints,
// a face with three a vertex at its centroid and the 3 segments from it to its edges'
// midpoints. Each triangle separates two labels and faces away from its `inside` one (the
// one that is not background, else the smaller id). Every label's surface is then the
// 0.5-level set of its indicator (bent through the centroids), a 2-manifold whatever the
// configuration, closed away from the grid's box, or closed there too with `close` (the
// volume padded with background).
//
// The layer is staged into its LayerExtractor's buffers (which owns this and commits the
// layer); the patch of each staged triangle is kept here until the commit gives it the
// store's index. Vertices are shared through maps keyed by their position in twelfths of a
// voxel (every midpoint and centroid is a whole number of them): the points of the plane z = k
// carry over to the next layer, the others live for one layer.
//
// A part of a split session (ExtractorConfig::x_offset, seam_faces) meshes its own cubes of
// the whole grid: the points on a seam plane are its neighbour's too (the same labels there
// give the same points), kSeam, and listed at the commit by position, which both parts agree
// on whichever cube made them first.
#ifndef TANDEM_LABEL_EXTRACTOR_H_
#define TANDEM_LABEL_EXTRACTOR_H_

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/status/status.h"
#include "layer_extractor.h"
#include "mesh_store.h"
#include "tandem/labels.h"
#include "tandem/volume.h"

namespace tandem {

// The label of voxel i of a slice of `dtype` (an integer type). The one place a raw value
// becomes a LabelId: false for a value that is no label (a negative one, then in *refused).
bool LabelOfVoxel(DType dtype, const uint8_t* bytes, size_t i, LabelId* out, int64_t* refused);
// Slice k of an nx x ny label map (rows `stride` voxels apart) as LabelLayers reads it:
// InvalidArgument naming its first voxel that is no label, as LabelLayers::Compute does. A
// split session checks a slice so before any part moves.
absl::Status CheckLabelSlice(SliceValues slice, int64_t nx, int64_t ny, int64_t stride, int64_t k);

class LabelLayers {
 public:
  // The extractor's grid part (nx, ny, nz, x_offset, row_stride, seam_faces) and labels.
  explicit LabelLayers(const ExtractorConfig& config);

  // Slice k's labels into the top plane, and layer k (between slices k-1 and k; with close,
  // slice 0 has background below it) staged into *ex. InvalidArgument for a slice that is no
  // label map (float values, a negative label), the extractor then left as it was.
  absl::Status Compute(SliceValues slice, LayerExtractor* ex);
  // With close, after the last slice: the layer between it and the background above, staged
  // into *ex (false: nothing to do, not closing or done already).
  bool ComputeClosing(LayerExtractor* ex);
  // The commit: the staged triangles `tris` (in staging order) get their store patches, the
  // carried plane points their store ids (staged index -> store id), and `new_seam` (when
  // given) the new seam points of each seam face, by height, then y. The layer's pairs are
  // then forgotten (the store keeps them), met again as they come.
  void Commit(MeshStore* store, std::span<const TriId> tris,
              std::span<const VertexId> staged_to_store,
              std::array<std::vector<VertexId>, 2>* new_seam);
  // After Commit, per committed triangle (`staged`, in staging order, whose new corners are
  // still pending staged indices, of `vertices` staged ones; `tris` their store ids): its
  // LayerEdges, appended to *rules (mesh_store.h: each edge with a new end queued once,
  // the rest left to DELAY's search).
  void EdgeRules(std::span<const std::array<VertexId, 3>> staged, size_t vertices,
                 std::span<const TriId> tris, std::vector<uint8_t>* rules);
  size_t MemoryBytes() const;
  // Between layers (nothing staged): forgets the pairs met so far and their store patches
  // (the store's pairs were compacted), met again as they come.
  void ForgetPairs();

 private:
  using Point = std::array<int64_t, 3>;  // twelfths of a voxel, within the cube
  void ReadSlice(SliceValues slice, std::vector<LabelId>* plane, int64_t k,
                 absl::Status* status) const;
  LabelId Filter(LabelId l) const;
  // Stages the layer between plane z = zb (bottom_) and zb + 1 (top_).
  void EmitLayer(int64_t zb, LayerExtractor* ex);
  void EmitCube(int64_t i, int64_t j, int64_t zb, const LabelId (&l)[8], LayerExtractor* ex);
  VertexId Vertex(const Point& p, LayerExtractor* ex);
  // Triangle (a, b, c) separating the labels of cube corners u and w, whose ends lie on
  // either side of its plane: turned to face away from its inside label.
  void Emit(Point a, Point b, Point c, int u, int w, const LabelId (&l)[8], LayerExtractor* ex);
  size_t Index(int64_t i, int64_t j) const {  // into a padded plane
    return static_cast<size_t>((j + 1) * (nx_ + 2) + (i + 1));
  }

  int64_t nx_, ny_, nz_;
  int64_t x_offset_, row_stride_;
  uint8_t seam_faces_;
  LabelOptions labels_;
  // Slices k-1 and k, padded with one background voxel on every side (read only with close).
  std::vector<LabelId> bottom_, top_;
  bool closed_ = false;  // the closing layer was staged
  // The cube being emitted: its corner (i, j, zb) in twelfths.
  int64_t ox_ = 0, oy_ = 0, oz_ = 0;
  // Vertices by key: the planes z = zb and zb + 1 and the points between.
  absl::flat_hash_map<uint64_t, VertexId> plane_bottom_, plane_top_, inside_;
  // The staged triangles' pairs (indices into pairs_), until the commit.
  std::vector<uint32_t> staged_patch_;
  std::vector<LabelPair> pairs_;
  absl::flat_hash_map<std::pair<LabelId, LabelId>, uint32_t> pair_index_;
  std::vector<uint32_t> store_patch_;  // pairs_ index -> the store's (kInvalid: not yet)
  // The staged points on the seam faces (x = 0, x = nx - 1): z and y in twelfths, staged
  // index.
  struct SeamPoint {
    int64_t z, y;
    uint32_t staged;
  };
  std::array<std::vector<SeamPoint>, 2> seam_;
  // EdgeRules' edges at each new vertex: those of staged vertex v are listed_[listed_at_[v]]
  // up to listed_[listed_end_[v]], each its other end and the triangle edge (3 * staged
  // triangle + k) that queues it.
  struct ListedEdge {
    VertexId other;
    uint32_t edge;
  };
  size_t EdgeListBytes() const;
  std::vector<uint32_t> listed_at_, listed_end_;
  std::vector<ListedEdge> listed_;
};

}  // namespace tandem

#endif  // TANDEM_LABEL_EXTRACTOR_H_
