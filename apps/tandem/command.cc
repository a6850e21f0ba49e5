// How the subcommands of `tandem` report mistakes and failures, and their shared parsing.
#include "command.h"

#include <cstdio>
#include <fstream>
#include <string>

#include "absl/strings/str_cat.h"
#include "apps/common/cli_util.h"

namespace tandem::app {

int Fail(const absl::Status& st) {
  std::fprintf(stderr, "tandem: %s\n", std::string(st.message()).c_str());
  return cli::kExitFailure;
}

int Usage(const absl::Status& st) {
  std::fprintf(stderr, "tandem: %s\n", std::string(st.message()).c_str());
  return cli::kExitUsage;
}

int FailWriting(const absl::Status& st) {
  return st.code() == absl::StatusCode::kInvalidArgument ||
                 st.code() == absl::StatusCode::kUnimplemented
             ? Usage(st)
             : Fail(st);
}

int ParseOrExit(cli::FlagSet& flags, int argc, char** argv) {
  absl::Status st = flags.Parse(argc, argv, 2);
  if (flags.help_requested()) {
    std::fputs(flags.Help().c_str(), stdout);
    return 0;
  }
  if (!st.ok()) return Usage(st);
  return -1;
}

absl::Status WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
  out.close();
  if (!out) return absl::InternalError(absl::StrCat(path, ": cannot write"));
  return absl::OkStatus();
}

}  // namespace tandem::app
