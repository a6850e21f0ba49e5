// The viewer's HTTP side on 127.0.0.1 with a real HTTP client (cpp-httplib's, or plain
// sockets for what it will not send): addresses, the token (the page's files included),
// immutable chunks and bands, the event stream, a busy port, and the doors closed: bodies,
// methods, ranges, foreign Host headers, slow and idle connections.
#include "tandem/viewer/view_server.h"

#include <gtest/gtest.h>
#include <httplib.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <iterator>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "testutil/raw_http.h"
#include "testutil/testutil.h"

namespace tandem::viewer {
namespace {

using ::tandem::testing::GetRequest;
using ::tandem::testing::RawHttp;
using ::tandem::testing::RawRequest;
using ::tandem::testing::RawResponse;
using ::tandem::testing::ResidentBytes;
using Clock = std::chrono::steady_clock;

int PortOf(const std::string& url) {
  const size_t colon = url.rfind(':');
  return std::stoi(url.substr(colon + 1));
}

struct Viewer {
  std::unique_ptr<ViewServer> server;
  int port = 0;
};

Viewer StartViewer(const std::string& token = "", const std::string& listen = "127.0.0.1:0") {
  ViewOptions options;
  options.listen = listen;
  options.token = token;
  auto server = ViewServer::Start(options);
  EXPECT_TRUE(server.ok()) << server.status();
  if (!server.ok()) return {};
  const int port = PortOf((*server)->url().substr(0, (*server)->url().rfind('/')));
  return {*std::move(server), port};
}

double SecondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

TEST(ViewServer, AddressesAreParsedAndLoopbackIsRecognised) {
  std::string host;
  int port = -1;
  ASSERT_TRUE(ParseListen("127.0.0.1:8080", &host, &port).ok());
  EXPECT_EQ(host, "127.0.0.1");
  EXPECT_EQ(port, 8080);
  ASSERT_TRUE(ParseListen("[::1]:0", &host, &port).ok());
  EXPECT_EQ(host, "::1");
  EXPECT_EQ(port, 0);
  for (const char* bad : {"8080", ":80", "host:", "host:65536", "host:-1", "host:x"}) {
    EXPECT_FALSE(ParseListen(bad, &host, &port).ok()) << bad;
  }
  EXPECT_TRUE(IsLoopback("127.0.0.1"));
  EXPECT_TRUE(IsLoopback("localhost"));
  EXPECT_TRUE(IsLoopback("::1"));
  EXPECT_FALSE(IsLoopback("0.0.0.0"));
  EXPECT_FALSE(IsLoopback("192.168.1.5"));
}

TEST(ViewServer, ServesTheStateChunksAndBandBehindItsToken) {
  ViewOptions options;
  options.listen = "127.0.0.1:0";
  options.token = "s3cret";
  auto server = ViewServer::Start(options);
  ASSERT_TRUE(server.ok()) << server.status();
  EXPECT_NE((*server)->url().find("?token=s3cret"), std::string::npos);
  (*server)->SetSession("abc", "volume.nii", 40);
  (*server)->AddChunk("chunk-zero", 12, 0);
  (*server)->SetBand(0, "band-one", 5, 7, true);
  ViewProgress progress;
  progress.slices_sent = 9;
  progress.slices_meshed = 8;
  progress.triangles_held = 100;
  progress.triangles_sealed = 12;
  (*server)->SetProgress(progress);
  httplib::Client http("127.0.0.1", PortOf((*server)->url()));

  for (const char* path : {"/", "/viewer.js", "/viewer.css", "/three/build/three.module.js",
                           "/state.json", "/chunk/0.drc", "/band/1.drc", "/events"}) {
    auto refused = http.Get(path);
    ASSERT_TRUE(refused) << path;
    EXPECT_EQ(refused->status, 401) << path;
  }
  auto state = http.Get("/state.json?token=s3cret");
  ASSERT_TRUE(state);
  ASSERT_EQ(state->status, 200);
  const auto s = nlohmann::json::parse(state->body);
  EXPECT_EQ(s["session"], "abc");
  EXPECT_EQ(s["nz"], 40);
  EXPECT_EQ(s["chunks"], 1);
  EXPECT_EQ(s["chunk_triangles"][0], 12);
  EXPECT_EQ(s["bands"][0]["version"], 1);
  EXPECT_EQ(s["slices_meshed"], 8);
  EXPECT_FALSE(s["finished"].get<bool>());

  httplib::Headers bearer = {{"Authorization", "Bearer s3cret"}};
  EXPECT_EQ(http.Get("/three/build/three.module.js", bearer)->status, 200);
  EXPECT_EQ(http.Get("/three/../package.json", bearer)->status, 404);
  auto chunk = http.Get("/chunk/0.drc", bearer);
  ASSERT_TRUE(chunk);
  EXPECT_EQ(chunk->body, "chunk-zero");
  EXPECT_NE(chunk->get_header_value("Cache-Control").find("immutable"), std::string::npos);
  EXPECT_EQ(http.Get("/chunk/1.drc", bearer)->status, 404);
  EXPECT_EQ(http.Get("/band/1.drc", bearer)->body, "band-one");
  (*server)->SetBand(0, "band-two", 6, 9, true);
  EXPECT_EQ(http.Get("/band/1.drc", bearer)->status, 404) << "superseded";
  EXPECT_EQ(http.Get("/band/2.drc", bearer)->body, "band-two");

  // The event stream: the current state at once.
  std::string first_event;
  http.Get("/events?token=s3cret", [&](const char* data, size_t size) {
    first_event.append(data, size);
    return first_event.find("\n\n") == std::string::npos;  // stop after one event
  });
  ASSERT_EQ(first_event.rfind("data: ", 0), 0u) << first_event;
  const auto e = nlohmann::json::parse(first_event.substr(6, first_event.find("\n\n") - 6));
  EXPECT_EQ(e["bands"][0]["version"], 2);
  (*server)->Finish(R"({"triangles_final": 18})", "");
  const auto end = nlohmann::json::parse(http.Get("/state.json?token=s3cret")->body);
  EXPECT_TRUE(end["finished"].get<bool>());
  EXPECT_EQ(end["metrics"]["triangles_final"], 18);
}

// Several surfaces: labels, each chunk's surface, a band per surface (each served by its own
// version, a newer one of one surface leaving the other's in place), the slices on disk, the
// finishing state with its time counted by the server and frozen at the end, and one
// metrics object per surface.
TEST(ViewServer, SurfacesHaveTheirOwnChunksBandsAndMetricsAndTheEndIsTimed) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  httplib::Client http("127.0.0.1", v.port);
  auto state = [&] { return nlohmann::json::parse(http.Get("/state.json")->body); };
  v.server->SetSurfaces({"iso -500", "iso 300"});
  v.server->AddChunk("skin-0", 4, 0);
  v.server->AddChunk("bone-0", 5, 1);
  v.server->SetBand(1, "bone-band", 7, 11, true);
  v.server->SetBand(0, "skin-band", 6, 12, true);
  ViewProgress progress;
  progress.slices_sent = 14;
  progress.slices_meshed = 13;
  progress.slices_on_disk = 20;
  v.server->SetProgress(progress);
  nlohmann::json s = state();
  EXPECT_EQ(s["surfaces"][1]["label"], "iso 300");
  EXPECT_EQ(s["chunk_surfaces"], nlohmann::json::parse("[0, 1]"));
  EXPECT_EQ(s["bands"][1]["version"], 1);
  EXPECT_EQ(s["bands"][0]["version"], 2);
  EXPECT_EQ(s["bands"][0]["slice"], 12);
  EXPECT_EQ(s["slices_on_disk"], 20);
  EXPECT_TRUE(s["finishing"].is_null());
  EXPECT_EQ(http.Get("/band/1.drc")->body, "bone-band");
  EXPECT_EQ(http.Get("/band/2.drc")->body, "skin-band");
  v.server->SetBand(1, "bone-band-2", 8, 13, true);
  EXPECT_EQ(http.Get("/band/1.drc")->status, 404) << "superseded";
  EXPECT_EQ(http.Get("/band/2.drc")->body, "skin-band") << "the other surface's stays";
  EXPECT_EQ(http.Get("/band/3.drc")->body, "bone-band-2");

