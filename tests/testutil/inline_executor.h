// An Executor a caller supplies (tandem/executor.h): runs each task at once on the thread that
// enqueues it and counts them. Tests compare its mesh with the built-in pool's.
#ifndef TANDEM_TESTS_TESTUTIL_INLINE_EXECUTOR_H_
#define TANDEM_TESTS_TESTUTIL_INLINE_EXECUTOR_H_

#include <functional>

#include "tandem/executor.h"

namespace tandem {

class InlineExecutor final : public Executor {
 public:
  void Enqueue(std::function<void()> task) override {
    ++tasks;
    task();
  }
  int threads() const override { return 1; }
  int tasks = 0;
};

}  // namespace tandem

#endif  // TANDEM_TESTS_TESTUTIL_INLINE_EXECUTOR_H_
