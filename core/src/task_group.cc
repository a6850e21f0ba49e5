// TaskGroup (task_group.h): tasks on an Executor, claimed once by whoever starts them first.
#include "tandem/task_group.h"

#include <utility>

namespace tandem {

TaskGroup::~TaskGroup() {
  std::unique_lock<std::mutex> lock(mu_);
  while (outstanding_ > 0) {
    if (!HelpLocked(lock)) cv_.wait(lock);
  }
}

void TaskGroup::Run(std::function<void()> fn) {
  auto task = std::make_shared<Task>();
  task->fn = std::move(fn);
  {
    std::lock_guard<std::mutex> lock(mu_);
    while (!unstarted_.empty() && unstarted_.front()->claimed) unstarted_.pop_front();
    unstarted_.push_back(task);  // may throw: then nothing has changed
    ++outstanding_;
  }
  if (executor_->threads() == 0) return;  // the waiting thread runs it
  try {
    executor_->Enqueue([this, task = std::move(task)] {
      if (!task->claimed.exchange(true)) Execute(task);  // else a waiting thread ran it
    });
  } catch (...) {  // only waiting threads can run it now
    std::lock_guard<std::mutex> lock(mu_);
    stranded_ = true;
    throw;
  }
}

void TaskGroup::Notify() {
  std::lock_guard<std::mutex> lock(mu_);
  cv_.notify_all();
}

bool TaskGroup::HelpLocked(std::unique_lock<std::mutex>& lock) {
  while (!unstarted_.empty()) {
    std::shared_ptr<Task> task = std::move(unstarted_.front());
    unstarted_.pop_front();
    if (task->claimed.exchange(true)) continue;  // an executor thread has it
    lock.unlock();
    Execute(task);
    lock.lock();
    return true;
  }
  return false;
}

void TaskGroup::Execute(const std::shared_ptr<Task>& task) {
  std::exception_ptr error;
  try {
    task->fn();
  } catch (...) {
    error = std::current_exception();
  }
  task->fn = nullptr;  // what it captured goes now, not when the queue lets go of it
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (error && !error_) error_ = error;
    --outstanding_;
    cv_.notify_all();  // under the lock: once it is released, the group may be gone
  }
}

void TaskGroup::RethrowLocked() {
  if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
}

}  // namespace tandem
