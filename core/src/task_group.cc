#include "tandem/executor.h"

#include <algorithm>
#include <system_error>
#include <utility>

namespace tandem {

Executor::Executor(int threads) {
  try {
    for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { Loop(); });
  } catch (const std::system_error&) {
    // Fewer threads than asked: waiting threads run what the others cannot.
  }
}

Executor::~Executor() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  for (std::thread& t : threads_) t.join();
}

Executor& Executor::Shared() {
  static Executor* shared =
      new Executor(static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
  return *shared;  // never destroyed: sessions may outlive static destruction order
}

void Executor::Enqueue(std::shared_ptr<Task> task) {
  if (threads_.empty()) return;  // the waiting thread runs it
  {
    std::lock_guard<std::mutex> lock(mu_);
    queue_.push_back(std::move(task));
  }
  cv_.notify_one();
}

void Executor::Loop() {
  for (;;) {
    std::shared_ptr<Task> task;
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [&] { return stop_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stop_ and nothing left
      task = std::move(queue_.front());
      queue_.pop_front();
    }
    if (task->claimed.exchange(true)) continue;  // a waiting thread ran it
    task->group->Execute(task);
  }
}

TaskGroup::~TaskGroup() {
  std::unique_lock<std::mutex> lock(mu_);
  while (outstanding_ > 0) {
    if (!HelpLocked(lock)) cv_.wait(lock);
  }
}

void TaskGroup::Run(std::function<void()> fn) {
  auto task = std::make_shared<Executor::Task>();
  task->fn = std::move(fn);
  task->group = this;
  {
    std::lock_guard<std::mutex> lock(mu_);
    while (!unstarted_.empty() && unstarted_.front()->claimed) unstarted_.pop_front();
    unstarted_.push_back(task);  // may throw: then nothing has changed
    ++outstanding_;
  }
  try {
    executor_->Enqueue(std::move(task));
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
    std::shared_ptr<Executor::Task> task = std::move(unstarted_.front());
    unstarted_.pop_front();
    if (task->claimed.exchange(true)) continue;  // an executor thread has it
    lock.unlock();
    Execute(task);
    lock.lock();
    return true;
  }
  return false;
}

void TaskGroup::Execute(const std::shared_ptr<Executor::Task>& task) {
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
