// Executor: the threads a session may use, owned by the caller. A process running many sessions
// (the server) makes one executor and hands it to every session, so that all of them together
// use that many threads, however many streams arrive; a program running one session can use the
// shared one (Executor::Shared(), one thread per core), or supply its own.
#ifndef TANDEM_EXECUTOR_H_
#define TANDEM_EXECUTOR_H_

#include <functional>
#include <memory>

namespace tandem {

class Executor {
 public:
  virtual ~Executor() = default;

  // Runs `task` once, on any thread, now (inline) or later; the task itself never throws.
  // Called only when threads() > 0. It may throw (the task is then not queued): whoever waits
  // for the task runs it instead.
  // A session calls it once per task (a slab's step, a batch), never per voxel or triangle.
  virtual void Enqueue(std::function<void()> task) = 0;
  // How many tasks may run at once, for sizing parallel work. 0: Enqueue is never called, and
  // every task runs on the thread that waits for it (sequential).
  virtual int threads() const = 0;

  // The built-in pool, one thread per core, started on first use and kept for the life of
  // the process.
  static Executor& Shared();
};

// A pool of `threads` (>= 0) threads of its own; destroying it finishes the queued tasks, then
// joins. A thread that cannot be started (the system refuses) is simply not there.
std::unique_ptr<Executor> NewThreadPool(int threads);

}  // namespace tandem

#endif  // TANDEM_EXECUTOR_H_
