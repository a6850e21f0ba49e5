#include "apps/common/flags.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>

#include <CLI/CLI.hpp>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/status_macros.h"

namespace tandem::cli {

void FlagSet::Add(Flag flag) { flags_.push_back(std::move(flag)); }

void FlagSet::AddString(const std::string& name, std::string* var, const std::string& value_name,
                        const std::string& help, bool required) {
  Add(Flag{name, value_name, help, *var, Kind::kString, var, required, false, ""});
}

void FlagSet::AddInt(const std::string& name, int64_t* var, const std::string& help,
                     const std::string& value_name) {
  Add(Flag{name, value_name, help, absl::StrCat(*var), Kind::kInt, var, false, false, ""});
}

void FlagSet::AddDouble(const std::string& name, double* var, const std::string& help,
                        bool required, const std::string& value_name) {
  Add(Flag{name, value_name, help, absl::StrFormat("%g", *var), Kind::kDouble, var, required,
           false, ""});
}

void FlagSet::AddBool(const std::string& name, bool* var, const std::string& help) {
  Add(Flag{name, "", help, *var ? "true" : "false", Kind::kBool, var, false, false, ""});
}

void FlagSet::AddSecret(const std::string& name, std::string* var, const std::string& value_name,
                        const std::string& env, const std::string& help) {
  secret_files_.emplace_back();
  Flag value{name, value_name,
             absl::StrCat(help, " (on the command line other users can read it: prefer --",
                          name, "-file or $", env, ")"),
             "", Kind::kString, var, false, false, env};
  value.secret_file = &secret_files_.back();
  Add(std::move(value));
  Add(Flag{name + "-file", "FILE",
           absl::StrCat("read --", name, " from FILE (its first line that is not blank or a "
                        "#comment)"),
           "", Kind::kString, &secret_files_.back(), false, false, ""});
}

void FlagSet::SetDefaultText(const std::string& name, const std::string& text) {
  if (Flag* f = Find(name)) f->default_text = text;
}

void FlagSet::UseEnvironment(const std::string& prefix, const std::vector<std::string>& names) {
  for (Flag& f : flags_) {
    if (!names.empty() && std::find(names.begin(), names.end(), f.name) == names.end()) continue;
    if (f.secret_file != nullptr) continue;  // its own variable
    std::string env = prefix + f.name;
    for (char& c : env) c = c == '-' ? '_' : absl::ascii_toupper(static_cast<unsigned char>(c));
    f.env = env;
  }
}

absl::Status FlagSet::Set(Flag& f, const std::string& value, const std::string& source) {
  bool ok = true;
  const char* expected = "a number";
  switch (f.kind) {
    case Kind::kString:
      *static_cast<std::string*>(f.var) = value;
      break;
    case Kind::kInt:
      ok = absl::SimpleAtoi(value, static_cast<int64_t*>(f.var));
      expected = "an integer";
      break;
    case Kind::kDouble: {
      double* d = static_cast<double*>(f.var);
      ok = absl::SimpleAtod(value, d) && std::isfinite(*d);
      break;
    }
    case Kind::kBool:
      ok = absl::SimpleAtob(value, static_cast<bool*>(f.var));
      expected = "true or false";
      break;
  }
  if (!ok) {
    return absl::InvalidArgumentError(absl::StrCat(source, ": '", value, "' is not ", expected));
  }
  f.set = true;
  return absl::OkStatus();
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
  // CLI11 collects every flag's raw values (all of them: a repeat is our error, with both
  // values) and, for flags not on the command line, its environment variable's.
  CLI::App app;
  app.set_help_flag();  // --help and -h are ours, below
  app.allow_extras();   // positional arguments and unknown options: checked below
  std::vector<std::vector<std::string>> raw(flags_.size());
  std::vector<CLI::Option*> options(flags_.size());
  for (size_t i = 0; i < flags_.size(); ++i) {
    const Flag& f = flags_[i];
    CLI::Option* o =
        f.kind == Kind::kBool
            ? app.add_flag("--" + f.name, raw[i], f.help)
            : app.add_option("--" + f.name, raw[i], f.help)->expected(1)->allow_extra_args(false);
    o->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
    if (!f.env.empty()) o->envname(f.env);
    options[i] = o;
  }
  std::vector<std::string> args;
  bool after_dashes = false;
  std::vector<std::string> literal;  // after "--": positional whatever they look like
  for (int i = first; i < argc; ++i) {
    const std::string a = argv[i];
    if (after_dashes) {
      literal.push_back(a);
    } else if (a == "--") {
      after_dashes = true;
    } else if (a == "--help" || a == "-h") {
      help_requested_ = true;
    } else {
      args.push_back(a);
    }
  }
  std::vector<std::string> reversed(args.rbegin(), args.rend());  // CLI11's order
  try {
    app.parse(reversed);
  } catch (const CLI::ArgumentMismatch& e) {
    // A valued flag last on the line, with nothing after it.
    for (const Flag& f : flags_) {
      if (std::string(e.what()).rfind("--" + f.name + ":", 0) == 0) {
        return absl::InvalidArgumentError(absl::StrCat("--", f.name, " needs a value"));
      }
    }
    return absl::InvalidArgumentError(e.what());
  } catch (const CLI::ParseError& e) {
    return absl::InvalidArgumentError(e.what());
  }
  std::vector<std::string> known;
  for (const Flag& f : flags_) known.push_back(f.name);
  for (const std::string& extra : app.remaining()) {
    if (extra.size() > 1 && extra[0] == '-' && !absl::ascii_isdigit(extra[1]) && extra[1] != '.') {
      std::string name = extra.substr(extra.find_first_not_of('-'));
      name = name.substr(0, name.find('='));
      return absl::InvalidArgumentError(
          absl::StrCat("unknown option --", name, DidYouMean(name, known), " (see --help)"));
    }
    positional_.push_back(extra);
  }
  positional_.insert(positional_.end(), literal.begin(), literal.end());
  for (size_t i = 0; i < flags_.size(); ++i) {
    Flag& f = flags_[i];
    const std::vector<std::string>& values = raw[i];
    if (values.empty()) continue;
    if (values.size() > 1 && f.kind != Kind::kBool) {
      return absl::InvalidArgumentError(absl::StrCat("--", f.name, " given twice ('", values[0],
                                                     "' and '", values[1], "'): give it once"));
    }
    // From the command line, unless only the variable can have given it.
    bool on_line = false;
    for (const std::string& a : args) {
      on_line |= a == "--" + f.name || a.rfind("--" + f.name + "=", 0) == 0;
    }
    const std::string source = on_line || f.env.empty() ? "--" + f.name : f.env;
    TANDEM_RETURN_IF_ERROR(Set(f, values.back(), source));
  }
  if (help_requested_) return absl::OkStatus();
  const std::string program = first > 0 && argc > 0 ? argv[0] : "";
  TANDEM_RETURN_IF_ERROR(ResolveSecrets(args, program.substr(program.rfind('/') + 1)));
  for (const Flag& f : flags_) {
    if (f.required && !f.set) {
      return absl::InvalidArgumentError(absl::StrCat("missing --", f.name, " (see --help)"));
    }
  }
  return absl::OkStatus();
}

absl::Status FlagSet::ResolveSecrets(const std::vector<std::string>& args,
                                     const std::string& program) {
  auto on_line = [&](const std::string& name) {
    for (const std::string& a : args) {
      if (a == "--" + name || a.rfind("--" + name + "=", 0) == 0) return true;
    }
    return false;
  };
  for (Flag& f : flags_) {
    if (f.secret_file == nullptr) continue;
    const std::string& file = *f.secret_file;
    if (!file.empty()) {
      if (on_line(f.name)) {
        return absl::InvalidArgumentError(
            absl::StrCat("--", f.name, " and --", f.name, "-file: give one of them"));
      }
      std::ifstream in(file);
      if (!in) {
        return absl::InvalidArgumentError(absl::StrCat("--", f.name, "-file ", file,
                                                       ": cannot open (", std::strerror(errno),
                                                       ")"));
      }
      std::string line, value;
      while (value.empty() && std::getline(in, line)) {
        const absl::string_view v = absl::StripAsciiWhitespace(line);
        if (!v.empty() && v[0] != '#') value = std::string(v);
      }
      if (value.empty()) {
        return absl::InvalidArgumentError(absl::StrCat(
            "--", f.name, "-file ", file, ": no value in it (blank lines and #comments only)"));
      }
      *static_cast<std::string*>(f.var) = value;
      f.set = true;
    } else if (on_line(f.name)) {
      warnings_.push_back(absl::StrCat(
          "--", f.name, " on the command line can be read by every user of this machine (ps); "
          "use --", f.name, "-file FILE or $", f.env, " instead"));
      absl::FPrintF(stderr, "%s: warning: %s\n", program.empty() ? "tandem" : program,
                    warnings_.back());
    }
  }
  return absl::OkStatus();
}

namespace {

// `text` wrapped to lines of at most `width` characters, every line after the first
// indented by `indent` spaces.
std::string Wrap(const std::string& text, size_t indent, size_t width) {
  std::string out, line;
  size_t begin = 0;
  while (begin < text.size()) {
    size_t end = text.find(' ', begin);
    if (end == std::string::npos) end = text.size();
    const std::string word = text.substr(begin, end - begin);
    if (!line.empty() && line.size() + 1 + word.size() > width) {
      absl::StrAppend(&out, line, "\n", std::string(indent, ' '));
      line.clear();
    }
    absl::StrAppend(&line, line.empty() ? "" : " ", word);
    begin = end + 1;
  }
  return out + line;
}

}  // namespace

std::string FlagSet::Help() const {
  constexpr size_t kLeft = 28, kWidth = 100;
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
    if (left.size() >= kLeft) {
      absl::StrAppend(&out, left, "\n", std::string(kLeft + 1, ' '));
    } else {
      absl::StrAppend(&out, absl::StrFormat("%-28s ", left));
    }
    // The help wrapped; the default and the variable (searched for by scripts and tests)
    // never split: on the last line if they fit, else on their own.
    std::string text = Wrap(f.help, kLeft + 1, kWidth - kLeft - 1);
    const size_t last = text.rfind('\n');
    const size_t last_len = last == std::string::npos ? text.size() : text.size() - last - 1 - (kLeft + 1);
    if (last_len + def.size() > kWidth - kLeft - 1) {
      absl::StrAppend(&text, "\n", std::string(kLeft + 1, ' '), def.substr(1));
    } else {
      absl::StrAppend(&text, def);
    }
    absl::StrAppend(&out, text, "\n");
  }
  absl::StrAppend(&out, absl::StrFormat("%-28s %s\n", "  --help", "print this help and exit"));
  if (!epilog_.empty()) absl::StrAppend(&out, "\n", epilog_);
  return out;
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

}  // namespace tandem::cli
