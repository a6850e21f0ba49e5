// ExtractJob's intake: the config, the slices assembled from their chunks, progress, and the
// detach and attach of a resume.
#include "tandem/server/extract_job.h"

#include <bit>
#include <cstring>
#include <string>

#include "absl/strings/str_cat.h"
#include "extract_job_internal.h"
#include "tandem/status_macros.h"

namespace tandem::server {
namespace {

// The wire carries little-endian voxels and core reads host order: a big-endian port
// would need a byte swap in ConsumeSlice.
static_assert(std::endian::native == std::endian::little, "voxel bytes are little-endian");

}  // namespace

const char* KindName(const v1::ExtractRequest& r) {
  switch (r.kind_case()) {
    case v1::ExtractRequest::kConfig: return "a SessionConfig";
    case v1::ExtractRequest::kChunk: return "a SliceChunk";
    case v1::ExtractRequest::kEnd: return "an End";
    case v1::ExtractRequest::kChunksReceived: return "a ChunksReceived";
    default: return "an empty ExtractRequest";
  }
}

ExtractJob::ExtractJob(const ServerLimits& limits, JobSink* sink, Executor* compute,
                       std::shared_ptr<MemoryBudget> budget)
    : limits_(limits),
      compute_(compute != nullptr ? compute : &Executor::Shared()),
      budget_(budget ? std::move(budget)
                     : std::make_shared<MemoryBudget>(limits.session_memory_bytes)),
      sink_(sink) {}

ExtractJob::~ExtractJob() {
  // The sessions stop and let go first (their own ends), then this job's own bytes.
  surfaces_.clear();
  session_.reset();
  reference_.reset();
  budget_->AddOutside(-static_cast<int64_t>(own_reported_));
}

int64_t ExtractJob::triangles() const {
  if (!surfaces_.empty()) {
    int64_t sum = 0;
    for (const auto& s : surfaces_) sum += s->triangles();
    return sum;
  }
  return session_ ? session_->Peek().triangles : final_triangles_;
}

absl::Status ExtractJob::Handle(v1::ExtractRequest& request) {
  absl::Status st = HandleMessage(request);
  ReportOwnBytes();
  return st;
}

absl::Status ExtractJob::HandleMessage(v1::ExtractRequest& request) {
  if (!surfaces_.empty()) return HandleSurfaces(request);
  switch (state_) {
    case State::kWaitConfig:
      if (!request.has_config()) {
        return absl::InvalidArgumentError(absl::StrCat(
            "the first message must be a SessionConfig, got ", KindName(request)));
      }
      return HandleConfig(request.config());
    case State::kStreaming:
      if (request.has_chunk()) return HandleChunk(*request.mutable_chunk());
      if (request.has_end()) return HandleEnd(request.end());
      return absl::InvalidArgumentError(absl::StrCat(
          "expected a SliceChunk or End after the config, got ", KindName(request)));
    case State::kDone:
      return absl::InvalidArgumentError(absl::StrCat("got ", KindName(request), " after End"));
  }
  return absl::InternalError("unreachable");
}

absl::Status ExtractJob::HandleEndOfInput() const {
  if (done()) return absl::OkStatus();
  if (state_ == State::kWaitConfig) {
    return absl::InvalidArgumentError("the stream ended before a SessionConfig");
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "the stream ended without an End marker after ", slices(),
      " complete slices; send End after the last slice"));
}

