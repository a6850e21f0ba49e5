#include "cli/cli_util.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace tandem::cli {

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
