#include "tandem/server/log.h"

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"

namespace tandem::server {

std::string LogQuoted(std::string_view text, size_t max_bytes) {
  std::string out;
  const size_t n = std::min(text.size(), max_bytes);
  out.reserve(n + 16);
  for (size_t i = 0; i < n; ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (c >= 0x20 && c < 0x7f) {
          out += static_cast<char>(c);
        } else {
          absl::StrAppendFormat(&out, "\\x%02x", c);
        }
    }
  }
  if (text.size() > max_bytes) absl::StrAppend(&out, "...(", text.size(), " bytes in all)");
  return out;
}

namespace {

LogFormat g_format = LogFormat::kText;

std::string Now() {
  return absl::FormatTime("%Y-%m-%dT%H:%M:%E3SZ", absl::Now(), absl::UTCTimeZone());
}

void Write(const std::string& line) {
  std::fwrite(line.data(), 1, line.size(), stderr);
  std::fflush(stderr);
}

// JSON-escaped and truncated (on a UTF-8 boundary, invalid sequences replaced).
std::string JsonString(std::string_view text, size_t max_bytes) {
  std::string cut(text.substr(0, max_bytes));
  if (text.size() > max_bytes) {
    while (!cut.empty() && (static_cast<unsigned char>(cut.back()) & 0xC0) == 0x80) {
      cut.pop_back();  // continuation bytes of a cut character
    }
    if (!cut.empty() && static_cast<unsigned char>(cut.back()) >= 0xC0) cut.pop_back();
    absl::StrAppend(&cut, "...(", text.size(), " bytes in all)");
  }
  return nlohmann::json(cut).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace

void SetLogFormat(LogFormat format) { g_format = format; }

namespace {
bool g_quiet = false;
}  // namespace

void SetLogQuiet(bool quiet) { g_quiet = quiet; }
bool LogQuiet() { return g_quiet; }

void LogEvent(std::string_view event, absl::Span<const LogField> fields) {
  std::string line;
  const bool json = g_format == LogFormat::kJson;
  if (json) {
    absl::StrAppend(&line, "{\"time\":\"", Now(), "\",\"event\":", JsonString(event, 100));
  } else {
    absl::StrAppend(&line, Now(), " tandem-server: ", absl::string_view(event.data(), event.size()));
  }
  for (const LogField& f : fields) {
    const absl::string_view key(f.key.data(), f.key.size());
    if (json) {
      absl::StrAppend(&line, ",", JsonString(f.key, 100), ":");
    } else {
      absl::StrAppend(&line, " ", key, "=");
    }
    if (const auto* i = std::get_if<int64_t>(&f.value)) {
      absl::StrAppend(&line, *i);
    } else if (const auto* d = std::get_if<double>(&f.value)) {
      absl::StrAppendFormat(&line, "%.3f", std::isfinite(*d) ? *d : 0.0);
    } else if (const auto* str = std::get_if<LogField::Str>(&f.value)) {
      absl::StrAppend(&line, json ? JsonString(str->text, str->max_bytes)
                                  : absl::StrCat("\"", LogQuoted(str->text, str->max_bytes),
                                                 "\""));
    } else {
      const auto& w = std::get<LogField::Word>(f.value);
      absl::StrAppend(&line, json ? JsonString(w.text, 100) : std::string(w.text));
    }
  }
  absl::StrAppend(&line, json ? "}\n" : "\n");
  Write(line);
}

void LogLine(std::string_view text) {
  if (g_format == LogFormat::kJson) {
    LogEvent("server", {{"message", LogField::Str{text, 4000}}});
    return;
  }
  Write(absl::StrCat(Now(), " tandem-server: ", absl::string_view(text.data(), text.size()),
                     "\n"));
}

}  // namespace tandem::server
