// ExtractJob: one Extract stream's work, as a synchronous state machine driven message by
// message on the session's worker thread (never on a gRPC thread). It owns the
// TandemSession, assembles slices from chunks, validates everything, and hands its
// output (progress, previews, the final mesh and metrics) to a JobSink. No gRPC here, so
// tests can drive it directly.
//
// Memory: one slice buffer (nx*ny*sizeof(dtype)), the session (and, with
// compute_distances, a second full-resolution session kept as the reference surface),
// plus, at the end, the copy of the mesh and its Draco encoding. Never the whole volume.
// The per-session budget (ServerLimits::session_memory_bytes) is checked against
// MemoryBytes() after the config (which counts the slice buffers and plane caches the
// session will allocate on its first slice), after every slice, and before each copy or
// encoding of the mesh, by an estimate of what it will take (extract_job_internal.h: EncodeBytes);
// past it the job fails with RESOURCE_EXHAUSTED, and a preview is skipped. The sessions
// check the same budget themselves while they work (a MemoryBudget shared by the job's
// sessions, tandem/budget.h, told what the job holds beside them): inside their steps,
// where a noisy slice grows them by hundreds of MiB before its message is handled.
#ifndef TANDEM_SERVER_EXTRACT_JOB_H_
#define TANDEM_SERVER_EXTRACT_JOB_H_

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "tandem/budget.h"
#include "tandem/eval/metrics.h"
#include "tandem/eval/report.h"
#include "tandem/server/request_validation.h"
#include "tandem/tandem.h"
#include "tandem/v1/tandem.pb.h"

namespace tandem::server {

// Receives a job's output, on the job's thread. Progress and Preview are "latest wins":
// the sink may drop an unsent one when a newer one arrives. Final messages must all be
// delivered, in order (FinalMesh chunks 0..n-1, then FinalMetrics).
class JobSink {
 public:
  virtual ~JobSink() = default;
  virtual void PostProgress(v1::Progress progress) = 0;
  virtual void PostPreview(v1::Preview preview) = 0;
  // True while a posted preview has not been handed to the transport yet (the client reads
  // slower than previews come): the job then skips encoding another one.
  virtual bool PreviewPending() const { return false; }
  virtual void PostFinal(std::vector<v1::ExtractResponse> messages) = 0;
  // A sealed chunk: every one delivered, in order, before the final messages.
  virtual void PostChunk(v1::SealedChunk chunk) = 0;
};

// Several surfaces in one pass (SessionConfig.extra_isos): the job runs one child job per
// iso-value, each with its own session and a SurfaceSink that tags what it posts with the
// surface, and hands every message to each child in turn (each copies the slice into its
// session's ring, whose pipeline then runs on: the surfaces run side by side). Progress is
// summed over the children, chunk indices count all surfaces together, and the children's
// final messages are posted at once, surface after surface, when the last one is done.
class ExtractJob {
 public:
  // `compute`: the executor the job's sessions run on (null: Executor::Shared()). `budget`:
  // the one its sessions check (null: one of limits.session_memory_bytes; a job of several
  // surfaces hands its own to the children).
  ExtractJob(const ServerLimits& limits, JobSink* sink, Executor* compute = nullptr,
             std::shared_ptr<MemoryBudget> budget = nullptr);
  ~ExtractJob();

  // Handles the next message of the stream (chunk data may be moved out of `request`).
  // A non-OK status ends the stream with that status; the job must not be used again.
  // After End, done() is true and the final messages have been posted.
  absl::Status Handle(v1::ExtractRequest& request);
  // The client closed its side. Always an error unless done(): the stream needs End.
  absl::Status HandleEndOfInput() const;

  bool done() const { return state_ == State::kDone; }
  // Resume (tandem/server/resume.h). A job past its config and before End can wait for a new
  // stream: Detach drops a partly received slice and the sink (nothing is posted while
  // detached); Attach gives it the new stream's sink and posts a Progress.
  bool resumable() const { return state_ == State::kStreaming; }
  void Detach();
  void Attach(JobSink* sink);
  int64_t chunks_posted() const { return chunks_sent_; }
  const std::string& description() const { return config_.description; }
  int64_t slices() const { return surfaces_.empty() ? cursor_.slice : surfaces_[0]->slices(); }
  int64_t triangles() const;
  // Memory held now (sessions, slice buffer, encoded output not yet handed over).
  size_t MemoryBytes() const;
  // The budget its sessions check. Its Cancel (any thread) stops their work at once: the
  // job then fails at its next call into a session.
  const std::shared_ptr<MemoryBudget>& budget() const { return budget_; }
  // Seconds spent so far in each phase (for the server's metrics).
  struct Phases {
    double extract_s = 0, simplify_s = 0, encode_s = 0;
  };
  Phases PhaseSeconds() const;

