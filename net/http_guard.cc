#include "tandem/net/http_guard.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "tandem/net/listen.h"

namespace tandem::net {
namespace {

// Set by Admit when it refused a request whose body is still unread: the connection must
// close after the answer (the body would be read as the next request).
thread_local bool t_close_after = false;

// What a refused request's peer may still send after the answer is read and dropped, up to
// these, so that it gets the answer rather than a reset.
constexpr int64_t kMaxDiscardBytes = 1 << 20;
constexpr absl::Duration kLinger = absl::Seconds(1);

// cpp-httplib hands each accepted socket to its task queue; ours passes it on at once.
class InlineQueue final : public httplib::TaskQueue {
 public:
  void enqueue(std::function<void()> fn) override { fn(); }
  void shutdown() override {}
};

absl::string_view View(std::string_view s) { return absl::string_view(s.data(), s.size()); }

// The host of a Host header value ("name:port", "[v6]:port", either without a port), lower
// case, without a trailing dot; "" when malformed.
std::string HostPart(std::string_view value) {
  std::string v(absl::StripAsciiWhitespace(View(value)));
  if (!v.empty() && v[0] == '[') {
    const size_t end = v.find(']');
    if (end == std::string::npos) return "";
    v = v.substr(1, end - 1);
  } else if (const size_t colon = v.find(':');
             colon != std::string::npos && v.find(':', colon + 1) == std::string::npos) {
    v = v.substr(0, colon);
  }
  while (!v.empty() && v.back() == '.') v.pop_back();
  return absl::AsciiStrToLower(v);
}

bool IsIpLiteral(const std::string& host) {
  in_addr v4;
  in6_addr v6;
  return inet_pton(AF_INET, host.c_str(), &v4) == 1 || inet_pton(AF_INET6, host.c_str(), &v6) == 1;
}

std::string HostPort(const std::string& host, int port) {
  return absl::StrCat(absl::StrContains(host, ':') ? absl::StrCat("[", host, "]") : host, ":",
                      port);
}

// Best effort, never blocking: a one-line answer to a connection about to close.
void SendStatusLine(int fd, int status, const char* reason) {
  const std::string answer = absl::StrFormat(
      "HTTP/1.1 %d %s\r\nContent-Length: 0\r\nConnection: close\r\n\r\n", status, reason);
  (void)!send(fd, answer.data(), answer.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
}

// The end of the headers ("\r\n\r\n") in `in`, searched from `from` on.
bool HasHeaderEnd(const std::string& in, size_t from = 0) {
  return in.find("\r\n\r\n", from >= 3 ? from - 3 : 0) != std::string::npos;
}

void Address(int fd, bool peer, std::string& ip, int& port) {
  sockaddr_storage addr{};
  socklen_t len = sizeof(addr);
  const int rc = peer ? getpeername(fd, reinterpret_cast<sockaddr*>(&addr), &len)
                      : getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  if (rc != 0) return;
  char text[INET6_ADDRSTRLEN] = "";
  if (addr.ss_family == AF_INET) {
    const auto* a = reinterpret_cast<const sockaddr_in*>(&addr);
    inet_ntop(AF_INET, &a->sin_addr, text, sizeof(text));
    port = ntohs(a->sin_port);
  } else if (addr.ss_family == AF_INET6) {
    const auto* a = reinterpret_cast<const sockaddr_in6*>(&addr);
    inet_ntop(AF_INET6, &a->sin6_addr, text, sizeof(text));
    port = ntohs(a->sin6_port);
  }
  ip = text;
}

// Waits until `fd` is ready for `events`, at most until `deadline`.
bool WaitFor(int fd, short events, absl::Time deadline) {
  pollfd p{fd, events, 0};
  while (true) {
    const int64_t ms = absl::ToInt64Milliseconds(deadline - absl::Now()) + 1;
    if (ms <= 0) return false;
    const int rc = poll(&p, 1, static_cast<int>(std::min<int64_t>(ms, 60000)));
    if (rc > 0) return true;
    if (rc < 0 && errno != EINTR) return false;
  }
}

}  // namespace

bool IsLoopbackHost(std::string_view host) {
  const std::string h = HostPart(host);
  if (h == "localhost") return true;
  in_addr v4;
  if (inet_pton(AF_INET, h.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  in6_addr v6;
  if (inet_pton(AF_INET6, h.c_str(), &v6) == 1) {
    if (IN6_IS_ADDR_LOOPBACK(&v6)) return true;
    return IN6_IS_ADDR_V4MAPPED(&v6) && v6.s6_addr[12] == 127;
  }
  return false;
}

bool HostAllowed(std::string_view host_header, std::string_view bound_host) {
  if (absl::StripAsciiWhitespace(View(host_header)).empty()) return true;
  const std::string host = HostPart(host_header);
  if (host.empty()) return false;
  if (IsLoopbackHost(host)) return true;
  const std::string bound = HostPart(bound_host);
  if (IsLoopbackHost(bound)) return false;
  if (IsIpLiteral(host) || host == bound) return true;
  char name[256] = "";
  if (gethostname(name, sizeof(name) - 1) != 0 || name[0] == '\0') return false;
  const std::string self = absl::AsciiStrToLower(name);
  return host == self || host == self.substr(0, self.find('.'));
}

// One connection: its socket (closed with it) and what was received and not yet parsed.
struct GuardedHttpServer::Conn {
  Conn(int f, std::atomic<int64_t>* count) : fd(f), open(count) { open->fetch_add(1); }
  ~Conn() {
    close(fd);
    open->fetch_sub(1);
  }
  Conn(const Conn&) = delete;
  Conn& operator=(const Conn&) = delete;

  const int fd;
  std::atomic<int64_t>* const open;
  std::string in;
  absl::Time deadline;
  bool request_started = false;  // bytes of the next request are in
  bool closing = false;          // answered and shut down: what still comes is dropped
  int64_t discarded = 0;
  int served = 0;
  uint64_t order = 0;  // when it was last handed to the reactor
};

// What cpp-httplib reads a request from and writes its answer to: the bytes the reactor
// received first, then the socket, every wait bounded.
class GuardedHttpServer::ConnStream final : public httplib::Stream {
 public:
  ConnStream(Conn& c, absl::Duration write_timeout) : c_(c), write_timeout_(write_timeout) {}
  // Drops what was read from the received bytes; the rest is the next request.
  void Consume() {
    c_.in.erase(0, pos_);
    pos_ = 0;
  }

  bool is_readable() const override {
    return pos_ < c_.in.size() || WaitFor(c_.fd, POLLIN, c_.deadline);
  }
  // Also false once the peer has closed its side: an event stream (which the peer never
  // writes to) notices a page that left.
  bool is_writable() const override {
    pollfd p{c_.fd, POLLOUT | POLLRDHUP, 0};
    const int ms = static_cast<int>(absl::ToInt64Milliseconds(write_timeout_));
    int rc;
    while ((rc = poll(&p, 1, ms)) < 0 && errno == EINTR) {
    }
    return rc > 0 && (p.revents & (POLLRDHUP | POLLHUP | POLLERR)) == 0 &&
           (p.revents & POLLOUT) != 0;
  }
  ssize_t read(char* ptr, size_t size) override {
    if (pos_ < c_.in.size()) {
      const size_t n = std::min(size, c_.in.size() - pos_);
      std::memcpy(ptr, c_.in.data() + pos_, n);
      pos_ += n;
      return static_cast<ssize_t>(n);
    }
    while (WaitFor(c_.fd, POLLIN, c_.deadline)) {
      const ssize_t n = recv(c_.fd, ptr, size, 0);
      if (n >= 0) return n;
      if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) return -1;
    }
    return -1;
  }
  ssize_t write(const char* ptr, size_t size) override {
    while (WaitFor(c_.fd, POLLOUT, absl::Now() + write_timeout_)) {
      const ssize_t n = send(c_.fd, ptr, size, MSG_NOSIGNAL);
      if (n >= 0) return n;
      if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) return -1;
    }
    return -1;
  }
  void get_remote_ip_and_port(std::string& ip, int& port) const override {
    Address(c_.fd, true, ip, port);
  }
  void get_local_ip_and_port(std::string& ip, int& port) const override {
    Address(c_.fd, false, ip, port);
  }
  socket_t socket() const override { return c_.fd; }

 private:
  Conn& c_;
  const absl::Duration write_timeout_;
  size_t pos_ = 0;
};

GuardedHttpServer::GuardedHttpServer(HttpLimits limits) : limits_(limits) {
  new_task_queue = [] { return new InlineQueue; };
  // SO_REUSEADDR only (cpp-httplib's default adds SO_REUSEPORT, which lets a second server
  // share a port another one listens on).
  set_socket_options([](socket_t sock) {
    const int yes = 1;
    setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
  });
  set_keep_alive_max_count(static_cast<size_t>(limits_.max_requests_per_connection));
  set_keep_alive_timeout(std::max<time_t>(1, absl::ToInt64Seconds(limits_.idle_timeout)));
  set_payload_max_length(0);
  set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    // The request is the server's own, not const (cpp-httplib passes it so to handlers).
    OfferNoBrotli(const_cast<httplib::Request&>(req));
    return Admit(req, res) ? HandlerResponse::Unhandled : HandlerResponse::Handled;
  });
  // Before "100 Continue" is sent: a request refused anyway is answered without its body.
  set_expect_100_continue_handler([this](const httplib::Request& req, httplib::Response& res) {
    return Admit(req, res) ? 100 : res.status;
  });
}

