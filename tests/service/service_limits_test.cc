// Server limits: every limit is a flag with a default, shown by --help and reported by
// GetInfo; the per-session memory budget fails only the stream that exceeds it; the bytes
// in flight per stream are bounded (the server stops reading a stream whose client does
// not read); a stream stalled on either side ends after the idle timeout; keepalive finds
// a frozen client; the server's ping policy is enforced.
#include <dirent.h>
#include <gtest/gtest.h>
#include <signal.h>

#include <atomic>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_split.h"
#include "service/bad_input_cases.h"
#include "service/service_testutil.h"
#include "tandem/eval/synthetic.h"
#include "tandem/server/extract_job.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

bool FinishedOk(const StreamOutcome& o) {
  return o.status.ok() && !o.responses.empty() && o.responses.back().has_final_metrics();
}

std::chrono::system_clock::time_point In(double seconds) {
  return std::chrono::system_clock::now() +
         std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000));
}

// Polls GetInfo until `pred` holds (true) or `timeout_s` passes (false).
bool WaitFor(const TestServer& server, double timeout_s,
             const std::function<bool(const v1::Counters&)>& pred, v1::Counters* last = nullptr) {
  const auto deadline =
      Clock::now() + std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000));
  while (Clock::now() < deadline) {
    auto info = server.Info();
    if (info.ok()) {
      if (last) *last = info->counters();
      if (pred(info->counters())) return true;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return false;
}

// A channel whose receive window stays at 64 KiB (no BDP growth): what the server can push
// ahead of a client that does not read is small and known.
std::unique_ptr<v1::Tandem::Stub> SmallWindowStub(const TestServer& server) {
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 64 * 1024);
  args.SetMaxReceiveMessageSize(64 << 20);
  return v1::Tandem::NewStub(
      grpc::CreateCustomChannel(server.address(), grpc::InsecureChannelCredentials(), args));
}

// Full-resolution previews after every slice: tens of KB of output per slice.
std::vector<v1::ExtractRequest> PreviewHeavy(int64_t n, int64_t nz) {
  v1::SessionConfig config;
  config.set_schedule(v1::SCHEDULE_NONE);
  config.mutable_preview()->set_every_slices(1);
  config.mutable_draco()->set_compression_level(0);
  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, n, n, nz);
  return VolumeRequests(*source, config, 1 << 20);
}

// A budget refusal says where the stream was: after a slice (the job's check between
// messages) or while a slice was worked on (the session's own, inside its steps; which comes
// first depends on the threads and the allocator).
bool NamesASlice(absl::string_view message) {
  static const std::regex kWhere(" (after|while [a-z ]+) slice [0-9]+");
  return std::regex_search(std::string(message), kWhere);
}

class NullSink : public server::JobSink {
 public:
  void PostProgress(v1::Progress) override {}
  void PostPreview(v1::Preview) override {}
  void PostFinal(std::vector<v1::ExtractResponse>) override { ++finals; }
  void PostChunk(v1::SealedChunk) override { ++chunks; }
  int chunks = 0;
  int finals = 0;
};

TEST(LimitsTest, DefaultsAreShownByHelpAndReportedByInfo) {
  RunResult help = RunProcess({BinPath("tandem-server"), "--help"});
  ASSERT_EQ(help.exit_code, 0);
  for (const char* want : {"--max-sessions N",
                           "(default: 8) [$TANDEM_MAX_SESSIONS]",
                           "--max-voxels-per-slice N",
                           "(default: 16777216)",
                           "--max-slices N",
                           "(default: 16384)",
                           "--max-message-bytes N",
                           "(default: 16777216)",
                           "--session-memory-mb N",
                           "(default: 1024) [$TANDEM_SESSION_MEMORY_MB]",
                           "--max-inflight-bytes N",
                           "[$TANDEM_MAX_INFLIGHT_BYTES]",
                           "--idle-timeout-seconds X",
                           "(default: 300)",
                           "--keepalive-time-ms N",
                           "(default: 60000) [$TANDEM_KEEPALIVE_TIME_MS]",
                           "--keepalive-timeout-ms N",
                           "(default: 20000)",
                           "--keepalive-min-ping-interval-ms N",
                           "(default: 10000)",
                           "--keepalive-permit-without-calls",
                           "(default: false)",
                           "--min-preview-interval-ms N",
                           "(default: 250)",
                           "--metrics-listen HOST:PORT",
                           "[$TANDEM_METRICS_LISTEN]",
                           "--log-format text|json",
                           "(default: text) [$TANDEM_LOG_FORMAT]",
                           "--tls-cert FILE",
                           "[$TANDEM_TLS_CERT]",
                           "--tls-key FILE",
                           "[$TANDEM_TLS_KEY]",
                           "--compute-threads N",
                           "--watch-spill-dir DIR",
                           "[$TANDEM_WATCH_SPILL_DIR]",
                           "--auth-tokens-file FILE",
                           "[$TANDEM_AUTH_TOKENS_FILE]"}) {
    EXPECT_NE(help.out.find(want), std::string::npos) << want << "\n" << help.out;
  }
  auto server = TestServer::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  auto info = (*server)->Info();
  ASSERT_TRUE(info.ok()) << info.status();
  const v1::Limits& l = info->limits();
  const server::ServerLimits defaults;
  EXPECT_EQ(l.max_voxels_per_slice(), defaults.max_voxels_per_slice);
  EXPECT_EQ(l.max_slices(), defaults.max_slices);
  EXPECT_EQ(l.max_sessions(), defaults.max_sessions);
  EXPECT_EQ(l.max_message_bytes(), defaults.max_message_bytes);
  EXPECT_EQ(l.idle_timeout_seconds(), defaults.idle_timeout_s);
  EXPECT_EQ(l.session_memory_bytes(), int64_t{1024} << 20);
  EXPECT_EQ(l.max_inflight_bytes(), int64_t{16} << 20);
  EXPECT_EQ(l.keepalive_time_ms(), 60000);
  EXPECT_EQ(l.keepalive_timeout_ms(), 20000);
  EXPECT_EQ(l.min_ping_interval_ms(), 10000);
  EXPECT_FALSE(l.permit_keepalive_without_calls());
  EXPECT_EQ(l.min_preview_interval_ms(), 250);
  EXPECT_FALSE(info->tls());
  EXPECT_FALSE(info->token_required());
}

