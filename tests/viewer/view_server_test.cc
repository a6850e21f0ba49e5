// The viewer's HTTP side on 127.0.0.1 with a real HTTP client (cpp-httplib's): addresses,
// the token, immutable chunks and bands, the event stream, and a busy port.
#include "viewer/view_server.h"

#include <httplib.h>

#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

namespace tandem::viewer {
namespace {

int PortOf(const std::string& url) {
  const size_t colon = url.rfind(':');
  return std::stoi(url.substr(colon + 1));
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
  (*server)->AddChunk("chunk-zero", 12);
  (*server)->SetBand("band-one", 5, 7, true);
  (*server)->SetProgress(9, 8, 100, 12);
  httplib::Client http("127.0.0.1", PortOf((*server)->url()));

  auto page = http.Get("/");  // the page itself is public
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("viewer.js"), std::string::npos);
  auto three = http.Get("/three/build/three.module.js");
  ASSERT_TRUE(three);
  EXPECT_EQ(three->status, 200);
  EXPECT_EQ(http.Get("/three/../package.json")->status, 404);

  for (const char* path : {"/state.json", "/chunk/0.drc", "/band/1.drc", "/events"}) {
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
  EXPECT_EQ(s["band"]["version"], 1);
  EXPECT_EQ(s["slices_meshed"], 8);
  EXPECT_FALSE(s["finished"].get<bool>());

  httplib::Headers bearer = {{"Authorization", "Bearer s3cret"}};
  auto chunk = http.Get("/chunk/0.drc", bearer);
  ASSERT_TRUE(chunk);
  EXPECT_EQ(chunk->body, "chunk-zero");
  EXPECT_NE(chunk->get_header_value("Cache-Control").find("immutable"), std::string::npos);
  EXPECT_EQ(http.Get("/chunk/1.drc", bearer)->status, 404);
  EXPECT_EQ(http.Get("/band/1.drc", bearer)->body, "band-one");
  (*server)->SetBand("band-two", 6, 9, true);
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
  EXPECT_EQ(e["band"]["version"], 2);
  (*server)->Finish(R"({"triangles_final": 18})", "");
  const auto end = nlohmann::json::parse(http.Get("/state.json?token=s3cret")->body);
  EXPECT_TRUE(end["finished"].get<bool>());
  EXPECT_EQ(end["metrics"]["triangles_final"], 18);
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

}  // namespace
}  // namespace tandem::viewer
