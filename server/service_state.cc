// ServiceState: the worker count, the registry of live streams, and the heap handed back when idle.
#include "tandem/server/service_state.h"

#include <malloc.h>  // malloc_trim (glibc)

#include <memory>
#include <utility>
#include <vector>

namespace tandem::server {

void ServiceState::TrimIfIdle() const {
#if defined(__GLIBC__)
  // Sessions allocate and free tens of MiB on worker threads, whose glibc arenas keep
  // freed pages mapped; hand them back once nothing is running, so the server's resident
  // size returns to its idle level.
  if (active_sessions.load() == 0) malloc_trim(0);
#endif
}

void ServiceState::WorkerStarted() {
  absl::MutexLock lock(&mu_);
  ++workers_;
}

void ServiceState::WorkerExited() {
  absl::MutexLock lock(&mu_);
  --workers_;
}

int64_t ServiceState::worker_threads() const {
  absl::MutexLock lock(&mu_);
  return workers_;
}

bool ServiceState::WaitForWorkers(absl::Time deadline) {
  absl::MutexLock lock(&mu_);
  auto none = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return workers_ == 0; };
  return mu_.AwaitWithDeadline(absl::Condition(&none), deadline);
}

void ServiceState::AddStream(const LiveStream* key, std::weak_ptr<LiveStream> stream) {
  absl::MutexLock lock(&mu_);
  streams_[key] = std::move(stream);
}

void ServiceState::RemoveStream(const LiveStream* key) {
  absl::MutexLock lock(&mu_);
  streams_.erase(key);
}

int64_t ServiceState::AbortStreams(const grpc::Status& status) {
  std::vector<std::shared_ptr<LiveStream>> alive;
  {
    absl::MutexLock lock(&mu_);
    for (const auto& [key, weak] : streams_) {
      if (auto s = weak.lock()) alive.push_back(std::move(s));
    }
  }
  resumable.Close();
  for (const auto& s : alive) s->Abort(status);  // without mu_: Abort takes the stream's lock
  return static_cast<int64_t>(alive.size());
}

}  // namespace tandem::server
