// --view for tandem-client stream and watch: the live browser viewer (viewer/view_server.h)
// fed from the stream's callbacks, kept up after the end until Ctrl-C (or --view-linger).
#ifndef TANDEM_CLIENT_LIVE_VIEW_H_
#define TANDEM_CLIENT_LIVE_VIEW_H_

#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/stream_client.h"
#include "cli/flags.h"
#include "viewer/view_server.h"

namespace tandem::client {

class LiveView {
 public:
  // --view ADDR, --view-token (or --view-token-file, $TANDEM_VIEW_TOKEN), --view-linger.
  // `listen`: the default address ("" = off; when set, --listen is accepted as another name
  // of --view).
  void AddFlags(cli::FlagSet& flags, const std::string& listen = "");
  bool on() const { return !listen_.empty(); }
  // Starts serving (when on) and prints the address on stderr, with a warning when it is
  // not loopback and has no token. The error names the address (a busy port).
  absl::Status Start(const std::string& description, int64_t nz);
  // Publishes what `callbacks` receive to the page as well (call after setting them).
  void Wire(StreamCallbacks* callbacks);
  // Publishes the end (the final mesh of an unsealed stream, the metrics, or the error),
  // then keeps the page up for --view-linger seconds (default: until SIGINT / SIGTERM).
  void Finish(const absl::StatusOr<StreamResult>& result);

 private:
  std::string listen_, token_;
  double linger_s_ = -1;
  std::string description_;
  int64_t nz_ = 0;
  std::unique_ptr<viewer::ViewServer> server_;
};

}  // namespace tandem::client

#endif  // TANDEM_CLIENT_LIVE_VIEW_H_
