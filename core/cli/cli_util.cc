#include "cli/cli_util.h"

#include <unistd.h>

#include <algorithm>
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
      if (auto it = a.values_.find(name); it != a.values_.end()) {
        return absl::InvalidArgumentError(absl::StrCat("--", name, " given twice ('", it->second,
                                                       "' and '", value, "'): give it once"));
      }
      a.values_[name] = value;
    } else {
      std::vector<std::string> known(valued.begin(), valued.end());
      known.insert(known.end(), flags.begin(), flags.end());
      return absl::InvalidArgumentError(
          absl::StrCat("unknown option --", name, DidYouMean(name, known), " (see --help)"));
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

absl::StatusOr<std::vector<IsoValue>> ParseIsoList(const std::string& text) {
  std::vector<IsoValue> isos;
  size_t begin = 0;
  while (true) {
    const size_t comma = text.find(',', begin);
    std::string item = text.substr(begin, comma == std::string::npos ? std::string::npos
                                                                     : comma - begin);
    item.erase(0, item.find_first_not_of(' '));
    item.erase(item.find_last_not_of(' ') + 1);
    char* end = nullptr;
    const double v = item.empty() ? 0.0 : std::strtod(item.c_str(), &end);
    if (item.empty() || *end != '\0' || !std::isfinite(v)) {
      return absl::InvalidArgumentError(absl::StrCat(
          "--iso: '", item, "' is not a number (one value, or several separated "
          "by commas: --iso 60,120)"));
    }
    for (const IsoValue& seen : isos) {
      if (seen.value == v) {
        return absl::InvalidArgumentError(
            absl::StrCat("--iso '", text, "': ", item, " is given twice"));
      }
    }
    isos.push_back({v, item});
    if (comma == std::string::npos) break;
    begin = comma + 1;
  }
  if (isos.size() > static_cast<size_t>(kMaxIsoValues)) {
    return absl::InvalidArgumentError(absl::StrCat("--iso '", text, "': at most ", kMaxIsoValues,
                                                   " iso-values in one pass, got ", isos.size()));
  }
  return isos;
}

absl::StatusOr<std::string> NameForIso(const std::string& flag, const std::string& pattern,
                                       const IsoValue& iso, size_t count) {
  const size_t at = pattern.find("{iso}");
  if (at == std::string::npos) {
    if (count <= 1) return pattern;
    const size_t dot = pattern.rfind('.');
    const std::string stem = dot == std::string::npos ? pattern : pattern.substr(0, dot);
    const std::string ext = dot == std::string::npos ? "" : pattern.substr(dot);
    return absl::InvalidArgumentError(absl::StrCat(
        "--", flag, " ", pattern, ": with ", count, " iso-values, name the outputs with a "
        "pattern holding {iso}, e.g. --", flag, " ", stem, "_{iso}", ext));
  }
  std::string name = pattern;
  for (size_t p = name.find("{iso}"); p != std::string::npos; p = name.find("{iso}", p + iso.text.size())) {
    name.replace(p, 5, iso.text);
  }
  return name;
}

namespace {

// Optimal string alignment distance (Damerau-Levenshtein without repeated edits).
size_t EditDistance(const std::string& a, const std::string& b) {
  std::vector<std::vector<size_t>> d(a.size() + 1, std::vector<size_t>(b.size() + 1));
  for (size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) {
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
      }
    }
  }
  return d[a.size()][b.size()];
}

}  // namespace

std::string ClosestName(const std::string& name, const std::vector<std::string>& known) {
  size_t best = 3;
  std::string closest;
  bool tie = false;
  for (const std::string& k : known) {
    const size_t dist = EditDistance(name, k);
    if (dist < best) {
      best = dist;
      closest = k;
      tie = false;
    } else if (dist == best) {
      tie = true;
    }
  }
  if (!closest.empty() && !tie) return closest;
  std::string prefixed;
  for (const std::string& k : known) {
    if (!name.empty() && k.rfind(name, 0) == 0) {
      if (!prefixed.empty()) return "";
      prefixed = k;
    }
  }
  return prefixed;
}

std::string DidYouMean(const std::string& name, const std::vector<std::string>& known) {
  const std::string closest = ClosestName(name, known);
  return closest.empty() ? "" : absl::StrCat(" (did you mean --", closest, "?)");
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
