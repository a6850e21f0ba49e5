// ExtractJob in a label session (SessionConfig.labels): the interface complex cut into one
// surface per label, for the previews and at the end, each sent with its label.
#include <algorithm>
#include <array>
#include <string>
#include <utility>
#include <vector>

#include "absl/container/flat_hash_map.h"
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

absl::Status ExtractJob::PostLabelChunks(SealedChunk part, IndexedMesh complex,
                                         const codec::MovedCorners& moved, std::string bytes) {
  // The pairs go in the order the buffer decodes its triangles, which only decoding tells:
  // each decoded triangle is found by its corners' ids (rotated to start at the least, so
  // orientation tells a triangle from its reverse; equal ones are alike whichever is taken).
  auto t0 = Clock::now();
  std::vector<uint32_t> decoded_ids;
  absl::StatusOr<IndexedMesh> decoded = codec::DecodeDraco(bytes, &decoded_ids);
  if (!decoded.ok() || decoded->num_triangles() != complex.num_triangles()) {
    return absl::InternalError(absl::StrCat(
        "decoding sealed chunk ", chunks_sent_, " to order its label pairs: ",
        decoded.ok() ? "the triangle count changed" : std::string(decoded.status().message())));
  }
  using Corners = std::array<uint32_t, 3>;
  auto key = [](uint32_t a, uint32_t b, uint32_t c) {
    return a <= b && a <= c ? Corners{a, b, c} : b <= c ? Corners{b, c, a} : Corners{c, a, b};
  };
  const size_t nt = complex.num_triangles();
  absl::flat_hash_map<Corners, uint32_t> first;  // the first triangle of each key
  std::vector<uint32_t> next(nt, kInvalid);      // the next with the same key
  first.reserve(nt);
  for (size_t t = nt; t-- > 0;) {
    const uint32_t* v = &complex.indices[3 * t];
    auto [it, fresh] = first.try_emplace(key(part.ids[v[0]], part.ids[v[1]], part.ids[v[2]]),
                                         static_cast<uint32_t>(t));
    if (!fresh) {
      next[t] = it->second;
      it->second = static_cast<uint32_t>(t);
    }
  }
  std::vector<uint32_t> patch(nt);
  for (size_t t = 0; t < nt; ++t) {
    const uint32_t* v = &decoded->indices[3 * t];
    auto it = first.find(key(decoded_ids[v[0]], decoded_ids[v[1]], decoded_ids[v[2]]));
    if (it == first.end() || it->second == kInvalid) {
      return absl::InternalError(absl::StrCat(
          "sealed chunk ", chunks_sent_, " decodes to triangle ", t, ", which it does not hold"));
    }
    patch[t] = part.patch[it->second];
    it->second = next[it->second];
  }
  v1::SealedChunk out;
  out.set_index(chunks_sent_);
  out.set_first_slice(part.first_slice);
  out.set_last_slice(part.last_slice);
  out.set_draco(std::move(bytes));
  out.set_triangles(static_cast<int64_t>(nt));
  out.set_vertices(static_cast<int64_t>(complex.num_vertices()));
  const LabelId background = config_.options.labels.background;
  common::LabelPairsToProto(patch, part.pairs, background, out.mutable_label_pairs());
  encode_s_ += SecondsSince(t0);
  sealed_posted_ += out.triangles();
  ++chunks_sent_;
  chunk_bytes_ += static_cast<int64_t>(out.draco().size());
  sink_->PostChunk(std::move(out));

  // Each label's part, for its figures at End, with the corners where the encoding put them.
  for (const auto& [v, at] : moved) complex.positions[v] = at;
  part.positions = std::move(complex.positions);
  part.indices = std::move(complex.indices);
  for (auto& [label, c] : SplitLabeledChunk(part, background)) {
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
