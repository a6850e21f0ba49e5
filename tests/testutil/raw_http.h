// HTTP over a plain socket, for tests that need what an HTTP library will not do: a body
// announced and never sent, a request trickled byte by byte, a connection left idle, a
// thousand ranges, a forged Host header. 127.0.0.1 only; every wait is bounded.
#ifndef TANDEM_TESTS_TESTUTIL_RAW_HTTP_H_
#define TANDEM_TESTS_TESTUTIL_RAW_HTTP_H_

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <string_view>

namespace tandem::testing {

struct RawResponse {
  int status = -1;                             // -1: no status line came
  std::map<std::string, std::string> headers;  // names in lower case
  std::string body;
};

class RawHttp {
 public:
  // Connects to 127.0.0.1:port; nullptr on failure.
  static std::unique_ptr<RawHttp> Connect(int port);
  ~RawHttp();
  RawHttp(const RawHttp&) = delete;
  RawHttp& operator=(const RawHttp&) = delete;

  // Sends all of `bytes` within timeout_s; false once the peer closed or reset the
  // connection (or the time is up).
  bool Send(std::string_view bytes, double timeout_s = 5);
  // Sends up to `total` filler bytes while the peer takes them, for at most timeout_s;
  // returns how many it took.
  int64_t SendFiller(int64_t total, double timeout_s);
  // The status line and headers of the next response (body left unread), within timeout_s.
  RawResponse ReadHead(double timeout_s);
  // A whole response: ReadHead, then the body by its Content-Length (else up to the close).
  RawResponse ReadResponse(double timeout_s);
  // True when the peer closes the connection (end of stream or reset) within timeout_s;
  // what it sent meanwhile is dropped.
  bool WaitClosed(double timeout_s);

 private:
  explicit RawHttp(int fd) : fd_(fd) {}
  // Reads what is there (waiting up to timeout_s); false at the end of the stream.
  bool Fill(double timeout_s);
  int fd_;
  std::string in_;
  bool eof_ = false;
};

// One request on a connection of its own.
RawResponse RawRequest(int port, const std::string& request, double timeout_s = 5);

// A socket of this process listening on 127.0.0.1 at any free port, for tests that hold a
// port: its descriptor (the caller closes it), or -1; the port in *port.
int ListenOnLoopback(int* port);

// "GET PATH HTTP/1.1" with Host 127.0.0.1:PORT (unless `extra_headers` has its own Host)
// and `extra_headers` (each "Name: value\r\n").
std::string GetRequest(int port, const std::string& path, const std::string& extra_headers = "");

}  // namespace tandem::testing

#endif  // TANDEM_TESTS_TESTUTIL_RAW_HTTP_H_
