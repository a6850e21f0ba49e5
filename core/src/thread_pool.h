// ThreadPool: the built-in Executor, a fixed set of threads taking tasks from one queue.
#ifndef TANDEM_THREAD_POOL_H_
#define TANDEM_THREAD_POOL_H_

#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include "tandem/executor.h"

namespace tandem {

class ThreadPool final : public Executor {
 public:
  // `threads` >= 0. With 0, every task runs on the thread that waits for it (sequential).
  explicit ThreadPool(int threads);
  ~ThreadPool() override;  // finishes the queued tasks, then joins
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  void Enqueue(std::function<void()> task) override;
  int threads() const override { return static_cast<int>(threads_.size()); }

 private:
  void Loop();

  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> queue_;
  bool stop_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace tandem

#endif  // TANDEM_THREAD_POOL_H_
