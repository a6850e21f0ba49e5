// ExtractJob with several surfaces (SessionConfig.extra_isos): one child job per iso-value.
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "extract_job_internal.h"
#include "tandem/common/wire.h"
#include "tandem/server/extract_job.h"

namespace tandem::server {

absl::Status ExtractJob::StartSurfaces(const v1::SessionConfig& config) {
  const size_t n = config_.isos.size();
  ServerLimits child_limits = limits_;
  child_limits.session_memory_bytes = limits_.session_memory_bytes / static_cast<int64_t>(n);
  surface_progress_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    surface_sinks_.push_back(std::make_unique<SurfaceSink>(this, static_cast<int>(i)));
    surfaces_.push_back(std::make_unique<ExtractJob>(child_limits, surface_sinks_.back().get(),
                                                     compute_, budget_));
  }
  for (size_t i = 0; i < n; ++i) {
    v1::ExtractRequest request;
    v1::SessionConfig& c = *request.mutable_config();
    c = config;
    c.set_iso(config_.isos[i]);
    c.clear_extra_isos();
    if (absl::Status st = surfaces_[i]->Handle(request); !st.ok()) {
      return absl::Status(st.code(), absl::StrCat("surface ", i, " (iso ", config_.isos[i], "): ",
                                                  std::string(st.message())));
    }
  }
  start_ = Clock::now();
  state_ = State::kStreaming;
  return absl::OkStatus();
}

absl::Status ExtractJob::HandleSurfaces(v1::ExtractRequest& request) {
  if (state_ == State::kDone) {
    return absl::InvalidArgumentError(absl::StrCat("got ", KindName(request), " after End"));
  }
  for (size_t i = 0; i < surfaces_.size(); ++i) {
    absl::Status st;
    if (i + 1 < surfaces_.size()) {
      v1::ExtractRequest copy = request;
      st = surfaces_[i]->Handle(copy);
    } else {
      st = surfaces_[i]->Handle(request);  // the last one may take the data
    }
    // A problem of the request is found by the first child; one of a surface (its memory,
    // say) names it.
    if (!st.ok()) {
      if (i == 0) return st;
      return absl::Status(st.code(), absl::StrCat("surface ", i, " (iso ", config_.isos[i], "): ",
                                                  std::string(st.message())));
    }
  }
  if (surfaces_.back()->done()) {
    state_ = State::kDone;
    if (sink_) sink_->PostFinal(std::move(surface_final_));
    surface_final_.clear();
  }
  return absl::OkStatus();
}

v1::Progress ExtractJob::SumProgress() const {
  v1::Progress sum;
  for (size_t i = 0; i < surface_progress_.size(); ++i) {
    const v1::Progress& p = surface_progress_[i];
    if (i == 0 || p.slices_consumed() < sum.slices_consumed()) {
      sum.set_slices_consumed(p.slices_consumed());
    }
    sum.set_triangles(sum.triangles() + p.triangles());
    sum.set_peak_triangles(sum.peak_triangles() + p.peak_triangles());
    sum.set_sealed_triangles(sum.sealed_triangles() + p.sealed_triangles());
    if (!p.finishing().empty()) {  // the surface finishing now (they finish in turn)
      common::FinishingToProto(common::FinishingFromProto(p), &sum);
    }
  }
  if (config_.options.seal) sum.set_sealed_chunks(chunks_sent_);
  sum.set_slices_expected(config_.grid.nz);
  return sum;
}

}  // namespace tandem::server
