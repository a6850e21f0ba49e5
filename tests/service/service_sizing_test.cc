// The per-session memory budget bounds the process: N sessions at --max-sessions N,
// --session-memory-mb B and --max-inflight-bytes I keep the server's peak resident size
// under its idle size + N x (B + I), the rule deploy/README.md sizes pods by. The streams
// are the hard case for the accounting: full-resolution surfaces (every triangle kept), so
// that the final copy and Draco encoding of the mesh weigh as much as the session itself.
// Some streams end with RESOURCE_EXHAUSTED (honestly: their final mesh would not fit); the
// process stays under the bound either way. And whatever the voxels: streams of noise, a
// checkerboard or an iso-value inside noise, which grow a session by hundreds of MiB a
// slice, keep the pod under its memory limit too (the sessions check their budget while
// they extract and simplify, and stop at once when refused). Normal builds only: under ASan
// the resident size is the sanitizer's.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "service/service_testutil.h"
#include "tandem/eval/synthetic.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

// VmHWM (peak resident size) of a process in bytes, or -1.
int64_t PeakResidentBytes(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stoll(line.substr(6)) * 1024;
  }
  return -1;
}

// `n` concurrent full-resolution streams of `volume` (client --timeout `timeout_s`, each
// waited for up to `wait_s`); `ok` counts those that succeeded. The others must have been
// refused for memory (RESOURCE_EXHAUSTED), and at least one must succeed.
void RunFullResolutionStreams(const TestServer& server, const std::string& volume,
                              const std::string& dir, int n, int timeout_s, int wait_s,
                              int* ok) {
  std::vector<std::unique_ptr<ChildProcess>> clients;
  for (int i = 0; i < n; ++i) {
    auto c = ChildProcess::Spawn(
        {BinPath("tandem-client"), "stream", "--server", server.address(), "--input", volume,
         "--iso", "0", "--error", "0.2", "--schedule", "none", "--timeout",
         std::to_string(timeout_s), "--out", dir + "/out" + std::to_string(i) + ".drc"},
        dir);
    ASSERT_TRUE(c.ok()) << c.status();
    clients.push_back(*std::move(c));
  }
  for (auto& c : clients) {
    const std::optional<int> code = c->Wait(wait_s);
    ASSERT_TRUE(code.has_value()) << "a client did not finish";
    if (*code == 0) ++*ok;
    else EXPECT_NE(c->Stderr().find("RESOURCE_EXHAUSTED"), std::string::npos) << c->Stderr();
  }
  EXPECT_GT(*ok, 0) << "every stream was refused: the test no longer measures the encoding";
}

TEST(Sizing, SessionsStayWithinTheirBudgetsAtThePeak) {
  if (kSanitized) GTEST_SKIP() << "resident sizes are the sanitizer's own under ASan and TSan";
  const std::string dir = MakeTempDir();
  // 192^3 gyroid: 466,110 triangles at full resolution, a session of about 50 MiB and a
  // final encoding of about as much again.
  auto volume = WriteSyntheticVolume(
      dir, "gyroid", eval::MakeSyntheticSource(eval::Shape::kGyroid, 192, 192, 192));
  ASSERT_TRUE(volume.ok()) << volume.status();
  constexpr int kSessions = 4;
  constexpr int64_t kBudgetMiB = 80, kInflight = 8 << 20;
  auto server = TestServer::Start({"--max-sessions", std::to_string(kSessions),
                                   "--session-memory-mb", std::to_string(kBudgetMiB),
                                   "--max-inflight-bytes", std::to_string(kInflight),
                                   "--max-message-bytes", std::to_string(4 << 20)});
  ASSERT_TRUE(server.ok()) << server.status();
  const pid_t pid = (*server)->process().pid();
  const int64_t idle = ResidentBytes(pid);
  ASSERT_GT(idle, 0);

  int ok = 0;
  ASSERT_NO_FATAL_FAILURE(
      RunFullResolutionStreams(**server, *volume, dir, kSessions, 120, 180, &ok));
  const int64_t peak = PeakResidentBytes(pid);
  const int64_t bound = idle + kSessions * ((kBudgetMiB << 20) + kInflight);
  std::printf("server peak %lld MiB (idle %lld MiB, bound %lld MiB), %d of %d streams OK\n",
              static_cast<long long>(peak >> 20), static_cast<long long>(idle >> 20),
              static_cast<long long>(bound >> 20), ok, kSessions);
  EXPECT_LE(peak, bound) << "peak " << (peak >> 20) << " MiB, idle " << (idle >> 20)
                         << " MiB, bound " << (bound >> 20) << " MiB";
}

