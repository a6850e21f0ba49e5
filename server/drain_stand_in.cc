#include "tandem/server/drain_stand_in.h"

#include <grpcpp/generic/async_generic_service.h>

#include <cerrno>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "tandem/net/listen.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::server {

using grpc::health::v1::HealthCheckRequest;
using grpc::health::v1::HealthCheckResponse;

// Readiness ("" and tandem.v1.Tandem) NOT_SERVING, "liveness" SERVING, as the real server's
// health service says from the first signal on.
class DrainStandIn::Health final : public grpc::health::v1::Health::CallbackService {
  grpc::ServerUnaryReactor* Check(grpc::CallbackServerContext* context,
                                  const HealthCheckRequest* request,
                                  HealthCheckResponse* response) override {
    grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
    const std::string& service = request->service();
    if (service == "liveness") {
      response->set_status(HealthCheckResponse::SERVING);
    } else if (service.empty() || service == v1::Tandem::service_full_name()) {
      response->set_status(HealthCheckResponse::NOT_SERVING);
    } else {
      reactor->Finish(grpc::Status(grpc::StatusCode::NOT_FOUND, "unknown service"));
      return reactor;
    }
    reactor->Finish(grpc::Status::OK);
    return reactor;
  }
};

// Every call but the health check.
class DrainStandIn::Refuse final : public grpc::CallbackGenericService {
  grpc::ServerGenericBidiReactor* CreateReactor(grpc::GenericCallbackServerContext*) override {
    class Refused final : public grpc::ServerGenericBidiReactor {
     public:
      Refused() {
        Finish(grpc::Status(grpc::StatusCode::UNAVAILABLE,
                            "tandem-server is shutting down and takes no new calls; send the "
                            "scan to another replica"));
      }
      void OnDone() override { delete this; }
    };
    return new Refused;
  }
};

DrainStandIn::DrainStandIn()
    : health_(std::make_unique<Health>()), refuse_(std::make_unique<Refuse>()) {}

DrainStandIn::~DrainStandIn() {
  if (server_) server_->Shutdown(std::chrono::system_clock::now());
}

std::unique_ptr<DrainStandIn> DrainStandIn::Start(
    const std::string& host, int port, std::shared_ptr<grpc::ServerCredentials> credentials,
    absl::Duration patience) {
  grpc::EnableDefaultHealthCheckService(false);
  std::string bare = host;
  if (bare.size() >= 2 && bare.front() == '[' && bare.back() == ']') {
    bare = bare.substr(1, bare.size() - 2);
  }
  const absl::Time give_up = absl::Now() + patience;
  do {
    // gRPC closes its listening socket on a thread of its own: wait for that rather than
    // have gRPC log a failed bind.
    if (net::ListenError(bare, port) == EADDRINUSE) {
      absl::SleepFor(absl::Milliseconds(5));
      continue;
    }
    // (services are bound to the first server they were registered with, even a failed one)
    std::unique_ptr<DrainStandIn> stand_in(new DrainStandIn());
    grpc::ServerBuilder builder;
    int bound = 0;
    builder.AddListeningPort(absl::StrCat(host, ":", port), credentials, &bound);
    builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
    builder.RegisterService(stand_in->health_.get());
    builder.RegisterCallbackGenericService(stand_in->refuse_.get());
    stand_in->server_ = builder.BuildAndStart();
    if (stand_in->server_ != nullptr && bound > 0) return stand_in;
  } while (absl::Now() < give_up);
  return nullptr;
}

}  // namespace tandem::server
