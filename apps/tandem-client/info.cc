// tandem-client info: the server's version, security, limits, live counters and the sessions
// this call may see.
#include <memory>
#include <string>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "command.h"
#include "tandem/common/wire.h"
#include "tandem/options.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::client_app {

int InfoCommand(int argc, char** argv) {
  ConnectionFlags connection;
  double timeout_s = 10;
  std::string watch_key;
  FlagSet flags(
      "usage: tandem-client info [--server HOST:PORT] [flags]\n"
      "Prints the server's version, security, limits, supported dtypes and live "
      "counters, and the sessions this call may see: those created with its bearer "
      "token, and the one of --watch-key.");
  connection.Add(flags, /*token=*/true);
  flags.AddDouble("timeout", &timeout_s, "seconds to wait for the answer");
  flags.AddSecret("watch-key", &watch_key, "KEY", "TANDEM_WATCH_KEY",
                  "also list the session of this watch key (its streaming client prints it)");
  if (int rc = ParseOrExit(flags, argc, argv, &connection); rc >= 0) return rc;
  absl::StatusOr<std::shared_ptr<grpc::Channel>> channel =
      tandem::client::MakeChannel(connection.options);
  if (!channel.ok()) return Fail(channel.status());
  auto stub = tandem::v1::Tandem::NewStub(*channel);
  grpc::ClientContext context;
  SetDeadline(&context, timeout_s);
  tandem::client::AddToken(connection.options, &context);
  tandem::v1::InfoResponse info;
  tandem::v1::InfoRequest request;
  if (!watch_key.empty()) request.add_watch_keys(watch_key);
  grpc::Status st = stub->GetInfo(&context, request, &info);
  if (!st.ok()) return connection.Fail(tandem::common::FromGrpcStatus(st));
  std::string dtypes, schedules;
  for (int d : info.dtypes()) {
    absl::StrAppend(&dtypes, dtypes.empty() ? "" : ", ",
                    absl::AsciiStrToLower(tandem::v1::DType_Name(d).substr(6)));
  }
  for (int s : info.schedules()) {
    absl::StatusOr<tandem::Schedule> schedule = tandem::common::ScheduleFromProto(s);
    if (schedule.ok()) {
      absl::StrAppend(&schedules, schedules.empty() ? "" : ", ",
                      std::string(tandem::ScheduleName(*schedule)));
    }
  }
  const auto& l = info.limits();
  const auto& c = info.counters();
  absl::PrintF("server                 %s (%s)\n", connection.options.server, info.version());
  absl::PrintF("security               %s, %s\n", info.tls() ? "TLS" : "plaintext",
               info.token_required() ? "bearer token required" : "no authentication");
  absl::PrintF("dtypes                 %s\n", dtypes);
  absl::PrintF("schedules              %s\n", schedules);
  absl::PrintF("max voxels per slice   %d\n", l.max_voxels_per_slice());
  absl::PrintF("max slices             %d\n", l.max_slices());
  absl::PrintF("max sessions           %d\n", l.max_sessions());
  absl::PrintF("max message bytes      %d\n", l.max_message_bytes());
  absl::PrintF("idle timeout           %g s\n", l.idle_timeout_seconds());
  absl::PrintF("session memory         %d MiB\n", l.session_memory_bytes() >> 20);
  absl::PrintF("max inflight bytes     %d\n", l.max_inflight_bytes());
  absl::PrintF(
      "keepalive              time %d ms, timeout %d ms, min client ping interval %d ms, "
      "pings without calls %s\n",
      l.keepalive_time_ms(), l.keepalive_timeout_ms(), l.min_ping_interval_ms(),
      l.permit_keepalive_without_calls() ? "allowed" : "refused");
  absl::PrintF("min preview interval   %d ms (and at most %.0f%% of a stream's time)\n",
               l.min_preview_interval_ms(), 100 * l.max_preview_share());
  absl::PrintF("resume window          %g s\n", l.resume_window_seconds());
  absl::PrintF("compute threads        %d (shared by all sessions)\n", l.compute_threads());
  absl::PrintF("watch                  %d MiB kept per session, %g s after it ends\n",
               l.watch_retain_bytes() >> 20, l.watch_linger_seconds());
  absl::PrintF("active sessions        %d\n", c.active_sessions());
  absl::PrintF("sessions started       %d (finished %d, rejected %d)\n", c.sessions_started(),
               c.sessions_finished(), c.sessions_rejected());
  absl::PrintF("worker threads         %d\n", c.worker_threads());
  absl::PrintF("session bytes          %d\n", c.session_bytes());
  absl::PrintF("buffered bytes         %d\n", c.buffered_bytes());
  absl::PrintF("draining sessions      %d\n", c.sessions_draining());
  absl::PrintF("waiting for a resume   %d\n", c.sessions_waiting_for_resume());
  absl::PrintF("unauthenticated calls  %d\n", c.unauthenticated_calls());
  absl::PrintF(
      "sessions listed        %d (others' ids and descriptions are private: the bearer "
      "token that created a session, or its --watch-key, lists it)\n",
      info.sessions_size());
  for (const tandem::v1::SessionSummary& session : info.sessions()) {
    absl::PrintF("session                %s  %s, %d slices, %s%s, %.0f s\n", session.id(),
                 session.finished()             ? "finished"
                 : session.waiting_for_resume() ? "waiting for its client to resume"
                                                : "running",
                 session.slices_consumed(),
                 session.sealed_chunks() ? "sealed chunks (watchable)" : "no sealed chunks",
                 session.description().empty() ? "" : absl::StrCat(", ", session.description()),
                 session.age_seconds());
  }
  return 0;
}

}  // namespace tandem::client_app
