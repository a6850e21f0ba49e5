// TaskGroup: tasks run on an executor's threads (executor.h), waited for together. Waiting
// helps: a task no thread has started yet runs on the waiting thread instead, so a group makes
// progress even when every thread of the executor is busy (or when it has none), and waiting
// inside a task cannot deadlock. The first exception a task throws is rethrown by Wait.
#ifndef TANDEM_TASK_GROUP_H_
#define TANDEM_TASK_GROUP_H_

#include <atomic>
#include <condition_variable>
#include <deque>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>

#include "tandem/executor.h"

namespace tandem {

class TaskGroup {
 public:
  explicit TaskGroup(Executor* executor) : executor_(executor) {}
  ~TaskGroup();  // waits (exceptions of tasks not collected by Wait are dropped)
  TaskGroup(const TaskGroup&) = delete;
  TaskGroup& operator=(const TaskGroup&) = delete;

  // Queues fn on the executor. May be called from inside one of the group's tasks.
  void Run(std::function<void()> fn);
  // Until every task run so far has finished; rethrows the first exception of a task.
  void Wait() {
    WaitUntil([] { return false; });
  }
  // Until done() holds or no task is left (done is called with the group's lock held: it must
  // not call into the group). Tasks that change what done() reads call Notify() after.
  // help = false: leave the tasks to the executor's threads when it has any (a thread that
  // only feeds the executor, e.g. a session's caller, then does not compete with them).
  template <typename Done>
  void WaitUntil(Done done, bool help = true) {
    std::unique_lock<std::mutex> lock(mu_);
    help = help || executor_->threads() == 0;
    while (outstanding_ > 0 && !done()) {
      if (!(help || stranded_) || !HelpLocked(lock)) cv_.wait(lock);
    }
    RethrowLocked();
  }
  void Notify();

 private:
  struct Task {
    std::function<void()> fn;
    // Set by whoever starts it, a thread of the executor or a waiting one. The executor's
    // copy looks at the group only after claiming, so a group may end while a task it ran
    // itself is still in the executor's queue.
    std::atomic<bool> claimed{false};
  };
  // Runs one of the group's unstarted tasks here (false: none left).
  bool HelpLocked(std::unique_lock<std::mutex>& lock);
  void RethrowLocked();
  // Runs a claimed task and records its end.
  void Execute(const std::shared_ptr<Task>& task);

  Executor* executor_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::shared_ptr<Task>> unstarted_;  // may hold claimed ones: skipped
  int outstanding_ = 0;
  bool stranded_ = false;  // a task the executor never got (its queue could not grow)
  std::exception_ptr error_;
};

}  // namespace tandem

#endif  // TANDEM_TASK_GROUP_H_
