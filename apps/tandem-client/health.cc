// tandem-client health: the standard gRPC health service's answer (exit 0 only when SERVING).
#include <memory>
#include <string>

#include "absl/strings/str_format.h"
#include "command.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "tandem/common/wire.h"

namespace tandem::client_app {

int HealthCommand(int argc, char** argv) {
  ConnectionFlags connection;
  std::string service;
  double timeout_s = 5;
  FlagSet flags(
      "usage: tandem-client health [--server HOST:PORT] [flags]\n"
      "Asks grpc.health.v1.Health/Check; prints the status, exits 0 only if SERVING.\n"
      "The health service needs no token, even when the server requires one.");
  connection.Add(flags, /*token=*/false);
  flags.AddString("service", &service, "NAME", "service name to ask about (empty = the server)");
  flags.AddDouble("timeout", &timeout_s, "seconds to wait for the answer");
  if (int rc = ParseOrExit(flags, argc, argv, &connection); rc >= 0) return rc;
  absl::StatusOr<std::shared_ptr<grpc::Channel>> channel =
      tandem::client::MakeChannel(connection.options);
  if (!channel.ok()) return Fail(channel.status());
  auto stub = grpc::health::v1::Health::NewStub(*channel);
  grpc::ClientContext context;
  SetDeadline(&context, timeout_s);
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  grpc::health::v1::HealthCheckResponse response;
  grpc::Status st = stub->Check(&context, request, &response);
  if (!st.ok()) return connection.Fail(tandem::common::FromGrpcStatus(st));
  absl::PrintF("%s\n",
               grpc::health::v1::HealthCheckResponse::ServingStatus_Name(response.status()));
  return response.status() == grpc::health::v1::HealthCheckResponse::SERVING ? 0 : 1;
}

}  // namespace tandem::client_app
