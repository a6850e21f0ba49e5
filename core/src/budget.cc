#include "tandem/budget.h"

#include <algorithm>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "meter.h"

namespace tandem {

int64_t MemoryBudget::Add(int64_t delta) {
  const int64_t total = held_.fetch_add(delta, std::memory_order_relaxed) + delta;
  int64_t peak = peak_.load(std::memory_order_relaxed);
  while (total > peak && !peak_.compare_exchange_weak(peak, total, std::memory_order_relaxed)) {
  }
  return total;
}

bool MemoryBudget::Report(int64_t delta, const char* doing, int64_t slice) {
  const int64_t total = Add(delta);
  if (delta <= 0 || limit_ <= 0 || total <= limit_) return true;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (status_.ok()) {
      exceeded_bytes_ = total;
      exceeded_where_ = slice >= 0 ? absl::StrCat(doing, " ", slice) : std::string(doing);
      constexpr double kMiB = 1 << 20;
      status_ = absl::ResourceExhaustedError(absl::StrFormat(
          "memory budget exceeded while %s: the session would hold %.1f MiB, over its budget "
          "of %.1f MiB",
          exceeded_where_, static_cast<double>(total) / kMiB, static_cast<double>(limit_) / kMiB));
    }
    stopped_.store(true, std::memory_order_relaxed);
  }
  WakeAll();
  return false;
}

void MemoryBudget::Cancel() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (status_.ok()) status_ = absl::CancelledError("the session was cancelled");
    stopped_.store(true, std::memory_order_relaxed);
  }
  WakeAll();
}

void MemoryBudget::AddWaker(const void* key, std::function<void()> wake) {
  std::lock_guard<std::mutex> lock(wake_mu_);
  wakers_.emplace_back(key, std::move(wake));
}

void MemoryBudget::RemoveWaker(const void* key) {
  std::lock_guard<std::mutex> lock(wake_mu_);
  std::erase_if(wakers_, [key](const auto& w) { return w.first == key; });
}

void MemoryBudget::WakeAll() {
  // Under the lock: RemoveWaker (a session's end) waits for a call in progress.
  std::lock_guard<std::mutex> lock(wake_mu_);
  for (const auto& w : wakers_) w.second();
}

bool MemoryBudget::exceeded() const {
  std::lock_guard<std::mutex> lock(mu_);
  return absl::IsResourceExhausted(status_);
}

absl::Status MemoryBudget::status() const {
  std::lock_guard<std::mutex> lock(mu_);
  return status_;
}

int64_t MemoryBudget::exceeded_bytes() const {
  std::lock_guard<std::mutex> lock(mu_);
  return exceeded_bytes_;
}

std::string MemoryBudget::exceeded_where() const {
  std::lock_guard<std::mutex> lock(mu_);
  return exceeded_where_;
}

absl::Status Meter::status() const {
  if (budget_->stopped()) return budget_->status();
  if (stop_.load(std::memory_order_relaxed)) {
    return absl::CancelledError("the session is being destroyed");
  }
  return absl::OkStatus();
}

void Meter::Account::Set(size_t bytes) {
  const auto b = static_cast<int64_t>(bytes);
  if (b != held_) meter_->budget_->AddOutside(b - held_);
  held_ = b;
}

void Meter::Account::Report(int64_t bytes, const char* doing, int64_t slice) {
  const int64_t delta = bytes - held_;
  held_ = bytes;
  meter_->budget_->Report(delta, doing, slice);
}

}  // namespace tandem
