// FlagSet: the command line of all three programs (tandem, tandem-client, tandem-server),
// on CLI11 (Debian's libcli11-dev).
//
// Flags are registered with a pointer to their variable, whose current value is the
// default; Help() prints every flag with that default, so --help cannot drift from the
// code. CLI11 reads the command line: --name value, --name=value, --name alone for
// booleans (--name=false too), and anything else as a positional argument (everything
// after "--" as well). With UseEnvironment, a flag may also come from a variable
// PREFIX + NAME (upper case, '-' -> '_', e.g. TANDEM_MAX_SESSIONS): the command line beats
// the variable, which beats the default.
//
// Secrets (tokens) are kept off the command line, which every user of the machine can read
// (ps, /proc/PID/cmdline): AddSecret accepts them from a file or a variable as well, and
// warns when one is given on the command line all the same.
//
// The values are converted here rather than by CLI11, so that every program words its
// mistakes the same way: an unknown option names the closest real one ("did you mean"), a
// valued flag given twice is an error that shows both values (never "the last one wins"),
// and a malformed number names the flag (or the variable) and the text.
#ifndef TANDEM_APPS_COMMON_FLAGS_H_
#define TANDEM_APPS_COMMON_FLAGS_H_

#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include "absl/status/status.h"

namespace tandem::cli {

class FlagSet {
 public:
  // `usage`: the first help line(s), e.g. "usage: tandem-server [flags]\n<what it does>".
  explicit FlagSet(std::string usage) : usage_(std::move(usage)) {}

  // `value_name` shows in the help ("--input FILE"); `required` flags have no default.
  void AddString(const std::string& name, std::string* var, const std::string& value_name,
                 const std::string& help, bool required = false);
  void AddInt(const std::string& name, int64_t* var, const std::string& help,
              const std::string& value_name = "N");
  void AddDouble(const std::string& name, double* var, const std::string& help,
                 bool required = false, const std::string& value_name = "X");
  void AddBool(const std::string& name, bool* var, const std::string& help);
  // A secret: --NAME VALUE, --NAME-file FILE (the first line of FILE that is neither blank
  // nor a #comment, without surrounding whitespace) or the variable `env`. The command line
  // beats the variable; --NAME and --NAME-file together are an error. --NAME on the command
  // line still works, but Parse warns on stderr that other users can read it there.
  void AddSecret(const std::string& name, std::string* var, const std::string& value_name,
                 const std::string& env, const std::string& help);
  // What the help shows as the default of `name`, when the variable's value is not it
  // (a default worked out after parsing, e.g. "0.2 x the smallest spacing").
  void SetDefaultText(const std::string& name, const std::string& text);
  // Text printed after the flags (exit codes, notes).
  void SetEpilog(std::string epilog) { epilog_ = std::move(epilog); }
  // Reads PREFIX + NAME variables for the flags named (all flags if `names` is empty; a
  // secret keeps its own variable). Call after the Add* calls.
  void UseEnvironment(const std::string& prefix, const std::vector<std::string>& names = {});

  // Parses argv[first..argc) and the environment (see UseEnvironment). InvalidArgument
  // names the flag or variable: unknown flag, missing or malformed value, a valued flag
  // given twice, missing required flag. --help / -h sets help_requested() and skips the
  // required-flag check.
  absl::Status Parse(int argc, char** argv, int first = 1);

  bool help_requested() const { return help_requested_; }
  // What Parse warned about on stderr (a secret given on the command line).
  const std::vector<std::string>& warnings() const { return warnings_; }
  bool IsSet(const std::string& name) const;
  const std::vector<std::string>& positional() const { return positional_; }
  std::string Help() const;

 private:
  enum class Kind { kString, kInt, kDouble, kBool };
  struct Flag {
    std::string name, value_name, help, default_text;
    Kind kind;
    void* var;
    bool required = false;
    bool set = false;
    std::string env;  // environment variable name, "" = none
    std::string* secret_file = nullptr;  // a secret's --NAME-file value
  };
  Flag* Find(const std::string& name);
  void Add(Flag flag);
  // Stores `value` into the flag's variable; `source` names it in the error.
  absl::Status Set(Flag& flag, const std::string& value, const std::string& source);

  // After the values are set: reads the secrets' files, warns about the command line.
  absl::Status ResolveSecrets(const std::vector<std::string>& args, const std::string& program);

  std::string usage_, epilog_;
  std::vector<Flag> flags_;
  std::deque<std::string> secret_files_;  // (stable addresses for the flags' variables)
  std::vector<std::string> warnings_;
  std::vector<std::string> positional_;
  bool help_requested_ = false;
};

// The known name closest to `name` for a "did you mean" hint: the nearest by edit
// distance (insertions, deletions, substitutions, transpositions) if at most 2 and
// unambiguous, else the only name that starts with `name`, else "".
std::string ClosestName(const std::string& name, const std::vector<std::string>& known);

// " (did you mean --NAME?)" for an unknown option, or "" when nothing is close.
std::string DidYouMean(const std::string& name, const std::vector<std::string>& known);

}  // namespace tandem::cli

#endif  // TANDEM_APPS_COMMON_FLAGS_H_
