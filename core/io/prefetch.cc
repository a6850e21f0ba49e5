#include "prefetch.h"

#include <utility>

namespace tandem::io {

SlicePrefetcher::SlicePrefetcher(SliceSource* source, size_t depth)
    : source_(source), depth_(depth < 1 ? 1 : depth), thread_([this] { Run(); }) {}

SlicePrefetcher::~SlicePrefetcher() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void SlicePrefetcher::Run() {
  while (true) {
    std::vector<uint8_t> bytes;
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [this] { return stop_ || ready_.size() < depth_; });
      if (stop_) break;
      if (!spare_.empty()) {
        bytes = std::move(spare_.back());
        spare_.pop_back();
      }
    }
    absl::Status st = source_->ReadSlice(&bytes);  // outside the lock: this is the slow part
    const bool last = !st.ok();
    {
      std::lock_guard<std::mutex> lock(mu_);
      ready_.push_back(Item{std::move(st), std::move(bytes)});
      if (last) done_ = true;
    }
    cv_.notify_all();
    if (last) break;
  }
}

absl::Status SlicePrefetcher::Next(std::vector<uint8_t>* bytes) {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [this] { return !ready_.empty() || done_; });
  if (ready_.empty()) return absl::OutOfRangeError("no more slices");
  Item item = std::move(ready_.front());
  ready_.pop_front();
  if (!item.status.ok()) {
    ready_.push_front(Item{item.status, {}});  // keep answering with the same error
    return item.status;
  }
  if (!bytes->empty()) spare_.push_back(std::move(*bytes));
  *bytes = std::move(item.bytes);
  lock.unlock();
  cv_.notify_all();
  return absl::OkStatus();
}

}  // namespace tandem::io