 private:
  enum class State { kWaitConfig, kStreaming, kDone };
  class SurfaceSink;
  absl::Status HandleMessage(v1::ExtractRequest& request);  // Handle, but for ReportOwnBytes
  // Several surfaces: creates the children and hands them the config.
  absl::Status StartSurfaces(const v1::SessionConfig& config);
  absl::Status HandleSurfaces(v1::ExtractRequest& request);
  v1::Progress SumProgress() const;
  absl::Status HandleConfig(const v1::SessionConfig& config);
  absl::Status HandleChunk(v1::SliceChunk& chunk);
  absl::Status ConsumeSlice(const uint8_t* bytes);
  absl::Status HandleEnd(const v1::End& end);
  absl::Status FinishSealed();  // HandleEnd's tail when the mesh left in sealed chunks
  // HandleEnd's tail in a label session (SessionConfig.labels): each label's surface and
  // figures, then the session's (extract_job_labels.cc).
  absl::Status FinishLabels();
  // A label session's sealed chunk (`complex` its triangles, before the grid `moved` its
  // corners, `bytes` their encoding): one SealedChunk with the pairs its triangles separate;
  // each label's part is kept for its figures at End.
  absl::Status PostLabelChunks(SealedChunk part, IndexedMesh complex,
                               const codec::MovedCorners& moved, std::string bytes);
  // Each label's figures from its chunks, welded (FinalMetrics with the label and its place).
  void AppendSealedLabelMetrics(std::vector<v1::ExtractResponse>* out);
  // compute_distances: the L1/L2/Linf distances of `mesh` to the reference (freed after);
  // and the process's peak RSS, in any case.
  absl::Status MeasureDistancesTo(const IndexedMesh& mesh, eval::MetricsReport* report);
  // Appends FinalMetrics to `out` and posts it all: the job is done.
  void PostMetrics(const eval::MetricsReport& report, std::vector<v1::ExtractResponse> out);
  void MaybePreview();
  // Sealed chunks: posts what the session sealed since the last one, when there is enough
  // of it or enough time went by (always with `now`). `last`: the stream's last chunk,
  // which goes out in parts when it is large, their encodings side by side.
  absl::Status MaybeChunk(bool now, bool last = false);
  // RESOURCE_EXHAUSTED when MemoryBytes() + `extra` exceeds the budget; `when` says where.
  // Also records the peak (peak_memory_): every allocation the session makes outside its
  // engine is checked here first.
  absl::Status CheckMemory(size_t extra, const std::string& when);
  // The error of a stream over `budget`: `bytes` needed `when`.
  absl::Status BudgetError(size_t bytes, int64_t budget, const std::string& when) const;
  // A session's failure, as this job reports it: over the budget, BudgetError.
  absl::Status SessionFailure(absl::Status st) const;
  // What the job holds beside its sessions (slice buffer, the ids of sent chunks), and
  // telling the budget when that moved.
  size_t OwnBytes() const;
  void ReportOwnBytes();
  v1::Progress MakeProgress() const;

  ServerLimits limits_;
  Executor* compute_;                     // never null (Executor::Shared() when none is given)
  std::shared_ptr<MemoryBudget> budget_;  // never null
  size_t own_reported_ = 0;               // OwnBytes as the budget was last told
  JobSink* sink_;
  State state_ = State::kWaitConfig;
  JobConfig config_;
  std::unique_ptr<TandemSession> session_;
  std::unique_ptr<TandemSession> reference_;  // full resolution, for compute_distances
  SliceCursor cursor_;
  std::vector<uint8_t> slice_;  // assembly buffer, used when a slice comes in pieces
  std::chrono::steady_clock::time_point start_;
  std::optional<std::chrono::steady_clock::time_point> last_preview_;
  double encode_s_ = 0;
  double preview_s_ = 0;  // of encode_s_, the previews' (and the chunks they flushed)
  int64_t preview_bytes_ = 0, chunk_bytes_ = 0;  // Draco bytes posted
  PhaseTimes session_time_;                      // of the session, kept when it is freed
  int64_t final_triangles_ = 0;
  size_t peak_memory_ = 0;  // the most MemoryBytes() + extra a passed CheckMemory saw
  // Sealed chunks.
  int64_t chunks_sent_ = 0;
  int64_t sealed_posted_ = 0;        // triangles in the chunks posted by this job
  codec::DracoOptions chunk_draco_;  // the config's, on the session's quantization grid
  std::optional<std::chrono::steady_clock::time_point> last_chunk_;
  eval::ShapeSums shape_;          // of everything sealed, for the final metrics
  std::vector<SealedChunk> kept_;  // compute_distances only: the chunks, to weld at the end
  // A sealed label session: each label's chunks as sent, welded at End for its figures.
  std::map<LabelId, std::vector<SealedChunk>> label_chunks_;
  size_t label_chunk_bytes_ = 0;  // what label_chunks_ holds, in OwnBytes: it grows with depth
  // The ids a chunk sent that a later chunk may send again (not retired): on the shared grid
  // those corners may not move (codec::EncodeDraco's `fixed`), and those the encoder moved
  // go out again where they were sent. The front's border and the unsettled seams, not the
  // depth.
  absl::flat_hash_set<uint32_t> sent_ids_;
  absl::flat_hash_map<uint32_t, Vec3> sent_moved_;
  // The positions the last chunk sent: a vertex of the next may not take one's grid point
  // (codec::EncodeDraco's `avoid`), where two sheets touch across the two chunks.
  std::vector<Vec3> last_sent_;
  // Several surfaces (see above): the children, their sinks, the latest Progress of each and
  // their final messages, held until the last child is done.
  std::vector<std::unique_ptr<ExtractJob>> surfaces_;
  std::vector<std::unique_ptr<SurfaceSink>> surface_sinks_;
  std::vector<v1::Progress> surface_progress_;
  std::vector<v1::ExtractResponse> surface_final_;
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_EXTRACT_JOB_H_
