// bench_run RESULT.json PROGRAM [ARGS...]: runs PROGRAM as a child process and writes its
// wall time, CPU time (user + system) and peak resident set size (wait4 rusage) to
// RESULT.json as {"rc": ..., "wall_s": ..., "cpu_s": ..., "peak_rss_bytes": ...}; rc is the
// exit status, or -N when killed by signal N. Exits with 0 once the result is written.
//
// Why a launcher: Linux carries a process's peak RSS across exec() (it starts from the
// high-water mark of the address space being replaced), and a child spawned directly by the
// Python driver would start from Python's own peak (15-50 MiB). Forked from this small
// program, the floor is this program's footprint (about 1-3 MiB).
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace {

double Now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: bench_run RESULT.json PROGRAM [ARGS...]\n");
    return 2;
  }
  const double t0 = Now();
  const pid_t pid = fork();
  if (pid < 0) {
    std::perror("bench_run: fork");
    return 1;
  }
  if (pid == 0) {
    execvp(argv[2], argv + 2);
    std::fprintf(stderr, "bench_run: cannot run %s: %s\n", argv[2], std::strerror(errno));
    _exit(127);
  }
  int status = 0;
  rusage ru{};
  while (wait4(pid, &status, 0, &ru) < 0) {
    if (errno != EINTR) {
      std::perror("bench_run: wait4");
      return 1;
    }
  }
  const double wall = Now() - t0;
  const int rc = WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
  const double cpu = double(ru.ru_utime.tv_sec) + 1e-6 * double(ru.ru_utime.tv_usec) +
                     double(ru.ru_stime.tv_sec) + 1e-6 * double(ru.ru_stime.tv_usec);
  FILE* f = std::fopen(argv[1], "w");
  if (f == nullptr) {
    std::perror("bench_run: result file");
    return 1;
  }
  std::fprintf(f, "{\"rc\": %d, \"wall_s\": %.6f, \"cpu_s\": %.6f, \"peak_rss_bytes\": %lld}\n", rc,
               wall, cpu, static_cast<long long>(ru.ru_maxrss) * 1024);  // Linux: KiB
  return std::fclose(f) == 0 ? 0 : 1;
}
