#include "tandem/io/run_session.h"

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <utility>

#include "absl/strings/str_cat.h"
#include "prefetch.h"
#include "tandem/status_macros.h"
#include "tandem/task_group.h"

namespace tandem::io {

absl::StatusOr<std::unique_ptr<TandemSession>> RunSession(
    SliceSource& source, const SessionOptions& options,
    const std::function<void(int64_t, int64_t)>& progress,
    const std::function<absl::Status(SealedChunk)>& on_chunk, Executor* executor) {
  std::function<absl::Status(size_t, SealedChunk)> each;
  if (on_chunk) each = [&](size_t, SealedChunk c) { return on_chunk(std::move(c)); };
  TANDEM_ASSIGN_OR_RETURN(auto sessions, RunSessions(source, {options}, progress, each, executor));
  return std::move(sessions.front());
}

absl::StatusOr<std::vector<std::unique_ptr<TandemSession>>> RunSessions(
    SliceSource& source, const std::vector<SessionOptions>& options,
    const std::function<void(int64_t, int64_t)>& progress,
    const std::function<absl::Status(size_t, SealedChunk)>& on_chunk, Executor* executor,
    const FinishingFn& finishing) {
  const VolumeInfo& info = source.info();
  if (options.empty()) return absl::InvalidArgumentError("RunSessions: no session options");
  std::vector<std::unique_ptr<TandemSession>> sessions;
  for (const SessionOptions& o : options) {
    if (o.seal && on_chunk == nullptr) {
      return absl::InvalidArgumentError("RunSession: sealing needs somewhere to put the chunks");
    }
    TANDEM_ASSIGN_OR_RETURN(auto session, TandemSession::Create(info, o, executor));
    sessions.push_back(std::move(session));
  }
  // Sealed chunks, one a slice, kSlicesInFlight slices behind the last one added: those
  // steps have finished, so the slabs' steps in flight go on (TakeSealedThrough); the same
  // chunks as taking each slice's right after it, without the slabs stepping in lock-step.
  // Then, once finished, what Finish sealed.
  int64_t next_take = 0;
  auto take = [&](int64_t through, bool finished) -> absl::Status {
    for (; next_take <= through; ++next_take) {
      for (size_t i = 0; i < sessions.size(); ++i) {
        SealedChunk c;
        if (options[i].seal && sessions[i]->TakeSealedThrough(next_take, &c)) {
          TANDEM_RETURN_IF_ERROR(on_chunk(i, std::move(c)));
        }
      }
    }
    for (size_t i = 0; finished && i < sessions.size(); ++i) {
      SealedChunk c;
      while (options[i].seal && sessions[i]->TakeSealed(&c)) {
        TANDEM_RETURN_IF_ERROR(on_chunk(i, std::move(c)));
      }
    }
    return absl::OkStatus();
  };
  int64_t added = 0;  // slices
  // Each session copies the slice into its own ring and, when pipelined, returns while its
  // workers go on: the sessions run side by side from one read of the slice.
  auto add = [&](int64_t k, const uint8_t* bytes) {
    for (auto& session : sessions) {
      absl::Status st = session->AddSliceBytes(info.dtype, bytes);
      if (!st.ok()) {
        return absl::Status(st.code(), absl::StrCat("slice ", k, ": ", std::string(st.message())));
      }
    }
    added = k + 1;
    TANDEM_RETURN_IF_ERROR(take(k - TandemSession::kSlicesInFlight, false));
    if (progress) progress(k + 1, info.nz);
    return absl::OkStatus();
  };
  // A mapped file hands its slices over in place: the session's copy into its ring is the
  // only one (a read() would copy every byte out of the page cache first).
  const uint8_t* view = nullptr;
  TANDEM_RETURN_IF_ERROR(source.ViewSlice(&view));
  if (view != nullptr) {
    for (int64_t k = 0; k < info.nz; ++k) {
      if (k > 0) {
        TANDEM_RETURN_IF_ERROR(source.ViewSlice(&view));
      }
      TANDEM_RETURN_IF_ERROR(add(k, view));
    }
  } else {
    // Reading runs ahead on another thread; conversion happens on the way into the session.
    // nz = 0 (a followed acquisition): until the source says OutOfRange.
    SlicePrefetcher prefetch(&source);
    std::vector<uint8_t> bytes;
    for (int64_t k = 0; info.nz == 0 || k < info.nz; ++k) {
      absl::Status st = prefetch.Next(&bytes);
      if (info.nz == 0 && absl::IsOutOfRange(st)) break;
      if (!st.ok()) return st;
      TANDEM_RETURN_IF_ERROR(add(k, bytes.data()));
    }
  }
  TANDEM_RETURN_IF_ERROR(take(added - 1, false));
  // The final SIMPLIFY of each surface, side by side as well, watched from a thread of its
  // own when asked to.
  std::vector<absl::Status> finished(sessions.size());
  std::mutex watch_mu;
  std::condition_variable watch_cv;
  bool done = false;
  std::thread watcher;
  if (finishing) {
    watcher = std::thread([&] {
      std::unique_lock<std::mutex> lock(watch_mu);
      const auto every = std::chrono::duration<double>(kFinishingEvery);
      while (!watch_cv.wait_for(lock, every, [&] { return done; })) {
        std::vector<TandemSession::Finishing> now;
        for (const auto& s : sessions) now.push_back(s->FinishProgress());
        finishing(now);
      }
    });
  }
  struct StopWatcher {  // however the block below is left
    std::mutex& mu;
    std::condition_variable& cv;
    bool& done;
    std::thread& watcher;
    ~StopWatcher() {
      {
        std::lock_guard<std::mutex> lock(mu);
        done = true;
      }
      cv.notify_all();
      if (watcher.joinable()) watcher.join();
    }
  } stop_watcher{watch_mu, watch_cv, done, watcher};
  {
    TaskGroup finishing(executor != nullptr ? executor : &Executor::Shared());
    for (size_t i = 1; i < sessions.size(); ++i) {
      finishing.Run([&, i] { finished[i] = sessions[i]->Finish(); });
    }
    finished[0] = sessions[0]->Finish();
    finishing.Wait();
  }
  for (const absl::Status& st : finished) {
    if (!st.ok()) return st;
  }
  TANDEM_RETURN_IF_ERROR(take(added - 1, true));
  return sessions;
}

}  // namespace tandem::io
