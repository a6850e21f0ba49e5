// The CPU time of the calling thread, for the phase times of SessionStats: the parts and the
// extraction beside their SIMPLIFY run on more threads than a small machine has cores, and a
// wall clock there counts every wait for a core (docs/decisions.md 44; the test
// Executor.PhaseTimesAreCpuTimeHoweverManyThreadsShareTheCores).
#ifndef TANDEM_THREAD_CLOCK_H_
#define TANDEM_THREAD_CLOCK_H_

#include <time.h>

namespace tandem {

inline double ThreadCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

}  // namespace tandem

#endif  // TANDEM_THREAD_CLOCK_H_
