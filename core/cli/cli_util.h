// Minimal command-line helpers for the tandem executables: "--name value" and "--flag"
// options, positional arguments, and a terminal progress line.
#ifndef TANDEM_CLI_UTIL_H_
#define TANDEM_CLI_UTIL_H_

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace tandem::cli {

class Args {
 public:
  // Parses argv[first..]; `valued` names take a value ("--iso 120" or "--iso=120"), `flags`
  // take none. Unknown options are an error naming them (with the closest known name), and
  // so is a valued option given twice.
  static absl::StatusOr<Args> Parse(int argc, char** argv, int first,
                                    const std::set<std::string>& valued,
                                    const std::set<std::string>& flags);

  bool Has(const std::string& name) const { return values_.count(name) || flags_.count(name); }
  std::optional<std::string> Get(const std::string& name) const;
  absl::StatusOr<double> GetDouble(const std::string& name, std::optional<double> def) const;
  absl::StatusOr<int64_t> GetInt(const std::string& name, std::optional<int64_t> def) const;
  const std::vector<std::string>& positional() const { return positional_; }

 private:
  std::map<std::string, std::string> values_;
  std::set<std::string> flags_;
  std::vector<std::string> positional_;
};

// Several surfaces in one pass: "--iso 60,120" as its values and the text of each (for
// output names). At most kMaxIsoValues, finite, no value twice; errors name the flag.
inline constexpr int kMaxIsoValues = 8;
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

// The known name closest to `name` for a "did you mean" hint: the nearest by edit
// distance (insertions, deletions, substitutions, transpositions) if at most 2 and
// unambiguous, else the only name that starts with `name`, else "".
std::string ClosestName(const std::string& name, const std::vector<std::string>& known);

// " (did you mean --NAME?)" for an unknown option, or "" when nothing is close.
std::string DidYouMean(const std::string& name, const std::vector<std::string>& known);

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

}  // namespace tandem::cli

#endif  // TANDEM_CLI_UTIL_H_
