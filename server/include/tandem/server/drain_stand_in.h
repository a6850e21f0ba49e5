// What answers on tandem-server's port while it drains, once gRPC has stopped listening.
// grpc::Server::Shutdown closes the listening socket at once (and tells connected clients,
// with GOAWAY, to take new calls elsewhere), so health checks would fail with "connection
// refused" for the whole grace period, whereas a load balancer or an orchestrator should
// read NOT_SERVING there, and "liveness" SERVING (the process is busy finishing streams,
// not stuck). The stand-in is a second, tiny gRPC server on the same address: the health
// service says exactly that, every other call gets UNAVAILABLE (a client retries elsewhere).
// It can bind the port only once gRPC has closed it: a check in that moment is refused, which
// a probe's failure threshold absorbs (SO_REUSEPORT would close the gap and let any process
// of the same user share the port).
#ifndef TANDEM_SERVER_DRAIN_STAND_IN_H_
#define TANDEM_SERVER_DRAIN_STAND_IN_H_

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>

#include "absl/time/time.h"

namespace tandem::server {

class DrainStandIn {
 public:
  // Listens on HOST:PORT (`host` as --listen wrote it, brackets and all; the port the real
  // server had) once the real server's listening socket is gone, waiting up to `patience`
  // for that. Disables gRPC's default health service for servers built from now on (the
  // stand-in has its own). nullptr when the port could not be had (another process took it).
  static std::unique_ptr<DrainStandIn> Start(const std::string& host, int port,
                                             std::shared_ptr<grpc::ServerCredentials> credentials,
                                             absl::Duration patience);
  ~DrainStandIn();

 private:
  class Health;
  class Refuse;
  DrainStandIn();
  std::unique_ptr<Health> health_;
  std::unique_ptr<Refuse> refuse_;
  std::unique_ptr<grpc::Server> server_;
};

}  // namespace tandem::server

#endif  // TANDEM_SERVER_DRAIN_STAND_IN_H_
