// The subcommands of tandem-client (one file each; main.cc dispatches), the connection flags
// they all take, and how each reports a mistake, a local failure or a call's failure.
#ifndef TANDEM_APPS_TANDEM_CLIENT_COMMAND_H_
#define TANDEM_APPS_TANDEM_CLIENT_COMMAND_H_

#include <grpcpp/grpcpp.h>

#include <cstdint>
#include <string>

#include "absl/status/status.h"
#include "apps/common/flags.h"
#include "tandem/client/connection.h"
#include "tandem/common/wire.h"

namespace tandem::client_app {

using tandem::cli::FlagSet;

// Each takes the whole command line (argv[1] is the subcommand) and returns the exit status.
int StreamCommand(int argc, char** argv);
int InfoCommand(int argc, char** argv);
// `watch`, and `view` (the same with the browser viewer on 127.0.0.1:8080 by default and
// --out optional).
int WatchCommand(int argc, char** argv, bool view_command);
int HealthCommand(int argc, char** argv);

// A failure here, with no server involved (a file that cannot be read or written): its
// message, without a gRPC code.
int Fail(const absl::Status& st);

// A call's failure: the server's (or the transport's) status code, its message, and a hint.
int RpcFail(const absl::Status& st, const std::string& hint = "");

// A mistake in the flags, found before anything was sent: exit status 2, no gRPC code.
int UsageError(const absl::Status& st);

// --server and the TLS / token flags every command has (health: no token).
struct ConnectionFlags {
  tandem::client::ConnectionOptions options;
  std::string token_file;
  bool with_token = true;
  int64_t retries_flag = 4;

  ConnectionFlags() { options.server = tandem::common::kDefaultServerAddress; }
  void Add(FlagSet& flags, bool token);
  // After parsing: loads the token. -1 to go on, else the exit status.
  int Finish();
  int Fail(const absl::Status& st) const;
};

// Parses flags; returns -1 to go on, else the exit status (help printed or usage error).
int ParseOrExit(FlagSet& flags, int argc, char** argv, ConnectionFlags* connection);

std::string Lower(std::string s);

absl::Status WriteFile(const std::string& path, const std::string& bytes);

void SetDeadline(grpc::ClientContext* context, double seconds);

}  // namespace tandem::client_app

#endif  // TANDEM_APPS_TANDEM_CLIENT_COMMAND_H_
