// tandem-server's shutdown after SIGTERM or SIGINT: NOT_SERVING, the drain delay, a stand-in
// answering health checks, the grace period for running streams, then UNAVAILABLE for the rest.
#ifndef TANDEM_APPS_TANDEM_SERVER_DRAIN_H_
#define TANDEM_APPS_TANDEM_SERVER_DRAIN_H_

#include <grpcpp/grpcpp.h>
#include <signal.h>

#include <memory>
#include <string>

#include "tandem/server/drain_stand_in.h"
#include "tandem/server/tandem_service.h"

namespace tandem::server_app {

struct DrainOptions {
  double delay_seconds = 0;   // --drain-delay-seconds
  double grace_seconds = 10;  // --grace-seconds
  std::string host;           // where the server listens, for the stand-in
  int port = 0;
  std::shared_ptr<grpc::ServerCredentials> credentials;
};

// Drains `server` after the signal `name` ("SIGTERM") came: marks it NOT_SERVING (health
// service "" and tandem.v1.Tandem; "liveness" stays SERVING), keeps accepting streams for the
// delay (another of `signals`, which every thread blocks, cuts it short), then shuts it down:
// *stand_in answers health checks on the port until the exit, running streams get the grace
// period, the rest end with UNAVAILABLE, and the connections left are cut. Returns once the
// server's Shutdown has.
void Drain(const char* name, const sigset_t& signals, grpc::Server& server,
           tandem::server::TandemService& service, const DrainOptions& options,
           std::unique_ptr<tandem::server::DrainStandIn>* stand_in);

}  // namespace tandem::server_app

#endif  // TANDEM_APPS_TANDEM_SERVER_DRAIN_H_
