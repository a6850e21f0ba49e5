// What operators see: the Prometheus endpoint (--metrics-listen, served by cpp-httplib)
// counts sessions by final status, slices, bytes and phase time, and closes the doors a
// metrics port does not need (bodies, other methods, ranges, foreign Host headers, slow
// clients); --log-format json writes one JSON object per line, client strings escaped and
// truncated; a busy port is refused at start-up.
#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <thread>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "service/service_testutil.h"
#include "tandem/client/connection.h"
#include "tandem/eval/synthetic.h"
#include "testutil/raw_http.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

int PortOf(const std::string& host_port) {
  return std::stoi(host_port.substr(host_port.rfind(':') + 1));
}

// A tandem-server with --metrics-listen 127.0.0.1:0 (and `extra`): the server, its metrics'
// HOST:PORT and port; `server` is null (and the test failed) when it did not start.
struct WithMetrics {
  std::unique_ptr<TestServer> server;
  std::string url;
  int port = 0;
};
WithMetrics StartWithMetrics(std::vector<std::string> extra = {}) {
  extra.insert(extra.begin(), {"--metrics-listen", "127.0.0.1:0"});
  auto server = TestServer::Start(extra);
  EXPECT_TRUE(server.ok()) << server.status();
  if (!server.ok()) return {};
  WithMetrics m{*std::move(server), "", 0};
  m.url = MetricsUrl(*m.server);
  EXPECT_FALSE(m.url.empty()) << m.server->process().Stderr();
  if (m.url.empty()) return {};
  m.port = PortOf(m.url);
  return m;
}

std::vector<v1::ExtractRequest> Sphere(int64_t n) {
  v1::SessionConfig config;
  config.set_error(0.3);
  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, n, n, n);
  return VolumeRequests(*source, config, 1 << 20);
}

