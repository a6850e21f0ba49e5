// Meter: a session's side of its MemoryBudget (tandem/budget.h). Each part of the session that
// grows on a thread of its own (a slab's extractor while it stages a layer, the rest of the
// slab, the session's slice buffers, the sealed shares) has an Account, reported to by one
// thread at a time at the points where it grows; a report that takes the budget past its
// limit, a Cancel, or the session's own end stops every check after it with a SessionStop,
// which the session's barrier turns into its status (StatusOfException).
#ifndef TANDEM_METER_H_
#define TANDEM_METER_H_

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <memory>
#include <utility>

#include "absl/status/status.h"
#include "tandem/budget.h"

namespace tandem {

// Thrown by a check that finds the session stopped: its status says why.
class SessionStop : public std::exception {
 public:
  explicit SessionStop(absl::Status status) : status_(std::move(status)) {}
  const absl::Status& status() const { return status_; }
  const char* what() const noexcept override { return "the session was stopped"; }

 private:
  absl::Status status_;
};

class Meter {
 public:
  // null: a budget of its own, without a limit.
  explicit Meter(std::shared_ptr<MemoryBudget> budget)
      : budget_(budget ? std::move(budget) : std::make_shared<MemoryBudget>()) {}
  Meter(const Meter&) = delete;
  Meter& operator=(const Meter&) = delete;

  // This session only (its end): every later check throws, CANCELLED.
  void Stop() { stop_.store(true, std::memory_order_relaxed); }
  bool stopped() const { return stop_.load(std::memory_order_relaxed) || budget_->stopped(); }
  absl::Status status() const;  // why it stopped (OK while it runs)
  MemoryBudget& budget() const { return *budget_; }
  // A point where long work may stop: throws SessionStop once stopped. A flag read.
  void CheckStop() const {
    if (stopped()) throw SessionStop(status());
  }

  // What one part of the session holds. One thread at a time reports to it.
  class Account {
   public:
    explicit Account(Meter* meter) : meter_(meter) {}
    ~Account() { Set(0); }
    Account(const Account&) = delete;
    Account& operator=(const Account&) = delete;

    // The part holds `bytes` now, while `doing` slice `slice` (for the message): reported
    // once it moved by MemoryBudget::kGrainBytes since the last report. Throws SessionStop
    // when the session must stop: this report took the budget past its limit, or it was
    // stopped before.
    void Hold(size_t bytes, const char* doing, int64_t slice) {
      const auto b = static_cast<int64_t>(bytes);
      if (b > held_ + MemoryBudget::kGrainBytes || b < held_ - MemoryBudget::kGrainBytes) {
        Report(b, doing, slice);
      }
      meter_->CheckStop();
    }
    // Reports `bytes` as it is, without a check: figures as planned, before anything is
    // allocated, and what is given back.
    void Set(size_t bytes);
    size_t held() const { return static_cast<size_t>(held_); }

   private:
    void Report(int64_t bytes, const char* doing, int64_t slice);
    Meter* meter_;
    int64_t held_ = 0;
  };

 private:
  std::shared_ptr<MemoryBudget> budget_;
  std::atomic<bool> stop_{false};
};

}  // namespace tandem

#endif  // TANDEM_METER_H_