GuardedHttpServer::~GuardedHttpServer() { Stop(); }

void OfferNoBrotli(httplib::Request& req) {
  std::string offered;  // every Accept-Encoding header, lower case
  auto [begin, end] = req.headers.equal_range("Accept-Encoding");
  for (auto it = begin; it != end; ++it)
    absl::StrAppend(&offered, absl::AsciiStrToLower(it->second), ",");
  if (!absl::StrContains(offered, "br")) return;
  req.headers.erase("Accept-Encoding");
  if (absl::StrContains(offered, "gzip")) req.headers.emplace("Accept-Encoding", "gzip");
}

bool GuardedHttpServer::Admit(const httplib::Request& req, httplib::Response& res) {
  auto refuse = [&](int status, const char* text, bool close) {
    res.status = status;
    // (with a Range header, cpp-httplib would cut the text by it)
    if (req.ranges.empty()) res.set_content(text, "text/plain; charset=utf-8");
    if (close) t_close_after = true;
    return false;
  };
  if (!HostAllowed(req.get_header_value("Host"), bound_host_)) {
    return refuse(403, "the Host header does not name this server\n", false);
  }
  if (req.method != "GET" && req.method != "HEAD") {
    res.set_header("Allow", "GET, HEAD");
    return refuse(405, "only GET and HEAD are served here\n", true);
  }
  const std::string length = req.get_header_value("Content-Length");
  if (req.has_header("Transfer-Encoding") || (!length.empty() && length != "0")) {
    return refuse(413, "requests here have no body\n", true);
  }
  if (req.ranges.size() > 1) return refuse(416, "", false);
  return !gate_ || gate_(req, res);
}

