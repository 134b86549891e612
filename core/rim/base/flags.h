// rim's one way to read a command line: CLI11 (Debian's libcli11-dev, header-only), and the few
// conventions every rim binary keeps on top of it (docs/clients.md, "Command lines: one flag
// library"). rim_core links CLI11 for every binary, the server's included.
//
//   CLI::App app;
//   rim::cli::SetHelp(app, "usage: rim_x DATASET --out DIR [--voxel M]", "What it does.");
//   app.add_option("--voxel", voxel, "voxel size in metres (default 0.1)")
//       ->type_name("M")
//       ->transform(rim::cli::NumberIn(1e-3, 10, true, [](const std::string& v) {
//         return "--voxel must be in [0.001, 10], got '" + v + "'";
//       }));
//   const absl::Status parsed = rim::cli::Parse(app, argc, argv);
//   // OK; Cancelled: -h/--help was asked, print app.help() and exit 0; InvalidArgument: a usage
//   // error whose message names the flag, exit 2.
//
// The conventions:
//   - `--flag value` and `--flag=value` alike; a switch (add_flag) is given alone ("--x takes no
//     value"); "--" ends the flags;
//   - usage errors read "unknown flag '--x'", "unexpected argument 'x'", "--x needs a value",
//     "--x given more than once" (options that keep their last value instead say
//     ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast)), or what a check below says;
//   - numbers are read as rim always read them (absl::SimpleAtoi / SimpleAtod: decimal only, so
//     "010" is ten, where CLI11 alone would read octal eight) and reach CLI11 in plain decimal:
//     attach the checks below with ->transform(), which lets them rewrite the text (->check()
//     would hand CLI11 the text as given);
//   - a check's message is printed as it is: it names the flag itself, in a sentence.
#pragma once

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace rim::cli {

// A usage error whose message is printed as it is. Thrown from the checks below or from an
// option's callback (add_option_function): CLI11 2.1 wraps only its own ValidationError into
// "NAME: message", so this one reaches Parse unchanged.
class UsageError : public CLI::ParseError {
 public:
  explicit UsageError(std::string message)
      : CLI::ParseError("UsageError", std::move(message), CLI::ExitCodes::ValidationError) {}
};

// The message for a bad value TEXT of one flag.
using Message = std::function<std::string(const std::string& text)>;

// A check on a flag's text before CLI11 converts it (attach with ->transform()): ACCEPT(text) may
// rewrite the text and returns false for a bad value, whose usage error is then MESSAGE(text).
inline CLI::Validator Check(std::function<bool(std::string&)> accept, Message message) {
  return CLI::Validator(
      [accept = std::move(accept), message = std::move(message)](std::string& text) {
        const std::string given = text;
        if (!accept(text)) throw UsageError(message(given));
        return std::string();
      },
      /*validator_desc=*/"");
}

// An integer in [lo, hi], read by absl::SimpleAtoi.
template <typename T>
CLI::Validator IntegerIn(T lo, T hi, Message message) {
  static_assert(std::is_integral_v<T>);
  return Check(
      [lo, hi](std::string& text) {
        T v{};
        if (!absl::SimpleAtoi(text, &v) || v < lo || v > hi) return false;
        text = std::to_string(v);
        return true;
      },
      std::move(message));
}

// A finite number in [lo, hi] ((lo, hi] without LO_INCLUSIVE), read by absl::SimpleAtod.
inline CLI::Validator NumberIn(double lo, double hi, bool lo_inclusive, Message message) {
  return Check(
      [lo, hi, lo_inclusive](std::string& text) {
        double v = 0;
        if (!absl::SimpleAtod(text, &v) || !std::isfinite(v) || v < lo || v > hi ||
            (!lo_inclusive && v == lo))
          return false;
        char exact[32];
        std::snprintf(exact, sizeof exact, "%.17g", v);
        text = exact;
        return true;
      },
      std::move(message));
}

// Any finite number.
inline CLI::Validator Finite(Message message) {
  return NumberIn(-std::numeric_limits<double>::max(), std::numeric_limits<double>::max(), true,
                  std::move(message));
}

// `--frames A:B`: frames A to B, B excluded, either side left out keeps *FIRST or *LAST as it
// is (the caller's defaults: 0 and -1 for "to the end"). A usage error names the flag; the last
// one given counts.
inline CLI::Option* AddFrameRange(CLI::App& app, long* first, long* last) {
  return app
      .add_option_function<std::string>(
          "--frames",
          [first, last](const std::string& range) {
            std::vector<std::string> parts = absl::StrSplit(range, ':');
            if (parts.size() != 2 || (!parts[0].empty() && !absl::SimpleAtoi(parts[0], first)) ||
                (!parts[1].empty() && !absl::SimpleAtoi(parts[1], last)) || *first < 0)
              throw UsageError(absl::StrCat("--frames '", range, "' is not A:B"));
          },
          "frames A to B (B excluded; either may be left out: all by default)")
      ->type_name("A:B")
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
}

// Help as rim writes it: SYNOPSIS (the "usage:" lines) and DESCRIPTION first, then CLI11's list
// of positionals and options, each with its description, then the app's footer if it has one.
class HelpFormatter : public CLI::Formatter {
 public:
  HelpFormatter(std::string synopsis, std::string description)
      : synopsis_(std::move(synopsis)), description_(std::move(description)) {}
  std::string make_description(const CLI::App*) const override { return ""; }
  std::string make_usage(const CLI::App*, std::string) const override {
    std::string out = synopsis_ + "\n";
    if (!description_.empty()) out += "\n" + description_ + "\n";
    return out;
  }

 private:
  std::string synopsis_, description_;
};

inline void SetHelp(CLI::App& app, std::string synopsis, std::string description = "",
                    std::size_t column_width = 24) {
  auto formatter = std::make_shared<HelpFormatter>(std::move(synopsis), std::move(description));
  formatter->column_width(column_width);
  app.formatter(formatter);
  app.set_help_flag("-h,--help", "print this help and exit");
}

namespace internal {

// The flag's name in CLI11's "NAME: ..." messages.
inline std::string NameBefore(const std::string& what, const std::string& tail) {
  const size_t colon = what.find(": ");
  if (colon == std::string::npos || what.find(tail, colon) == std::string::npos) return "";
  return what.substr(0, colon);
}

inline absl::Status Translate(const CLI::ParseError& e) {
  const std::string what = e.what();
  if (dynamic_cast<const CLI::ArgumentMismatch*>(&e) != nullptr) {
    // CLI11 2.1: "NAME: 1 required TYPE missing", "NAME: At Most 1 required but received 2".
    if (std::string name = NameBefore(what, " missing"); !name.empty())
      return absl::InvalidArgumentError(absl::StrCat(name, " needs a value"));
    if (std::string name = NameBefore(what, "At Most 1 required"); !name.empty())
      return absl::InvalidArgumentError(absl::StrCat(name, " given more than once"));
    // "NAME was given a disallowed flag override" (NAME without its dashes).
    if (const size_t at = what.find(" was given a disallowed flag override");
        at != std::string::npos) {
      const std::string name = what.substr(0, at);
      return absl::InvalidArgumentError(
          absl::StrCat(name.rfind("-", 0) == 0 ? "" : "--", name, " takes no value"));
    }
  }
  return absl::InvalidArgumentError(what);
}

// After a parse with extras allowed: the first unknown flag, else the first stray argument. CLI11
// keeps the "--" that ends the flags among them.
inline absl::Status Leftovers(std::vector<std::string> left) {
  left.erase(std::remove(left.begin(), left.end(), "--"), left.end());
  for (const std::string& word : left) {
    if (word.size() > 1 && word[0] == '-') {
      return absl::InvalidArgumentError(
          absl::StrCat("unknown flag '", word.substr(0, word.find('=')), "'"));
    }
  }
  if (!left.empty())
    return absl::InvalidArgumentError(absl::StrCat("unexpected argument '", left.front(), "'"));
  return absl::OkStatus();
}

}  // namespace internal

// Parses ARGS (the words after the program's name) into APP. OK; Cancelled when -h/--help was
// asked (print app.help()); InvalidArgument with a message that names the bad flag or argument.
// With LEFT, the words APP does not know (say, after a prefix_command()'s first positional) go
// there instead of being usage errors.
inline absl::Status Parse(CLI::App& app, std::vector<std::string> args,
                          std::vector<std::string>* left = nullptr) {
  app.allow_extras();  // worded by Leftovers
  for (CLI::Option* opt : app.get_options()) {
    if (opt->get_expected_max() == 0) opt->disable_flag_override();  // a switch takes no value
  }
  std::reverse(args.begin(), args.end());  // CLI11's vector form takes them last first
  try {
    app.parse(args);
  } catch (const CLI::CallForHelp&) {
    return absl::CancelledError("help");
  } catch (const CLI::CallForAllHelp&) {
    return absl::CancelledError("help");
  } catch (const CLI::ParseError& e) {
    return internal::Translate(e);
  }
  if (left != nullptr) {
    *left = app.remaining();
    return absl::OkStatus();
  }
  return internal::Leftovers(app.remaining());
}

inline absl::Status Parse(CLI::App& app, int argc, const char* const* argv) {
  if (app.get_name().empty() && argc > 0) app.name(argv[0]);
  return Parse(app, std::vector<std::string>(argv + (argc > 0 ? 1 : 0), argv + argc));
}

}  // namespace rim::cli