  v.server->SetFinishing(1234, 2.5);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  s = state();
  EXPECT_EQ(s["finishing"]["triangles"], 1234);
  EXPECT_EQ(s["finishing"]["estimate_s"], 2.5);
  EXPECT_GE(s["finishing"]["elapsed_s"].get<double>(), 0.3);
  v.server->ClearBands();
  v.server->Finish(R"([{"triangles_final": 10}, {"triangles_final": 12}])", "");
  s = state();
  EXPECT_TRUE(s["bands"][0].is_null() && s["bands"][1].is_null());
  EXPECT_EQ(http.Get("/band/2.drc")->status, 404);
  EXPECT_EQ(s["metrics"][1]["triangles_final"], 12);
  const double took = s["finishing"]["elapsed_s"].get<double>();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  EXPECT_EQ(state()["finishing"]["elapsed_s"].get<double>(), took) << "frozen at the end";
}

TEST(ViewServer, ABusyPortIsAnErrorNamingIt) {
  ViewOptions options;
  options.listen = "127.0.0.1:0";
  auto first = ViewServer::Start(options);
  ASSERT_TRUE(first.ok()) << first.status();
  const std::string port = std::to_string(PortOf((*first)->url()));
  options.listen = "127.0.0.1:" + port;
  auto second = ViewServer::Start(options);
  ASSERT_FALSE(second.ok());
  EXPECT_NE(second.status().message().find("port " + port + " is in use"), std::string::npos)
      << second.status();
  options.listen = "no-port";
  EXPECT_FALSE(ViewServer::Start(options).ok());
}

// The page's own files need the token as well. The printed address (with ?token=) gives the
// browser a cookie for what the page loads next; the cookie holds another value than the
// token, is named after the port, and a wrong one is refused.
TEST(ViewServer, ThePagesFilesNeedTheTokenAndTheAddressGivesACookie) {
  Viewer v = StartViewer("s3cret");
  ASSERT_TRUE(v.server);
  const std::string name = "tandem_view_" + std::to_string(v.port);
  RawResponse page = RawRequest(v.port, GetRequest(v.port, "/?token=s3cret"));
  ASSERT_EQ(page.status, 200);
  EXPECT_NE(page.body.find("viewer.js"), std::string::npos);
  const std::string cookie = page.headers["set-cookie"];
  ASSERT_EQ(cookie.rfind(name + "=", 0), 0u) << cookie;
  EXPECT_NE(cookie.find("HttpOnly"), std::string::npos) << cookie;
  EXPECT_NE(cookie.find("SameSite=Strict"), std::string::npos) << cookie;
  EXPECT_EQ(cookie.find("s3cret"), std::string::npos) << "the cookie must not be the token";
  const std::string value = cookie.substr(name.size() + 1, cookie.find(';') - name.size() - 1);
  ASSERT_GE(value.size(), 16u);
  for (const char* path : {"/viewer.js", "/viewer.css", "/three/build/three.module.js",
                           "/state.json"}) {
    SCOPED_TRACE(path);
    EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, path)).status, 401);
    EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, path, "Cookie: " + name + "=wrong\r\n")).status,
              401);
    EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, path, "Cookie: tandem_view_1=" + value +
                                                            "\r\n")).status,
              401);
    RawResponse ok = RawRequest(
        v.port, GetRequest(v.port, path, "Cookie: other=1; " + name + "=" + value + "\r\n"));
    EXPECT_EQ(ok.status, 200);
    EXPECT_FALSE(ok.body.empty());
    EXPECT_EQ(ok.headers.count("set-cookie"), 0u) << "only the page itself sets it";
  }
  RawResponse three = RawRequest(v.port, GetRequest(v.port, "/three/build/three.module.js",
                                                    "Cookie: " + name + "=" + value + "\r\n"));
  EXPECT_EQ(three.headers["cache-control"].rfind("private", 0), 0u)
      << "no shared cache may keep what needs the token: " << three.headers["cache-control"];
}

