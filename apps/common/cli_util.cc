#include "apps/common/cli_util.h"

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
    if (item.empty() || *end != '\0') {
      return absl::InvalidArgumentError(absl::StrCat(
          "--iso: '", item, "' is not a number (one value, or several separated "
          "by commas: --iso 60,120)"));
    }
    isos.push_back({v, item});
    if (comma == std::string::npos) break;
    begin = comma + 1;
  }
  std::vector<double> values;
  for (const IsoValue& iso : isos) values.push_back(iso.value);
  if (absl::Status st = ValidateIsoList(values); !st.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("--iso '", text, "': ", st.message()));
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

namespace {
// Seconds left in a step: unknown (< 0) until 2 % of it lies behind.
double SecondsLeft(const TandemSession::Finishing& f) {
  if (!(f.share >= 0.02)) return -1;
  return f.step_seconds * (1.0 - f.share) / f.share;
}
}  // namespace

std::string FinishingLine(const std::vector<TandemSession::Finishing>& sessions) {
  const TandemSession::Finishing* pick = nullptr;
  for (const TandemSession::Finishing& f : sessions) {
    if (!f.running) continue;
    if (pick == nullptr || SecondsLeft(f) > SecondsLeft(*pick)) pick = &f;
  }
  if (pick == nullptr) return "";
  const TandemSession::Finishing& f = *pick;
  std::string line = absl::StrCat("finishing: ", f.step);
  if (f.share >= 0) absl::StrAppend(&line, ", ", static_cast<int>(100 * f.share), "%");
  if (const double left = SecondsLeft(f); left >= 0) {
    absl::StrAppend(&line, ", about ", static_cast<int64_t>(std::max(1.0, std::ceil(left))),
                    " s left");
  }
  absl::StrAppend(&line, " (", absl::StrFormat("%.1f", f.seconds), " s so far)");
  return line;
}

FinishingStatus::FinishingStatus(std::string prefix, bool quiet)
    : prefix_(std::move(prefix)), quiet_(quiet), tty_(isatty(STDERR_FILENO) != 0) {
  if (const char* env = std::getenv("TANDEM_PROGRESS_SECONDS"); env != nullptr) {
    char* end = nullptr;
    const double v = std::strtod(env, &end);
    if (end != env && *end == '\0' && v >= 0) every_s_ = v;
  }
}

void FinishingStatus::Show(const std::vector<TandemSession::Finishing>& sessions) {
  if (quiet_) return;
  const std::string line = FinishingLine(sessions);
  if (line.empty()) return;
  double seconds = 0;
  for (const TandemSession::Finishing& f : sessions) seconds = std::max(seconds, f.seconds);
  if (tty_) {
    std::fprintf(stderr, "\r%s%s   ", prefix_.c_str(), line.c_str());
    std::fflush(stderr);
    shown_ = true;
  } else if (seconds >= every_s_ && (last_ < 0 || seconds - last_ >= every_s_)) {
    std::fprintf(stderr, "%s%s\n", prefix_.c_str(), line.c_str());
    last_ = seconds;
  }
}

void FinishingStatus::Done() {
  if (shown_) std::fprintf(stderr, "\n");
  shown_ = false;
}

}  // namespace tandem::cli
