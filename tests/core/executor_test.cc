// The executor (executor.h, task_group.h): every task runs once, waiting helps, nested waits
// cannot deadlock, and a session works only on the executor it is given (the built-in pool or
// one the caller supplies): it starts no thread of its own, and its mesh does not depend on how
// many threads the executor has. Its phase times are CPU time, however many threads share the
// cores.
#include <dirent.h>
#include <signal.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <atomic>
#include <functional>
#include <stdexcept>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "tandem/task_group.h"
#include "thread_pool.h"
#include "tandem/eval/synthetic.h"
#include "tandem/tandem.h"
#include "testutil/inline_executor.h"

namespace tandem {
namespace {

int ThreadsOfThisProcess() {
  int n = 0;
  if (DIR* d = opendir("/proc/self/task")) {
    while (dirent* e = readdir(d)) n += e->d_name[0] != '.';
    closedir(d);
  }
  return n;
}

TEST(Executor, RunsEveryTaskOnceAndWaitRethrows) {
  for (int threads : {0, 1, 3}) {
    ThreadPool ex(threads);
    EXPECT_EQ(ex.threads(), threads);
    std::atomic<int> runs{0};
    TaskGroup g(&ex);
    for (int i = 0; i < 100; ++i) g.Run([&] { ++runs; });
    g.Wait();
    EXPECT_EQ(runs.load(), 100) << threads << " threads";
    g.Run([] { throw std::runtime_error("boom"); });
    EXPECT_THROW(g.Wait(), std::runtime_error);
    g.Wait();  // the exception was collected once
  }
}

TEST(Executor, WithoutThreadsTheWaiterRunsTheTasks) {
  ThreadPool ex(0);
  std::thread::id ran;
  TaskGroup g(&ex);
  g.Run([&] { ran = std::this_thread::get_id(); });
  g.Wait();
  EXPECT_EQ(ran, std::this_thread::get_id());
}

TEST(Executor, TasksThatWaitForTasksDoNotDeadlock) {
  // One thread, and every task waits for a group of its own: only helping makes progress.
  ThreadPool ex(1);
  std::atomic<int> inner{0};
  TaskGroup outer(&ex);
  for (int i = 0; i < 4; ++i) {
    outer.Run([&] {
      TaskGroup g(&ex);
      for (int j = 0; j < 5; ++j) g.Run([&] { ++inner; });
      g.Wait();
    });
  }
  outer.Wait();
  EXPECT_EQ(inner.load(), 20);
}

IndexedMesh RunLink(Executor* ex, bool pipeline, int* threads_added) {
  auto src = eval::MakeSyntheticSource(eval::Shape::kLink, 96, 96, 40);
  SessionOptions o;
  o.error = 0.2;
  o.parts = 4;
  o.pipeline = pipeline;
  const int before = ThreadsOfThisProcess();
  auto session = TandemSession::Create(src->info(), o, ex);
  EXPECT_TRUE(session.ok()) << session.status();
  std::vector<uint8_t> bytes;
  int most = before;
  while (src->ReadSlice(&bytes).ok()) {
    EXPECT_TRUE((*session)->AddSliceBytes(src->info().dtype, bytes.data()).ok());
    most = std::max(most, ThreadsOfThisProcess());
  }
  EXPECT_TRUE((*session)->Finish().ok());
  if (threads_added != nullptr) *threads_added = most - before;
  return (*session)->Snapshot();
}

TEST(Executor, ASessionUsesOnlyTheExecutorItIsGiven) {
  ThreadPool one(1);  // started before counting
  int added = -1;
  const IndexedMesh mesh = RunLink(&one, /*pipeline=*/true, &added);
  EXPECT_EQ(added, 0) << "a session on a given executor started threads of its own";
  ASSERT_GT(mesh.num_triangles(), 300u);
  // Same mesh on no threads, more threads, and with no pipelining at all.
  ThreadPool none(0), three(3);
  for (auto [ex, pipeline] : {std::pair{&none, true}, {&three, true}, {&one, false}}) {
    const IndexedMesh other = RunLink(ex, pipeline, nullptr);
    EXPECT_EQ(other.positions, mesh.positions);
    EXPECT_EQ(other.indices, mesh.indices);
  }
}

// Executors the caller supplies (executor.h's interface): InlineExecutor (testutil), and one
// that counts the tasks it hands to a pool.
class CountingExecutor final : public Executor {
 public:
  explicit CountingExecutor(int threads) : pool_(threads) {}
  void Enqueue(std::function<void()> task) override {
    ++tasks;
    pool_.Enqueue(std::move(task));
  }
  int threads() const override { return pool_.threads(); }
  std::atomic<int> tasks{0};