// A request's body is refused before it is read: a POST announcing 256 MiB gets 405 (GET
// and HEAD only) before any of it is sent, the viewer takes little of what is sent anyway,
// and its memory does not grow; a GET with a body gets 413, and "Expect: 100-continue" the
// refusal instead of "100 Continue".
TEST(ViewServer, RequestBodiesAreRefusedBeforeTheyAreRead) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  const int64_t before = ResidentBytes(getpid());
  auto post = RawHttp::Connect(v.port);
  ASSERT_TRUE(post);
  const auto start = Clock::now();
  ASSERT_TRUE(post->Send(
      "POST /state.json HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 268435456\r\n\r\n"));
  RawResponse refused = post->ReadResponse(5);
  EXPECT_EQ(refused.status, 405);
  EXPECT_LT(SecondsSince(start), 2.0);
  const int64_t taken = post->SendFiller(int64_t{256} << 20, 10);
  EXPECT_LT(taken, int64_t{32} << 20) << "the viewer read the body it refused";
  EXPECT_TRUE(post->WaitClosed(5));
  if (!::tandem::testing::kSanitized) {
    EXPECT_LT(ResidentBytes(getpid()) - before, int64_t{8} << 20);
  }

  for (const char* method : {"PUT", "DELETE", "OPTIONS", "PATCH", "POST"}) {
    RawResponse r = RawRequest(v.port, std::string(method) +
                                           " / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
    EXPECT_EQ(r.status, 405) << method;
    EXPECT_EQ(r.headers["allow"], "GET, HEAD") << method;
  }
  EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/state.json", "Content-Length: 5\r\n") +
                                   "hello").status,
            413);
  EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/state.json", "Transfer-Encoding: chunked\r\n") +
                                   "5\r\nhello\r\n0\r\n\r\n").status,
            413);
  RawResponse expect = RawRequest(
      v.port, "POST / HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000000\r\n"
              "Expect: 100-continue\r\n\r\n");
  EXPECT_EQ(expect.status, 405);
  auto head = RawHttp::Connect(v.port);
  ASSERT_TRUE(head);
  head->Send("HEAD /state.json HTTP/1.1\r\nHost: localhost\r\n\r\n");
  EXPECT_EQ(head->ReadHead(5).status, 200);
  EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/state.json")).status, 200);
}

