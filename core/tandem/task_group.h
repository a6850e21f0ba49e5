// Executor: the threads a session may use, owned by the caller. A process running many sessions
// (the server) makes one Executor and hands it to every session, so that all of them together
// use that many threads, however many streams arrive; a program running one session can use the
// shared one (Executor::Shared(), one thread per core).
//
// TaskGroup: tasks run on an executor's threads, waited for together. Waiting helps: a task no
// thread has started yet runs on the waiting thread instead, so a group makes progress even when
// every thread of the executor is busy (or when it has none), and waiting inside a task cannot
// deadlock. The first exception a task throws is rethrown by Wait.
#ifndef TANDEM_EXECUTOR_H_
#define TANDEM_EXECUTOR_H_

#include <atomic>
#include <condition_variable>
#include <deque>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace tandem {

class TaskGroup;

class Executor {
 public:
  // `threads` >= 0. With 0, every task runs on the thread that waits for it (sequential).
  // A thread that cannot be started (the system refuses) is simply not there.
  explicit Executor(int threads);
  ~Executor();  // finishes the queued tasks, then joins
  Executor(const Executor&) = delete;
  Executor& operator=(const Executor&) = delete;

  int threads() const { return static_cast<int>(threads_.size()); }
  // One thread per core, started on first use and kept for the life of the process.
  static Executor& Shared();

 private:
  friend class TaskGroup;
  struct Task {
    std::function<void()> fn;
    TaskGroup* group = nullptr;
    // Set by whoever starts it, a thread of the executor or a waiting one. The executor looks
    // at the group only after claiming, so a group may end while a task it ran itself is
    // still in the executor's queue.
    std::atomic<bool> claimed{false};
  };
  void Enqueue(std::shared_ptr<Task> task);
  void Loop();

  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::shared_ptr<Task>> queue_;
  bool stop_ = false;
  std::vector<std::thread> threads_;
};

class TaskGroup {
 public:
  explicit TaskGroup(Executor* executor) : executor_(executor) {}
  ~TaskGroup();  // waits (exceptions of tasks not collected by Wait are dropped)
  TaskGroup(const TaskGroup&) = delete;
  TaskGroup& operator=(const TaskGroup&) = delete;

  // Queues fn on the executor. May be called from inside one of the group's tasks.
  void Run(std::function<void()> fn);
  // Until every task run so far has finished; rethrows the first exception of a task.
  void Wait() { WaitUntil([] { return false; }); }
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
  friend class Executor;
  // Runs one of the group's unstarted tasks here (false: none left).
  bool HelpLocked(std::unique_lock<std::mutex>& lock);
  void RethrowLocked();
  // Runs a claimed task and records its end.
  void Execute(const std::shared_ptr<Executor::Task>& task);

  Executor* executor_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::shared_ptr<Executor::Task>> unstarted_;  // may hold claimed ones: skipped
  int outstanding_ = 0;
  bool stranded_ = false;  // a task the executor never got (its queue could not grow)
  std::exception_ptr error_;
};

}  // namespace tandem

#endif  // TANDEM_EXECUTOR_H_
