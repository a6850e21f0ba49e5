// Command-line helpers shared by the tandem executables: iso-value lists and the output
// names they give, and a terminal progress line. Flags: apps/common/flags.h.
#ifndef TANDEM_APPS_COMMON_CLI_UTIL_H_
#define TANDEM_APPS_COMMON_CLI_UTIL_H_

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "tandem/tandem.h"

namespace tandem::cli {

// The exit statuses of the three programs (and the Python client): 2 for a mistake in the
// command line itself (a flag unknown, missing, malformed or given twice, a value an
// option's rule refuses, an output extension no writer has, an unknown subcommand), 1 for
// what goes wrong while running (the input, files, devices, servers, the network, a
// session's failure). 0 is success; 3 is `--strict`'s empty surface.
inline constexpr int kExitFailure = 1;
inline constexpr int kExitUsage = 2;

// Several surfaces in one pass: "--iso 60,120" as its values and the text of each (for
// output names). The list is held to ValidateIsoList (tandem/options.h); errors name the flag.
struct IsoValue {
  double value;
  std::string text;  // as the user wrote it, e.g. "120" or "0.5"
};
absl::StatusOr<std::vector<IsoValue>> ParseIsoList(const std::string& text);

// An output name for one surface of several: `pattern` with "{iso}" replaced by the
// value's text. Without "{iso}" it is returned as is when `count` is 1, and is an error
// naming `flag` otherwise (two surfaces would overwrite one file).
absl::StatusOr<std::string> NameForIso(const std::string& flag, const std::string& pattern,
                                       const IsoValue& iso, size_t count);

// "slices 12/128" on stderr, rewritten in place; only when stderr is a terminal.
class Progress {
 public:
  explicit Progress(std::string label);
  void Update(int64_t done, int64_t total);
  void Done();

 private:
  std::string label_;
  bool tty_;
  int64_t last_percent_ = -1;
};

// After the last slice, while the sessions finish: "finishing: STEP, 43%, about 3 s left
// (12 s so far)", the estimate from the step's share done and its time so far (none before
// 2 % of it); for several surfaces finishing side by side, the one with the most time left.
// "" when none is running.
std::string FinishingLine(const std::vector<TandemSession::Finishing>& sessions);

// Shows FinishingLine on stderr: on a terminal, rewritten in place at every call; elsewhere
// (a log), one line every TANDEM_PROGRESS_SECONDS seconds (10 by default; 0 = at every
// call) once the finish has run that long. `prefix` starts each line ("tandem extract: ").
class FinishingStatus {
 public:
  FinishingStatus(std::string prefix, bool quiet);
  void Show(const std::vector<TandemSession::Finishing>& sessions);
  void Done();  // ends the line left on a terminal

 private:
  std::string prefix_;
  bool quiet_, tty_;
  double every_s_ = 10;
  double last_ = -1;  // Finish's seconds at the last line written to a log
  bool shown_ = false;
};

}  // namespace tandem::cli

#endif  // TANDEM_APPS_COMMON_CLI_UTIL_H_
