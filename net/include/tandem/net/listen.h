// Why an address cannot be listened on, for the error messages of tandem's servers (gRPC's
// --listen, the metrics endpoint, the viewer), found by trying it with a plain socket.
#ifndef TANDEM_NET_LISTEN_H_
#define TANDEM_NET_LISTEN_H_

#include <string>

namespace tandem::net {

// The errno of binding and listening on HOST:PORT (SO_REUSEADDR, as the servers do) with
// sockets closed at once: 0 when it can be had now, EADDRINUSE when another socket listens
// on one of HOST's addresses, EADDRNOTAVAIL when none is this machine's, -1 when HOST does
// not resolve.
int ListenError(const std::string& host, int port);

// The same in words: "port 8080 is in use by another process", "10.9.9.9 is not an address
// of this machine", ...
std::string DescribeBindFailure(const std::string& host, int port);

}  // namespace tandem::net

#endif  // TANDEM_NET_LISTEN_H_
