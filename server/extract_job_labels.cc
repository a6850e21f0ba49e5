// ExtractJob in a label session (SessionConfig.labels): the interface complex cut into one
// surface per label, for the previews and at the end, each sent with its label.
#include <algorithm>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "extract_job_internal.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/common/wire.h"
#include "tandem/eval/label_metrics.h"
#include "tandem/eval/report.h"
#include "tandem/labels.h"
#include "tandem/server/extract_job.h"
#include "tandem/status_macros.h"

namespace tandem::server {

IndexedMesh LabelPreviewMesh(const TandemSession& session, LabelId background,
                             std::vector<uint32_t>* group, std::vector<LabelId>* labels) {
  const std::vector<std::pair<LabelId, IndexedMesh>> surfaces =
      SplitByLabel(session.SnapshotLabeled(), background);
  IndexedMesh all;
  size_t vertices = 0, indices = 0;
  for (const auto& [id, mesh] : surfaces) {
    vertices += mesh.positions.size();
    indices += mesh.indices.size();
  }
  all.positions.reserve(vertices);
  all.indices.reserve(indices);
  group->clear();
  group->reserve(vertices);
  labels->clear();
  for (const auto& [id, mesh] : surfaces) {
    const auto base = static_cast<uint32_t>(all.positions.size());
    all.positions.insert(all.positions.end(), mesh.positions.begin(), mesh.positions.end());
    for (uint32_t v : mesh.indices) all.indices.push_back(base + v);
    group->insert(group->end(), mesh.positions.size(), static_cast<uint32_t>(labels->size()));
    labels->push_back(id);
  }
  return all;
}

absl::Status ExtractJob::FinishLabels() {
  const int64_t triangles = session_->num_triangles();
  // The complex, and its split, in which an interface triangle is in both its labels.
  TANDEM_RETURN_IF_ERROR(
      CheckMemory(3 * SnapshotBytes(triangles), "to copy out the labels' surfaces"));
  LabeledMesh complex = session_->SnapshotLabeled();
  eval::MetricsReport report = eval::MakeReport(*session_, complex.mesh);
  const LabelId background = config_.options.labels.background;
  // The figures of the surfaces as the session made them (tandem extract --labels' own).
  std::vector<eval::LabelMetrics> figures;
  for (const auto& [id, mesh] : SplitByLabel(complex, background)) {
    figures.push_back(eval::MeasureLabel(id, mesh));
  }
  sink_->PostProgress(MakeProgress());
  session_time_ = session_->stats().time;
  session_.reset();
  final_triangles_ = triangles;
  report.peak_rss_bytes = eval::PeakRssBytes();

  // One quantization grid for every label, the complex's vertices snapped onto it once (a
  // corner moved to keep a triangle's area moves in every label alike), so that a vertex two
  // labels share decodes to the same coordinates in both: their interfaces stay one.
  TANDEM_RETURN_IF_ERROR(CheckMemory(EncodeBytes(triangles), "to encode the labels' surfaces"));
  VolumeInfo box = config_.grid;
  box.nz = cursor_.slice;
  const codec::DracoOptions grid = ChunkGrid(box, config_.draco, limits_.max_slices);
  auto t0 = Clock::now();
  {
    codec::DracoOptions snap = grid;
    snap.compression_level = 0;  // keeps the vertices' order
    absl::StatusOr<std::string> bytes = codec::EncodeDraco(complex.mesh, snap);
    absl::StatusOr<IndexedMesh> snapped =
        bytes.ok() ? codec::DecodeDraco(*bytes) : absl::StatusOr<IndexedMesh>(bytes.status());
    if (!snapped.ok() || snapped->positions.size() != complex.mesh.positions.size()) {
      return absl::InternalError(absl::StrCat(
          "snapping the labels' vertices onto one grid: ",
          snapped.ok() ? "the vertex count changed" : std::string(snapped.status().message())));
    }
    complex.mesh.positions = std::move(snapped->positions);
  }
  encode_s_ += SecondsSince(t0);
  const std::vector<std::pair<LabelId, IndexedMesh>> surfaces = SplitByLabel(complex, background);
  complex = {};

  std::vector<v1::ExtractResponse> out;
  for (size_t i = 0; i < surfaces.size(); ++i) {
    const auto& [id, mesh] = surfaces[i];
    TANDEM_RETURN_IF_ERROR(CheckMemory(EncodeBytes(static_cast<int64_t>(mesh.num_triangles())),
                                       absl::StrCat("to encode label ", id)));
    t0 = Clock::now();
    // On the grid already: no corner moves again.
    const std::vector<uint8_t> fixed(mesh.num_vertices(), 1);
    absl::StatusOr<std::string> bytes = codec::EncodeDraco(mesh, grid, {}, fixed);
    encode_s_ += SecondsSince(t0);
    if (!bytes.ok()) {
      return absl::InternalError(absl::StrCat(
          "encoding label ", id, "'s surface: ", std::string(bytes.status().message())));
    }
    for (v1::FinalMesh* m : AppendFinalMesh(*bytes, mesh, &out)) {
      m->set_surface(static_cast<int32_t>(i));
      m->set_label(id);
    }
    v1::FinalMetrics* metrics = out.emplace_back().mutable_final_metrics();
    common::LabelMetricsToProto(figures[i], metrics);
    metrics->set_surface(static_cast<int32_t>(i));
  }
  PostMetrics(report, std::move(out));
  return absl::OkStatus();
}

absl::Status ExtractJob::PostLabelChunks(const SealedChunk& part, IndexedMesh complex,
                                         const codec::MovedCorners& moved) {
  std::vector<Vec3>& positions = complex.positions;
  // The complex's corners where its encoding put them: each label's chunk then keeps every
  // corner fixed, so that a vertex two labels share decodes to one grid point in both.
  for (const auto& [v, at] : moved) positions[v] = at;
  const LabelId background = config_.options.labels.background;
  const std::vector<LabelSide> sides =
      LabelSides(part.patch, part.pairs, complex.num_triangles(), background);
  constexpr uint32_t kUnused = ~uint32_t{0};
  std::vector<uint32_t> local(positions.size(), kUnused);
  for (size_t begin = 0; begin < sides.size();) {
    const LabelId label = sides[begin].label;
    size_t end = begin;
    while (end < sides.size() && sides[end].label == label) ++end;
    SealedChunk c;
    c.index = part.index;
    c.first_slice = part.first_slice;
    c.last_slice = part.last_slice;
    IndexedMesh mesh;
    mesh.indices.reserve(3 * (end - begin));
    for (size_t s = begin; s < end; ++s) {
      const uint32_t* tri = complex.indices.data() + 3 * size_t{sides[s].tri};
      const uint32_t corners[3] = {tri[0], sides[s].reversed ? tri[2] : tri[1],
                                   sides[s].reversed ? tri[1] : tri[2]};
      for (uint32_t v : corners) {
        if (local[v] == kUnused) {
          local[v] = static_cast<uint32_t>(mesh.positions.size());
          mesh.positions.push_back(positions[v]);
          c.ids.push_back(part.ids[v]);
        }
        mesh.indices.push_back(local[v]);
      }
    }
    for (size_t s = begin; s < end; ++s) {  // reset for the next label
      const uint32_t* tri = complex.indices.data() + 3 * size_t{sides[s].tri};
      for (int k = 0; k < 3; ++k) local[tri[k]] = kUnused;
    }
    begin = end;
    const auto t0 = Clock::now();
    const std::vector<uint8_t> fixed(mesh.num_vertices(), 1);
    absl::StatusOr<std::string> bytes = codec::EncodeDraco(mesh, chunk_draco_, c.ids, fixed);
    encode_s_ += SecondsSince(t0);
    if (!bytes.ok()) {
      return absl::InternalError(absl::StrCat("encoding sealed chunk ", chunks_sent_, " (label ",
                                              label, "): ", std::string(bytes.status().message())));
    }
    v1::SealedChunk out;
    out.set_index(chunks_sent_);
    out.set_first_slice(c.first_slice);
    out.set_last_slice(c.last_slice);
    out.set_draco(*std::move(bytes));
    out.set_triangles(static_cast<int64_t>(mesh.num_triangles()));
    out.set_vertices(static_cast<int64_t>(mesh.num_vertices()));
    out.set_label(label);
    sealed_posted_ += out.triangles();
    ++chunks_sent_;
    chunk_bytes_ += static_cast<int64_t>(out.draco().size());
    sink_->PostChunk(std::move(out));
    c.positions = std::move(mesh.positions);
    c.indices = std::move(mesh.indices);
    label_chunk_bytes_ += sizeof(SealedChunk) + c.positions.capacity() * sizeof(Vec3) +
                          (c.indices.capacity() + c.ids.capacity()) * sizeof(uint32_t);
    label_chunks_[label].push_back(std::move(c));
  }
  ReportOwnBytes();
  return CheckMemory(0, "after a sealed chunk");
}

void ExtractJob::AppendSealedLabelMetrics(std::vector<v1::ExtractResponse>* out) {
  int32_t surface = 0;
  for (auto& [id, chunks] : label_chunks_) {
    const IndexedMesh mesh = WeldChunks(chunks);
    chunks = {};
    v1::FinalMetrics* metrics = out->emplace_back().mutable_final_metrics();
    common::LabelMetricsToProto(eval::MeasureLabel(id, mesh), metrics);
    metrics->set_surface(surface++);
  }
  label_chunks_.clear();
  label_chunk_bytes_ = 0;
}

}  // namespace tandem::server