// The pod as deploy/k8s/deployment.yaml runs it: its server flags (sessions, budgets, slice
// and message limits, grace), read from the manifest, and its memory limit.
struct Pod {
  std::vector<std::string> flags;
  int64_t limit_mib = 0, sessions = 0, budget_mib = 0, slice_voxels = 0, inflight = 0;
};

void ReadPod(Pod* pod) {
  std::ifstream yaml(TANDEM_DEPLOYMENT_YAML);
  ASSERT_TRUE(yaml) << TANDEM_DEPLOYMENT_YAML;
  bool in_args = false, in_limits = false;
  auto value = [](const std::string& flag) { return std::stoll(flag.substr(flag.find('=') + 1)); };
  for (std::string line; std::getline(yaml, line);) {
    const size_t text = line.find_first_not_of(' ');
    if (text == std::string::npos) continue;
    const std::string item = line.substr(text);
    if (item == "args:") { in_args = true; continue; }
    if (item == "limits:") { in_limits = true; continue; }
    if (in_args && item.rfind("- --", 0) == 0) {
      const std::string flag = item.substr(2);
      // Off here: the metrics port, JSON logs and the drain delay (they do not change
      // memory; the delay would only slow the test's shutdown).
      if (flag.rfind("--metrics-listen", 0) == 0 || flag.rfind("--log-format", 0) == 0 ||
          flag.rfind("--drain-delay-seconds", 0) == 0) {
        continue;
      }
      if (flag.rfind("--max-sessions=", 0) == 0) pod->sessions = value(flag);
      if (flag.rfind("--session-memory-mb=", 0) == 0) pod->budget_mib = value(flag);
      if (flag.rfind("--max-voxels-per-slice=", 0) == 0) pod->slice_voxels = value(flag);
      if (flag.rfind("--max-inflight-bytes=", 0) == 0) pod->inflight = value(flag);
      pod->flags.push_back(flag);
      continue;
    }
    in_args = false;
    if (in_limits && item.rfind("memory:", 0) == 0) {
      const std::string limit = item.substr(item.find_first_not_of(' ', 7));
      ASSERT_EQ(limit.substr(limit.size() - 2), "Mi") << line;
      pod->limit_mib = std::stoll(limit.substr(0, limit.size() - 2));
      in_limits = false;
    }
  }
  ASSERT_GT(pod->sessions, 0) << "no --max-sessions in the manifest's args";
  ASSERT_GT(pod->budget_mib, 0) << "no --session-memory-mb in the manifest's args";
  ASSERT_GT(pod->slice_voxels, 0) << "no --max-voxels-per-slice in the manifest's args";
  ASSERT_GT(pod->inflight, 0) << "no --max-inflight-bytes in the manifest's args";
  ASSERT_GT(pod->limit_mib, 0) << "no memory limit in the manifest";
}

