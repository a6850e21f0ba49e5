#include "tandem/layer_extractor.h"

#include <cassert>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "tandem/mc_tables.h"

namespace tandem {

LayerExtractor::LayerExtractor(const ExtractorConfig& config, MeshStore* store)
    : config_(config), store_(store) {
  const size_t n = static_cast<size_t>(config.nx * config.ny);
  f_bottom_.resize(n);
  f_top_.resize(n);
  xe_bottom_.assign(static_cast<size_t>((config.nx - 1) * config.ny), kInvalid);
  xe_top_ = xe_bottom_;
  ye_bottom_.assign(static_cast<size_t>(config.nx * (config.ny - 1)), kInvalid);
  ye_top_ = ye_bottom_;
  ze_.assign(n, kInvalid);
}

uint8_t LayerExtractor::BoxMask(double i, double j, double k) const {
  uint8_t m = 0;
  if (i == 0) m |= kBoxXMin;
  if (i == static_cast<double>(config_.nx - 1)) m |= kBoxXMax;
  if (j == 0) m |= kBoxYMin;
  if (j == static_cast<double>(config_.ny - 1)) m |= kBoxYMax;
  if (k == 0) m |= kBoxZMin;
  if (config_.nz > 0 && k == static_cast<double>(config_.nz - 1)) m |= kBoxZMax;
  return m;
}

void LayerExtractor::EdgePoint(double pi, double pj, double pk, int axis, double fp, double fq,
                               double idx[3]) {
  // fp and fq have different signs (one >= 0, one < 0), so the denominator is never 0 and
  // t lies in [0, 1]; t = 0 or 1 exactly when a grid value equals the iso-value. The cube
  // loop recomputes points with this same function, so they match bit for bit.
  const double t = fp / (fp - fq);
  idx[0] = pi;
  idx[1] = pj;
  idx[2] = pk;
  idx[axis] += t;
}

VertexId LayerExtractor::StageVertex(const double idx[3]) {
  const VertexId id = kPending | static_cast<VertexId>(staged_vertices_.size());
  staged_vertices_.push_back(
      {Physical(idx[0], idx[1], idx[2]), idx[2], BoxMask(idx[0], idx[1], idx[2])});
  return id;
}

absl::Status LayerExtractor::AddSlice(const float* values, std::vector<TriId>* new_tris,
                                      std::vector<VertexId>* new_verts) {
  if (absl::Status st = ComputeLayer(values); !st.ok()) return st;
  CommitLayer(new_tris, new_verts);
  return absl::OkStatus();
}

void LayerExtractor::CommitLayer(std::vector<TriId>* new_tris, std::vector<VertexId>* new_verts) {
  if (!staged_) return;
  staged_ = false;
  staged_to_store_.resize(staged_vertices_.size());
  for (size_t i = 0; i < staged_vertices_.size(); ++i) {
    const StagedVertex& sv = staged_vertices_[i];
    const VertexId v = store_->AddVertex(sv.pos, sv.height, staged_layer_, sv.box_mask);
    assert(v < kPending);
    staged_to_store_[i] = v;
    if (new_verts) new_verts->push_back(v);
  }
  auto resolve = [this](VertexId v) { return IsPending(v) ? staged_to_store_[v & ~kPending] : v; };
  for (const auto& tri : staged_triangles_) {
    const TriId t = store_->AddTriangle(resolve(tri[0]), resolve(tri[1]), resolve(tri[2]));
    if (new_tris) new_tris->push_back(t);
  }
  // The top plane's cached ids become the next layer's bottom: store ids from now on.
  for (VertexId& v : xe_top_) v = resolve(v);
  for (VertexId& v : ye_top_) v = resolve(v);
  for (VertexId& v : top_plane_vertices_) v = resolve(v);
  staged_vertices_.clear();
  staged_triangles_.clear();
}

absl::Status LayerExtractor::ComputeLayer(const float* values) {
  const int64_t nx = config_.nx, ny = config_.ny;
  const int64_t k = slices_done_;
  if (staged_) return absl::FailedPreconditionError("CommitLayer the previous layer first");
  if (finished_ || (config_.nz > 0 && k >= config_.nz)) {
    return absl::InvalidArgumentError(
        absl::StrCat("slice ", k, " is past the end of the volume (nz = ", config_.nz, ")"));
  }
  // Validate before touching the store, so a bad slice leaves the mesh as it was.
  const size_t n = static_cast<size_t>(nx * ny);
  for (size_t idx = 0; idx < n; ++idx) {
    if (!std::isfinite(values[idx])) {
      return absl::InvalidArgumentError(absl::StrCat(
          "slice ", k, ": value at (x=", idx % nx, ", y=", idx / nx, ") is ", values[idx],
          "; every voxel must be a finite number"));
    }
  }
  std::swap(f_bottom_, f_top_);
  std::swap(xe_bottom_, xe_top_);
  std::swap(ye_bottom_, ye_top_);
  for (size_t idx = 0; idx < n; ++idx) f_top_[idx] = static_cast<double>(values[idx]) - config_.iso;

  staged_ = true;
  staged_layer_ = static_cast<int32_t>(k);
  const double kz = static_cast<double>(k);
  double idx3[3];
  top_plane_vertices_.clear();
  // Plane vertices of slice k: x-edges then y-edges.
  for (int64_t j = 0; j < ny; ++j) {
    for (int64_t i = 0; i + 1 < nx; ++i) {
      const double a = f_top_[j * nx + i], b = f_top_[j * nx + i + 1];
      VertexId& v = xe_top_[j * (nx - 1) + i];
      v = kInvalid;
      if ((a >= 0) != (b >= 0)) {
        EdgePoint(double(i), double(j), kz, 0, a, b, idx3);
        v = StageVertex(idx3);
      }
      if (v != kInvalid) top_plane_vertices_.push_back(v);
    }
  }
  for (int64_t j = 0; j + 1 < ny; ++j) {
    for (int64_t i = 0; i < nx; ++i) {
      const double a = f_top_[j * nx + i], b = f_top_[(j + 1) * nx + i];
      VertexId& v = ye_top_[j * nx + i];
      v = kInvalid;
      if ((a >= 0) != (b >= 0)) {
        EdgePoint(double(i), double(j), kz, 1, a, b, idx3);
        v = StageVertex(idx3);
      }
      if (v != kInvalid) top_plane_vertices_.push_back(v);
    }
  }
  ++slices_done_;
  if (k == 0) return absl::OkStatus();  // slice 0 has no layer below it

  // z-edges between slices k-1 and k.
  for (int64_t idx = 0; idx < nx * ny; ++idx) {
    const double a = f_bottom_[idx], b = f_top_[idx];
    ze_[idx] = kInvalid;
    if ((a >= 0) != (b >= 0)) {
      EdgePoint(double(idx % nx), double(idx / nx), kz - 1, 2, a, b, idx3);
      ze_[idx] = StageVertex(idx3);
    }
    if (ze_[idx] != kInvalid && b == 0) top_plane_vertices_.push_back(ze_[idx]);
  }

  // Cubes of layer k.
  VertexId ev[12];
  double f[8];
  for (int64_t j = 0; j + 1 < ny; ++j) {
    for (int64_t i = 0; i + 1 < nx; ++i) {
      const int64_t p00 = j * nx + i, p10 = p00 + 1, p01 = p00 + nx, p11 = p01 + 1;
      f[0] = f_bottom_[p00]; f[1] = f_bottom_[p10]; f[2] = f_bottom_[p01]; f[3] = f_bottom_[p11];
      f[4] = f_top_[p00];    f[5] = f_top_[p10];    f[6] = f_top_[p01];    f[7] = f_top_[p11];
      uint8_t config = 0;
      for (int c = 0; c < 8; ++c) config |= static_cast<uint8_t>((f[c] >= 0) << c);
      if (config == 0 || config == 255) continue;
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
      const int64_t xb = j * (nx - 1) + i, yb = j * nx + i;
      ev[0] = xe_bottom_[xb];  ev[1] = xe_bottom_[xb + nx - 1];
      ev[2] = xe_top_[xb];     ev[3] = xe_top_[xb + nx - 1];
      ev[4] = ye_bottom_[yb];  ev[5] = ye_bottom_[yb + 1];
      ev[6] = ye_top_[yb];     ev[7] = ye_top_[yb + 1];
      ev[8] = ze_[p00]; ev[9] = ze_[p10]; ev[10] = ze_[p01]; ev[11] = ze_[p11];
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
            EdgePoint(double(i + (c0 & 1)), double(j + ((c0 >> 1) & 1)), kz - 1 + ((c0 >> 2) & 1),
                      axis, f[c0], f[c1], p);
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
          staged_vertices_.push_back({Vec3{c[0], c[1], c[2]}, ci[2], BoxMask(ci[0], ci[1], ci[2])});
          for (int s = 0; s < len; ++s) {
            staged_triangles_.push_back({cv, ev[e[s]], ev[e[(s + 1) % len]]});
          }
        } else {
          for (int s = 1; s + 1 < len; ++s) {
            staged_triangles_.push_back({ev[e[0]], ev[e[s]], ev[e[s + 1]]});
          }
        }
      }
    }
  }
  return absl::OkStatus();
}

void LayerExtractor::Finish() {
  if (finished_) return;
  finished_ = true;
  if (config_.nz > 0) return;  // kBoxZMax was set at creation
  for (VertexId v : top_plane_vertices_) {
    if (store_->vertex_alive(v)) {
      store_->set_box_mask(v, store_->box_mask(v) | kBoxZMax);
    }
  }
}

}  // namespace tandem
