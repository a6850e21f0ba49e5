// MemoryBudget: a bound on what one or more sessions hold, checked by the engine where their
// arrays grow, and a way to stop them.
//
// A session given a budget (TandemSession::Create) reports what it holds at the points where
// it grows: every 2,048 vertices and triangles a layer stages (counting what the layer will
// take once committed: the mesh store's records and the quadrics), each layer committed,
// each batch of edges queued and every 4,096 edges SIMPLIFY pops, each part merged at the
// end. It counts what TandemSession::MemoryBytes counts (the store's written pages, the
// queues, the extractor's planes and staging, the slices in flight), not allocator slack.
// Once the total of every session sharing the budget, plus what the owner declared
// (AddOutside), passes the limit, the session that found it fails with RESOURCE_EXHAUSTED,
// and every session on the budget stops at its next check with that status: no step runs to
// its end first. Cancel stops them the same way with CANCELLED. The checks cost no time per element:
// an atomic add when a part's figure moved by kGrainBytes, a flag read otherwise. A session
// waiting for its own queued steps (behind other sessions' on a shared executor) is woken by
// the stop (AddWaker), so that it returns at once instead of when those steps get a thread.
#ifndef TANDEM_BUDGET_H_
#define TANDEM_BUDGET_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"

namespace tandem {

class MemoryBudget {
 public:
  // limit_bytes <= 0: no limit (Cancel still stops the sessions).
  explicit MemoryBudget(int64_t limit_bytes = 0) : limit_(limit_bytes) {}
  MemoryBudget(const MemoryBudget&) = delete;
  MemoryBudget& operator=(const MemoryBudget&) = delete;

  // A part publishes its figure again once it moved by this much (so a session's figure is
  // at most this much a part behind what it holds).
  static constexpr int64_t kGrainBytes = int64_t{256} << 10;

  int64_t limit() const { return limit_; }
  // What the sessions on this budget held at their last reports, plus AddOutside's.
  int64_t held() const { return held_.load(std::memory_order_relaxed); }
  // The most held() was at any report (the failing one included).
  int64_t peak() const { return peak_.load(std::memory_order_relaxed); }
  // Bytes the owner holds beside the sessions (negative: given back), counted with theirs.
  // Never refused here: the owner checks its own allocations.
  void AddOutside(int64_t delta) { Add(delta); }

  // Stops every session on this budget at its next check (CANCELLED). Any thread.
  void Cancel();
  // Whether the sessions must stop: cancelled, or a report found the limit passed.
  bool stopped() const { return stopped_.load(std::memory_order_relaxed); }
  bool exceeded() const;
  // OK, or why the sessions stopped: RESOURCE_EXHAUSTED (the first report past the limit,
  // saying where and how much) or CANCELLED.
  absl::Status status() const;
  // After a report past the limit: what was held then, and where ("extracting slice 12").
  int64_t exceeded_bytes() const;
  std::string exceeded_where() const;

  // For the sessions (a report): adds `delta` to held(); false when that took the total past
  // the limit (delta > 0 only), after which stopped() is true.
  bool Report(int64_t delta, const char* doing, int64_t slice);

  // `wake` is called when the sessions must stop (Cancel, or a report past the limit), until
  // RemoveWaker(key); a waiter checks stopped() before it sleeps. It runs under a lock of the
  // budget's: it must not call into the budget.
  void AddWaker(const void* key, std::function<void()> wake);
  void RemoveWaker(const void* key);

 private:
  int64_t Add(int64_t delta);
  void WakeAll();
  const int64_t limit_;
  std::atomic<int64_t> held_{0};
  std::atomic<int64_t> peak_{0};
  std::atomic<bool> stopped_{false};
  mutable std::mutex mu_;  // the failure's details
  absl::Status status_;
  int64_t exceeded_bytes_ = 0;
  std::string exceeded_where_;
  std::mutex wake_mu_;  // never held with mu_
  std::vector<std::pair<const void*, std::function<void()>>> wakers_;
};

}  // namespace tandem

#endif  // TANDEM_BUDGET_H_
