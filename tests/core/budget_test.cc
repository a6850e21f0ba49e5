// A session's memory budget (tandem/budget.h): checked inside the steps where the arrays grow,
// so that a slice of noise (every cube crossed, two to three triangles a voxel) fails the
// session while its layer is staged, not slices later; shared by several sessions; and
// stopping: a cancelled or destroyed session's queued steps do not run, its running one
// returns at its next check.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <future>
#include <memory>
#include <random>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "absl/strings/match.h"
#include "tandem/budget.h"
#include "tandem/task_group.h"
#include "thread_pool.h"
#include "tandem/eval/synthetic.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace tandem {
namespace {

constexpr int64_t kMiB = int64_t{1} << 20;
// What a session may hold past its budget at a report: a grain for each of its parts' figures
// (2 a slab, its slices, its sealed shares) and the last row scanned.
constexpr int64_t kSlack = 4 * kMiB;

using Clock = std::chrono::steady_clock;
double SecondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// Uniform random bytes (iso 127.5, the median: every cube of every layer is crossed).
std::vector<std::vector<uint8_t>> NoiseSlices(int64_t n, int64_t nz, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<std::vector<uint8_t>> out(static_cast<size_t>(nz));
  for (auto& s : out) {
    s.resize(static_cast<size_t>(n * n));
    for (auto& v : s) v = static_cast<uint8_t>(rng() >> 24);
  }
  return out;
}

VolumeInfo ByteGrid(int64_t n, int64_t nz) {
  VolumeInfo g;
  g.nx = g.ny = n;
  g.nz = nz;
  g.dtype = DType::kUInt8;
  return g;
}

SessionOptions NoiseOptions() {
  SessionOptions o;
  o.iso = 127.5;
  o.error = 0.5;
  return o;
}

// Feeds slices until one fails; returns that status (OK if none did, Finish included).
absl::Status Feed(TandemSession& s, const std::vector<std::vector<uint8_t>>& slices,
                  int64_t* fed = nullptr) {
  for (size_t k = 0; k < slices.size(); ++k) {
    if (fed) *fed = static_cast<int64_t>(k);
    if (absl::Status st = s.AddSliceBytes(DType::kUInt8, slices[k].data()); !st.ok()) return st;
  }
  return s.Finish();
}

TEST(MemoryBudget, CountsReportsAndOutsideBytesAndSaysWhereItWasPassed) {
  MemoryBudget b(10 * kMiB);
  b.AddOutside(3 * kMiB);
  EXPECT_TRUE(b.Report(6 * kMiB, "extracting slice", 3));
  EXPECT_EQ(b.held(), 9 * kMiB);
  EXPECT_FALSE(b.stopped());
  EXPECT_TRUE(b.Report(-2 * kMiB, "simplifying slice", 3));
  EXPECT_FALSE(b.Report(4 * kMiB, "extracting slice", 4));  // 11 MiB
  EXPECT_TRUE(b.stopped());
  EXPECT_TRUE(b.exceeded());
  EXPECT_EQ(b.exceeded_bytes(), 11 * kMiB);
  EXPECT_EQ(b.exceeded_where(), "extracting slice 4");
  EXPECT_EQ(b.peak(), 11 * kMiB);
  EXPECT_EQ(b.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_EQ(b.status().message(),
            "memory budget exceeded while extracting slice 4: the session would hold 11.0 MiB, "
            "over its budget of 10.0 MiB");
  b.Cancel();  // the first reason stays
  EXPECT_EQ(b.status().code(), absl::StatusCode::kResourceExhausted);

  MemoryBudget unlimited;
  EXPECT_TRUE(unlimited.Report(int64_t{1} << 40, "extracting slice", 0));
  unlimited.Cancel();
  EXPECT_TRUE(unlimited.stopped());
  EXPECT_FALSE(unlimited.exceeded());
  EXPECT_EQ(unlimited.status().code(), absl::StatusCode::kCancelled);
}

// Split and pipelined (the server's sessions), one slab stepped on the caller's thread, and
// one slab overlapping EXTRACT with SIMPLIFY: the noise's first layer (about 650,000 triangles
// at 512², some 65 MiB once committed) stops the session while it is staged.
TEST(MemoryBudget, ANoisyLayerFailsTheSessionWhileItIsExtracted) {
  const auto slices = NoiseSlices(512, 8, 1);
  struct Variant {
    int parts;
    bool pipeline;
  };
  for (const Variant v : {Variant{0, true}, Variant{1, false}, Variant{1, true}}) {
    SCOPED_TRACE(testing::Message() << "parts " << v.parts << " pipeline " << v.pipeline);
    SessionOptions o = NoiseOptions();
    o.parts = v.parts;
    o.pipeline = v.pipeline;
    auto budget = std::make_shared<MemoryBudget>(32 * kMiB);
    auto s = TandemSession::Create(ByteGrid(512, 8), o, nullptr, budget);
    ASSERT_TRUE(s.ok()) << s.status();
    int64_t fed = 0;
    const absl::Status st = Feed(**s, slices, &fed);
    ASSERT_EQ(st.code(), absl::StatusCode::kResourceExhausted) << st;
    EXPECT_TRUE(absl::StartsWith(st.message(), "memory budget exceeded while ")) << st;
    EXPECT_TRUE(absl::StrContains(st.message(), "over its budget of 32.0 MiB")) << st;
    // Its first layer: the queued steps run at most kSlicesInFlight behind, and the session
    // reports as soon as one has stopped.
    EXPECT_LE(fed, 1 + TandemSession::kSlicesInFlight) << st;
    EXPECT_GT(budget->exceeded_bytes(), 32 * kMiB);
    EXPECT_LE(budget->peak(), 32 * kMiB + kSlack);
    EXPECT_LE(static_cast<int64_t>((*s)->MemoryBytes()), 32 * kMiB + kSlack);
    // Every later call says the same.
    EXPECT_EQ((*s)->AddSliceBytes(DType::kUInt8, slices[0].data()), st);
    EXPECT_EQ((*s)->Finish(), st);
    s->reset();
    EXPECT_EQ(budget->held(), 0) << "a destroyed session gives its figures back";
  }
}

// A session that fits is not changed by its budget: the same mesh as without one.
TEST(MemoryBudget, ASessionWithinItsBudgetGivesTheSameMesh) {
  auto run = [](std::shared_ptr<MemoryBudget> budget) {
    auto src = eval::MakeSyntheticSource(eval::Shape::kGyroid, 160, 96, 64);
    SessionOptions o;
    o.error = 0.2;
    auto s = TandemSession::Create(src->info(), o, nullptr, std::move(budget));
    EXPECT_TRUE(s.ok()) << s.status();
    std::vector<uint8_t> bytes;
    while (src->ReadSlice(&bytes).ok()) {
      EXPECT_TRUE((*s)->AddSliceBytes(src->info().dtype, bytes.data()).ok());
    }
    EXPECT_TRUE((*s)->Finish().ok());
    return (*s)->Snapshot();
  };
  auto budget = std::make_shared<MemoryBudget>(256 * kMiB);
  const IndexedMesh with = run(budget);
  const IndexedMesh without = run(nullptr);
  EXPECT_GT(with.num_triangles(), 1000u);
  EXPECT_EQ(with.positions, without.positions);
  EXPECT_EQ(with.indices, without.indices);
  EXPECT_GT(budget->peak(), 0);
  EXPECT_FALSE(budget->stopped());
}

// Two sessions and their owner's own bytes on one budget: the total is what is bounded, and
// the first to pass it stops both.
TEST(MemoryBudget, SessionsSharingABudgetAreBoundedTogether) {
  const auto slices = NoiseSlices(256, 6, 2);
  auto budget = std::make_shared<MemoryBudget>(24 * kMiB);
  budget->AddOutside(8 * kMiB);
  auto a = TandemSession::Create(ByteGrid(256, 6), NoiseOptions(), nullptr, budget);
  auto b = TandemSession::Create(ByteGrid(256, 6), NoiseOptions(), nullptr, budget);
  ASSERT_TRUE(a.ok() && b.ok());
  absl::Status sa, sb;
  for (size_t k = 0; k < slices.size() && (sa.ok() || sb.ok()); ++k) {
    if (sa.ok()) sa = (*a)->AddSliceBytes(DType::kUInt8, slices[k].data());
    if (sb.ok()) sb = (*b)->AddSliceBytes(DType::kUInt8, slices[k].data());
  }
  if (sa.ok()) sa = (*a)->Finish();
  if (sb.ok()) sb = (*b)->Finish();
  EXPECT_EQ(sa.code(), absl::StatusCode::kResourceExhausted) << sa;
  EXPECT_EQ(sb.code(), absl::StatusCode::kResourceExhausted) << sb;
  EXPECT_EQ(sa, sb) << "one failure, reported by both";
  EXPECT_LE(budget->peak(), 24 * kMiB + 2 * kSlack);
  a->reset();
  b->reset();
  EXPECT_EQ(budget->held(), 8 * kMiB) << "only the owner's own bytes are left";
}

// A session's step of noise grows long once the time lag releases the layers' edges (at
// 256², split in two, the fifth slice's step takes about half a second). Cancelled while that
// step runs, the session says so at the next call and its destructor returns at once;
// destroyed without a cancel, the same: the running steps stop at their next check instead
// of running to their end, and those not started never run.
TEST(MemoryBudget, CancelledOrDestroyedSessionsStopTheirRunningStepsAtOnce) {
  constexpr int64_t n = 256, nz = 6;
  const auto slices = NoiseSlices(n, nz, 3);
  ThreadPool executor(2);
  SessionOptions o = NoiseOptions();
  o.parts = 2;  // a step a thread
  // Slices 0..3 stepped, then slice 4 queued (at *queued), and its steps seen running (the
  // budget hears from them as the layer is staged).
  auto start = [&](const std::shared_ptr<MemoryBudget>& budget, Clock::time_point* queued) {
    auto s = TandemSession::Create(ByteGrid(n, nz), o, &executor, budget);
    EXPECT_TRUE(s.ok()) << s.status();
    EXPECT_EQ((*s)->num_parts(), 2);
    for (size_t k = 0; k <= 4; ++k) {
      if (k == 4) {
        (void)(*s)->num_triangles();  // waits for the steps queued so far
        *queued = Clock::now();
      }
      EXPECT_TRUE((*s)->AddSliceBytes(DType::kUInt8, slices[k].data()).ok());
    }
    const int64_t before = budget->held();
    const auto deadline = Clock::now() + std::chrono::seconds(10);
    while (budget->held() < before + kMiB && Clock::now() < deadline) std::this_thread::yield();
    EXPECT_GE(budget->held(), before + kMiB) << "slice 4's steps did not start";
    return *std::move(s);
  };
  // The whole step of slice 4, from its queueing: the stops below begin once it is seen
  // running, so a stop that waited for the step would take most of this. Each stop is the
  // quickest of up to three tries, so that a moment without a core on a loaded machine is not
  // counted.
  Clock::time_point t0;
  auto stepped = start(std::make_shared<MemoryBudget>(), &t0);
  (void)stepped->num_triangles();
  const double step_s = SecondsSince(t0);
  stepped.reset();

  double cancel_s = 1e9, drop_s = 1e9;
  std::shared_ptr<MemoryBudget> budget;
  for (int attempt = 0; attempt < 3 && std::max(cancel_s, drop_s) >= step_s / 4; ++attempt) {
    budget = std::make_shared<MemoryBudget>();
    auto cancelled = start(budget, &t0);
    t0 = Clock::now();
    budget->Cancel();
    const absl::Status st = cancelled->AddSliceBytes(DType::kUInt8, slices[5].data());
    EXPECT_EQ(st.code(), absl::StatusCode::kCancelled) << st;
    cancelled.reset();
    cancel_s = std::min(cancel_s, SecondsSince(t0));
    EXPECT_EQ(budget->held(), 0);

    auto dropped = start(std::make_shared<MemoryBudget>(), &t0);
    t0 = Clock::now();
    dropped.reset();
    drop_s = std::min(drop_s, SecondsSince(t0));
  }
  std::printf("slice 4's steps took %.3f s; cancelled and destroyed in %.3f s, destroyed in "
              "%.3f s (the quickest tries)\n", step_s, cancel_s, drop_s);
  EXPECT_LT(cancel_s, step_s / 4);
  EXPECT_LT(drop_s, step_s / 4);
  EXPECT_EQ(budget->held(), 0);
}

// A session whose slices wait in the ring for its queued steps, which stand behind another
// session's long step on a shared executor (here: its one thread, held by a task that does
// not end), returns from AddSlice as soon as its budget is cancelled, not when its steps
// get the thread: a server gives a vanished client's slot back at once under load.
TEST(MemoryBudget, ASessionWaitingBehindOtherWorkWakesWhenCancelled) {
  constexpr int64_t n = 96, nz = 8;
  const auto slices = NoiseSlices(n, nz, 5);
  ThreadPool executor(1);
  std::promise<void> release;
  std::shared_future<void> released = release.get_future().share();
  TaskGroup other(&executor);
  other.Run([released] { released.wait(); });  // another session's step, as long as we like
  SessionOptions o = NoiseOptions();
  o.parts = 2;
  auto budget = std::make_shared<MemoryBudget>();
  auto s = TandemSession::Create(ByteGrid(n, nz), o, &executor, budget);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ((*s)->num_parts(), 2);
  // The ring holds TandemSession::kSlicesInFlight slices; the next one waits for a slot.
  for (int64_t k = 0; k < TandemSession::kSlicesInFlight; ++k) {
    ASSERT_TRUE((*s)->AddSliceBytes(DType::kUInt8, slices[k].data()).ok());
  }
  std::future<absl::Status> waiting = std::async(std::launch::async, [&] {
    return (*s)->AddSliceBytes(DType::kUInt8, slices[TandemSession::kSlicesInFlight].data());
  });
  EXPECT_EQ(waiting.wait_for(std::chrono::milliseconds(200)), std::future_status::timeout)
      << "the slice did not wait for the ring";
  const auto t0 = Clock::now();
  budget->Cancel();
  const bool woke = waiting.wait_for(std::chrono::seconds(5)) == std::future_status::ready;
  const double wake_s = SecondsSince(t0);
  release.set_value();  // (without the wake, the slice waits for this)
  const absl::Status st = waiting.get();
  EXPECT_TRUE(woke) << "AddSlice waited for the executor";
  EXPECT_LT(wake_s, 1.0);
  EXPECT_EQ(st.code(), absl::StatusCode::kCancelled) << st;
  EXPECT_EQ((*s)->AddSliceBytes(DType::kUInt8, slices[5].data()).code(),
            absl::StatusCode::kCancelled);
  s->reset();
  other.Wait();
  EXPECT_EQ(budget->held(), 0);
}

}  // namespace
}  // namespace tandem