TEST(LimitsTest, FlagsAndVariablesAreReportedByInfo) {
  auto server = TestServer::Start(
      {"--max-sessions",
       "3",
       "--max-voxels-per-slice",
       "90000",
       "--max-slices",
       "500",
       "--max-message-bytes",
       "2097152",
       "--idle-timeout-seconds",
       "42.5",
       "--keepalive-time-ms",
       "15000",
       "--keepalive-permit-without-calls",
       "--min-preview-interval-ms",
       "40",
       "--compute-threads",
       "3",
       "--watch-retain-mb",
       "5",
       "--watch-linger-seconds",
       "7"},
      {},
      {"TANDEM_SESSION_MEMORY_MB=64", "TANDEM_MAX_INFLIGHT_BYTES=1000000",
       "TANDEM_KEEPALIVE_TIMEOUT_MS=7000", "TANDEM_KEEPALIVE_MIN_PING_INTERVAL_MS=5000",
       "TANDEM_MAX_SESSIONS=7"});  // the flag wins over the variable
  ASSERT_TRUE(server.ok()) << server.status();
  auto info = (*server)->Info();
  ASSERT_TRUE(info.ok()) << info.status();
  const v1::Limits& l = info->limits();
  EXPECT_EQ(l.max_sessions(), 3);
  EXPECT_EQ(l.max_voxels_per_slice(), 90000);
  EXPECT_EQ(l.max_slices(), 500);
  EXPECT_EQ(l.max_message_bytes(), 2097152);
  EXPECT_EQ(l.idle_timeout_seconds(), 42.5);
  EXPECT_EQ(l.session_memory_bytes(), int64_t{64} << 20);
  EXPECT_EQ(l.max_inflight_bytes(), 1000000);
  EXPECT_EQ(l.keepalive_time_ms(), 15000);
  EXPECT_EQ(l.keepalive_timeout_ms(), 7000);
  EXPECT_EQ(l.min_ping_interval_ms(), 5000);
  EXPECT_TRUE(l.permit_keepalive_without_calls());
  EXPECT_EQ(l.min_preview_interval_ms(), 40);
  EXPECT_EQ(l.compute_threads(), 3);
  EXPECT_EQ(l.watch_retain_bytes(), int64_t{5} << 20);
  EXPECT_EQ(l.watch_linger_seconds(), 7);
  RunResult client =
      RunProcess({BinPath("tandem-client"), "info", "--server", (*server)->address()});
  ASSERT_EQ(client.exit_code, 0) << client.err;
  for (const char* want :
       {"max sessions           3", "session memory         64 MiB",
        "max inflight bytes     1000000", "idle timeout           42.5 s",
        "keepalive              time 15000 ms, timeout 7000 ms, min client "
        "ping interval 5000 ms, pings without calls allowed",
        "min preview interval   40 ms", "compute threads        3 (shared by all sessions)",
        "watch                  5 MiB kept per session, 7 s after it ends"}) {
    EXPECT_NE(client.out.find(want), std::string::npos) << want << "\n" << client.out;
  }
  RunResult bad = RunProcess({BinPath("tandem-server"), "--session-memory-mb", "0"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("--session-memory-mb"), std::string::npos) << bad.err;
}

// Each numeric flag's bounds hold at both ends, for whole numbers and reals alike: a value
// outside them is a start-up error that names the flag.
TEST(LimitsTest, FlagValuesOutsideTheirBoundsAreRefused) {
  for (const std::vector<std::string>& bad :
       std::vector<std::vector<std::string>>{{"--max-sessions", "4097"},
                                             {"--max-sessions", "0"},
                                             {"--keepalive-time-ms", "2147483648"},
                                             {"--keepalive-timeout-ms", "0"},
                                             {"--idle-timeout-seconds", "0"},
                                             {"--grace-seconds", "-1"},
                                             {"--max-band-bytes-share", "2e6"}}) {
    std::vector<std::string> argv = {BinPath("tandem-server"), "--listen", "127.0.0.1:0"};
    argv.insert(argv.end(), bad.begin(), bad.end());
    RunResult r = RunProcess(argv);
    EXPECT_EQ(r.exit_code, 2) << bad[0] << " " << bad[1];
    EXPECT_NE(r.err.find("out of range"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(bad[0]), std::string::npos) << r.err;
  }
}

// A client that asks for a preview after every slice gets them at most every
// --min-preview-interval-ms: each one snapshots and encodes the whole partial mesh, so the
// server, not the client, bounds what previews cost it. With the floor at 0 the same stream
// gets a preview for most slices.
TEST(LimitsTest, ServerSpacesPreviewsWhateverTheClientAsks) {
  const std::string dir = MakeTempDir();
  auto volume = WriteSyntheticVolume(dir, "sphere",
                                     eval::MakeSyntheticSource(eval::Shape::kSphere, 32, 32, 60));
  ASSERT_TRUE(volume.ok()) << volume.status();
  auto previews = [&](int64_t floor_ms, double* wall_s) {
    auto server = TestServer::Start(
        {"--min-preview-interval-ms", std::to_string(floor_ms), "--max-preview-share", "0"});
    EXPECT_TRUE(server.ok()) << server.status();
    if (!server.ok()) return int64_t{-1};
    const auto start = Clock::now();
    RunResult r = RunProcess({BinPath("tandem-client"), "stream", "--server", (*server)->address(),
                              "--input", *volume, "--iso", "0", "--error", "0.2", "--rate", "100",
                              "--preview-every", "1", "--verbose", "--out", dir + "/out.drc"});
    *wall_s = SecondsSince(start);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    int64_t n = 0;
    for (absl::string_view line : absl::StrSplit(r.err, '\n')) {
      n += absl::StartsWith(line, "preview ") ? 1 : 0;
    }
    return n;
  };
  double wall_free = 0, wall_floor = 0;
  const int64_t free_count = previews(0, &wall_free);
  const int64_t floor_count = previews(200, &wall_floor);
  EXPECT_GE(free_count, 20) << "60 slices, a preview asked after each, no floor";
  EXPECT_GE(floor_count, 1);
  EXPECT_LE(floor_count, static_cast<int64_t>(wall_floor / 0.2) + 1)
      << "previews 200 ms apart at most in " << wall_floor << " s";
}

// ExtractJob alone: the budget is checked at the config (grid-sized buffers) and after
// every slice (the mesh grows), with a message that names the flag.
TEST(LimitsTest, JobEnforcesTheMemoryBudget) {
  server::ServerLimits limits;
  limits.session_memory_bytes = 1 << 20;
  {
    NullSink sink;
    server::ExtractJob job(limits, &sink);
    v1::ExtractRequest config;
    config.mutable_config()->set_nx(1024);
    config.mutable_config()->set_ny(1024);
    config.mutable_config()->set_dtype(v1::DTYPE_FLOAT32);
    config.mutable_config()->set_error(1);
    const absl::Status st = job.Handle(config);
    EXPECT_TRUE(absl::IsResourceExhausted(st)) << st;
    EXPECT_NE(st.message().find("for this grid"), std::string::npos) << st;
    EXPECT_NE(st.message().find("budget of 1.0 MiB (tandem-server --session-memory-mb)"),
              std::string::npos)
        << st;
    EXPECT_EQ(st.message().find("sealed chunks"), std::string::npos)
        << "sealing does not shrink a grid's buffers: " << st;
  }
  {
    NullSink sink;
    server::ExtractJob job(limits, &sink);
    v1::SessionConfig c;
    c.set_schedule(v1::SCHEDULE_NONE);  // nothing simplified: the mesh only grows
    auto source = eval::MakeSyntheticSource(eval::Shape::kGyroid, 48, 48, 200);
    std::vector<v1::ExtractRequest> requests = VolumeRequests(*source, c, 1 << 20);
    absl::Status st;
    size_t handled = 0;
    for (; handled < requests.size() && st.ok(); ++handled) st = job.Handle(requests[handled]);
    EXPECT_TRUE(absl::IsResourceExhausted(st)) << st;
    EXPECT_TRUE(NamesASlice(st.message())) << st;
    EXPECT_GT(handled, 3u) << "the grid fits; the mesh outgrew the budget later";
    EXPECT_EQ(sink.finals, 0);
  }
  {
    NullSink sink;
    server::ExtractJob job(server::ServerLimits{}, &sink);  // default budget: 1 GiB
    for (v1::ExtractRequest& r : Good()) ASSERT_TRUE(job.Handle(r).ok());
    EXPECT_TRUE(job.done());
  }
}

// A sealed chunk is encoded while the session's queued steps run on: its encoding's estimate
// is counted by the budget the steps check, for as long as the chunk is being made.
TEST(LimitsTest, ASealedChunkIsCountedByTheBudgetWhileItIsEncoded) {
  struct ChunkSink : NullSink {
    void PostChunk(v1::SealedChunk chunk) override {
      held.push_back(job->budget()->held());
      triangles.push_back(chunk.triangles());
    }
    server::ExtractJob* job = nullptr;
    std::vector<int64_t> held, triangles;
  };
  ChunkSink sink;
  server::ExtractJob job(server::ServerLimits{}, &sink);
  sink.job = &job;
  v1::SessionConfig c;
  c.set_schedule(v1::SCHEDULE_NONE);  // full resolution: a chunk every few slices
  c.set_sealed_chunks(true);
  c.set_parts(1);  // no step runs on after a slice: the budget's figure is the session's
  auto source = eval::MakeSyntheticSource(eval::Shape::kGyroid, 256, 256, 64);
  std::vector<v1::ExtractRequest> requests = VolumeRequests(*source, c, 1 << 20);
  requests.pop_back();  // the End: the last chunk goes out after the session is freed
  for (v1::ExtractRequest& r : requests) {
    const size_t chunks = sink.held.size();
    ASSERT_TRUE(job.Handle(r).ok());
    const int64_t after = job.budget()->held();
    for (size_t i = chunks; i < sink.held.size(); ++i) {
      EXPECT_GE(sink.held[i] - after, 100 * sink.triangles[i])
          << "chunk " << i << " of " << sink.triangles[i] << " triangles";
    }
  }
  EXPECT_GE(sink.held.size(), 1u) << "no chunk before the End";
}

// A tiny budget: the big stream fails with RESOURCE_EXHAUSTED mid-stream while a small one
// running at the same time completes.
TEST(LimitsTest, MemoryBudgetFailsTheBigStreamOnly) {
  auto server = TestServer::Start({"--session-memory-mb", "2"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  v1::SessionConfig c;
  c.set_schedule(v1::SCHEDULE_NONE);
  c.set_description("big gyroid");
  auto source = eval::MakeSyntheticSource(eval::Shape::kGyroid, 64, 64, 400);
  const std::vector<v1::ExtractRequest> big = VolumeRequests(*source, c, 1 << 20);

  StreamOutcome big_outcome;
  std::thread big_thread([&] {
    auto stub = s.NewStub();
    grpc::ClientContext context;
    context.set_deadline(In(60));
    auto stream = stub->Extract(&context);
    std::thread writer([&] {
      for (const v1::ExtractRequest& r : big) {
        if (!stream->Write(r)) return;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));  // a scanner's pace
      }
      stream->WritesDone();
    });
    v1::ExtractResponse response;
    while (stream->Read(&response)) big_outcome.responses.push_back(response);
    writer.join();
    big_outcome.status = stream->Finish();
  });
  v1::Counters counters;
  const bool big_running = WaitFor(
      s, 20,
      [](const v1::Counters& k) { return k.active_sessions() == 1 && k.session_bytes() > 0; },
      &counters);
  const StreamOutcome small = RunStream(*s.NewStub(), Good());
  big_thread.join();
  ASSERT_TRUE(big_running) << counters.ShortDebugString();
  EXPECT_TRUE(FinishedOk(small)) << small.status.error_message();
  EXPECT_EQ(big_outcome.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED)
      << big_outcome.status.error_message();
  EXPECT_NE(big_outcome.status.error_message().find(
                "over this server's per-session budget of 2.0 MiB (tandem-server "
                "--session-memory-mb)"),
            std::string::npos)
      << big_outcome.status.error_message();
  EXPECT_TRUE(NamesASlice(big_outcome.status.error_message()))
      << big_outcome.status.error_message();
  // Not sealed: its memory grew with the mesh, and the message says what would not.
  EXPECT_NE(
      big_outcome.status.error_message().find("stream with sealed chunks (tandem-client --seal"),
      std::string::npos)
      << big_outcome.status.error_message();
  EXPECT_TRUE(s.WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_EQ(counters.sessions_finished(), 2);
  EXPECT_EQ(s.Health(), "SERVING");
  EXPECT_TRUE(FinishedOk(RunStream(*s.NewStub(), Good()))) << "other sessions carry on";
}

// Noise (every layer a dense surface, about 200,000 triangles a slice here): the session
// checks its budget while it extracts, so each stream is refused inside its first layers
// with the budget's message, not after slices of growth; the refused sessions' work stops,
// so their slots and memory are free as soon as the streams end; the server carries on.
// Small enough for the sanitizer pass (the pod-sized patterns are in the sizing tests).
TEST(LimitsTest, NoiseIsRefusedWhileItIsExtractedAndItsSlotsComeFreeAtOnce) {
  auto server = TestServer::Start({"--max-sessions", "2", "--session-memory-mb", "16"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  const std::string dir = MakeTempDir();
  double iso = 0;
  auto volume = WritePattern(dir, Pattern::kNoise, 256, 16, &iso);
  ASSERT_TRUE(volume.ok()) << volume.status();
  std::vector<std::unique_ptr<ChildProcess>> clients;
  for (int i = 0; i < 2; ++i) {
    auto c = ChildProcess::Spawn(
        {BinPath("tandem-client"), "stream", "--server", s.address(), "--input", *volume, "--iso",
         absl::StrCat(iso), "--retries", "0", "--out", absl::StrCat(dir, "/out", i, ".drc")},
        dir);
    ASSERT_TRUE(c.ok()) << c.status();
    clients.push_back(*std::move(c));
  }
  for (auto& c : clients) {
    const std::optional<int> code = c->Wait(60);
    ASSERT_TRUE(code.has_value()) << "a client did not finish";
    EXPECT_EQ(*code, 1);
    const std::string err = c->Stderr();
    EXPECT_NE(err.find("RESOURCE_EXHAUSTED: session memory budget exceeded: this stream needs "),
              std::string::npos)
        << err;
    // Refused within its first layers, by the check inside extraction or, when the slices
    // queued ahead of a busy executor already fill the budget, by the one as a slice arrives.
    std::smatch at;
    ASSERT_TRUE(std::regex_search(err, at, std::regex(" while (extracting|adding) slice ([0-9]+)")))
        << err;
    EXPECT_LT(std::stoi(at[2].str()), 4) << err;
    EXPECT_NE(err.find("over this server's per-session budget of 16.0 MiB (tandem-server "
                       "--session-memory-mb)"),
              std::string::npos)
        << err;
  }
  const auto ended = Clock::now();
  v1::Counters counters;
  EXPECT_TRUE(s.WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_LT(SecondsSince(ended), 5) << "the refused sessions' work ran on";
  EXPECT_EQ(counters.sessions_finished(), 2);
  EXPECT_EQ(counters.sessions_rejected(), 0);
  EXPECT_EQ(s.Health(), "SERVING");
  EXPECT_TRUE(FinishedOk(RunStream(*s.NewStub(), Good()))) << "the server carries on";
}

// Dense streams keep the one compute thread busy: a session whose client is killed waits, in
// its next slice, for steps queued behind the other sessions'. Without a resume window its
// stream ends with the kill, its session stops waiting at once (its budget is cancelled, which
// wakes it) and its slot comes free within a fraction of a second. (Where in that round the
// kill lands is chance: budget_test's ASessionWaitingBehindOtherWorkWakesWhenCancelled pins
// the wake down.)
TEST(LimitsTest, AKilledClientsSlotComesFreeAtOnceUnderDenseLoad) {
  auto server = TestServer::Start(
      {"--max-sessions", "4", "--compute-threads", "1", "--resume-window-seconds", "0"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  const std::string dir = MakeTempDir();
  double iso = 0;
  auto volume = WritePattern(dir, Pattern::kNoise, 256, 24, &iso);
  ASSERT_TRUE(volume.ok()) << volume.status();
  std::vector<std::unique_ptr<ChildProcess>> clients;
  for (int i = 0; i < 4; ++i) {
    auto c = ChildProcess::Spawn({BinPath("tandem-client"), "stream", "--server", s.address(),
                                  "--input", *volume, "--iso", absl::StrCat(iso), "--parts", "2",
                                  "--retries", "0", "--out", absl::StrCat(dir, "/out", i, ".drc")},
                                 dir);
    ASSERT_TRUE(c.ok()) << c.status();
    clients.push_back(*std::move(c));
  }
  // Every session past its first slices: the ring full, steps queued on the one thread.
  ASSERT_TRUE(WaitFor(s, 60, [](const v1::Counters& c) {
    return c.active_sessions() == 4 && c.session_bytes() > 4 * (int64_t{64} << 20);
  }));
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  clients[0]->Signal(SIGKILL);
  const auto killed = Clock::now();
  EXPECT_EQ(clients[0]->Wait(10), 128 + SIGKILL);
  v1::Counters counters;
  EXPECT_TRUE(WaitFor(
      s, 30, [](const v1::Counters& c) { return c.active_sessions() == 3; }, &counters))
      << counters.ShortDebugString();
  const double freed_s = SecondsSince(killed);
  std::printf("the killed client's slot came free after %.3f s\n", freed_s);
  RecordProperty("slot_freed_seconds", std::to_string(freed_s));
  EXPECT_LT(freed_s, kSanitized ? 3.0 : 1.0);
  // The slot takes a new stream while the others go on.
  EXPECT_TRUE(FinishedOk(RunStream(*s.NewStub(), Good()))) << "the freed slot takes a stream";
  for (size_t i = 1; i < clients.size(); ++i) clients[i]->Signal(SIGKILL);
  EXPECT_TRUE(s.WaitIdle(30, &counters)) << counters.ShortDebugString();
}

// A client that stops reading: once the stream's unsent responses reach
// --max-inflight-bytes the server stops reading it (no slice consumed, memory constant);
// when the client reads again, the stream resumes and completes. (Previews are not encoded
// while one is unsent, so the progress messages are what piles up: a small limit.)
TEST(LimitsTest, ServerStopsReadingAStreamWhoseClientDoesNotRead) {
  constexpr int64_t kLimit = 2048;
  auto server = TestServer::Start({"--max-inflight-bytes", std::to_string(kLimit),
                                   "--min-preview-interval-ms", "0", "--max-preview-share", "0"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  const std::vector<v1::ExtractRequest> requests = PreviewHeavy(40, 120);
  auto stub = SmallWindowStub(s);
  grpc::ClientContext context;
  context.set_deadline(In(60));
  auto stream = stub->Extract(&context);
  std::atomic<int> written{0};
  std::thread writer([&] {
    for (const v1::ExtractRequest& r : requests) {
      if (!stream->Write(r)) return;
      ++written;
    }
    stream->WritesDone();
  });
  // Nobody reads: the session must settle with slices left unconsumed.
  v1::Counters before, after;
  ASSERT_TRUE(WaitFor(
      s, 10, [](const v1::Counters& k) { return k.buffered_bytes() >= kLimit; }, &before))
      << before.ShortDebugString();
  // Slices read before the pause may still be in the session's steps, slow on a loaded
  // machine: two readings 400 ms apart until they agree (a reader that never pauses consumes
  // the whole input meanwhile, which the checks below catch).
  for (int tries = 0; tries < 50; ++tries) {
    std::this_thread::sleep_for(std::chrono::milliseconds(400));
    auto i1 = s.Info();
    std::this_thread::sleep_for(std::chrono::milliseconds(400));
    auto i2 = s.Info();
    ASSERT_TRUE(i1.ok() && i2.ok());
    before = i1->counters();
    after = i2->counters();
    if (before.session_bytes() == after.session_bytes()) break;
  }
  EXPECT_EQ(before.session_bytes(), after.session_bytes()) << "no slice consumed meanwhile";
  EXPECT_EQ(after.sessions_draining(), 0) << "the input was not all consumed";
  EXPECT_EQ(after.worker_threads(), 1);
  EXPECT_GE(after.buffered_bytes(), kLimit);
  EXPECT_LT(after.buffered_bytes(), kLimit + 256 * 1024) << "one preview over the limit at most";
  RecordProperty("buffered_bytes_while_paused", static_cast<int>(after.buffered_bytes()));
  RecordProperty("requests_written_while_paused", written.load());
  // Read again: the stream completes.
  v1::ExtractResponse response;
  bool final_metrics = false;
  while (stream->Read(&response)) final_metrics |= response.has_final_metrics();
  writer.join();
  const grpc::Status st = stream->Finish();
  EXPECT_TRUE(st.ok()) << st.error_message();
  EXPECT_TRUE(final_metrics);
  v1::Counters counters;
  EXPECT_TRUE(s.WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_EQ(counters.buffered_bytes(), 0);
}

// A client that never reads is cancelled after the idle timeout, mid-stream and after the
// last slice (the final mesh unread), and its slot is free again. Previews are neither spaced
// in time nor bounded in share: on a fast machine the 120 slices take 30 ms, and spaced
// previews (one per 250 ms) left the whole stream's output (71 KB) inside the client's
// 64 KB window plus the socket's buffers, so it finished without ever stalling.
TEST(LimitsTest, ClientThatNeverReadsIsCancelledAfterTheIdleTimeout) {
  auto server = TestServer::Start({"--max-inflight-bytes", "16384", "--idle-timeout-seconds", "1",
                                   "--max-sessions", "1", "--min-preview-interval-ms", "0",
                                   "--max-preview-share", "0"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  auto stub = SmallWindowStub(s);
  for (bool whole_volume_first : {false, true}) {
    SCOPED_TRACE(whole_volume_first ? "final mesh unread" : "previews unread");
    std::vector<v1::ExtractRequest> requests;
    if (whole_volume_first) {
      v1::SessionConfig c;
      c.set_schedule(v1::SCHEDULE_NONE);
      c.mutable_draco()->set_compression_level(0);  // a final mesh of a few hundred KB
      auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, 64, 64, 64);
      requests = VolumeRequests(*source, c, 1 << 20);
    } else {
      requests = PreviewHeavy(40, 120);
    }
    grpc::ClientContext context;
    context.set_deadline(In(60));
    auto stream = stub->Extract(&context);
    const auto t0 = Clock::now();
    std::thread writer([&] {
      for (const v1::ExtractRequest& r : requests) {
        if (!stream->Write(r)) return;
      }
      stream->WritesDone();
    });
    // Wait until the server holds the session before waiting for it to go: polled too early,
    // active_sessions() == 0 held before the stream was accepted, the test went on to read
    // everything and the stream ended OK.
    v1::Counters k;
    EXPECT_TRUE(WaitFor(
        s, 10,
        [&](const v1::Counters& c) {
          return whole_volume_first ? c.sessions_draining() == 1 : c.active_sessions() == 1;
        },
        &k))
        << k.ShortDebugString();
    // Still not reading; the server gives up after about a second.
    v1::Counters counters;
    EXPECT_TRUE(WaitFor(
        s, 15, [](const v1::Counters& c) { return c.active_sessions() == 0; }, &counters))
        << counters.ShortDebugString();
    const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    EXPECT_LT(seconds, 10);
    v1::ExtractResponse response;
    while (stream->Read(&response)) {
    }
    writer.join();
    const grpc::Status st = stream->Finish();
    EXPECT_FALSE(st.ok());
    EXPECT_TRUE(s.WaitIdle(10, &counters)) << counters.ShortDebugString();
  }
  const std::string log = s.process().Stderr();
  size_t at = 0;
  int stalled = 0;
  while ((at = log.find("status=DEADLINE_EXCEEDED message=\"the client read none of the "
                        "server's messages for 1 s",
                        at)) != std::string::npos) {
    ++stalled;
    ++at;
  }
  EXPECT_EQ(stalled, 2) << log;
  EXPECT_TRUE(FinishedOk(RunStream(*s.NewStub(), Good()))) << "the only slot is free again";
}

// Keepalive: a client frozen mid-stream (SIGSTOP: its TCP connection stays open, nothing
// answers the pings) is found by the server's pings long before the idle timeout.
TEST(LimitsTest, KeepaliveFreesTheSessionOfAFrozenClient) {
  const std::string dir = MakeTempDir();
  auto server =
      TestServer::Start({"--keepalive-time-ms", "300", "--keepalive-timeout-ms", "500",
                         "--idle-timeout-seconds", "120", "--resume-window-seconds", "1"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  auto path = WriteSyntheticVolume(dir, "sphere",
                                   eval::MakeSyntheticSource(eval::Shape::kSphere, 24, 24, 40));
  ASSERT_TRUE(path.ok()) << path.status();
  auto stream_args = [&](const std::string& rate, const std::string& out) {
    return std::vector<std::string>{BinPath("tandem-client"),
                                    "stream",
                                    "--server",
                                    s.address(),
                                    "--input",
                                    *path,
                                    "--iso",
                                    "0",
                                    "--error",
                                    "0.5",
                                    "--rate",
                                    rate,
                                    "--out",
                                    dir + "/" + out};
  };
  // A healthy client answers the pings and completes (40 slices at 20/s: 2 s of pings).
  RunResult healthy = RunProcess(stream_args("20", "healthy.drc"), 60);
  EXPECT_EQ(healthy.exit_code, 0) << healthy.err;
  auto frozen = ChildProcess::Spawn(stream_args("5", "frozen.drc"), dir);
  ASSERT_TRUE(frozen.ok());
  v1::Counters counters;
  ASSERT_TRUE(WaitFor(
      s, 10, [](const v1::Counters& k) { return k.active_sessions() == 1; }, &counters));
  (*frozen)->Signal(SIGSTOP);
  const auto t0 = Clock::now();
  EXPECT_TRUE(WaitFor(
      s, 20, [](const v1::Counters& k) { return k.active_sessions() == 0; }, &counters))
      << counters.ShortDebugString();
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  RecordProperty("frozen_client_freed_after_s", std::to_string(seconds));
  EXPECT_LT(seconds, 10) << "keepalive, not the 120 s idle timeout";
  (*frozen)->Signal(SIGKILL);
  (*frozen)->Signal(SIGCONT);
  EXPECT_TRUE(s.WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_NE(s.process().Stderr().find("status=CANCELLED"), std::string::npos)
      << s.process().Stderr();
}

// The server's ping policy: a client pinging as often as gRPC lets it (once a second) with
// no data flowing is told off under the default 10 s minimum interval (after two strikes:
// GOAWAY too_many_pings and the connection closes, ending its call), and left alone on a server
// whose operator allows 50 ms. Both run at once; the allowed one must outlive the other.
TEST(LimitsTest, ServerEnforcesItsMinimumPingInterval) {
  struct Side {
    std::unique_ptr<TestServer> server;
    std::unique_ptr<v1::Tandem::Stub> stub;
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReaderWriter<v1::ExtractRequest, v1::ExtractResponse>> stream;
    std::atomic<bool> ended{false};
    std::thread reader;
  };
  Side strict, lenient;
  for (Side* side : {&strict, &lenient}) {
    std::vector<std::string> args = {"--keepalive-time-ms", "0"};  // only the client pings
    if (side == &lenient) args.insert(args.end(), {"--keepalive-min-ping-interval-ms", "50"});
    auto server = TestServer::Start(args);
    ASSERT_TRUE(server.ok()) << server.status();
    side->server = *std::move(server);
    grpc::ChannelArguments channel_args;
    channel_args.SetInt(GRPC_ARG_KEEPALIVE_TIME_MS, 100);
    channel_args.SetInt(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 5000);
    channel_args.SetInt(GRPC_ARG_HTTP2_MAX_PINGS_WITHOUT_DATA, 0);
    side->stub = v1::Tandem::NewStub(grpc::CreateCustomChannel(
        side->server->address(), grpc::InsecureChannelCredentials(), channel_args));
    side->context.set_deadline(In(30));
    side->stream = side->stub->Extract(&side->context);
    ASSERT_TRUE(side->stream->Write(Good()[0]));  // a config, then silence: only pings flow
    side->reader = std::thread([side] {
      v1::ExtractResponse response;
      while (side->stream->Read(&response)) {
      }
      side->ended = true;
    });
  }
  const auto t0 = Clock::now();
  while (!strict.ended && SecondsSince(t0) < 10) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  const bool strict_ended = strict.ended;
  const double strict_s = SecondsSince(t0);
  std::this_thread::sleep_for(std::chrono::milliseconds(1200));  // one more ping
  const bool lenient_ended = lenient.ended;
  for (Side* side : {&strict, &lenient}) {
    side->context.TryCancel();
    side->reader.join();
  }
  const grpc::Status strict_status = strict.stream->Finish();
  const grpc::Status lenient_status = lenient.stream->Finish();
  // The server closes the connection: the call ends (UNAVAILABLE or CANCELLED, depending
  // on which side notices first) before the test cancels it.
  EXPECT_TRUE(strict_ended) << "still open after " << strict_s << " s";
  EXPECT_FALSE(strict_status.ok());
  RecordProperty("too_many_pings_after_s", std::to_string(strict_s));
  EXPECT_FALSE(lenient_ended) << lenient_status.error_message();
  EXPECT_EQ(lenient_status.error_code(), grpc::StatusCode::CANCELLED) << "cancelled by the test";
}

}  // namespace
}  // namespace tandem::testing

namespace tandem::testing {
namespace {

int ThreadsOf(pid_t pid) {
  int n = 0;
  if (DIR* d = opendir(absl::StrCat("/proc/", pid, "/task").c_str())) {
    while (dirent* e = readdir(d)) n += e->d_name[0] != '.';
    closedir(d);
  }
  return n;
}

// However many streams arrive, their sessions compute on the --compute-threads threads the
// server shares between them: each stream adds its own worker thread, never a pool of its own
// (a 4-slab session used to start one thread per core for itself).
TEST(LimitsTest, StreamsShareTheServersComputeThreads) {
  const std::string dir = MakeTempDir();
  auto server = TestServer::Start({"--compute-threads", "1"});
  ASSERT_TRUE(server.ok()) << server.status();
  auto path =
      WriteSyntheticVolume(dir, "wide", eval::MakeSyntheticSource(eval::Shape::kLink, 320, 48, 60));
  ASSERT_TRUE(path.ok()) << path.status();
  const pid_t pid = (*server)->process().pid();
  const int idle = ThreadsOf(pid);
  constexpr int kStreams = 4;
  std::vector<std::unique_ptr<ChildProcess>> clients;
  for (int i = 0; i < kStreams; ++i) {
    auto c =
        ChildProcess::Spawn({BinPath("tandem-client"), "stream", "--server", (*server)->address(),
                             "--input", *path, "--iso", "0", "--error", "0.05", "--rate", "30",
                             "--out", absl::StrCat(dir, "/out", i, ".ply")},
                            dir);
    ASSERT_TRUE(c.ok()) << c.status();
    clients.push_back(*std::move(c));
  }
  int most = idle;
  for (int i = 0; i < 100; ++i) {  // the streams take about 2 s at 30 slices/s
    most = std::max(most, ThreadsOf(pid));
    std::this_thread::sleep_for(std::chrono::milliseconds(30));
  }
  for (auto& c : clients) EXPECT_EQ(c->Wait(60), 0) << c->Stderr();
  // Each stream's worker, and a few of gRPC's own under load; with a pool per session (2 or
  // more threads each) this was at least 3 per stream.
  EXPECT_LE(most - idle, kStreams + 4) << "idle " << idle << ", most " << most;
  std::cerr << "server threads: idle " << idle << ", at most " << most << " with " << kStreams
            << " streams\n";
}

}  // namespace
}  // namespace tandem::testing
