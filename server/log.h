// The server's log: one line per event on stderr, each starting with an RFC 3339 UTC
// timestamp (millisecond precision) and "tandem-server: ", written with one fwrite so that
// lines from different threads never interleave. Every string a client supplies (the
// session description, its peer address, messages that quote its input) goes through
// LogQuoted: escaped, so that newlines and terminal escape codes cannot forge lines, and
// truncated, so that an 8 MiB description cannot make an 8 MiB line.
#ifndef TANDEM_SERVER_LOG_H_
#define TANDEM_SERVER_LOG_H_

#include <cstddef>
#include <string>
#include <string_view>

namespace tandem::server {

// Printable ASCII as it is, except '"' and '\\', which are escaped; anything else as \n,
// \t, \r or \xHH; at most `max_bytes` input bytes, then "...(N bytes in all)".
std::string LogQuoted(std::string_view text, size_t max_bytes = 200);

// Writes "<RFC 3339 time> tandem-server: <text>\n" to stderr.
void LogLine(std::string_view text);

}  // namespace tandem::server

#endif  // TANDEM_SERVER_LOG_H_
