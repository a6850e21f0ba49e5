// tandem-client: the command-line client of tandem-server. Each subcommand has its own file:
//   tandem-client stream --server HOST:PORT --input VOLUME --iso C0 --error E0 --out MESH ...
//   tandem-client watch  --session ID --out MESH   (view: the same, live in a browser)
//   tandem-client info   --server HOST:PORT
//   tandem-client health --server HOST:PORT
// Exit status (apps/common/cli_util.h): 0 success, 1 a failure while running (the message on
// stderr names the problem and, for a server error, its gRPC code), 2 a mistake in the
// command line, 3 stream --strict: the iso-value lies outside the data sent (a warning
// otherwise).
#include <cstdio>
#include <string>
#if defined(__GLIBC__)  // (defined by the headers above)
#include <malloc.h>     // mallopt
#endif

#include "absl/strings/str_format.h"
#include "apps/common/version.h"
#include "command.h"

namespace {

constexpr char kMainUsage[] =
    "usage: tandem-client <command> [flags]   (tandem-client <command> --help for its flags)\n"
    "commands:\n"
    "  stream   stream a volume to tandem-server and save the simplified iso-surface\n"
    "  watch    follow another stream's sealed-chunk session by its id and save its mesh\n"
    "  view     show a sealed-chunk session live in a browser (watch --view)\n"
    "  info     print the server's version, security, limits, live counters and sessions\n"
    "  health   query the standard gRPC health service (exit 0 when SERVING)\n"
    "  --version  print the version and git revision\n"
    "environment: TANDEM_SERVER, TANDEM_TLS_CA, TANDEM_TLS_SERVER_NAME, TANDEM_TOKEN_FILE (as\n"
    "the flags), TANDEM_TOKEN (the bearer token itself; --token-file wins; never a flag,\n"
    "since command lines are visible to every user of the machine); likewise the viewer's\n"
    "token TANDEM_VIEW_TOKEN (or --view-token-file) and stream's TANDEM_RESUME (or\n"
    "--resume-file), which as flags work but draw a warning";

}  // namespace

int main(int argc, char** argv) {
#if defined(__GLIBC__)
  // Every message of a stream is a fresh buffer of about a chunk (1 MiB), serialized and
  // freed by gRPC. glibc hands freed memory at the top of a thread's heap back to the kernel
  // once it exceeds the trim threshold (a few MiB at most), so each buffer was faulted in
  // and zeroed anew (docs/decisions.md 54). A short-lived client can keep its few MiB of
  // buffers instead.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
#endif
  const std::string command = argc > 1 ? argv[1] : "";
  if (command == "stream") return tandem::client_app::StreamCommand(argc, argv);
  if (command == "info") return tandem::client_app::InfoCommand(argc, argv);
  if (command == "watch")
    return tandem::client_app::WatchCommand(argc, argv, /*view_command=*/false);
  if (command == "view") return tandem::client_app::WatchCommand(argc, argv, /*view_command=*/true);
  if (command == "health") return tandem::client_app::HealthCommand(argc, argv);
  if (command == "--help" || command == "-h" || command == "help") {
    absl::PrintF("%s\n", kMainUsage);
    return 0;
  }
  if (command == "--version" || command == "version") {
    absl::PrintF("%s", TANDEM_VERSION_LINE("tandem-client"));
    return 0;
  }
  absl::FPrintF(stderr, "%s\n", kMainUsage);
  return 2;
}
