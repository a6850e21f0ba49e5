// The per-session memory budget bounds the process: N sessions at --max-sessions N,
// --session-memory-mb B and --max-inflight-bytes I keep the server's peak resident size
// under its idle size + N x (B + I), the rule deploy/README.md sizes pods by. The streams
// are the hard case for the accounting: full-resolution surfaces (every triangle kept), so
// that the final copy and Draco encoding of the mesh weigh as much as the session itself.
// Some streams end with RESOURCE_EXHAUSTED (honestly: their final mesh would not fit); the
// process stays under the bound either way. Normal builds only: under ASan the resident
// size is the sanitizer's.
#include <cstdio>
#include <chrono>
#include <fstream>
#include <thread>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "service/service_testutil.h"
#include "tandem/synthetic.h"
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

TEST(Sizing, SessionsStayWithinTheirBudgetsAtThePeak) {
  if (kSanitized) GTEST_SKIP() << "resident sizes are the sanitizer's own under ASan and TSan";
  const std::string dir = MakeTempDir();
  // 192^3 gyroid: 466,110 triangles at full resolution, a session of about 50 MiB and a
  // final encoding of about as much again.
  auto volume = WriteSyntheticVolume(dir, "gyroid",
                                     MakeSyntheticSource(Shape::kGyroid, 192, 192, 192));
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

  std::vector<std::unique_ptr<ChildProcess>> clients;
  for (int i = 0; i < kSessions; ++i) {
    auto c = ChildProcess::Spawn(
        {BinPath("tandem-client"), "stream", "--server", (*server)->address(), "--input",
         *volume, "--iso", "0", "--error", "0.2", "--schedule", "none", "--timeout", "120",
         "--out", dir + "/out" + std::to_string(i) + ".drc"},
        dir);
    ASSERT_TRUE(c.ok()) << c.status();
    clients.push_back(*std::move(c));
  }
  int ok = 0;
  for (auto& c : clients) {
    const std::optional<int> code = c->Wait(180);
    ASSERT_TRUE(code.has_value()) << "a client did not finish";
    if (*code == 0) ++ok;
    else EXPECT_NE(c->Stderr().find("RESOURCE_EXHAUSTED"), std::string::npos) << c->Stderr();
  }
  EXPECT_GT(ok, 0) << "every stream was refused: the test no longer measures the encoding";
  const int64_t peak = PeakResidentBytes(pid);
  const int64_t bound = idle + kSessions * ((kBudgetMiB << 20) + kInflight);
  std::printf("server peak %lld MiB (idle %lld MiB, bound %lld MiB), %d of %d streams OK\n",
              static_cast<long long>(peak >> 20), static_cast<long long>(idle >> 20),
              static_cast<long long>(bound >> 20), ok, kSessions);
  EXPECT_LE(peak, bound) << "peak " << (peak >> 20) << " MiB, idle " << (idle >> 20)
                         << " MiB, bound " << (bound >> 20) << " MiB";
}

// A config alone commits no slice-sized memory: the plane caches and slice buffers of a
// 4096^2 grid (about 780 MiB) are allocated when the first voxel arrives, not before, so
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
  EXPECT_GT(planned, int64_t{512} << 20) << "the budget counts the grid's planned buffers";
  const int64_t held = ResidentBytes(pid) - idle;
  std::printf("4096^2 config: %lld MiB planned, %lld MiB resident over idle\n",
              static_cast<long long>(planned >> 20), static_cast<long long>(held >> 20));
  EXPECT_LT(held, int64_t{64} << 20);
  context.TryCancel();
}

}  // namespace
}  // namespace tandem::testing