// A stream whose client vanishes mid-scan shows as a session waiting for a resume until
// its window (5 s here) is over.
TEST(Metrics, CountSessionsWaitingForAResume) {
  WithMetrics m = StartWithMetrics({"--resume-window-seconds", "5"});
  ASSERT_TRUE(m.server);
  TestServer& s = *m.server;
  const std::string& url = m.url;
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
  WithMetrics m = StartWithMetrics();
  ASSERT_TRUE(m.server);
  TestServer& s = *m.server;
  const std::string& url = m.url;
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

double SecondsSince(absl::Time t) { return absl::ToDoubleSeconds(absl::Now() - t); }

// The metrics port reads no request body: a POST announcing 256 MiB is refused (405: GET and
// HEAD only) before any of it is sent, the server takes little of what is sent anyway and
// does not grow; a GET with a body gets 413; scrapes go on.
TEST(Metrics, ARequestBodyIsRefusedBeforeItIsRead) {
  WithMetrics m = StartWithMetrics();
  ASSERT_TRUE(m.server);
  TestServer& s = *m.server;
  const std::string& url = m.url;
  const int port = m.port;
  Scrape(url);
  const int64_t before = ResidentBytes(s.process().pid());
  for (const std::string method : {"POST", "GET"}) {
    SCOPED_TRACE(method);
    auto c = RawHttp::Connect(port);
    ASSERT_TRUE(c);
    const absl::Time start = absl::Now();
    ASSERT_TRUE(c->Send(method + " /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                                 "Content-Length: 268435456\r\n\r\n"));
    EXPECT_EQ(c->ReadResponse(5).status, method == "POST" ? 405 : 413);
    EXPECT_LT(SecondsSince(start), 2.0);
    const int64_t taken = c->SendFiller(int64_t{256} << 20, 10);
    EXPECT_LT(taken, int64_t{32} << 20) << "the server read the body it refused";
    EXPECT_TRUE(c->WaitClosed(5));
  }
  if (!kSanitized) {
    EXPECT_LT(ResidentBytes(s.process().pid()) - before, int64_t{4} << 20);
  }
  EXPECT_EQ(Scrape(url)["tandem_active_sessions"], 0);
}

// Slow and idle connections cannot starve a scrape (the autoscaler's signal): with 8 idle
// and 8 trickling connections open, scrapes are answered at once, again and again,
// and the trickling ones are dropped once their request has taken 5 s.
TEST(Metrics, SlowAndIdleConnectionsDoNotStarveAScrape) {
  WithMetrics m = StartWithMetrics();
  ASSERT_TRUE(m.server);
  const int port = m.port;
  std::vector<std::unique_ptr<RawHttp>> idle, slow;
  for (int i = 0; i < 8; ++i) {
    idle.push_back(RawHttp::Connect(port));
    slow.push_back(RawHttp::Connect(port));
    ASSERT_TRUE(idle.back() && slow.back());
    ASSERT_TRUE(slow.back()->Send("GET /metrics HTTP/1.1\r\nHost: 127"));
  }
  const absl::Time opened = absl::Now();
  std::vector<bool> closed(slow.size(), false);
  size_t open = slow.size();
  while (open > 0 && SecondsSince(opened) < 12) {
    const absl::Time asked = absl::Now();
    RawResponse scrape = RawRequest(port, GetRequest(port, "/metrics"), 5);
    EXPECT_EQ(scrape.status, 200);
    EXPECT_NE(scrape.body.find("tandem_active_sessions 0"), std::string::npos);
    // Starved, a scrape would wait for a slow request's 5 s; 2.5 s leaves a loaded machine room.
    EXPECT_LT(SecondsSince(asked), 2.5) << "a scrape waited behind slow connections";
    for (size_t i = 0; i < slow.size(); ++i) {  // a byte each, until the server hangs up
      if (!closed[i] && !slow[i]->Send(".", 0.1)) {
        closed[i] = true;
        --open;
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
  }
  EXPECT_EQ(open, 0u) << "trickling connections still open after 12 s";
  // 5 s a request plus the server's sweep and this loop's steps: about 8 s on an idle machine,
  // so the bound leaves room for a loaded one.
  EXPECT_LT(SecondsSince(opened), 10.5);
}

// Several ranges get 416, a Host header that does not name the server 403 (DNS rebinding),
// other methods 405, headers that never end 431.
TEST(Metrics, RangesForeignHostsOtherMethodsAndEndlessHeadersAreRefused) {
  WithMetrics m = StartWithMetrics();
  ASSERT_TRUE(m.server);
  const int port = m.port;
  std::string ranges = "bytes=0-";
  for (int i = 1; i < 1000; ++i) ranges += ",0-";
  RawResponse many = RawRequest(port, GetRequest(port, "/metrics", "Range: " + ranges + "\r\n"));
  EXPECT_EQ(many.status, 416);
  EXPECT_TRUE(many.body.empty());
  RawResponse foreign = RawRequest(port, GetRequest(port, "/metrics", "Host: attacker.example\r\n"));
  EXPECT_EQ(foreign.status, 403);
  EXPECT_EQ(foreign.body.find("tandem_"), std::string::npos);
  EXPECT_EQ(RawRequest(port, GetRequest(port, "/metrics", "Host: localhost:9090\r\n")).status, 200);
  RawResponse put = RawRequest(port, "PUT /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  EXPECT_EQ(put.status, 405);
  EXPECT_EQ(put.headers["allow"], "GET, HEAD");
  auto endless = RawHttp::Connect(port);
  ASSERT_TRUE(endless);
  std::string headers = "GET /metrics HTTP/1.1\r\n";
  while (headers.size() < (20 << 10)) headers += "X-Filler: 0123456789abcdef\r\n";
  endless->Send(headers);
  EXPECT_EQ(endless->ReadHead(3).status, 431);
  EXPECT_EQ(Scrape(m.url)["tandem_active_sessions"], 0);
}

// A port another process listens on is refused at start-up, naming the address: another
// tandem-server's gRPC or metrics port, or any listening socket; the first server keeps
// serving. (gRPC and cpp-httplib both bind with SO_REUSEPORT by default, which let a second
// server start on the same port and take half of its connections.)
TEST(Startup, ABusyPortIsRefusedAndTheFirstServerKeepsServing) {
  WithMetrics first = StartWithMetrics();
  ASSERT_TRUE(first.server);
  TestServer& a = *first.server;
  const std::string& metrics = first.url;
  const std::string grpc_port = std::to_string(PortOf(a.address()));
  for (const std::string host : {"127.0.0.1", "0.0.0.0"}) {
    RunResult second =
        RunProcess({BinPath("tandem-server"), "--listen", host + ":" + grpc_port}, 15);
    EXPECT_EQ(second.exit_code, 1) << second.err;
    EXPECT_NE(second.err.find("cannot listen on --listen " + host + ":" + grpc_port + ": port " +
                              grpc_port + " is in use by another process"),
              std::string::npos)
        << second.err;
  }
  const std::string metrics_port = std::to_string(first.port);
  RunResult third = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0",
                                "--metrics-listen", "127.0.0.1:" + metrics_port},
                               15);
  EXPECT_EQ(third.exit_code, 1) << third.err;
  EXPECT_NE(third.err.find("--metrics-listen: cannot listen on 127.0.0.1:" + metrics_port +
                           ": port " + metrics_port + " is in use by another process"),
            std::string::npos)
      << third.err;
  EXPECT_EQ(a.Health(), "SERVING");
  EXPECT_TRUE(a.Info().ok());
  EXPECT_EQ(Scrape(metrics)["tandem_active_sessions"], 0);

  // Any socket: one this test listens on.
  int held_port = 0;
  const int fd = ListenOnLoopback(&held_port);
  ASSERT_GE(fd, 0);
  const std::string held = std::to_string(held_port);
  RunResult fourth = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:" + held}, 15);
  close(fd);
  EXPECT_EQ(fourth.exit_code, 1) << fourth.err;
  EXPECT_NE(fourth.err.find("port " + held + " is in use by another process"), std::string::npos)
      << fourth.err;
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
  auto small = WriteSyntheticVolume(dir, "small",
                                    eval::MakeSyntheticSource(eval::Shape::kSphere, 16, 16, 16));
  auto slow = WriteSyntheticVolume(dir, "slow",
                                   eval::MakeSyntheticSource(eval::Shape::kSphere, 16, 16, 30));
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
  auto volume =
      WriteSyntheticVolume(dir, "v", eval::MakeSyntheticSource(eval::Shape::kSphere, 16, 16, 8));
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
