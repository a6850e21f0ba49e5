#include "tandem/net/listen.h"

#include <netdb.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "absl/strings/str_cat.h"

namespace tandem::net {

int ListenError(const std::string& host, int port) {
  addrinfo hints{};
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE;
  addrinfo* found = nullptr;
  const std::string service = std::to_string(port);
  if (getaddrinfo(host.empty() ? nullptr : host.c_str(), service.c_str(), &hints, &found) != 0) {
    return -1;
  }
  // One address in use is enough (a server listening on the others would split the
  // clients); other failures count only when no address can be had (no IPv6, say).
  int in_use = 0, first = 0;
  bool any = false;
  for (addrinfo* a = found; a != nullptr && in_use == 0; a = a->ai_next) {
    const int fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    const int yes = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
    // listen too: a bound, not listening socket lets bind through with SO_REUSEADDR.
    if (bind(fd, a->ai_addr, a->ai_addrlen) != 0 || listen(fd, 1) != 0) {
      if (errno == EADDRINUSE) in_use = errno;
      if (first == 0) first = errno;
    } else {
      any = true;
    }
    close(fd);
  }
  freeaddrinfo(found);
  return in_use != 0 ? in_use : any ? 0 : first;
}

std::string DescribeBindFailure(const std::string& host, int port) {
  switch (const int err = ListenError(host, port)) {
    case -1:
      return absl::StrCat(host, " is not a known address");
    case EADDRINUSE:
      return absl::StrCat("port ", port, " is in use by another process");
    case EADDRNOTAVAIL:
      return absl::StrCat(host, " is not an address of this machine");
    case EACCES:
      return absl::StrCat("port ", port, " needs privileges this process does not have");
    case 0:
      return "the address could not be had, though it is free now (try again)";
    default:
      return std::strerror(err);
  }
}

}  // namespace tandem::net
