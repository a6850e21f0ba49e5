// What the files of ExtractJob share: the clock, the byte estimates its memory checks use, the
// sink of a surface, and the helpers of more than one of its files.
#ifndef TANDEM_SERVER_EXTRACT_JOB_INTERNAL_H_
#define TANDEM_SERVER_EXTRACT_JOB_INTERNAL_H_

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "tandem/codec/draco_codec.h"
#include "tandem/server/extract_job.h"
#include "tandem/v1/tandem.pb.h"
#include "tandem/volume.h"

namespace tandem::server {

using Clock = std::chrono::steady_clock;
inline double SecondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// What a snapshot of a mesh of `triangles` triangles and its Draco encoding take at their
// peak, on top of the session: the IndexedMesh (24 bytes a vertex and 12 a triangle, about
// 24 a triangle), Draco's encoder (its own mesh, corner table and attribute buffers: 67 to
// 99 bytes a triangle measured at 0.1 to 0.6 M triangles, quantization 16, level 7) and
// its output (under 4). Rounded up to 160.
inline size_t EncodeBytes(int64_t triangles) { return static_cast<size_t>(triangles) * 160; }
inline size_t SnapshotBytes(int64_t triangles) { return static_cast<size_t>(triangles) * 32; }
// The distances of compute_distances: the reference's snapshot (about 24 bytes a triangle)
// and the BVH over it (boxes, centroids and a permutation: about 80), rounded up.
inline size_t DistanceBytes(int64_t reference_triangles) {
  return static_cast<size_t>(reference_triangles) * 128;
}

// One quantization grid for every chunk of a session (extract_job_output.cc).
codec::DracoOptions ChunkGrid(const VolumeInfo& g, codec::DracoOptions o, int64_t max_slices);

// What a child job posts, tagged with its surface and passed on through the parent's
// sink (none while the parent is detached: nothing is handled then, so nothing is lost).
class ExtractJob::SurfaceSink final : public JobSink {
 public:
  SurfaceSink(ExtractJob* parent, int surface) : parent_(parent), surface_(surface) {}
  void PostProgress(v1::Progress progress) override {
    parent_->surface_progress_[surface_] = std::move(progress);
    if (parent_->sink_) parent_->sink_->PostProgress(parent_->SumProgress());
  }
  void PostPreview(v1::Preview preview) override {
    preview.set_surface(surface_);
    if (parent_->sink_) parent_->sink_->PostPreview(std::move(preview));
  }
  bool PreviewPending() const override {
    return parent_->sink_ != nullptr && parent_->sink_->PreviewPending();
  }
  void PostFinal(std::vector<v1::ExtractResponse> messages) override {
    for (v1::ExtractResponse& m : messages) {
      if (m.has_final_mesh()) m.mutable_final_mesh()->set_surface(surface_);
      if (m.has_final_metrics()) m.mutable_final_metrics()->set_surface(surface_);
      parent_->surface_final_.push_back(std::move(m));
    }
  }
  void PostChunk(v1::SealedChunk chunk) override {
    chunk.set_surface(surface_);
    chunk.set_index(parent_->chunks_sent_++);
    if (parent_->sink_) parent_->sink_->PostChunk(std::move(chunk));
  }

 private:
  ExtractJob* parent_;
  int surface_;
};

// Appends `all` (the Draco bytes of `mesh`) to `out` as FinalMesh chunks, which it returns
// (the messages are in `out`: pointers valid until it grows).
std::vector<v1::FinalMesh*> AppendFinalMesh(const std::string& all, const IndexedMesh& mesh,
                                            std::vector<v1::ExtractResponse>* out);

// A label session's preview mesh: every label's surface (SplitByLabel) one after the other,
// with `group` the index into `labels` of each vertex's label.
IndexedMesh LabelPreviewMesh(const TandemSession& session, LabelId background,
                             std::vector<uint32_t>* group, std::vector<LabelId>* labels);

// "a SessionConfig", "an End", ...: the message's kind, for errors.
const char* KindName(const v1::ExtractRequest& r);

}  // namespace tandem::server

#endif  // TANDEM_SERVER_EXTRACT_JOB_INTERNAL_H_
