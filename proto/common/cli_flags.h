// FlagSet: the small command-line parser of tandem-server and tandem-client.
//
// Flags are registered with a pointer to their variable, whose current value is the
// default; Help() prints every flag with that default, so --help cannot drift from the
// code. Accepted forms: --name value, --name=value, and --name alone for booleans.
// Anything that does not start with "--" is a positional argument.
// With UseEnvironment, a flag may also come from a variable PREFIX + NAME (upper case,
// '-' → '_', e.g. TANDEM_MAX_SESSIONS): the command line beats the variable, which beats
// the default.
#ifndef TANDEM_PROTO_COMMON_CLI_FLAGS_H_
#define TANDEM_PROTO_COMMON_CLI_FLAGS_H_

#include <cstdint>
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
  void AddInt(const std::string& name, int64_t* var, const std::string& help);
  void AddDouble(const std::string& name, double* var, const std::string& help,
                 bool required = false);
  void AddBool(const std::string& name, bool* var, const std::string& help);
  // Reads PREFIX + NAME variables for the flags named (all flags if `names` is empty).
  // Call after the Add* calls.
  void UseEnvironment(const std::string& prefix, const std::vector<std::string>& names = {});

  // Parses the environment (see UseEnvironment), then argv[first..argc). InvalidArgument
  // names the flag or variable: unknown flag, missing or malformed value, missing
  // required flag. --help / -h sets help_requested() and
  // skips the required-flag check.
  absl::Status Parse(int argc, char** argv, int first = 1);

  bool help_requested() const { return help_requested_; }
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
  };
  Flag* Find(const std::string& name);
  void Add(Flag flag);
  // Stores `value` into the flag's variable; `source` names it in the error.
  absl::Status Set(Flag& flag, const std::string& value, const std::string& source);

  std::string usage_;
  std::vector<Flag> flags_;
  std::vector<std::string> positional_;
  bool help_requested_ = false;
};

}  // namespace tandem::cli

#endif  // TANDEM_PROTO_COMMON_CLI_FLAGS_H_
