// The HTTP policy both of tandem's small HTTP servers share: tandem-server's Prometheus
// endpoint (--metrics-listen) and the browser viewer (viewer/view_server.cc). Both are
// cpp-httplib servers that only ever answer GET; GuardedHttpServer is a cpp-httplib server
// with the doors they do not need closed:
//   * Methods: GET and HEAD; anything else gets 405 before its body is read.
//   * Bodies: a request that announces one (Content-Length other than 0, or any
//     Transfer-Encoding) gets 413 before a byte of it is read, and the connection closes.
//   * Ranges: one range at most; several get 416 (cpp-httplib would build the whole
//     multipart answer in memory: 1,000 ranges of a 1 MiB file are 1 GiB).
//   * Host: the Host header must name this server (HostAllowed below), against DNS
//     rebinding (a page on attacker.example whose name turns into 127.0.0.1 would
//     otherwise read the viewer from the user's browser); others get 403 and no data.
//   * Slow and idle connections hold no thread: one thread (the reactor) waits on every
//     connection and hands a request to the workers only once its line and headers are all
//     in. A request must arrive whole within request_timeout of its first byte (else 408
//     and closed); a connection with no request under way closes after idle_timeout; past
//     max_connections the one waiting longest is closed for the newcomer. So a slowloris
//     client, or many idle ones, cannot keep a scrape waiting.
//   * Compression: gzip when the client takes it, never Brotli (OfferNoBrotli below).
// The application adds its own check after these with set_gate (the viewer's token).
#ifndef TANDEM_NET_HTTP_GUARD_H_
#define TANDEM_NET_HTTP_GUARD_H_

#include <httplib.h>

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace tandem::net {

struct HttpLimits {
  int workers = 4;                  // threads answering complete requests
  int max_connections = 256;        // open connections; past it the one waiting longest goes
  int max_header_bytes = 16 << 10;  // request line and headers together (else 431)
  int max_requests_per_connection = 100;
  absl::Duration request_timeout = absl::Seconds(5);  // first byte to last header
  absl::Duration idle_timeout = absl::Seconds(5);     // between requests
  absl::Duration write_timeout = absl::Seconds(10);   // for each write to make progress
};

// Leaves Brotli out of what `req` accepts (gzip stays, if it was there): cpp-httplib
// compresses at Brotli's slowest quality, seconds for three.js on every fresh page load,
// where gzip takes a tenth of a second (docs/decisions.md, "The viewer's files go gzip").
void OfferNoBrotli(httplib::Request& req);

// Whether a request's Host header (`host_header`, "name[:port]" or "[v6][:port]") names a
// server bound to `bound_host` (the HOST of its HOST:PORT). The port is not compared (a
// tunnel or port-forward changes it). Always accepted: no Host at all (no browser omits it,
// so such a request cannot come from a rebinding page), "localhost" and loopback IPs. When
// bound to a loopback address, nothing else. Otherwise also: any IP literal (a browser sends
// one only when the user typed that address, which no rebinding page can make its own),
// the bound name itself, and this machine's host name (gethostname, whole or its first
// label).
bool HostAllowed(std::string_view host_header, std::string_view bound_host);

// True for "localhost", 127.0.0.0/8 and ::1 (what HostAllowed treats as loopback).
bool IsLoopbackHost(std::string_view host);

class GuardedHttpServer : public httplib::Server {
 public:
  // The application's own admission check, after the shared ones: false refuses the
  // request, with `res` saying why.
  using Gate = std::function<bool(const httplib::Request& req, httplib::Response& res)>;

  explicit GuardedHttpServer(HttpLimits limits = {});
  ~GuardedHttpServer() override;  // Stop()

  void set_gate(Gate gate) { gate_ = std::move(gate); }
  // Binds host:port (port 0 = any free one) without SO_REUSEPORT, so that a port another
  // process listens on is refused rather than shared, then serves on threads of its own.
  // Returns the port; the error names the address and why.
  absl::StatusOr<int> Start(const std::string& host, int port);
  // Stops listening, closes every connection and joins the threads. A handler still
  // running (an event stream) must return by itself: cpp-httplib's is_shutting_down
  // turns true.
  void Stop();

 private:
  struct Conn;
  class ConnStream;

  // cpp-httplib calls this for every accepted socket (on the accept thread, through an
  // inline task queue): the socket goes to the reactor. (A private virtual of cpp-httplib
  // 0.11, Debian 12's, as process_request is its protected parser: re-check on an upgrade.)
  bool process_and_close_socket(socket_t sock) override;
  // The checks above; true = go on to the routes. Fills `res` otherwise.
  bool Admit(const httplib::Request& req, httplib::Response& res);
  void ReactorLoop();
  void WorkerLoop();
  // One request on `c` (whose headers are all in). True when the connection may take
  // another one.
  bool Serve(Conn& c);
  void ToReactor(std::unique_ptr<Conn> c);
  void ToWorkers(std::unique_ptr<Conn> c);
  void Wake();

  const HttpLimits limits_;
  std::string bound_host_;
  Gate gate_;
  std::thread listener_, reactor_;
  std::vector<std::thread> workers_;
  int wake_fd_ = -1;
  bool started_ = false, stopped_ = false;
  std::atomic<bool> stopping_{false};
  std::atomic<int64_t> open_{0};  // connections, in every state
  std::atomic<uint64_t> next_order_{0};

  std::mutex mu_;
  std::condition_variable ready_cv_;
  std::deque<std::unique_ptr<Conn>> incoming_;  // new or returning connections, for the reactor
  std::deque<std::unique_ptr<Conn>> ready_;     // complete requests, for the workers
};

}  // namespace tandem::net

#endif  // TANDEM_NET_HTTP_GUARD_H_