// Several ranges get 416, with no multipart answer built (1,000 ranges of three.js's core
// would be 1.4 GB); one range is served; the viewer goes on serving.
TEST(ViewServer, SeveralRangesAreRefused) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  std::string ranges = "bytes=0-";
  for (int i = 1; i < 1000; ++i) ranges += ",0-";
  const int64_t before = ResidentBytes(getpid());
  auto c = RawHttp::Connect(v.port);
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->Send(GetRequest(v.port, "/three/build/three.core.js", "Range: " + ranges + "\r\n")));
  RawResponse many = c->ReadHead(10);
  EXPECT_EQ(many.status, 416);
  EXPECT_EQ(many.headers["content-length"], "0");
  if (!::tandem::testing::kSanitized) {
    EXPECT_LT(ResidentBytes(getpid()) - before, int64_t{16} << 20);
  }
  EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/state.json", "Range: bytes=0-0,2-2\r\n")).status,
            416);
  RawResponse one =
      RawRequest(v.port, GetRequest(v.port, "/three/build/three.core.js", "Range: bytes=0-9\r\n"));
  EXPECT_EQ(one.status, 206);
  std::ifstream file(FindThree("") + "/build/three.core.js", std::ios::binary);
  std::string first(10, '\0');
  file.read(first.data(), 10);
  EXPECT_EQ(one.body, first);
  EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/state.json")).status, 200);
}