// As many full-resolution streams as the pod takes sessions, each large enough to fill its
// budget (a 256x256x600 gyroid: 833,418 triangles, whose encoding alone is over half the 256
// MiB budget). The server's peak must stay under the container's memory limit (requests =
// limits, so this is also what the scheduler reserves): above it the kernel would OOM-kill
// the pod and every session on it.
TEST(Sizing, ThePodsFlagsKeepItsSessionsUnderItsMemoryLimit) {
  if (kSanitized) GTEST_SKIP() << "resident sizes are the sanitizer's own under ASan and TSan";
  Pod pod;
  ASSERT_NO_FATAL_FAILURE(ReadPod(&pod));
  const std::string dir = MakeTempDir();
  auto volume = WriteSyntheticVolume(
      dir, "gyroid", eval::MakeSyntheticSource(eval::Shape::kGyroid, 256, 256, 600));
  ASSERT_TRUE(volume.ok()) << volume.status();
  auto server = TestServer::Start(pod.flags);
  ASSERT_TRUE(server.ok()) << server.status();
  const pid_t pid = (*server)->process().pid();
  int ok = 0;
  ASSERT_NO_FATAL_FAILURE(RunFullResolutionStreams(**server, *volume, dir,
                                                   static_cast<int>(pod.sessions), 300, 400, &ok));
  const int64_t peak = PeakResidentBytes(pid);
  std::printf("pod flags (%zu from the manifest): server peak %lld MiB, limit %lld Mi, "
              "%d of %lld streams OK\n",
              pod.flags.size(), static_cast<long long>(peak >> 20),
              static_cast<long long>(pod.limit_mib), ok, static_cast<long long>(pod.sessions));
  EXPECT_LE(peak, pod.limit_mib << 20) << "the pod would be OOM-killed";
}

// The pod (its flags from the manifest) under as many streams of `pattern` as it takes
// sessions, slices as large as it allows: the server's peak stays under deploy/README.md's
// rule, idle + sessions x (budget + in flight), and so under the pod's memory limit; every
// stream ends (RESOURCE_EXHAUSTED with the budget's message, or a mesh), the slots come free
// as soon as the streams end (the refused sessions' work stops), and the server goes on
// serving: health SERVING, a normal stream after them succeeds.
void HoldThePodLimit(Pattern pattern) {
  if (kSanitized) GTEST_SKIP() << "resident sizes are the sanitizer's own under ASan and TSan";
  Pod pod;
  ASSERT_NO_FATAL_FAILURE(ReadPod(&pod));
  const std::string dir = MakeTempDir();
  const auto n = static_cast<int64_t>(std::sqrt(static_cast<double>(pod.slice_voxels)));
  double iso = 0;
  auto volume = WritePattern(dir, pattern, n, 8, &iso);
  ASSERT_TRUE(volume.ok()) << volume.status();
  auto server = TestServer::Start(pod.flags);
  ASSERT_TRUE(server.ok()) << server.status();
  const pid_t pid = (*server)->process().pid();
  const int64_t idle = ResidentBytes(pid);
  ASSERT_GT(idle, 0);
  const int64_t rule = idle + pod.sessions * ((pod.budget_mib << 20) + pod.inflight);

  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::unique_ptr<ChildProcess>> clients;
  for (int64_t i = 0; i < pod.sessions; ++i) {
    auto c = ChildProcess::Spawn(
        {BinPath("tandem-client"), "stream", "--server", (*server)->address(), "--input",
         *volume, "--iso", absl::StrCat(iso), "--retries", "0", "--timeout", "120", "--out",
         absl::StrCat(dir, "/out", i, ".drc")},
        dir);
    ASSERT_TRUE(c.ok()) << c.status();
    clients.push_back(*std::move(c));
  }
  int refused = 0;
  const std::string budget = absl::StrCat("budget of ", pod.budget_mib, ".0 MiB");
  for (auto& c : clients) {
    const std::optional<int> code = c->Wait(120);
    ASSERT_TRUE(code.has_value()) << "a client did not finish";
    if (*code == 0) continue;
    ++refused;
    const std::string err = c->Stderr();
    EXPECT_TRUE(absl::StrContains(err, "RESOURCE_EXHAUSTED: session memory budget exceeded") &&
                absl::StrContains(err, budget) &&
                absl::StrContains(err, "tandem-server --session-memory-mb"))
        << err;
  }
  const double streams_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const auto ended = std::chrono::steady_clock::now();
  v1::Counters last;
  EXPECT_TRUE((*server)->WaitIdle(10, &last)) << last.DebugString();
  const double free_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - ended).count();
  const int64_t peak = PeakResidentBytes(pid);
  std::printf("%lld streams of %lldx%lldx8 (iso %g): %d refused in %.2f s, slots free %.2f s "
              "later; server peak %lld MiB, rule %lld MiB, pod limit %lld Mi\n",
              static_cast<long long>(pod.sessions), static_cast<long long>(n),
              static_cast<long long>(n), iso, refused, streams_s, free_s,
              static_cast<long long>(peak >> 20), static_cast<long long>(rule >> 20),
              static_cast<long long>(pod.limit_mib));
  EXPECT_LE(peak, rule) << "idle " << (idle >> 20) << " MiB";
  EXPECT_LE(peak, pod.limit_mib << 20) << "the pod would be OOM-killed";
  EXPECT_LT(free_s, 5) << "the refused sessions' work ran on";

  EXPECT_EQ((*server)->Health(), "SERVING");
  auto normal = WriteSyntheticVolume(dir, "sphere",
                                     eval::MakeSyntheticSource(eval::Shape::kSphere, 64, 64, 64));
  ASSERT_TRUE(normal.ok()) << normal.status();
  RunResult after = RunProcess({BinPath("tandem-client"), "stream", "--server",
                                (*server)->address(), "--input", *normal, "--iso", "0",
                                "--out", dir + "/sphere.drc"},
                               120);
  EXPECT_EQ(after.exit_code, 0) << after.err;
  EXPECT_FALSE((*server)->process().Wait(0).has_value()) << "the server exited";
}