 private:
  ThreadPool pool_;
};

TEST(Executor, ASessionRunsOnAnExecutorTheCallerSupplies) {
  const IndexedMesh shared = RunLink(&Executor::Shared(), /*pipeline=*/true, nullptr);
  ASSERT_GT(shared.num_triangles(), 300u);
  InlineExecutor serial;
  CountingExecutor counting(2);
  for (Executor* ex : {static_cast<Executor*>(&serial), static_cast<Executor*>(&counting)}) {
    const IndexedMesh mesh = RunLink(ex, /*pipeline=*/true, nullptr);
    EXPECT_EQ(mesh.positions, shared.positions);
    EXPECT_EQ(mesh.indices, shared.indices);
  }
  // A task a slab step (4 slabs, 40 slices) or a batch, never one a voxel or a triangle.
  EXPECT_GE(serial.tasks, 4 * 40);
  EXPECT_GE(counting.tasks.load(), 4 * 40);
  EXPECT_LT(counting.tasks.load(), 2 * 4 * 40);
}

TEST(Executor, SessionsShareOneExecutor) {
  // Four sessions on one 2-thread executor, fed in turn: each gives the mesh it gives alone.
  ThreadPool two(2);
  const IndexedMesh alone = RunLink(&two, true, nullptr);
  auto src = eval::MakeSyntheticSource(eval::Shape::kLink, 96, 96, 40);
  SessionOptions o;
  o.error = 0.2;
  o.parts = 4;
  std::vector<std::unique_ptr<TandemSession>> sessions;
  for (int i = 0; i < 4; ++i) sessions.push_back(*TandemSession::Create(src->info(), o, &two));
  std::vector<uint8_t> bytes;
  while (src->ReadSlice(&bytes).ok()) {
    for (auto& s : sessions) ASSERT_TRUE(s->AddSliceBytes(src->info().dtype, bytes.data()).ok());
  }
  for (auto& s : sessions) {
    ASSERT_TRUE(s->Finish().ok());
    const IndexedMesh m = s->Snapshot();
    EXPECT_EQ(m.positions, alone.positions);
    EXPECT_EQ(m.indices, alone.indices);
  }
}

double ProcessCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

TEST(Executor, PhaseTimesAreCpuTimeHoweverManyThreadsShareTheCores) {
  // Eight parts on four times as many threads as there are cores, each simplifying its whole
  // surface at the end (classical), beside a busy process on every core: timed by the wall
  // clock, each part's SIMPLIFY also counted its waits for a core, and the phases summed to
  // more than the process's CPU time. (In lock-step each step is too short to be preempted
  // often.)
  const int cores = static_cast<int>(std::max(2u, std::thread::hardware_concurrency()));
  ThreadPool many(4 * cores);
  struct Busy {
    std::vector<pid_t> pids;
    ~Busy() {  // also when an assertion below returns early
      for (pid_t pid : pids) kill(pid, SIGKILL);
      for (pid_t pid : pids) waitpid(pid, nullptr, 0);
    }
  } busy;
  for (int i = 0; i < cores; ++i) {
    const pid_t pid = fork();
    if (pid == 0) {
      alarm(60);  // whatever happens to the test
      std::atomic<uint64_t> spins{0};
      for (;;) spins.fetch_add(1, std::memory_order_relaxed);
    }
    if (pid > 0) busy.pids.push_back(pid);
  }
  auto src = eval::MakeSyntheticSource(eval::Shape::kGyroid, 384, 384, 48);
  SessionOptions o;
  o.error = 0.2;
  o.parts = 8;
  o.pipeline = true;
  o.schedule = Schedule::kClassical;
  auto session = TandemSession::Create(src->info(), o, &many);
  ASSERT_TRUE(session.ok()) << session.status();
  std::vector<std::vector<uint8_t>> slices;  // read before: the field's sines are no phase
  for (std::vector<uint8_t> bytes; src->ReadSlice(&bytes).ok();) slices.push_back(bytes);
  const double cpu0 = ProcessCpuSeconds();
  for (const auto& bytes : slices) {
    ASSERT_TRUE((*session)->AddSliceBytes(src->info().dtype, bytes.data()).ok());
  }
  ASSERT_TRUE((*session)->Finish().ok());
  const double cpu = ProcessCpuSeconds() - cpu0;
  const PhaseTimes& t = (*session)->stats().time;
  EXPECT_GT(t.extract_s, 0.0);
  EXPECT_GT(t.simplify_s, 0.0);
  EXPECT_LE(t.extract_s + t.simplify_s, cpu + 0.01)  // 10 ms: a clock tick or so of slack
      << "extract " << t.extract_s << " s, simplify " << t.simplify_s << " s, process CPU " << cpu
      << " s";
}

}  // namespace
}  // namespace tandem
