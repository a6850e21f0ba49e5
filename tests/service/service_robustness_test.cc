// Bad and hostile streams against the real tandem-server, through raw gRPC stubs (so the
// requests can be malformed on purpose): each gets the right code and a message that
// names the problem, and the server keeps serving. Also: session limit, message size
// limit, cancellation, and the latest-wins previews of a slow reader.
#include <gtest/gtest.h>
#include <signal.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <thread>

#include "absl/strings/str_split.h"
#include "service/bad_input_cases.h"
#include "service/service_testutil.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/eval/synthetic.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

bool FinishedOk(const StreamOutcome& o) {
  return o.status.ok() && !o.responses.empty() && o.responses.back().has_final_metrics();
}

class ServiceRobustnessTest : public ::testing::Test {
 protected:
  // Streams cancelled mid-scan wait 1 s for a resume (not the default 60) before the
  // checks that nothing is left behind.
  void Start(std::vector<std::string> args) {
    if (std::find(args.begin(), args.end(), "--resume-window-seconds") == args.end()) {
      args.insert(args.end(), {"--resume-window-seconds", "1"});
    }
    auto server = TestServer::Start(args);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    stub_ = server_->NewStub();
  }
  std::unique_ptr<TestServer> server_;
  std::unique_ptr<v1::Tandem::Stub> stub_;
};