absl::StatusOr<int> GuardedHttpServer::Start(const std::string& host, int port) {
  bound_host_ = host;
  const int bound = port == 0 ? bind_to_any_port(host) : (bind_to_port(host, port) ? port : -1);
  if (bound <= 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", HostPort(host, port), ": ",
                                               DescribeBindFailure(host, port)));
  }
  wake_fd_ = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  started_ = true;
  reactor_ = std::thread([this] { ReactorLoop(); });
  for (int i = 0; i < std::max(1, limits_.workers); ++i) {
    workers_.emplace_back([this] { WorkerLoop(); });
  }
  listener_ = std::thread([this] { listen_after_bind(); });
  return bound;
}

void GuardedHttpServer::Stop() {
  if (!started_ || stopped_) return;
  stopped_ = true;
  // What httplib::Server::stop does, also before its loop has marked itself running.
  if (const socket_t sock = svr_sock_.exchange(INVALID_SOCKET); sock != INVALID_SOCKET) {
    shutdown(sock, SHUT_RDWR);
    close(sock);
  }
  listener_.join();
  {
    std::lock_guard<std::mutex> lock(mu_);
    stopping_ = true;
  }
  Wake();
  ready_cv_.notify_all();
  reactor_.join();
  for (std::thread& w : workers_) w.join();
  std::lock_guard<std::mutex> lock(mu_);
  incoming_.clear();
  ready_.clear();
  close(wake_fd_);
}

bool GuardedHttpServer::process_and_close_socket(socket_t sock) {
  fcntl(sock, F_SETFL, fcntl(sock, F_GETFL) | O_NONBLOCK);
  fcntl(sock, F_SETFD, FD_CLOEXEC);
  auto c = std::make_unique<Conn>(sock, &open_);
  c->deadline = absl::Now() + limits_.idle_timeout;
  ToReactor(std::move(c));
  return true;
}

void GuardedHttpServer::Wake() {
  const uint64_t one = 1;
  (void)!::write(wake_fd_, &one, sizeof(one));
}

void GuardedHttpServer::ToReactor(std::unique_ptr<Conn> c) {
  c->order = next_order_.fetch_add(1);
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_) return;  // (closes it)
    incoming_.push_back(std::move(c));
  }
  Wake();
}

void GuardedHttpServer::ToWorkers(std::unique_ptr<Conn> c) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_) return;
    ready_.push_back(std::move(c));
  }
  ready_cv_.notify_one();
}

