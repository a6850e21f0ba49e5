// The service's RPCs: each checks the bearer token first; Extract starts an ExtractCall, Watch
// reads a feed, GetInfo reports the limits, counters and the caller's sessions.
#include "tandem/server/tandem_service.h"

#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "extract_call.h"
#include "metrics.h"
#include "tandem/common/wire.h"

namespace tandem::server {
namespace {

// A call refused before it started (authentication): finishes at once.
class RefusedCall final : public grpc::ServerBidiReactor<Request, Response> {
 public:
  explicit RefusedCall(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

}  // namespace

TandemService::TandemService(const ServerLimits& limits, std::vector<std::string> tokens,
                             bool tls)
    : state_(std::make_shared<ServiceState>(limits, std::move(tokens), tls)) {}

TandemService::~TandemService() {
  state_->resumable.Close();
  state_->WaitForWorkers(absl::Now() + absl::Seconds(5));
}

grpc::ServerBidiReactor<Request, Response>* TandemService::Extract(
    grpc::CallbackServerContext* context) {
  int identity = TokenAuthenticator::kNoIdentity;
  if (grpc::Status st = state_->auth.Check(*context, "Extract", &identity); !st.ok()) {
    return new RefusedCall(st);
  }
  return ExtractCall::Start(state_, context, identity);
}

v1::Counters TandemService::CountersSnapshot() const {
  v1::Counters c;
  c.set_active_sessions(state_->active_sessions.load());
  c.set_sessions_started(state_->sessions_started.load());
  c.set_sessions_finished(state_->sessions_finished.load());
  c.set_sessions_rejected(state_->sessions_rejected.load());
  c.set_worker_threads(state_->worker_threads());
  c.set_session_bytes(state_->session_bytes.load());
  c.set_unauthenticated_calls(state_->auth.refused());
  c.set_buffered_bytes(state_->buffered_bytes.load());
  c.set_sessions_draining(state_->sessions_draining.load());
  c.set_sessions_waiting_for_resume(state_->resumable.parked());
  return c;
}

std::string TandemService::MetricsText() const { return PrometheusText(*state_); }

grpc::ServerWriteReactor<v1::ExtractResponse>* TandemService::Watch(
    grpc::CallbackServerContext* context, const v1::WatchRequest* request) {
  int identity = TokenAuthenticator::kNoIdentity;
  if (grpc::Status st = state_->auth.Check(*context, "Watch", &identity); !st.ok()) {
    return StartWatch(nullptr, "", st);
  }
  return StartWatch(
      state_->feeds.FindReadable(request->session_id(), request->watch_key(), identity),
      request->session_id());
}

grpc::ServerUnaryReactor* TandemService::GetInfo(grpc::CallbackServerContext* context,
                                                 const v1::InfoRequest* request,
                                                 v1::InfoResponse* response) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  int identity = TokenAuthenticator::kNoIdentity;
  if (grpc::Status st = state_->auth.Check(*context, "GetInfo", &identity); !st.ok()) {
    reactor->Finish(st);
    return reactor;
  }
  response->set_version(common::ServiceVersion());
  v1::Limits* l = response->mutable_limits();
  l->set_max_voxels_per_slice(state_->limits.max_voxels_per_slice);
  l->set_max_slices(state_->limits.max_slices);
  l->set_max_sessions(state_->limits.max_sessions);
  l->set_max_message_bytes(state_->limits.max_message_bytes);
  l->set_idle_timeout_seconds(state_->limits.idle_timeout_s);
  l->set_session_memory_bytes(state_->limits.session_memory_bytes);
  l->set_max_inflight_bytes(state_->limits.max_inflight_bytes);
  l->set_keepalive_time_ms(state_->limits.keepalive_time_ms);
  l->set_keepalive_timeout_ms(state_->limits.keepalive_timeout_ms);
  l->set_min_ping_interval_ms(state_->limits.min_ping_interval_ms);
  l->set_permit_keepalive_without_calls(state_->limits.permit_keepalive_without_calls);
  l->set_min_preview_interval_ms(state_->limits.min_preview_interval_ms);
  l->set_max_preview_share(state_->limits.max_preview_share);
  l->set_max_band_bytes_share(state_->limits.max_band_bytes_share);
  l->set_resume_window_seconds(state_->limits.resume_window_s);
  l->set_compute_threads(state_->compute->threads());
  l->set_watch_retain_bytes(state_->limits.watch_retain_bytes);
  l->set_watch_linger_seconds(state_->limits.watch_linger_s);
  for (v1::DType d : common::WireDTypes()) response->add_dtypes(d);
  for (v1::Schedule s : {v1::SCHEDULE_NONE, v1::SCHEDULE_CLASSICAL, v1::SCHEDULE_TANDEM,
                         v1::SCHEDULE_TANDEM_LAG}) {
    response->add_schedules(s);
  }
  *response->mutable_counters() = CountersSnapshot();
  response->set_tls(state_->tls);
  response->set_token_required(state_->auth.enabled());
  // Only the sessions this call may read: ids and descriptions are the creators' (patient
  // data, for a scan); everyone gets the counters.
  const std::vector<std::string_view> keys(request->watch_keys().begin(),
                                           request->watch_keys().end());
  for (v1::SessionSummary& summary : state_->feeds.Summaries(keys, identity)) {
    *response->add_sessions() = std::move(summary);
  }
  reactor->Finish(grpc::Status::OK);
  return reactor;
}

}  // namespace tandem::server
