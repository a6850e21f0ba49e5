#include "cli/cli_util.h"

#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "absl/strings/str_cat.h"

namespace tandem::cli {

absl::StatusOr<Args> Args::Parse(int argc, char** argv, int first,
                                 const std::set<std::string>& valued,
                                 const std::set<std::string>& flags) {
  Args a;
  for (int i = first; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg.rfind("--", 0) != 0 || arg == "--") {
      a.positional_.push_back(arg);
      continue;
    }
    std::string name = arg.substr(2), value;
    bool has_value = false;
    if (auto eq = name.find('='); eq != std::string::npos) {
      value = name.substr(eq + 1);
      name = name.substr(0, eq);
      has_value = true;
    }
    if (flags.count(name)) {
      if (has_value) return absl::InvalidArgumentError(absl::StrCat("--", name, " takes no value"));
      a.flags_.insert(name);
    } else if (valued.count(name)) {
      if (!has_value) {
        if (i + 1 >= argc) return absl::InvalidArgumentError(absl::StrCat("--", name, " needs a value"));
        value = argv[++i];
      }
      a.values_[name] = value;
    } else {
      return absl::InvalidArgumentError(absl::StrCat("unknown option --", name, " (see --help)"));
    }
  }
  return a;
}

std::optional<std::string> Args::Get(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

namespace {

// Parses the value of --name with `parse` (a strtod/strtoll-style function that sets `end`),
// or returns `def` when the option is absent; `what` names the expected kind in errors.
template <typename T, typename Parse>
absl::StatusOr<T> GetNumber(const std::optional<std::string>& v, const std::string& name,
                            std::optional<T> def, const char* what, Parse parse) {
  if (!v) {
    if (def) return *def;
    return absl::InvalidArgumentError(absl::StrCat("--", name, " is required"));
  }
  char* end = nullptr;
  errno = 0;
  const T x = parse(v->c_str(), &end);
  if (v->empty() || *end != '\0' || errno != 0) {
    return absl::InvalidArgumentError(absl::StrCat("--", name, ": '", *v, "' is not ", what));
  }
  return x;
}

}  // namespace

absl::StatusOr<double> Args::GetDouble(const std::string& name, std::optional<double> def) const {
  absl::StatusOr<double> d = GetNumber<double>(
      Get(name), name, def, "a number", [](const char* s, char** e) { return std::strtod(s, e); });
  if (d.ok() && !std::isfinite(*d)) {
    return absl::InvalidArgumentError(absl::StrCat("--", name, ": '", *Get(name), "' is not a number"));
  }
  return d;
}

absl::StatusOr<int64_t> Args::GetInt(const std::string& name, std::optional<int64_t> def) const {
  return GetNumber<int64_t>(Get(name), name, def, "an integer", [](const char* s, char** e) {
    return static_cast<int64_t>(std::strtoll(s, e, 10));
  });
}

Progress::Progress(std::string label) : label_(std::move(label)), tty_(isatty(STDERR_FILENO)) {}

void Progress::Update(int64_t done, int64_t total) {
  if (!tty_ || total <= 0) return;
  const int64_t pct = done * 100 / total;
  if (pct == last_percent_ && done != total) return;
  last_percent_ = pct;
  std::fprintf(stderr, "\r%s %lld/%lld (%lld%%)", label_.c_str(), static_cast<long long>(done),
               static_cast<long long>(total), static_cast<long long>(pct));
  std::fflush(stderr);
}

void Progress::Done() {
  if (tty_ && last_percent_ >= 0) std::fprintf(stderr, "\n");
}

}  // namespace tandem::cli