void GuardedHttpServer::ReactorLoop() {
  std::vector<std::unique_ptr<Conn>> parked;  // waiting for a request (or to close)
  std::vector<pollfd> fds;
  std::string scratch(16 << 10, '\0');
  const size_t max_header = static_cast<size_t>(limits_.max_header_bytes);
  auto linger = [&](Conn& c) {
    shutdown(c.fd, SHUT_WR);
    c.closing = true;
    c.deadline = absl::Now() + kLinger;
  };
  while (true) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (stopping_) break;
      for (auto& c : incoming_) parked.push_back(std::move(c));
      incoming_.clear();
    }
    // Over the cap: the connections waiting longest give way (closing ones first).
    while (open_.load() > limits_.max_connections) {
      auto victim =
          std::min_element(parked.begin(), parked.end(), [](const auto& a, const auto& b) {
            return std::make_pair(!a->closing, a->order) < std::make_pair(!b->closing, b->order);
          });
      if (victim == parked.end()) break;
      parked.erase(victim);
    }
    const absl::Time now = absl::Now();
    for (auto& c : parked) {
      if (now < c->deadline) continue;
      if (c->request_started && !c->closing) SendStatusLine(c->fd, 408, "Request Timeout");
      c.reset();
    }
    std::erase(parked, nullptr);
    fds.assign(1, pollfd{wake_fd_, POLLIN, 0});
    absl::Time next = absl::InfiniteFuture();
    for (const auto& c : parked) {
      fds.push_back(pollfd{c->fd, POLLIN, 0});
      next = std::min(next, c->deadline);
    }
    const int timeout_ms = next == absl::InfiniteFuture()
                               ? -1
                               : static_cast<int>(std::clamp<int64_t>(
                                     absl::ToInt64Milliseconds(next - absl::Now()) + 1, 0, 60000));
    if (poll(fds.data(), fds.size(), timeout_ms) < 0 && errno != EINTR) break;
    if (fds[0].revents != 0) {
      uint64_t drained;
      (void)!::read(wake_fd_, &drained, sizeof(drained));
    }
    for (size_t i = 1; i < fds.size(); ++i) {
      if (fds[i].revents == 0) continue;
      std::unique_ptr<Conn>& slot = parked[i - 1];
      Conn& c = *slot;
      bool eof = false;
      const size_t before = c.in.size();
      while (!eof && (c.closing || c.in.size() < max_header)) {
        const size_t want =
            c.closing ? scratch.size() : std::min(scratch.size(), max_header - c.in.size());
        const ssize_t n = recv(c.fd, scratch.data(), want, 0);
        if (n > 0) {
          if (c.closing) {
            c.discarded += n;
            eof = c.discarded >= kMaxDiscardBytes;
          } else {
            c.in.append(scratch.data(), static_cast<size_t>(n));
          }
        } else if (n < 0 && errno == EINTR) {
          continue;
        } else {
          eof = n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK);
          break;
        }
      }
      if (c.closing) {
        if (eof) slot.reset();
        continue;
      }
      if (!c.request_started && !c.in.empty()) {
        c.request_started = true;
        c.deadline = absl::Now() + limits_.request_timeout;
      }
      if (HasHeaderEnd(c.in, before)) {
        ToWorkers(std::move(slot));  // (answered even after the peer's half-close)
      } else if (eof) {
        slot.reset();
      } else if (c.in.size() >= max_header) {
        SendStatusLine(c.fd, 431, "Request Header Fields Too Large");
        linger(c);
      }
    }
    std::erase(parked, nullptr);
  }
}

void GuardedHttpServer::WorkerLoop() {
  while (true) {
    std::unique_ptr<Conn> c;
    {
      std::unique_lock<std::mutex> lock(mu_);
      ready_cv_.wait(lock, [this] { return stopping_.load() || !ready_.empty(); });
      if (stopping_) return;
      c = std::move(ready_.front());
      ready_.pop_front();
    }
    if (Serve(*c)) {
      c->request_started = !c->in.empty();
      c->deadline =
          absl::Now() + (c->request_started ? limits_.request_timeout : limits_.idle_timeout);
      if (HasHeaderEnd(c->in)) {
        ToWorkers(std::move(c));
      } else {
        ToReactor(std::move(c));
      }
    } else if (t_close_after && !stopping_) {
      // The unread body may still be arriving: closing now would reset the connection,
      // and with it the answer the peer has not read yet.
      shutdown(c->fd, SHUT_WR);
      c->closing = true;
      c->deadline = absl::Now() + kLinger;
      ToReactor(std::move(c));
    }
  }
}

bool GuardedHttpServer::Serve(Conn& c) {
  ConnStream stream(c, limits_.write_timeout);
  t_close_after = false;
  bool closed = false;
  const bool last = ++c.served >= limits_.max_requests_per_connection;
  const bool ok = process_request(stream, last, closed, nullptr);
  stream.Consume();
  return ok && !closed && !last && !t_close_after && !stopping_;
}

}  // namespace tandem::net
