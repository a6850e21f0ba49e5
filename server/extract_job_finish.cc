// How an ExtractJob ends: the sessions finish, the final mesh or the last sealed chunk goes
// out, and the final metrics.
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "extract_job_internal.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/common/wire.h"
#include "tandem/eval/distance.h"
#include "tandem/eval/report.h"
#include "tandem/server/extract_job.h"
#include "tandem/status_macros.h"
#include "tandem/tandem.h"
#include "tandem/task_group.h"

namespace tandem::server {
namespace {

// While a session finishes (its caller's thread inside Finish), posts the last Progress
// again every kFinishingEvery seconds (the CLI's period, so a short finish shows in both) with
// the finishing fields: the client's status line after the last slice. The session's other
// observers wait for Finish; FinishProgress alone is read.
class FinishingTicker {
 public:
  FinishingTicker(const TandemSession& session, v1::Progress last, JobSink* sink)
      : thread_([this, &session, last = std::move(last), sink] {
          std::unique_lock<std::mutex> lock(mu_);
          const auto every = std::chrono::duration<double>(kFinishingEvery);
          while (!cv_.wait_for(lock, every, [this] { return stop_; })) {
            v1::Progress p = last;
            common::FinishingToProto(session.FinishProgress(), &p);
            if (!p.finishing().empty()) sink->PostProgress(std::move(p));
          }
        }) {}
  ~FinishingTicker() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  FinishingTicker(const FinishingTicker&) = delete;
  FinishingTicker& operator=(const FinishingTicker&) = delete;

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread thread_;  // last: started once the rest is
};

}  // namespace

absl::Status ExtractJob::HandleEnd(const v1::End& end) {
  TANDEM_RETURN_IF_ERROR(ValidateEnd(end, config_, cursor_));
  for (TandemSession* s : {session_.get(), reference_.get()}) {
    if (s == nullptr) continue;
    std::optional<FinishingTicker> ticker;
    if (s == session_.get() && sink_ != nullptr) ticker.emplace(*s, MakeProgress(), sink_);
    if (absl::Status st = s->Finish(); !st.ok()) return SessionFailure(st);
  }
  TANDEM_RETURN_IF_ERROR(CheckMemory(0, "after the last slice"));
  if (config_.options.seal) return FinishSealed();
  if (config_.options.labels.enabled) return FinishLabels();
  // Every step below is counted before it allocates; the session is freed as soon as its
  // mesh and report are out, so the encoder never runs beside it.
  const int64_t triangles = session_->num_triangles();
  if (absl::Status st = CheckMemory(SnapshotBytes(triangles), "to copy out the final mesh");
      !st.ok()) {
    return st;
  }
  const IndexedMesh mesh = session_->Snapshot();
  // The triangles' shape sums (a tenth of a second a million triangles) are taken beside the
  // encoding below, on a core the finished session left idle.
  eval::MetricsReport report =
      eval::MakeReport(*session_, static_cast<int64_t>(mesh.num_triangles()),
                       static_cast<int64_t>(mesh.num_vertices()), eval::ShapeSums{});
  sink_->PostProgress(MakeProgress());
  session_time_ = session_->stats().time;
  session_.reset();
  final_triangles_ = triangles;
  TANDEM_RETURN_IF_ERROR(MeasureDistancesTo(mesh, &report));
  if (absl::Status st = CheckMemory(EncodeBytes(triangles), "to encode the final mesh");
      !st.ok()) {
    return st;
  }

  const auto t0 = Clock::now();
  absl::StatusOr<std::string> bytes;
  {
    eval::ShapeSums shape;
    TaskGroup group(compute_);
    group.Run([&] { shape.Add(mesh); });
    bytes = codec::EncodeDraco(mesh, config_.draco);
    group.Wait();
    report.anisotropy = shape.anisotropy();
    report.directional_bias = shape.directional_bias();
  }
  encode_s_ += SecondsSince(t0);
  if (!bytes.ok()) {
    return absl::InternalError(absl::StrCat("encoding the final mesh: ",
                                            std::string(bytes.status().message())));
  }
  std::vector<v1::ExtractResponse> out;
  AppendFinalMesh(*bytes, mesh, &out);
  final_triangles_ = static_cast<int64_t>(mesh.num_triangles());
  PostMetrics(report, std::move(out));
  return absl::OkStatus();
}

std::vector<v1::FinalMesh*> AppendFinalMesh(const std::string& all, const IndexedMesh& mesh,
                                            std::vector<v1::ExtractResponse>* out) {
  const size_t chunk = common::kFinalMeshChunkBytes;
  const size_t count = std::max<size_t>(1, (all.size() + chunk - 1) / chunk);
  std::vector<v1::FinalMesh*> added;
  out->reserve(out->size() + count + 1);
  for (size_t i = 0; i < count; ++i) {
    v1::FinalMesh* m = out->emplace_back().mutable_final_mesh();
    m->set_chunk_index(static_cast<uint32_t>(i));
    m->set_chunk_count(static_cast<uint32_t>(count));
    m->set_draco(all.substr(i * chunk, chunk));  // i * chunk <= size: no throw
    m->set_total_bytes(all.size());
    m->set_triangles(static_cast<int64_t>(mesh.num_triangles()));
    m->set_vertices(static_cast<int64_t>(mesh.num_vertices()));
    added.push_back(m);
  }
  return added;
}

absl::Status ExtractJob::FinishSealed() {
  if (absl::Status st = MaybeChunk(true, true); !st.ok()) return st;  // the rest, sealed by Finish
  const SessionStats& stats = session_->stats();
  final_triangles_ = stats.sealed_triangles;
  eval::MetricsReport report =
      eval::MakeReport(*session_, stats.sealed_triangles, stats.sealed_vertices, shape_);
  sink_->PostProgress(MakeProgress());
  session_time_ = stats.time;
  session_.reset();
  if (reference_) {
    const IndexedMesh mesh = WeldChunks(kept_);
    kept_ = {};
    TANDEM_RETURN_IF_ERROR(MeasureDistancesTo(mesh, &report));
  }
  std::vector<v1::ExtractResponse> out;
  if (config_.options.labels.enabled) AppendSealedLabelMetrics(&out);
  PostMetrics(report, std::move(out));
  return absl::OkStatus();
}

absl::Status ExtractJob::MeasureDistancesTo(const IndexedMesh& mesh, eval::MetricsReport* report) {
  if (reference_) {
    if (absl::Status st = CheckMemory(EncodeBytes(static_cast<int64_t>(mesh.num_triangles())) +
                                          DistanceBytes(reference_->num_triangles()),
                                      "to measure the distances");
        !st.ok()) {
      return st;
    }
    eval::DistanceOptions dopt;
    dopt.threads = 1;  // one core per session: other sessions share the machine
    report->distance = eval::MeasureDistances(mesh, reference_->Snapshot(), dopt);
    reference_.reset();
  }
  report->peak_rss_bytes = eval::PeakRssBytes();
  return absl::OkStatus();
}

void ExtractJob::PostMetrics(const eval::MetricsReport& report,
                             std::vector<v1::ExtractResponse> out) {
  v1::FinalMetrics* metrics = out.emplace_back().mutable_final_metrics();
  common::ReportToProto(report, metrics);
  metrics->set_time_encode_s(encode_s_);
  metrics->set_time_wall_s(SecondsSince(start_));
  metrics->set_sealed_chunks(chunks_sent_);
  metrics->set_peak_session_bytes(static_cast<int64_t>(std::max(peak_memory_, MemoryBytes())));
  if (config_.options.labels.enabled) {
    metrics->set_labels(std::count_if(out.begin(), out.end(), [](const v1::ExtractResponse& r) {
      return r.has_final_metrics() && r.final_metrics().has_label();
    }));
  }
  // bytes_received, bytes_sent and previews_sent are filled in by the transport, which
  // alone knows what went over the wire.
  slice_ = {};
  state_ = State::kDone;
  sink_->PostFinal(std::move(out));
}

}  // namespace tandem::server
