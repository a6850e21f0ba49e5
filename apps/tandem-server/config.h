// tandem-server's configuration from its command line and TANDEM_* variables.
#ifndef TANDEM_APPS_TANDEM_SERVER_CONFIG_H_
#define TANDEM_APPS_TANDEM_SERVER_CONFIG_H_

#include <cstdint>
#include <string>

#include "tandem/common/wire.h"
#include "tandem/server/tandem_service.h"

namespace tandem::server_app {

struct ServerConfig {
  std::string listen = tandem::common::kDefaultServerAddress;
  std::string tls_cert, tls_key, tokens_file, metrics_listen;
  tandem::server::ServerLimits limits;
  double grace_seconds = 10;
  double drain_delay_seconds = 0;
  int64_t malloc_arenas = 2;
};

// Reads the flags (a flag beats its TANDEM_* variable) into *config, checks their ranges and
// sets the log's format and quietness. -1 to go on, else the exit status: 0 after --help or
// --version, 2 for a mistake in the command line (its message on stderr).
int ParseServerFlags(int argc, char** argv, ServerConfig* config);

}  // namespace tandem::server_app

#endif  // TANDEM_APPS_TANDEM_SERVER_CONFIG_H_
