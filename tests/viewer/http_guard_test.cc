// tandem/net/http_guard.h's rules on their own: which Host headers name a server bound where, and
// what a failed bind is reported as (with real sockets on 127.0.0.1).
#include "tandem/net/http_guard.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <string>
#include <vector>

#include "tandem/net/listen.h"
#include "testutil/raw_http.h"

namespace tandem::net {
namespace {

TEST(HttpGuard, HostRuleBoundToLoopback) {
  for (const char* bound : {"127.0.0.1", "localhost", "::1"}) {
    SCOPED_TRACE(bound);
    for (const char* ok : {"127.0.0.1:8080", "localhost", "LOCALHOST:1", "localhost.", "[::1]:80",
                           "127.9.9.9", "", "  "}) {
      EXPECT_TRUE(HostAllowed(ok, bound)) << ok;
    }
    for (const char* bad : {"evil.example", "evil.example:8080", "192.168.1.5", "[fe80::1]",
                            "localhost.evil.example", "127.0.0.1.nip.io", "[::1", "0.0.0.0"}) {
      EXPECT_FALSE(HostAllowed(bad, bound)) << bad;
    }
  }
}

TEST(HttpGuard, HostRuleBoundElsewhere) {
  char self[256] = "";
  ASSERT_EQ(gethostname(self, sizeof(self) - 1), 0);
  const std::string host(self);
  for (const char* bound : {"0.0.0.0", "::", "", "192.168.1.5", "scanner-pc.lab.example"}) {
    SCOPED_TRACE(bound);
    for (const std::string& ok :
         std::vector<std::string>{"localhost:8080", "127.0.0.1", "192.168.1.5:8080", "10.0.0.7",
                                  "[fe80::1]:9090", host, host + ":9090"}) {
      EXPECT_TRUE(HostAllowed(ok, bound)) << ok;
    }
    for (const char* bad : {"evil.example", "evil.example:9090", "localhost.evil.example"}) {
      EXPECT_FALSE(HostAllowed(bad, bound)) << bad;
    }
  }
  EXPECT_TRUE(HostAllowed("Scanner-PC.lab.example:8080", "scanner-pc.lab.example"));
  EXPECT_FALSE(HostAllowed("scanner-pc.lab.example", "0.0.0.0"));
}

TEST(HttpGuard, ABindFailureSaysWhy) {
  int port = 0;
  const int fd = testing::ListenOnLoopback(&port);
  ASSERT_GE(fd, 0);
  EXPECT_EQ(DescribeBindFailure("127.0.0.1", port),
            "port " + std::to_string(port) + " is in use by another process");
  GuardedHttpServer server;
  auto started = server.Start("127.0.0.1", port);
  ASSERT_FALSE(started.ok());
  EXPECT_EQ(started.status().message(), "cannot listen on 127.0.0.1:" + std::to_string(port) +
                                            ": port " + std::to_string(port) +
                                            " is in use by another process");
  close(fd);
  EXPECT_EQ(DescribeBindFailure("192.0.2.1", 0), "192.0.2.1 is not an address of this machine");
  EXPECT_NE(DescribeBindFailure("no-such-host.invalid", 0).find("is not a known address"),
            std::string::npos);
}

}  // namespace
}  // namespace tandem::net
