#include "common/cli_flags.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <set>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "cli/cli_util.h"

namespace tandem::cli {

void FlagSet::Add(Flag flag) { flags_.push_back(std::move(flag)); }

void FlagSet::UseEnvironment(const std::string& prefix, const std::vector<std::string>& names) {
  for (Flag& f : flags_) {
    if (!names.empty() && std::find(names.begin(), names.end(), f.name) == names.end()) continue;
    std::string env = prefix + f.name;
    for (char& c : env) c = c == '-' ? '_' : absl::ascii_toupper(static_cast<unsigned char>(c));
    f.env = env;
  }
}

absl::Status FlagSet::Set(Flag& f, const std::string& value, const std::string& source) {
  bool ok = true;
  switch (f.kind) {
    case Kind::kString:
      *static_cast<std::string*>(f.var) = value;
      break;
    case Kind::kInt:
      ok = absl::SimpleAtoi(value, static_cast<int64_t*>(f.var));
      break;
    case Kind::kDouble: {
      double* d = static_cast<double*>(f.var);
      ok = absl::SimpleAtod(value, d) && std::isfinite(*d);
      break;
    }
    case Kind::kBool:
      ok = absl::SimpleAtob(value, static_cast<bool*>(f.var));
      break;
  }
  if (!ok) {
    return absl::InvalidArgumentError(
        absl::StrCat(source, ": cannot read '", value, "' as ",
                     f.kind == Kind::kInt    ? "an integer"
                     : f.kind == Kind::kBool ? "true/false"
                                             : "a number"));
  }
  f.set = true;
  return absl::OkStatus();
}

void FlagSet::AddString(const std::string& name, std::string* var, const std::string& value_name,
                        const std::string& help, bool required) {
  Add(Flag{name, value_name, help, *var, Kind::kString, var, required, false, ""});
}

void FlagSet::AddInt(const std::string& name, int64_t* var, const std::string& help) {
  Add(Flag{name, "N", help, absl::StrCat(*var), Kind::kInt, var, false, false, ""});
}

void FlagSet::AddDouble(const std::string& name, double* var, const std::string& help,
                        bool required) {
  Add(Flag{name, "X", help, absl::StrFormat("%g", *var), Kind::kDouble, var, required, false, ""});
}

void FlagSet::AddBool(const std::string& name, bool* var, const std::string& help) {
  Add(Flag{name, "", help, *var ? "true" : "false", Kind::kBool, var, false, false, ""});
}

FlagSet::Flag* FlagSet::Find(const std::string& name) {
  for (Flag& f : flags_) {
    if (f.name == name) return &f;
  }
  return nullptr;
}

bool FlagSet::IsSet(const std::string& name) const {
  for (const Flag& f : flags_) {
    if (f.name == name) return f.set;
  }
  return false;
}

absl::Status FlagSet::Parse(int argc, char** argv, int first) {
  for (Flag& f : flags_) {
    if (f.env.empty()) continue;
    if (const char* value = std::getenv(f.env.c_str()); value != nullptr) {
      if (absl::Status st = Set(f, value, f.env); !st.ok()) return st;
    }
  }
  std::set<std::string> on_command_line;  // valued flags seen, to refuse a repeat
  for (int i = first; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      help_requested_ = true;
      continue;
    }
    if (arg.rfind("--", 0) != 0) {
      positional_.push_back(arg);
      continue;
    }
    std::string name = arg.substr(2), value;
    bool has_value = false;
    if (size_t eq = name.find('='); eq != std::string::npos) {
      value = name.substr(eq + 1);
      name = name.substr(0, eq);
      has_value = true;
    }
    Flag* f = Find(name);
    if (f == nullptr) {
      std::vector<std::string> known;
      for (const Flag& k : flags_) known.push_back(k.name);
      return absl::InvalidArgumentError(absl::StrCat("unknown flag --", name,
                                                     cli::DidYouMean(name, known), " (see --help)"));
    }
    if (f->kind != Kind::kBool && !on_command_line.insert(f->name).second) {
      return absl::InvalidArgumentError(
          absl::StrCat("--", name, " given twice: give it once"));
    }
    if (f->kind == Kind::kBool && !has_value) {
      *static_cast<bool*>(f->var) = true;
      f->set = true;
      continue;
    }
    if (!has_value) {
      if (i + 1 >= argc) {
        return absl::InvalidArgumentError(absl::StrCat("--", name, " needs a value"));
      }
      value = argv[++i];
    }
    if (absl::Status st = Set(*f, value, "--" + name); !st.ok()) return st;
  }
  if (help_requested_) return absl::OkStatus();
  for (const Flag& f : flags_) {
    if (f.required && !f.set) {
      return absl::InvalidArgumentError(absl::StrCat("missing --", f.name, " (see --help)"));
    }
  }
  return absl::OkStatus();
}

std::string FlagSet::Help() const {
  std::string out = absl::StrCat(usage_, "\n\nflags:\n");
  for (const Flag& f : flags_) {
    std::string left = absl::StrCat("  --", f.name, f.value_name.empty() ? "" : " ", f.value_name);
    std::string def;
    if (f.required) {
      def = " (required)";
    } else if (f.kind == Kind::kString) {
      def = f.default_text.empty() ? " (default: none)" : absl::StrCat(" (default: ", f.default_text, ")");
    } else {
      def = absl::StrCat(" (default: ", f.default_text, ")");
    }
    if (!f.env.empty()) absl::StrAppend(&def, " [$", f.env, "]");
    absl::StrAppend(&out, absl::StrFormat("%-28s %s%s\n", left, f.help, def));
  }
  absl::StrAppend(&out, absl::StrFormat("%-28s %s\n", "  --help", "print this help and exit"));
  return out;
}

}  // namespace tandem::cli
