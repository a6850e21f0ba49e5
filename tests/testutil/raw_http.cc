#include "testutil/raw_http.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>

namespace tandem::testing {
namespace {

using Clock = std::chrono::steady_clock;

Clock::time_point After(double s) {
  return Clock::now() + std::chrono::microseconds(static_cast<int64_t>(s * 1e6));
}

// Waits for `events` on fd until `deadline`.
bool WaitUntil(int fd, short events, Clock::time_point deadline) {
  while (true) {
    const auto ms =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
    if (ms < 0) return false;
    pollfd p{fd, events, 0};
    const int rc = poll(&p, 1, static_cast<int>(ms));
    if (rc > 0) return true;
    if (rc == 0 || errno != EINTR) return false;
  }
}

}  // namespace

std::unique_ptr<RawHttp> RawHttp::Connect(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return nullptr;
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
    close(fd);
    return nullptr;
  }
  return std::unique_ptr<RawHttp>(new RawHttp(fd));
}

RawHttp::~RawHttp() { close(fd_); }

bool RawHttp::Send(std::string_view bytes, double timeout_s) {
  const auto deadline = After(timeout_s);
  while (!bytes.empty()) {
    if (!WaitUntil(fd_, POLLOUT, deadline)) return false;
    const ssize_t n = send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      return false;
    }
    bytes.remove_prefix(static_cast<size_t>(n));
  }
  return true;
}

int64_t RawHttp::SendFiller(int64_t total, double timeout_s) {
  const std::string block(64 << 10, 'x');
  const auto deadline = After(timeout_s);
  int64_t sent = 0;
  while (sent < total && WaitUntil(fd_, POLLOUT, deadline)) {
    const size_t want = static_cast<size_t>(std::min<int64_t>(total - sent, block.size()));
    const ssize_t n = send(fd_, block.data(), want, MSG_NOSIGNAL | MSG_DONTWAIT);
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      break;
    }
    sent += n;
  }
  return sent;
}

bool RawHttp::Fill(double timeout_s) {
  if (eof_ || !WaitUntil(fd_, POLLIN, After(timeout_s))) return !eof_;
  char buf[16384];
  const ssize_t n = recv(fd_, buf, sizeof(buf), MSG_DONTWAIT);
  if (n > 0) {
    in_.append(buf, static_cast<size_t>(n));
  } else if (n == 0 || (errno != EAGAIN && errno != EINTR)) {
    eof_ = true;
  }
  return !eof_;
}

RawResponse RawHttp::ReadHead(double timeout_s) {
  RawResponse r;
  const auto deadline = After(timeout_s);
  size_t end;
  while ((end = in_.find("\r\n\r\n")) == std::string::npos) {
    const double left = std::chrono::duration<double>(deadline - Clock::now()).count();
    if (left <= 0 || eof_) return r;
    Fill(left);
  }
  const std::string head = in_.substr(0, end);
  in_.erase(0, end + 4);
  size_t line_end = head.find("\r\n");
  const std::string status_line = head.substr(0, line_end);
  if (status_line.rfind("HTTP/1.", 0) == 0 && status_line.size() >= 12) {
    r.status = std::atoi(status_line.c_str() + 9);
  }
  while (line_end != std::string::npos) {
    const size_t next = head.find("\r\n", line_end + 2);
    const std::string line = head.substr(
        line_end + 2, next == std::string::npos ? std::string::npos : next - line_end - 2);
    const size_t colon = line.find(':');
    if (colon != std::string::npos) {
      std::string name = line.substr(0, colon);
      for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      std::string value = line.substr(colon + 1);
      value.erase(0, value.find_first_not_of(' '));
      r.headers[name] = value;
    }
    line_end = next;
  }
  return r;
}

RawResponse RawHttp::ReadResponse(double timeout_s) {
  const auto deadline = After(timeout_s);
  RawResponse r = ReadHead(timeout_s);
  if (r.status < 0) return r;
  const auto length = r.headers.find("content-length");
  const size_t want = length == r.headers.end()
                          ? std::string::npos
                          : std::strtoull(length->second.c_str(), nullptr, 10);
  while (in_.size() < want && !eof_) {
    const double left = std::chrono::duration<double>(deadline - Clock::now()).count();
    if (left <= 0) break;
    Fill(left);
  }
  r.body = in_.substr(0, want);
  in_.erase(0, std::min(want, in_.size()));
  return r;
}

bool RawHttp::WaitClosed(double timeout_s) {
  const auto deadline = After(timeout_s);
  while (!eof_) {
    const double left = std::chrono::duration<double>(deadline - Clock::now()).count();
    if (left <= 0) return false;
    Fill(left);
    in_.clear();
  }
  return true;
}

RawResponse RawRequest(int port, const std::string& request, double timeout_s) {
  std::unique_ptr<RawHttp> c = RawHttp::Connect(port);
  if (c == nullptr || !c->Send(request, timeout_s)) return RawResponse{};
  return c->ReadResponse(timeout_s);
}

int ListenOnLoopback(int* port) {
  const int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof(addr);
  if (bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 || listen(fd, 4) != 0 ||
      getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
    close(fd);
    return -1;
  }
  *port = ntohs(addr.sin_port);
  return fd;
}

std::string GetRequest(int port, const std::string& path, const std::string& extra_headers) {
  const bool own_host =
      extra_headers.rfind("Host:", 0) == 0 || extra_headers.find("\r\nHost:") != std::string::npos;
  return "GET " + path + " HTTP/1.1\r\n" +
         (own_host ? "" : "Host: 127.0.0.1:" + std::to_string(port) + "\r\n") + extra_headers +
         "\r\n";
}

}  // namespace tandem::testing