// Against DNS rebinding: a Host header that does not name this server gets 403 and none of
// the session's data. Bound to loopback, only loopback names pass; bound to every address,
// IP literals and this machine's name pass too, other names still do not.
TEST(ViewServer, AHostThatIsNotThisServersIsRefused) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  v.server->AddChunk("the-mesh-bytes", 3, 0);
  const std::string port = std::to_string(v.port);
  for (const std::string& host : std::vector<std::string>{"evil.example", "evil.example:" + port, "10.1.2.3",
                                 "localhost.evil.example", "127.0.0.1.evil.example:" + port,
                                 "[fe80::1]:" + port}) {
    SCOPED_TRACE(host);
    for (const char* path : {"/state.json", "/chunk/0.drc", "/"}) {
      RawResponse r = RawRequest(v.port, GetRequest(v.port, path, "Host: " + host + "\r\n"));
      EXPECT_EQ(r.status, 403) << path;
      EXPECT_EQ(r.body.find("the-mesh"), std::string::npos);
      EXPECT_EQ(r.body.find("chunk_triangles"), std::string::npos);
    }
  }
  for (const std::string& host : std::vector<std::string>{"127.0.0.1:" + port, "localhost:" + port, "LocalHost", "[::1]:" + port,
                                 "127.0.0.1", "localhost.", "127.5.6.7:9"}) {
    EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/chunk/0.drc", "Host: " + host + "\r\n")).body,
              "the-mesh-bytes")
        << host;
  }
  EXPECT_EQ(RawRequest(v.port, "GET /state.json HTTP/1.0\r\n\r\n").status, 200)
      << "no Host at all: not a browser";

  Viewer any = StartViewer("", "0.0.0.0:0");
  ASSERT_TRUE(any.server);
  char self[256] = "";
  ASSERT_EQ(gethostname(self, sizeof(self) - 1), 0);
  for (const std::string& host : std::vector<std::string>{"127.0.0.1", "192.168.7.9:8080", "[fe80::1]", std::string(self)}) {
    EXPECT_EQ(RawRequest(any.port, GetRequest(any.port, "/state.json", "Host: " + host + "\r\n")).status,
              200)
        << host;
  }
  EXPECT_EQ(RawRequest(any.port, GetRequest(any.port, "/state.json", "Host: evil.example\r\n")).status,
            403);
}

// Idle and slowly trickled connections hold no thread: with 20 of each open, a request is
// answered at once; a request still incomplete 5 s after its first byte gets 408 and is
// closed, however slowly its bytes keep coming.
TEST(ViewServer, SlowAndIdleConnectionsDoNotHoldUpOthers) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  std::vector<std::unique_ptr<RawHttp>> idle, slow;
  for (int i = 0; i < 20; ++i) {
    idle.push_back(RawHttp::Connect(v.port));
    slow.push_back(RawHttp::Connect(v.port));
    ASSERT_TRUE(idle.back() && slow.back());
    ASSERT_TRUE(slow.back()->Send("GET /state.json HTTP/1.1\r\nHo"));
  }
  const auto trickle_start = Clock::now();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  for (int round = 0; round < 3; ++round) {
    const auto asked = Clock::now();
    RawResponse r = RawRequest(v.port, GetRequest(v.port, "/state.json"), 5);
    EXPECT_EQ(r.status, 200);
    EXPECT_LT(SecondsSince(asked), 1.0);
    for (auto& s : slow) s->Send("s");
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
  }
  // Keep trickling (a byte every 0.3 s) until the server closes them.
  size_t open = slow.size();
  std::vector<bool> closed(slow.size(), false);
  while (open > 0 && SecondsSince(trickle_start) < 12) {
    for (size_t i = 0; i < slow.size(); ++i) {
      if (!closed[i] && !slow[i]->Send("t", 0.1)) {
        closed[i] = true;
        --open;
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
  }
  EXPECT_EQ(open, 0u) << "trickled requests still open after " << SecondsSince(trickle_start) << " s";
  EXPECT_LT(SecondsSince(trickle_start), 9.0);
  for (auto& c : idle) EXPECT_TRUE(c->WaitClosed(3)) << "an idle connection is closed too";
}

// Headers that never end are refused once they pass 16 KiB (431), not read on and on.
TEST(ViewServer, EndlessHeadersAreRefused) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  auto c = RawHttp::Connect(v.port);
  ASSERT_TRUE(c);
  std::string request = "GET /state.json HTTP/1.1\r\nHost: 127.0.0.1\r\n";
  while (request.size() < (20 << 10)) request += "X-Filler: abcdefghijklmnopqrstuvwxyz\r\n";
  c->Send(request);
  EXPECT_EQ(c->ReadHead(3).status, 431);
  EXPECT_TRUE(c->WaitClosed(3));
}

