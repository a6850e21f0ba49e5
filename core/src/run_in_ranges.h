// Cuts [0, n) into ranges and runs them side by side on an executor: the one way the
// simplifier hands pure per-element work (batch evaluations, the final sag correction) to
// other threads. The CPU time the ranges take on other threads is returned, for the phase
// times (thread_clock.h), which see only their own thread's.
#ifndef TANDEM_RUN_IN_RANGES_H_
#define TANDEM_RUN_IN_RANGES_H_

#include <cstddef>
#include <thread>
#include <vector>

#include "tandem/task_group.h"
#include "thread_clock.h"

namespace tandem {

// fn(piece, begin, end) for `pieces` ranges of about n / pieces elements each, in order of
// piece: pieces 1.. as tasks of `executor`, piece 0 on this thread (all of them here without
// an executor or with one piece). Returns the CPU seconds of the ranges run on other threads.
template <typename Fn>
double RunInRanges(Executor* executor, size_t n, size_t pieces, Fn&& fn) {
  if (executor == nullptr || pieces <= 1) {
    fn(size_t{0}, size_t{0}, n);
    return 0.0;
  }
  std::vector<double> seconds(pieces, 0.0);
  {
    TaskGroup group(executor);  // with no thread free, Wait runs the tasks here
    const std::thread::id caller = std::this_thread::get_id();
    for (size_t p = 1; p < pieces; ++p) {
      group.Run([&, p] {
        const double t0 = ThreadCpuSeconds();
        fn(p, p * n / pieces, (p + 1) * n / pieces);
        // On the waiting thread its time is that thread's own already.
        if (std::this_thread::get_id() != caller) seconds[p] = ThreadCpuSeconds() - t0;
      });
    }
    fn(size_t{0}, size_t{0}, n / pieces);
    group.Wait();
  }
  double sum = 0.0;
  for (double s : seconds) sum += s;
  return sum;
}

}  // namespace tandem

#endif  // TANDEM_RUN_IN_RANGES_H_
