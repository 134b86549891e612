// rimctl's command-line parsing: positional words and `--flag value` / `--flag=value` options,
// checked against the flags a command declares, so that a typo is an error naming the flag
// rather than a silently ignored word. CLI11 parses (rim/base/flags.h, as in every rim binary);
// the commands read the values through the typed getters below.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace rim::rimctl {

enum class FlagKind {
  kBool,      // --gradient
  kValue,     // --out FILE (given at most once)
  kRepeated,  // --set key=value (any number of times)
};

struct FlagSpec {
  std::string name;  // without the dashes
  FlagKind kind;
};

class Args {
 public:
  // Parses `words` (the command line after the program name). Flags may come before, between or
  // after positional words; "-" is a positional word (stdin), "--" ends flag parsing.
  // InvalidArgument naming the flag for an unknown flag, a missing value, a value given to a
  // boolean flag, or a single-valued flag given twice. -h and --help set help().
  static absl::StatusOr<Args> Parse(const std::vector<std::string>& words,
                                    const std::vector<FlagSpec>& specs);

  const std::vector<std::string>& positional() const { return positional_; }
  bool help() const { return help_; }
  bool Has(const std::string& name) const { return values_.count(name) > 0; }
  // The flag's (last) value, or `fallback` when it was not given.
  std::string Get(const std::string& name, const std::string& fallback = "") const;
  // Every value of a repeated flag, in order.
  std::vector<std::string> GetAll(const std::string& name) const;

  // Typed values; InvalidArgument naming the flag when the value does not parse or lies outside
  // [min, max].
  absl::StatusOr<double> GetDouble(const std::string& name, double fallback, double min,
                                   double max) const;
  absl::StatusOr<long> GetInt(const std::string& name, long fallback, long min, long max) const;

 private:
  std::vector<std::string> positional_;
  std::map<std::string, std::vector<std::string>> values_;
  bool help_ = false;
};

// "A:B" frame ranges as in rim_map: either end may be empty (A: to the end, :B from the start).
struct FrameRange {
  long first = 0;
  long last = -1;  // exclusive; -1: to the end
};
absl::StatusOr<FrameRange> ParseFrameRange(const std::string& text);

// Exactly `count` comma-separated finite numbers, e.g. "x0,y0,z0,x1,y1,z1,res" for --grid;
// InvalidArgument naming --flag otherwise.
absl::StatusOr<std::vector<double>> ParseNumberList(const std::string& flag,
                                                    const std::string& text, size_t count);

}  // namespace rim::rimctl