// Event streams hold a worker each: past 12 open ones the next gets 503 (and may retry),
// while the page's other requests are still answered.
TEST(ViewServer, EventStreamsAreCappedAndTheRestIsStillServed) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  std::vector<std::unique_ptr<RawHttp>> streams;
  for (int i = 0; i < 12; ++i) {
    streams.push_back(RawHttp::Connect(v.port));
    ASSERT_TRUE(streams.back());
    ASSERT_TRUE(streams.back()->Send(GetRequest(v.port, "/events")));
    ASSERT_EQ(streams.back()->ReadHead(5).status, 200) << i;
  }
  RawResponse over = RawRequest(v.port, GetRequest(v.port, "/events"));
  EXPECT_EQ(over.status, 503);
  EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/state.json")).status, 200);
  streams.pop_back();
  int status = 0;
  for (int i = 0; i < 50 && status != 200; ++i) {
    auto again = RawHttp::Connect(v.port);
    ASSERT_TRUE(again);
    again->Send(GetRequest(v.port, "/events"));
    status = again->ReadHead(5).status;
    if (status != 200) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_EQ(status, 200) << "a closed page's stream frees its place";
}

// What a browser offers (gzip, deflate, br) gets gzip, never Brotli, whose slowest quality
// (cpp-httplib's) takes seconds on three.js at every fresh page load; Brotli alone gets the
// file as it is.
TEST(ViewServer, ThePagesFilesComeGzippedNeverBrotli) {
  Viewer v = StartViewer();
  ASSERT_TRUE(v.server);
  std::ifstream file(FindThree("") + "/build/three.core.js", std::ios::binary);
  const std::string whole((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  ASSERT_GT(whole.size(), 100000u);
  RawResponse offered = RawRequest(v.port, GetRequest(v.port, "/three/build/three.core.js",
                                                      "Accept-Encoding: gzip, deflate, br\r\n"));
  EXPECT_EQ(offered.status, 200);
  EXPECT_EQ(offered.headers["content-encoding"], "gzip");
  EXPECT_LT(offered.body.size(), whole.size() / 2);
  for (const char* only_br : {"Accept-Encoding: br\r\n", "Accept-Encoding: BR;q=1.0\r\n"}) {
    RawResponse br = RawRequest(v.port, GetRequest(v.port, "/three/build/three.core.js", only_br));
    EXPECT_EQ(br.status, 200) << only_br;
    EXPECT_EQ(br.headers.count("content-encoding"), 0u) << only_br;
    EXPECT_TRUE(br.body == whole) << only_br << ": " << br.body.size() << " bytes";
  }
}

// A chunk, band or file that does not exist: a 404 whose text names it and what there is
// (plain, without a Range header, which would cut the text), nothing else; the server goes on.
TEST(ViewServer, AMissingChunkIsA404NamingIt) {
  Viewer v = StartViewer("s3cret");
  ASSERT_TRUE(v.server);
  v.server->AddChunk("chunk-zero", 1, 0);
  const std::vector<std::pair<std::string, std::string>> missing = {
      {"/chunk/1.drc", "no chunk 1: this session has 1 chunk (0 to 0) so far\n"},
      {"/chunk/99999999999999999999999999.drc",
       "no chunk 99999999999999999999999999: this session has 1 chunk (0 to 0) so far\n"},
      {"/band/7.drc",
       "no band version 7: superseded or never made (state.json names the current ones)\n"},
      {"/file/none.ply", "no such file here (state.json lists the files)\n"},
      {"/chunk/-1.drc", ""},  // no such address at all
      {"/chunk/x.drc", ""},
      {"/chunk/0.drc.bak", ""},
      {"/chunk/", ""}};
  for (const auto& [path, text] : missing) {
    for (const char* range : {"", "Range: bytes=0-0\r\n"}) {
      RawResponse r = RawRequest(v.port, GetRequest(v.port, path + "?token=s3cret", range));
      EXPECT_EQ(r.status, 404) << path << " " << range;
      const std::string body = *range == '\0' ? text : "";
      EXPECT_EQ(r.body, body) << path << " " << range;
      EXPECT_EQ(r.headers["content-length"], std::to_string(body.size())) << path;
      EXPECT_EQ(r.headers.count("set-cookie"), 0u) << path;
    }
  }
  Viewer empty = StartViewer();
  ASSERT_TRUE(empty.server);
  EXPECT_EQ(RawRequest(empty.port, GetRequest(empty.port, "/chunk/0.drc")).body,
            "no chunk 0: this session has 0 chunks so far\n");
  EXPECT_EQ(RawRequest(v.port, GetRequest(v.port, "/chunk/0.drc?token=s3cret")).body, "chunk-zero");
}

}  // namespace
}  // namespace tandem::viewer
