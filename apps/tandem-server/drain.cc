// The drain of tandem-server after SIGTERM or SIGINT (drain.h).
#include "drain.h"

#include <grpc/grpc.h>  // grpc_server_cancel_all_calls
#include <grpcpp/health_check_service_interface.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <ctime>
#include <thread>

#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "tandem/server/log.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::server_app {

void Drain(const char* name, const sigset_t& signals, grpc::Server& server,
           tandem::server::TandemService& service, const DrainOptions& options,
           std::unique_ptr<tandem::server::DrainStandIn>* stand_in) {
  // Readiness fails from now on; liveness (its own service name) does not.
  grpc::HealthCheckServiceInterface* health = server.GetHealthCheckService();
  health->SetServingStatus("", false);
  health->SetServingStatus(tandem::v1::Tandem::service_full_name(), false);
  auto seconds = [](double s) { return std::chrono::milliseconds(static_cast<int64_t>(s * 1000)); };
  // Waits up to `s` seconds for another signal; true if one came.
  auto another_signal = [&](double s) {
    const int64_t ms = static_cast<int64_t>(s * 1000);
    timespec ts{static_cast<time_t>(ms / 1000), static_cast<long>(ms % 1000) * 1000000};
    while (true) {
      const int got = sigtimedwait(&signals, nullptr, &ts);
      if (got > 0) return true;
      if (errno != EINTR) return false;  // EAGAIN: the time is up
    }
  };
  if (options.delay_seconds > 0) {
    tandem::server::LogLine(absl::StrFormat(
        "%s: NOT_SERVING; still accepting streams for %.1f s (--drain-delay-seconds)", name,
        options.delay_seconds));
    if (another_signal(options.delay_seconds)) {
      tandem::server::LogLine("second signal: the drain delay is cut short");
    }
  }
  tandem::server::LogLine(absl::StrFormat(
      "%s: draining: new streams are refused; running ones (%d) have %.1f s to finish", name,
      service.CountersSnapshot().active_sessions(), options.grace_seconds));
  const auto deadline = std::chrono::steady_clock::now() + seconds(options.grace_seconds);
  // Shutdown returns as soon as every call is done; its own deadline (a little after
  // ours) only cancels what did not even take UNAVAILABLE (a client that does not read).
  std::atomic<bool> shutdown_started{false}, shutdown_done{false};
  std::thread stopper([&] {
    shutdown_started = true;
    server.Shutdown(std::chrono::system_clock::now() + seconds(options.grace_seconds + 5));
    shutdown_done = true;
  });
  *stand_in = tandem::server::DrainStandIn::Start(options.host, options.port, options.credentials,
                                                  absl::Seconds(2));
  if (*stand_in == nullptr) {
    tandem::server::LogLine(absl::StrFormat(
        "%s:%d was taken by another process while draining: health checks go unanswered",
        options.host, options.port));
  }
  while (service.CountersSnapshot().active_sessions() > 0 &&
         std::chrono::steady_clock::now() < deadline) {
    if (another_signal(0.05)) break;  // yet another signal: end the streams now
  }
  const int64_t ended = service.EndAllStreams(grpc::Status(
      grpc::StatusCode::UNAVAILABLE,
      absl::StrFormat("tandem-server is shutting down and the stream did not finish within "
                      "its --grace-seconds (%g s); send the scan again (to another replica)",
                      options.grace_seconds)));
  if (ended > 0) {
    tandem::server::LogLine(
        absl::StrFormat("grace period over: %d streams ended with UNAVAILABLE", ended));
  }
  // Once every stream has delivered its status (a client that does not read keeps its
  // own until Shutdown's deadline), nothing is left but connections, and gRPC's graceful
  // GOAWAY waits for each client to answer a ping: an idle C++ client channel answers
  // only at its 5 s backup poll, one that never answers after 20 s. Cut them.
  // (grpc::Server::c_server is marked experimental; grpc_server_cancel_all_calls is
  // the C API's documented way to end a shutdown early, and it closes the connections.)
  const auto slack = std::chrono::steady_clock::now() + seconds(5);
  while (!shutdown_done &&
         (!shutdown_started || service.CountersSnapshot().active_sessions() > 0) &&
         std::chrono::steady_clock::now() < slack) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  // One more second for connections that close by themselves (a client reading its
  // last status answers the GOAWAY at once), so that none is cut with bytes in flight.
  const auto settle = std::chrono::steady_clock::now() + seconds(1);
  while (!shutdown_done && std::chrono::steady_clock::now() < settle) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  if (!shutdown_done && shutdown_started && service.CountersSnapshot().active_sessions() == 0) {
    grpc_server_cancel_all_calls(server.c_server());
  }
  stopper.join();
}

}  // namespace tandem::server_app
