// An ExtractJob's accounting: the memory it holds against its budget, and its phases' time.
#include <algorithm>
#include <string>

#include "absl/strings/str_format.h"
#include "extract_job_internal.h"
#include "tandem/server/extract_job.h"

namespace tandem::server {
ExtractJob::Phases ExtractJob::PhaseSeconds() const {
  if (!surfaces_.empty()) {
    Phases sum;
    for (const auto& child : surfaces_) {
      const Phases p = child->PhaseSeconds();
      sum.extract_s += p.extract_s;
      sum.simplify_s += p.simplify_s;
      sum.encode_s += p.encode_s;
    }
    return sum;
  }
  const PhaseTimes& t = session_ ? session_->stats().time : session_time_;
  return {t.extract_s, t.simplify_s, encode_s_};
}

absl::Status ExtractJob::CheckMemory(size_t extra, const std::string& when) {
  const int64_t budget = limits_.session_memory_bytes;
  const size_t bytes = MemoryBytes() + extra;
  if (budget <= 0 || bytes <= static_cast<uint64_t>(budget)) {
    peak_memory_ = std::max(peak_memory_, bytes);  // what is then allocated
    return absl::OkStatus();
  }
  return BudgetError(bytes, budget, when);
}

absl::Status ExtractJob::SessionFailure(absl::Status st) const {
  if (!absl::IsResourceExhausted(st) || !budget_->exceeded()) return st;
  return BudgetError(static_cast<size_t>(budget_->exceeded_bytes()), budget_->limit(),
                     "while " + budget_->exceeded_where());
}

absl::Status ExtractJob::BudgetError(size_t bytes, int64_t budget,
                                     const std::string& when) const {
  constexpr double kMiB = 1 << 20;
  return absl::ResourceExhaustedError(absl::StrFormat(
      "session memory budget exceeded: this stream needs %.1f MiB %s (mesh, simplification "
      "queues, slice buffers%s%s), over this server's per-session budget of %.1f MiB "
      "(tandem-server --session-memory-mb). Use a larger E0, a target triangle count or a "
      "smaller grid%s%s, or ask the operator to raise --session-memory-mb",
      static_cast<double>(bytes) / kMiB, when,
      reference_ ? ", and the full-resolution reference of compute_distances" : "",
      label_chunk_bytes_ > 0
          ? ", and each label's sealed chunks, kept to measure its figures at End"
          : "",
      static_cast<double>(budget) / kMiB, reference_ ? ", drop compute_distances" : "",
      // Without sealing the simplified mesh stays in the session: its memory grows with the
      // slices (none yet: the grid's own buffers, which sealing does not change).
      config_.options.seal || cursor_.slice == 0
          ? ""
          : ", stream with sealed chunks (tandem-client --seal, SessionConfig.sealed_chunks: "
            "the session then holds the front, not the whole mesh)"));
}

size_t ExtractJob::OwnBytes() const {
  return slice_.capacity() + sent_ids_.capacity() * (sizeof(uint32_t) + 1) +
         sent_moved_.capacity() * (sizeof(uint32_t) + sizeof(Vec3) + 1) +
         last_sent_.capacity() * sizeof(Vec3) + label_chunk_bytes_;
}

void ExtractJob::ReportOwnBytes() {
  const size_t own = OwnBytes();
  budget_->AddOutside(static_cast<int64_t>(own) - static_cast<int64_t>(own_reported_));
  own_reported_ = own;
}

size_t ExtractJob::MemoryBytes() const {
  size_t bytes = OwnBytes();
  for (const auto& child : surfaces_) bytes += child->MemoryBytes();
  // Peek: exact between messages except for the slab steps still in flight (a few slices'
  // growth, counted at their end), and exact after Finish.
  if (session_) bytes += session_->Peek().memory_bytes;
  if (reference_) bytes += reference_->Peek().memory_bytes;
  return bytes;
}

}  // namespace tandem::server