absl::Status ExtractJob::HandleConfig(const v1::SessionConfig& config) {
  TANDEM_ASSIGN_OR_RETURN(JobConfig cfg, ValidateConfig(config, limits_));
  config_ = std::move(cfg);
  if (config_.isos.size() > 1) return StartSurfaces(config);
  TANDEM_ASSIGN_OR_RETURN(auto session,
                          TandemSession::Create(config_.grid, config_.options, compute_, budget_));
  session_ = std::move(session);
  if (config_.options.seal) chunk_draco_ = ChunkGrid(config_.grid, config_.draco, limits_.max_slices);
  if (config_.compute_distances) {
    SessionOptions full = config_.options;
    full.schedule = Schedule::kNone;
    full.seal = false;  // the whole surface stays, to measure against
    TANDEM_ASSIGN_OR_RETURN(auto reference,
                            TandemSession::Create(config_.grid, full, compute_, budget_));
    reference_ = std::move(reference);
  }
  // A slice sent in pieces is assembled in a buffer of its own: count it now.
  TANDEM_RETURN_IF_ERROR(CheckMemory(config_.grid.slice_bytes(), "for this grid"));
  start_ = Clock::now();
  state_ = State::kStreaming;
  // At once, before any slice: tells the client the session is taken (it sends no slice
  // before it hears from the server, so a refused stream can be sent again untouched).
  sink_->PostProgress(MakeProgress());
  return absl::OkStatus();
}

absl::Status ExtractJob::HandleChunk(v1::SliceChunk& chunk) {
  TANDEM_RETURN_IF_ERROR(ValidateChunk(chunk, config_, cursor_, limits_));
  const size_t slice_bytes = config_.grid.slice_bytes();
  const std::string& data = chunk.data();
  if (cursor_.bytes_so_far == 0 && data.size() == slice_bytes) {
    // A whole slice in one message: no copy.
    return ConsumeSlice(reinterpret_cast<const uint8_t*>(data.data()));
  }
  if (slice_.size() != slice_bytes) {
    slice_.resize(slice_bytes);
    ReportOwnBytes();
  }
  std::memcpy(slice_.data() + cursor_.bytes_so_far, data.data(), data.size());
  cursor_.bytes_so_far += data.size();
  if (cursor_.bytes_so_far < slice_bytes) return absl::OkStatus();
  return ConsumeSlice(slice_.data());
}

absl::Status ExtractJob::ConsumeSlice(const uint8_t* bytes) {
  // The sessions refuse non-finite values (and name the voxel); the slice is prefixed here.
  for (TandemSession* s : {session_.get(), reference_.get()}) {
    if (s == nullptr) continue;
    if (absl::Status st = s->AddSliceBytes(config_.grid.dtype, bytes); !st.ok()) {
      if (budget_->stopped()) return SessionFailure(st);  // (names the slice it was at)
      return absl::Status(st.code(), absl::StrCat("slice ", cursor_.slice, ": ",
                                                  std::string(st.message())));
    }
  }
  ++cursor_.slice;
  cursor_.bytes_so_far = 0;
  TANDEM_RETURN_IF_ERROR(CheckMemory(0, absl::StrCat("after slice ", cursor_.slice - 1)));
  TANDEM_RETURN_IF_ERROR(MaybeChunk(false));
  sink_->PostProgress(MakeProgress());
  MaybePreview();
  return absl::OkStatus();
}

void ExtractJob::Detach() {
  cursor_.bytes_so_far = 0;  // the slice comes again, whole
  sink_ = nullptr;
  for (auto& s : surfaces_) s->cursor_.bytes_so_far = 0;
}

void ExtractJob::Attach(JobSink* sink) {
  sink_ = sink;
  sink_->PostProgress(surfaces_.empty() ? MakeProgress() : SumProgress());
}

v1::Progress ExtractJob::MakeProgress() const {
  v1::Progress p;
  p.set_slices_consumed(cursor_.slice);
  p.set_slices_expected(config_.grid.nz);
  // Sent after every slice: Peek, so that the stream does not wait for the session's
  // queued steps each time (they overlap the next slices).
  const TandemSession::Gauge gauge = session_->Peek();
  p.set_triangles(gauge.triangles);
  p.set_peak_triangles(gauge.peak_triangles);
  if (config_.options.seal) {
    p.set_sealed_triangles(sealed_posted_);
    p.set_sealed_chunks(chunks_sent_);
  }
  return p;
}

}  // namespace tandem::server
