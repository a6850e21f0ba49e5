// tandem-server: serves tandem.v1.Tandem (see proto/tandem/v1/tandem.proto) over gRPC.
// This file only parses flags, builds the server and handles SIGTERM/SIGINT: it marks the
// server NOT_SERVING, lets running streams finish for --grace-seconds, cancels the rest,
// waits for their worker threads, and exits 0.
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <memory>
#include <string>
#include <thread>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "common/cli_flags.h"
#include "common/wire.h"
#include "server/request_validation.h"
#include "server/tandem_service.h"

namespace {

constexpr char kUsage[] =
    "usage: tandem-server [flags]\n"
    "Serves tandem.v1.Tandem: streams of volume slices in, simplified iso-surface meshes\n"
    "(Draco) out, plus the standard gRPC health service and server reflection.\n"
    "Prints \"listening on HOST:PORT\" on stdout once ready (--listen with port 0 picks a\n"
    "free port), one line per session on stderr, and exits 0 after SIGTERM or SIGINT.";

}  // namespace

int main(int argc, char** argv) {
  std::string listen = tandem::wire::kDefaultServerAddress;
  tandem::server::ServerLimits limits;
  int64_t max_sessions = limits.max_sessions;
  double grace_seconds = 10;
  tandem::cli::FlagSet flags(kUsage);
  flags.AddString("listen", &listen, "HOST:PORT", "address to listen on (port 0 = any free port)");
  flags.AddInt("max-sessions", &max_sessions,
               "concurrent Extract streams; more get RESOURCE_EXHAUSTED (one worker thread each)");
  flags.AddInt("max-voxels-per-slice", &limits.max_voxels_per_slice,
               "largest nx*ny accepted (RESOURCE_EXHAUSTED above)");
  flags.AddInt("max-slices", &limits.max_slices, "largest number of slices accepted per stream");
  flags.AddInt("max-message-bytes", &limits.max_message_bytes,
               "largest request message accepted (bounds SliceChunk size)");
  flags.AddDouble("idle-timeout-seconds", &limits.idle_timeout_s,
                  "end a stream that sends nothing for this long (frees its session slot)");
  flags.AddDouble("grace-seconds", &grace_seconds,
                  "on SIGTERM/SIGINT, time running streams get to finish before cancellation");
  flags.UseEnvironment("TANDEM_");  // containers configure through TANDEM_* variables
  if (absl::Status st = flags.Parse(argc, argv); !st.ok()) {
    absl::FPrintF(stderr, "tandem-server: %s\n", std::string(st.message()));
    return 2;
  }
  if (flags.help_requested()) {
    absl::PrintF("%s", flags.Help());
    return 0;
  }
  if (!flags.positional().empty()) {
    absl::FPrintF(stderr, "tandem-server: unexpected argument '%s' (see --help)\n",
                  flags.positional().front());
    return 2;
  }
  if (max_sessions < 1 || max_sessions > 4096 || limits.max_voxels_per_slice < 4 ||
      limits.max_slices < 2 || limits.max_message_bytes < 1024 ||
      limits.max_message_bytes > (int64_t{1} << 30) || grace_seconds < 0 ||
      !(limits.idle_timeout_s > 0)) {
    absl::FPrintF(stderr,
                  "tandem-server: out of range: need 1 <= --max-sessions <= 4096, "
                  "--max-voxels-per-slice >= 4, --max-slices >= 2, 1024 <= "
                  "--max-message-bytes <= 2^30, --grace-seconds >= 0, "
                  "--idle-timeout-seconds > 0\n");
    return 2;
  }
  limits.max_sessions = static_cast<int>(max_sessions);

  // Block the shutdown signals in every thread (gRPC's included, so set before any is
  // created); one thread takes them with sigwait.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  tandem::server::TandemService service(limits);
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(listen, grpc::InsecureServerCredentials(), &port);
  builder.SetMaxReceiveMessageSize(static_cast<int>(limits.max_message_bytes));
  builder.RegisterService(&service);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (server == nullptr || port == 0) {
    absl::FPrintF(stderr, "tandem-server: cannot listen on %s (address in use or invalid?)\n",
                  listen);
    return 1;
  }
  const std::string host = listen.substr(0, listen.rfind(':'));
  absl::PrintF("listening on %s:%d\n", host, port);
  std::fflush(stdout);
  absl::FPrintF(stderr, "tandem-server: %s listening on %s:%d (max %d sessions)\n",
                tandem::wire::ServiceVersion(), host, port, limits.max_sessions);

  std::thread signal_thread([&] {
    int sig = 0;
    sigwait(&signals, &sig);
    absl::FPrintF(stderr, "tandem-server: %s: draining (grace %.1f s)\n",
                  sig == SIGTERM ? "SIGTERM" : "SIGINT", grace_seconds);
    server->GetHealthCheckService()->SetServingStatus(false);
    // Stops accepting streams, waits for running ones until the deadline, then cancels
    // them (their reactors finish with CANCELLED).
    server->Shutdown(std::chrono::system_clock::now() +
                     std::chrono::milliseconds(static_cast<int64_t>(grace_seconds * 1000)));
  });
  server->Wait();
  signal_thread.join();
  // Workers notice the cancellation between slices; a slice takes well under a second.
  if (!service.WaitForWorkers(absl::Now() + absl::Seconds(30))) {
    absl::FPrintF(stderr, "tandem-server: worker threads still busy after 30 s; exiting\n");
    return 1;
  }
  absl::FPrintF(stderr, "tandem-server: stopped\n");
  return 0;
}