TEST(Sizing, ThePodHoldsItsLimitUnderWhiteNoise) { HoldThePodLimit(Pattern::kNoise); }
TEST(Sizing, ThePodHoldsItsLimitUnderACheckerboard) { HoldThePodLimit(Pattern::kCheckerboard); }
TEST(Sizing, ThePodHoldsItsLimitUnderAnIsoInsideNoise) { HoldThePodLimit(Pattern::kNoisyField); }

// A config alone commits no slice-sized memory: the plane caches and slice buffers of a
// 4096^2 uint16 grid (201 MiB: 4 slices in flight at 2 bytes a voxel, the planes' values
// at 2 and their sign bits, 4.6 bytes a voxel) are allocated when the first voxel arrives, not before, so
// idle or abandoned configs cannot fill a pod. The budget still counts them from the config
// on (session_bytes), so a grid that cannot fit is refused before any voxel is sent.
TEST(Sizing, AConfigAloneCommitsNoSliceMemory) {
  if (kSanitized) GTEST_SKIP() << "resident sizes are the sanitizer's own under ASan and TSan";
  auto server = TestServer::Start({"--session-memory-mb", "4096"});
  ASSERT_TRUE(server.ok()) << server.status();
  const pid_t pid = (*server)->process().pid();
  const int64_t idle = ResidentBytes(pid);
  auto stub = (*server)->NewStub();
  grpc::ClientContext context;
  auto stream = stub->Extract(&context);
  v1::ExtractRequest config;
  config.mutable_config()->set_nx(4096);
  config.mutable_config()->set_ny(4096);
  config.mutable_config()->set_dtype(v1::DTYPE_UINT16);
  config.mutable_config()->set_error(0.5);
  ASSERT_TRUE(stream->Write(config));
  int64_t planned = 0;
  for (int i = 0; i < 100 && planned == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    auto info = (*server)->Info();
    if (info.ok()) planned = info->counters().session_bytes();
  }
  EXPECT_GT(planned, int64_t{192} << 20) << "the budget counts the grid's planned buffers";
  const int64_t held = ResidentBytes(pid) - idle;
  std::printf("4096^2 config: %lld MiB planned, %lld MiB resident over idle\n",
              static_cast<long long>(planned >> 20), static_cast<long long>(held >> 20));
  EXPECT_LT(held, int64_t{64} << 20);
  context.TryCancel();
}

}  // namespace
}  // namespace tandem::testing
