// What operators see: the Prometheus endpoint (--metrics-listen, served by cpp-httplib)
// counts sessions by final status, slices, bytes and phase time; --log-format json writes
// one JSON object per line, client strings escaped and truncated.
#include <gtest/gtest.h>
#include <signal.h>
#include <httplib.h>

#include <chrono>
#include <map>
#include <set>
#include <regex>
#include <thread>

#include <nlohmann/json.hpp>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "absl/strings/str_cat.h"
#include "client/connection.h"
#include "service/service_testutil.h"
#include "tandem/synthetic.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

// "http://HOST:PORT/metrics" from the server's log, once it is there.
std::string MetricsUrl(TestServer& server) {
  const std::regex re("metrics on http://([0-9.]+):([0-9]+)/metrics");
  for (int i = 0; i < 200; ++i) {
    std::smatch m;
    const std::string log = server.process().Stderr();
    if (std::regex_search(log, m, re)) return m[1].str() + ":" + m[2].str();
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  return "";
}

// Sample name (with labels) → value; fails the test on a line that is not valid text
// exposition (HELP/TYPE comments before each family's samples).
std::map<std::string, double> Scrape(const std::string& host_port) {
  std::map<std::string, double> out;
  const size_t colon = host_port.rfind(':');
  httplib::Client client(host_port.substr(0, colon), std::stoi(host_port.substr(colon + 1)));
  client.set_connection_timeout(5);
  auto res = client.Get("/metrics");
  EXPECT_TRUE(res) << "no answer from " << host_port;
  if (!res) return out;
  EXPECT_EQ(res->status, 200);
  EXPECT_TRUE(absl::StartsWith(res->get_header_value("Content-Type"), "text/plain; version=0.0.4"))
      << res->get_header_value("Content-Type");
  const std::regex sample(R"(^([a-z_]+)(\{[a-z_]+="[A-Za-z_]+"\})? (-?[0-9.e+]+)$)");
  const std::regex type(R"(^# TYPE ([a-z_]+) (counter|gauge)$)");
  std::set<std::string> typed;
  for (absl::string_view line : absl::StrSplit(res->body, '\n', absl::SkipEmpty())) {
    const std::string l(line);
    std::smatch m;
    if (absl::StartsWith(l, "# HELP ")) continue;
    if (std::regex_match(l, m, type)) {
      typed.insert(m[1].str());
      continue;
    }
    if (!std::regex_match(l, m, sample)) {
      ADD_FAILURE() << "not a sample line: " << l;
      continue;
    }
    EXPECT_TRUE(typed.count(m[1].str())) << "sample before its TYPE: " << l;
    if (absl::EndsWith(m[1].str(), "_total")) {
      EXPECT_EQ(l.find("TYPE"), std::string::npos);
    }
    out[m[1].str() + m[2].str()] = std::stod(m[3].str());
  }
  return out;
}

std::vector<v1::ExtractRequest> Sphere(int64_t n) {
  v1::SessionConfig config;
  config.set_error(0.3);
  auto source = MakeSyntheticSource(Shape::kSphere, n, n, n);
  return VolumeRequests(*source, config, 1 << 20);
}

// A stream whose client vanishes mid-scan shows as a session waiting for a resume until
// its window (5 s here) is over.
TEST(Metrics, CountSessionsWaitingForAResume) {
  auto server = TestServer::Start({"--metrics-listen", "127.0.0.1:0", "--resume-window-seconds", "5"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  const std::string url = MetricsUrl(s);
  ASSERT_FALSE(url.empty()) << s.process().Stderr();
  EXPECT_EQ(Scrape(url)["tandem_sessions_waiting_for_resume"], 0);
  auto stub = s.NewStub();
  {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    auto stream = stub->Extract(&context);
    const std::vector<v1::ExtractRequest> requests = Sphere(24);
    for (size_t i = 0; i + 1 < requests.size() && i < 6; ++i) ASSERT_TRUE(stream->Write(requests[i]));
    v1::ExtractResponse response;
    while (stream->Read(&response) && response.progress().slices_consumed() < 5) {
    }
    context.TryCancel();
    stream->Finish();
  }
  bool waiting = false;
  for (int i = 0; i < 100 && !waiting; ++i) {
    waiting = Scrape(url)["tandem_sessions_waiting_for_resume"] == 1;
    if (!waiting) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  EXPECT_TRUE(waiting) << s.process().Stderr();
  ASSERT_TRUE(s.WaitIdle(30));
  EXPECT_EQ(Scrape(url)["tandem_sessions_waiting_for_resume"], 0);
}

TEST(Metrics, CountSessionsByStatusSlicesBytesAndPhases) {
  auto server = TestServer::Start({"--metrics-listen", "127.0.0.1:0"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  const std::string url = MetricsUrl(s);
  ASSERT_FALSE(url.empty()) << s.process().Stderr();
  auto before = Scrape(url);
  EXPECT_EQ(before["tandem_active_sessions"], 0);
  EXPECT_EQ(before["tandem_sessions_finished_total{status=\"OK\"}"], 0);
  EXPECT_EQ(before["tandem_max_sessions"], 8);

  auto stub = s.NewStub();
  StreamOutcome good = RunStream(*stub, Sphere(24));
  ASSERT_TRUE(good.status.ok()) << good.status.error_message();
  std::vector<v1::ExtractRequest> bad = Sphere(24);
  bad[0].mutable_config()->set_nx(0);  // INVALID_ARGUMENT
  EXPECT_EQ(RunStream(*stub, bad).status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  ASSERT_TRUE(s.WaitIdle(10));

  auto after = Scrape(url);
  EXPECT_EQ(after["tandem_sessions_started_total"], 2);
  EXPECT_EQ(after["tandem_sessions_finished_total{status=\"OK\"}"], 1);
  EXPECT_EQ(after["tandem_sessions_finished_total{status=\"INVALID_ARGUMENT\"}"], 1);
  EXPECT_EQ(after["tandem_slices_total"], 24);
  EXPECT_GT(after["tandem_received_bytes_total"], 24.0 * 24 * 24 * 4);
  EXPECT_GT(after["tandem_sent_bytes_total"], 0);
  EXPECT_GT(after["tandem_phase_seconds_total{phase=\"extract\"}"], 0);
  EXPECT_GT(after["tandem_phase_seconds_total{phase=\"encode\"}"], 0);
  EXPECT_EQ(after["tandem_active_sessions"], 0);
  EXPECT_EQ(after["tandem_session_memory_bytes"], 0);
  EXPECT_EQ(after["tandem_session_memory_limit_bytes"], 8.0 * 1024 * 1024 * 1024);
}

TEST(Metrics, BadListenAddressIsAStartupError) {
  RunResult r = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0",
                            "--metrics-listen", "nonsense"});
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("--metrics-listen"), std::string::npos) << r.err;
  RunResult f = RunProcess({BinPath("tandem-server"), "--log-format", "xml"});
  EXPECT_EQ(f.exit_code, 2) << f.err;
  EXPECT_NE(f.err.find("--log-format"), std::string::npos) << f.err;
}

TEST(Watch, OutOfRangeWatchAndPreviewFlagsAreStartupErrors) {
  for (std::vector<std::string> args :
       {std::vector<std::string>{"--max-preview-share", "1.5"},
        {"--max-band-bytes-share", "-1"},
        {"--watch-retain-mb", "-3"},
        {"--watch-linger-seconds", "nan"}}) {
    const std::string flag = args[0];
    args.insert(args.begin(), {BinPath("tandem-server"), "--listen", "127.0.0.1:0"});
    RunResult r = RunProcess(args);
    EXPECT_EQ(r.exit_code, 2) << flag << ": " << r.err;
    EXPECT_NE(r.err.find(flag), std::string::npos) << r.err;
  }
}

// Every stderr line is one JSON object with a time and an event; the session line carries
// its figures as fields, and a hostile description (newlines, quotes, control bytes,
// invalid UTF-8, 5000 bytes) stays inside its field, truncated.
TEST(JsonLog, OneObjectPerLineWithEscapedClientStrings) {
  auto server = TestServer::Start({"--log-format", "json"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  std::vector<v1::ExtractRequest> requests = Sphere(16);
  // (Protobuf strings are UTF-8, so no invalid sequence: "é" × 2500 makes the cut fall
  // inside characters, which the log must not split.)
  std::string hostile = "scan\n2026-01-01T00:00:00Z tandem-server: session status=OK \"\x1b[31m";
  for (int i = 0; i < 2500; ++i) hostile += "\xc3\xa9";
  requests[0].mutable_config()->set_description(hostile);
  auto stub = s.NewStub();
  const StreamOutcome outcome = RunStream(*stub, requests);
  ASSERT_TRUE(outcome.status.ok()) << outcome.status.error_message();
  ASSERT_TRUE(s.WaitIdle(10));
  stub.reset();  // an open connection that ran a stream holds a graceful exit for a while
  s.process().Signal(SIGTERM);
  ASSERT_EQ(s.process().Wait(20), 0);
  int sessions = 0, lines = 0;
  for (absl::string_view line : absl::StrSplit(s.process().Stderr(), '\n', absl::SkipEmpty())) {
    ++lines;
    nlohmann::json j = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
    ASSERT_FALSE(j.is_discarded()) << "not JSON: " << line;
    ASSERT_TRUE(j.is_object()) << line;
    EXPECT_TRUE(j.contains("time") && j["time"].is_string()) << line;
    EXPECT_TRUE(std::regex_match(j["time"].get<std::string>(),
                                 std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z)")))
        << line;
    ASSERT_TRUE(j.contains("event")) << line;
    if (j["event"] != "session") continue;
    ++sessions;
    EXPECT_EQ(j["status"], "OK");
    EXPECT_EQ(j["slices"], 16);
    EXPECT_GT(j["triangles"].get<int64_t>(), 0);
    const std::string input = j["input"].get<std::string>();
    EXPECT_TRUE(absl::StartsWith(input, "scan\n2026-01-01T00:00:00Z tandem-server")) << input;
    EXPECT_NE(input.find("(" + std::to_string(hostile.size()) + " bytes in all)"),
              std::string::npos)
        << input;
    EXPECT_LT(input.size(), 400u);
    EXPECT_NE(input.find("\xc3\xa9...("), std::string::npos) << "cut between characters";
  }
  EXPECT_EQ(sessions, 1);
  EXPECT_GE(lines, 3) << s.process().Stderr();
}


// --lb round_robin spreads the streams of one channel over every address of the target;
// pick_first (the default) puts them all on the first.
TEST(Client, RoundRobinSpreadsStreamsOverReplicas) {
  auto a = TestServer::Start();
  auto b = TestServer::Start();
  ASSERT_TRUE(a.ok() && b.ok());
  const std::string target =
      absl::StrCat("ipv4:", (*a)->address(), ",", (*b)->address());
  for (const char* policy : {"round_robin", "pick_first"}) {
    SCOPED_TRACE(policy);
    client::ConnectionOptions options;
    options.server = target;
    options.lb_policy = policy;
    auto channel = client::MakeChannel(options);
    ASSERT_TRUE(channel.ok()) << channel.status();
    auto stub = v1::Tandem::NewStub(*channel);
    if (std::string(policy) == "round_robin") {
      // Round robin takes the addresses whose connection is ready: under load the second
      // may connect a few streams later. Wait until both have had one (bounded).
      const int64_t a_start = (*a)->Info()->counters().sessions_started();
      const int64_t b_start = (*b)->Info()->counters().sessions_started();
      for (int i = 0; i < 20; ++i) {
        ASSERT_TRUE(RunStream(*stub, Sphere(12)).status.ok());
        if ((*a)->Info()->counters().sessions_started() > a_start &&
            (*b)->Info()->counters().sessions_started() > b_start) {
          break;
        }
      }
    }
    const int64_t a0 = (*a)->Info()->counters().sessions_started();
    const int64_t b0 = (*b)->Info()->counters().sessions_started();
    for (int i = 0; i < 4; ++i) {
      ASSERT_TRUE(RunStream(*stub, Sphere(12)).status.ok());
    }
    const int64_t na = (*a)->Info()->counters().sessions_started() - a0;
    const int64_t nb = (*b)->Info()->counters().sessions_started() - b0;
    EXPECT_EQ(na + nb, 4);
    if (std::string(policy) == "round_robin") {
      EXPECT_EQ(na, 2);
      EXPECT_EQ(nb, 2);
    } else {
      EXPECT_TRUE(na == 4 || nb == 4) << na << " " << nb;
    }
  }
  RunResult r = RunProcess({BinPath("tandem-client"), "info", "--server", target, "--lb",
                            "round_robin"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  RunResult bad = RunProcess({BinPath("tandem-client"), "info", "--lb", "random"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("--lb"), std::string::npos) << bad.err;
}

// A server whose only session slot is taken refuses a second stream with
// RESOURCE_EXHAUSTED; the client retries with backoff and gets its mesh once the slot is
// free. With --retries 0 it fails at once.
TEST(Client, RetriesAStreamRefusedBecauseTheServerIsBusy) {
  const std::string dir = MakeTempDir();
  auto server = TestServer::Start({"--max-sessions", "1"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  auto small = WriteSyntheticVolume(dir, "small", MakeSyntheticSource(Shape::kSphere, 16, 16, 16));
  auto slow = WriteSyntheticVolume(dir, "slow", MakeSyntheticSource(Shape::kSphere, 16, 16, 30));
  ASSERT_TRUE(small.ok() && slow.ok());
  auto stream = [&](const std::string& input, std::vector<std::string> extra) {
    std::vector<std::string> argv = {BinPath("tandem-client"), "stream", "--server",
                                     s.address(), "--input", input, "--iso", "0", "--error",
                                     "0.3", "--out", dir + "/out.ply"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    return argv;
  };
  for (int retries : {0, 4}) {
    SCOPED_TRACE(retries);
    auto busy = ChildProcess::Spawn(stream(*slow, {"--rate", "10"}), dir);  // 3 s
    ASSERT_TRUE(busy.ok());
    bool active = false;
    for (int i = 0; i < 200 && !active; ++i) {
      auto info = s.Info();
      active = info.ok() && info->counters().active_sessions() == 1;
      if (!active) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ASSERT_TRUE(active);
    const int64_t rejected0 = s.Info()->counters().sessions_rejected();
    RunResult r = RunProcess(stream(*small, {"--retries", std::to_string(retries)}));
    if (retries == 0) {
      EXPECT_EQ(r.exit_code, 1) << r.err;
      EXPECT_NE(r.err.find("RESOURCE_EXHAUSTED"), std::string::npos) << r.err;
      EXPECT_EQ(s.Info()->counters().sessions_rejected() - rejected0, 1);
    } else {
      EXPECT_EQ(r.exit_code, 0) << r.err;
      EXPECT_GE(s.Info()->counters().sessions_rejected() - rejected0, 1) << "it was refused";
      EXPECT_NE(r.err.find("refused (RESOURCE_EXHAUSTED: "), std::string::npos) << r.err;
      EXPECT_NE(r.err.find("; retry 1 of 4 in "), std::string::npos) << r.err;
    }
    EXPECT_EQ((*busy)->Wait(30), 0) << (*busy)->Stderr();
    ASSERT_TRUE(s.WaitIdle(10));
  }
}

// A request over the server's limits is final: the server marks it (grpc-retry-pushback-ms
// -1) and the client does not retry it.
TEST(Client, DoesNotRetryARequestOverTheServersLimits) {
  const std::string dir = MakeTempDir();
  auto server = TestServer::Start({"--max-voxels-per-slice", "100"});
  ASSERT_TRUE(server.ok()) << server.status();
  auto volume = WriteSyntheticVolume(dir, "v", MakeSyntheticSource(Shape::kSphere, 16, 16, 8));
  ASSERT_TRUE(volume.ok());
  RunResult r = RunProcess({BinPath("tandem-client"), "stream", "--server",
                            (*server)->address(), "--input", *volume, "--iso", "0",
                            "--error", "0.3", "--out", dir + "/out.ply"});
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("RESOURCE_EXHAUSTED"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("retry"), std::string::npos) << "retried:\n" << r.err;
  ASSERT_TRUE((*server)->WaitIdle(10));
  EXPECT_EQ((*server)->Info()->counters().sessions_started(), 1) << "one attempt only";
}

// A client process that keeps its channel open after a stream (an idle connection that
// has carried a call) does not hold the exit: gRPC's graceful GOAWAY would wait for the
// client to answer a ping, which an idle C++ channel does only at its 5 s backup poll.
TEST(Shutdown, AnIdleChannelThatRanAStreamDoesNotHoldTheExit) {
  auto server = TestServer::Start({"--grace-seconds", "20"});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  auto stub = s.NewStub();  // kept open until the end of the test
  const StreamOutcome outcome = RunStream(*stub, Sphere(16));
  ASSERT_TRUE(outcome.status.ok()) << outcome.status.error_message();
  ASSERT_TRUE(s.WaitIdle(10));
  const absl::Time signalled = absl::Now();
  s.process().Signal(SIGTERM);
  ASSERT_EQ(s.process().Wait(30), 0) << s.process().Stderr();
  const double exit_s = absl::ToDoubleSeconds(absl::Now() - signalled);
  EXPECT_LT(exit_s, 2.5) << "measured 5.0 s before the server cut idle connections\n"
                         << s.process().Stderr();
  // The channel still works for what comes next: it reconnects (and finds no server).
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
  v1::InfoResponse info;
  EXPECT_FALSE(stub->GetInfo(&context, v1::InfoRequest(), &info).ok());
}

}  // namespace
}  // namespace tandem::testing