TEST_F(ServiceRobustnessTest, BadInputGetsTheRightCodeAndTheServerKeepsServing) {
  ASSERT_NO_FATAL_FAILURE(Start(kBadInputServerArgs));
  ASSERT_TRUE(FinishedOk(RunStream(*stub_, Good()))) << "the unmodified stream works";
  const std::vector<BadInputCase> cases = BadInputCases();
  for (const BadInputCase& c : cases) {
    std::vector<v1::ExtractRequest> requests = Good();
    c.edit(&requests);
    const StreamOutcome o = RunStream(*stub_, requests);
    EXPECT_EQ(o.status.error_code(), c.code) << c.name << ": " << o.status.error_message();
    EXPECT_NE(o.status.error_message().find(c.text), std::string::npos)
        << c.name << ": got \"" << o.status.error_message() << "\", want \"" << c.text << "\"";
    for (const v1::ExtractResponse& r : o.responses) {
      EXPECT_FALSE(r.has_final_mesh() || r.has_final_metrics()) << c.name;
    }
  }
  EXPECT_EQ(server_->Health(), "SERVING");
  EXPECT_TRUE(FinishedOk(RunStream(*stub_, Good()))) << "a good stream still works";
  v1::Counters counters;
  EXPECT_TRUE(server_->WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_EQ(counters.sessions_started(), static_cast<int64_t>(cases.size()) + 2);
}

TEST_F(ServiceRobustnessTest, SessionsBeyondTheLimitAreRejected) {
  ASSERT_NO_FATAL_FAILURE(Start({"--max-sessions", "1"}));
  // Hold one session open: config sent, nothing else.
  grpc::ClientContext holder;
  auto held = stub_->Extract(&holder);
  ASSERT_TRUE(held->Write(Good()[0]));
  bool active = false;
  for (int i = 0; i < 200 && !active; ++i) {
    auto info = server_->Info();
    active = info.ok() && info->counters().active_sessions() == 1;
    if (!active) std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  ASSERT_TRUE(active);
  const StreamOutcome rejected = RunStream(*stub_, Good());
  EXPECT_EQ(rejected.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(rejected.status.error_message().find("--max-sessions"), std::string::npos)
      << rejected.status.error_message();
  holder.TryCancel();
  v1::ExtractResponse ignored;
  while (held->Read(&ignored)) {
  }
  EXPECT_EQ(held->Finish().error_code(), grpc::StatusCode::CANCELLED);
  v1::Counters counters;
  EXPECT_TRUE(server_->WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_EQ(counters.sessions_rejected(), 1);
  EXPECT_TRUE(FinishedOk(RunStream(*stub_, Good()))) << "the slot is free again";
}

TEST_F(ServiceRobustnessTest, SilentClientTimesOutAndFreesItsSlot) {
  ASSERT_NO_FATAL_FAILURE(Start({"--max-sessions", "1", "--idle-timeout-seconds", "0.5"}));
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  auto stream = stub_->Extract(&context);
  const std::vector<v1::ExtractRequest> requests = Good();
  ASSERT_TRUE(stream->Write(requests[0]));
  ASSERT_TRUE(stream->Write(requests[1]));  // then silence, stream left open
  v1::ExtractResponse response;
  while (stream->Read(&response)) {
  }
  const grpc::Status status = stream->Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  EXPECT_NE(status.error_message().find("--idle-timeout-seconds"), std::string::npos)
      << status.error_message();
  v1::Counters counters;
  EXPECT_TRUE(server_->WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_TRUE(FinishedOk(RunStream(*stub_, Good()))) << "the only slot is free again";
}

TEST_F(ServiceRobustnessTest, OversizedMessagesAreRefused) {
  ASSERT_NO_FATAL_FAILURE(Start({"--max-message-bytes", "65536"}));
  // 120 x 120 float32 = 57,600 bytes per slice: whole-slice chunks fit, 3-slice ones not.
  EXPECT_TRUE(FinishedOk(RunStream(*stub_, Good(120, 57600))));
  std::vector<v1::ExtractRequest> big = Good(120, 57600);
  big[1].mutable_chunk()->mutable_data()->append(57600 * 2, '\0');
  const StreamOutcome o = RunStream(*stub_, big);
  EXPECT_EQ(o.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED)
      << o.status.error_message();
  EXPECT_EQ(server_->Health(), "SERVING");
  v1::Counters counters;
  EXPECT_TRUE(server_->WaitIdle(10, &counters)) << counters.ShortDebugString();
}

// Cancelling at different points (before the config is handled, mid-slice, with a write
// in flight, after the last slice) always ends with no session, thread or memory left.
TEST_F(ServiceRobustnessTest, CancelledStreamLeavesNothingBehind) {
  ASSERT_NO_FATAL_FAILURE(Start({}));
  v1::SessionConfig config;
  config.set_error(0.5);
  config.mutable_preview()->set_every_slices(1);  // keep writes in flight
  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, 48, 48, 48);
  const std::vector<v1::ExtractRequest> requests = VolumeRequests(*source, config, 4096);
  int streams = 0;
  for (size_t sent : {size_t{1}, size_t{3}, requests.size() / 2, requests.size() - 1}) {
    for (bool read_first : {false, true}) {
      SCOPED_TRACE(::testing::Message() << sent << " requests, read first: " << read_first);
      grpc::ClientContext context;
      auto stream = stub_->Extract(&context);
      ++streams;
      for (size_t i = 0; i < sent; ++i) ASSERT_TRUE(stream->Write(requests[i]));
      v1::ExtractResponse response;
      if (read_first && sent > 3) {
        ASSERT_TRUE(stream->Read(&response));  // the server is working on it
      }
      context.TryCancel();
      while (stream->Read(&response)) {
      }
      EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::CANCELLED);
      // WaitIdle also checks sessions_finished == sessions_started. (A stream cancelled
      // right after its first write may never reach the server at all.)
      v1::Counters counters;
      EXPECT_TRUE(server_->WaitIdle(10, &counters)) << counters.ShortDebugString();
    }
  }
  auto info = server_->Info();
  ASSERT_TRUE(info.ok());
  EXPECT_GE(info->counters().sessions_started(), streams / 2);
  EXPECT_TRUE(FinishedOk(RunStream(*stub_, Good())));
}

// A message after End is refused even when it comes after the session's final messages
// (the job was quicker than the client): the OK waits for the half-close. A client that
// never half-closes still gets its OK, after a short grace.
TEST_F(ServiceRobustnessTest, AMessageAfterEndIsRefusedWhateverTheTiming) {
  ASSERT_NO_FATAL_FAILURE(Start({}));
  const std::vector<v1::ExtractRequest> requests = Good();
  for (const bool send_extra : {true, false}) {
    SCOPED_TRACE(send_extra ? "a chunk after the final metrics" : "no half-close");
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    auto stream = stub_->Extract(&context);
    for (const v1::ExtractRequest& r : requests) ASSERT_TRUE(stream->Write(r));
    v1::ExtractResponse response;
    bool final_metrics = false;
    while (!final_metrics && stream->Read(&response)) final_metrics = response.has_final_metrics();
    ASSERT_TRUE(final_metrics);  // the job is done, its OK is due
    const auto start = std::chrono::steady_clock::now();
    if (send_extra) {
      stream->Write(requests[1]);
      stream->WritesDone();
    }
    while (stream->Read(&response)) {
    }
    const grpc::Status status = stream->Finish();
    const double waited =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (send_extra) {
      EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT)
          << status.error_message();
      EXPECT_NE(status.error_message().find("got a SliceChunk after End"), std::string::npos)
          << status.error_message();
    } else {
      EXPECT_TRUE(status.ok()) << status.error_message();
      EXPECT_LT(waited, 10.0);  // the grace is 1 s
    }
  }
  EXPECT_TRUE(server_->WaitIdle(10));
}

// A reader that does not read while slices stream in gets a few recent previews, not one
// per slice; they come in increasing slice order and each decodes.
TEST_F(ServiceRobustnessTest, SlowReaderGetsFewerNewerPreviews) {
  // Previews neither spaced in time nor bounded in share: with the default 250 ms spacing a
  // fast machine consumed the 48 slices between two previews and only one was ever encoded,
  // so nothing was dropped and the bound below could not fail.
  ASSERT_NO_FATAL_FAILURE(Start({"--min-preview-interval-ms", "0", "--max-preview-share", "0"}));
  const int64_t n = 48;
  v1::SessionConfig config;
  config.set_schedule(v1::SCHEDULE_NONE);  // full resolution: previews of tens of KB
  config.mutable_preview()->set_every_slices(1);
  config.mutable_draco()->set_compression_level(0);
  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, n, n, n);
  const std::vector<v1::ExtractRequest> requests = VolumeRequests(*source, config, 1 << 20);
  // A fixed 64 KiB receive window (no BDP growth): what HTTP/2 lets the server buffer
  // ahead of the reader stays small and known.
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 64 * 1024);
  args.SetMaxReceiveMessageSize(64 << 20);
  auto stub = v1::Tandem::NewStub(
      grpc::CreateCustomChannel(server_->address(), grpc::InsecureChannelCredentials(), args));
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto stream = stub->Extract(&context);
  for (const v1::ExtractRequest& r : requests) ASSERT_TRUE(stream->Write(r));
  ASSERT_TRUE(stream->WritesDone());
  // Let the server consume everything while nobody reads. (Its worker then waits for
  // the final messages to be read: a draining session.)
  bool consumed = false;
  for (int i = 0; i < 400 && !consumed; ++i) {
    auto info = server_->Info();
    consumed = info.ok() && info->counters().sessions_draining() == 1;
    if (!consumed) std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  ASSERT_TRUE(consumed);
  std::vector<int64_t> slices;
  size_t preview_bytes = 0;
  bool final_metrics = false;
  v1::ExtractResponse response;
  while (stream->Read(&response)) {
    if (response.has_preview()) {
      slices.push_back(response.preview().slice());
      preview_bytes += response.preview().draco().size();
      auto mesh = codec::DecodeDraco(response.preview().draco());
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      EXPECT_EQ(static_cast<int64_t>(mesh->num_triangles()), response.preview().triangles());
    }
    final_metrics |= response.has_final_metrics();
  }
  ASSERT_TRUE(stream->Finish().ok());
  EXPECT_TRUE(final_metrics);
  RecordProperty("previews_received", static_cast<int>(slices.size()));
  ASSERT_FALSE(slices.empty());
  EXPECT_LT(slices.size(), static_cast<size_t>(n / 2))
      << "previews were dropped, not queued (" << preview_bytes << " bytes received)";
  for (size_t i = 1; i < slices.size(); ++i) EXPECT_GT(slices[i], slices[i - 1]);
}

// A description is the client's text: in the log it is escaped (no line can be forged,
// no escape code reaches an operator's terminal) and truncated (an 8 MiB description makes
// a line of a few hundred bytes), and every line starts with an RFC 3339 UTC timestamp.
TEST_F(ServiceRobustnessTest, ClientTextInTheLogIsEscapedAndBounded) {
  ASSERT_NO_FATAL_FAILURE(Start({}));
  std::vector<v1::ExtractRequest> forged = Good();
  forged[0].mutable_config()->set_description(
      "scan\ntandem-server: session peer=evil status=OK\x1b[31m red");
  ASSERT_TRUE(FinishedOk(RunStream(*stub_, forged)));
  std::vector<v1::ExtractRequest> huge = Good();
  huge[0].mutable_config()->set_description(std::string(8 << 20, 'A'));
  ASSERT_TRUE(FinishedOk(RunStream(*stub_, huge)));
  ASSERT_TRUE(server_->WaitIdle(30));
  server_->process().Signal(SIGTERM);
  ASSERT_TRUE(server_->process().Wait(60).has_value());
  const std::string log = server_->process().Stderr();
  EXPECT_EQ(log.find('\x1b'), std::string::npos) << "an escape code reached the log";
  EXPECT_NE(log.find("input=\"scan\\ntandem-server: session peer=evil status=OK\\x1b[31m red\""),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("...(8388608 bytes in all)"), std::string::npos);
  size_t sessions = 0;
  for (const absl::string_view line : absl::StrSplit(log, '\n')) {
    if (line.empty()) continue;
    EXPECT_LT(line.size(), 2000u) << line.substr(0, 200);
    // 2026-11-24T23:15:24.123Z tandem-server: ...
    EXPECT_TRUE(line.size() > 25 && line[4] == '-' && line[10] == 'T' && line[23] == 'Z' &&
                line.substr(24, 15) == " tandem-server:")
        << line.substr(0, 200);
    if (line.find(" session peer=") != absl::string_view::npos) ++sessions;
  }
  EXPECT_EQ(sessions, 2u) << "one line per session, no forged one";
}

}  // namespace
}  // namespace tandem::testing
