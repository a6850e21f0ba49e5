// The server's log: one line per event on stderr, written with one fwrite so that lines
// from different threads never interleave.
//   text (default):  <RFC 3339 UTC time, ms> tandem-server: <event> key=value ...
//   json (--log-format json): {"time":"...","event":"...","key":value,...}
// Every string a client supplies (the session description, its peer address, messages
// that quote its input) is a Str field: escaped (text: LogQuoted; JSON: JSON escapes,
// invalid UTF-8 replaced), so that newlines and terminal escape codes cannot forge lines,
// and truncated, so that an 8 MiB description cannot make an 8 MiB line.
#ifndef TANDEM_SERVER_LOG_H_
#define TANDEM_SERVER_LOG_H_

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <variant>

#include "absl/types/span.h"

namespace tandem::server {

// Printable ASCII as it is, except '"' and '\\', which are escaped; anything else as \n,
// \t, \r or \xHH; at most `max_bytes` input bytes, then "...(N bytes in all)".
std::string LogQuoted(std::string_view text, size_t max_bytes = 200);

enum class LogFormat { kText, kJson };
// Set once at start-up, before any thread logs.
void SetLogFormat(LogFormat format);
// --quiet: no "session" line for a stream that ended OK (failures, refusals and the
// server's own lines still go out). Set once at start-up, like the format.
void SetLogQuiet(bool quiet);
bool LogQuiet();

// One field of an event. Str: quoted in text, truncated to `max_bytes`; Word: a value the
// server chose (a status name), written bare in text.
struct LogField {
  struct Str {
    std::string_view text;
    size_t max_bytes = 200;
  };
  struct Word {
    std::string_view text;
  };
  std::string_view key;
  std::variant<int64_t, double, Str, Word> value;
};

// Writes one event line: `event` is a fixed word ("session", "refused", ...).
void LogEvent(std::string_view event, absl::Span<const LogField> fields);

// A free-form line from the server itself (start-up, shutdown): text as it is; in JSON
// {"time":...,"event":"server","message":text}.
void LogLine(std::string_view text);

}  // namespace tandem::server

#endif  // TANDEM_SERVER_LOG_H_
