#include "rimctl/args.h"

#include <cmath>
#include <iterator>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "rim/base/flags.h"

namespace rim::rimctl {

absl::StatusOr<Args> Args::Parse(const std::vector<std::string>& words,
                                 const std::vector<FlagSpec>& specs) {
  Args args;
  CLI::App app("", "rimctl");
  // Positional words anywhere, "-" (stdin) among them; CLI11 ends flags at "--".
  app.add_option("WORDS", args.positional_);
  for (const FlagSpec& spec : specs) {
    std::vector<std::string>& slot = args.values_[spec.name];
    const std::string flag = "--" + spec.name;
    switch (spec.kind) {
      case FlagKind::kBool:
        app.add_flag_callback(flag, [&slot] { slot.push_back("true"); });
        break;
      case FlagKind::kValue:  // once: CLI11 refuses a second one
        app.add_option_function<std::string>(flag,
                                             [&slot](const std::string& v) { slot.push_back(v); });
        break;
      case FlagKind::kRepeated:
        app.add_option_function<std::vector<std::string>>(
               flag,
               [&slot](const std::vector<std::string>& v) {
                 slot.insert(slot.end(), v.begin(), v.end());
               })
            ->allow_extra_args(false);  // one value per flag
        break;
    }
  }
  const absl::Status parsed = cli::Parse(app, words);
  if (absl::IsCancelled(parsed)) {
    args.help_ = true;
  } else if (!parsed.ok()) {
    return parsed;
  }
  for (auto it = args.values_.begin(); it != args.values_.end();) {  // Has(): given
    it = it->second.empty() ? args.values_.erase(it) : std::next(it);
  }
  return args;
}

std::string Args::Get(const std::string& name, const std::string& fallback) const {
  auto it = values_.find(name);
  return it == values_.end() ? fallback : it->second.back();
}

std::vector<std::string> Args::GetAll(const std::string& name) const {
  auto it = values_.find(name);
  return it == values_.end() ? std::vector<std::string>() : it->second;
}

absl::StatusOr<double> Args::GetDouble(const std::string& name, double fallback, double min,
                                       double max) const {
  if (!Has(name)) return fallback;
  double v = 0;
  const std::string text = Get(name);
  if (!absl::SimpleAtod(text, &v) || !std::isfinite(v) || v < min || v > max) {
    return absl::InvalidArgumentError(
        absl::StrCat("--", name, " '", text, "' is not a number in [", min, ", ", max, "]"));
  }
  return v;
}

absl::StatusOr<long> Args::GetInt(const std::string& name, long fallback, long min,
                                  long max) const {
  if (!Has(name)) return fallback;
  long v = 0;
  const std::string text = Get(name);
  if (!absl::SimpleAtoi(text, &v) || v < min || v > max) {
    return absl::InvalidArgumentError(
        absl::StrCat("--", name, " '", text, "' is not an integer in [", min, ", ", max, "]"));
  }
  return v;
}

absl::StatusOr<FrameRange> ParseFrameRange(const std::string& text) {
  const std::vector<std::string> parts = absl::StrSplit(text, ':');
  FrameRange r;
  const bool ok = parts.size() == 2 && (parts[0].empty() || absl::SimpleAtoi(parts[0], &r.first)) &&
                  (parts[1].empty() || absl::SimpleAtoi(parts[1], &r.last)) && r.first >= 0 &&
                  (parts[1].empty() || r.last > r.first);
  if (!ok) {
    return absl::InvalidArgumentError(absl::StrCat(
        "--frames '", text, "' is not A:B with 0 <= A < B (either end may be left out)"));
  }
  if (parts[1].empty()) r.last = -1;
  return r;
}

absl::StatusOr<std::vector<double>> ParseNumberList(const std::string& flag,
                                                    const std::string& text, size_t count) {
  const std::vector<std::string> parts = absl::StrSplit(text, ',');
  std::vector<double> values(parts.size());
  bool ok = parts.size() == count;
  for (size_t i = 0; ok && i < parts.size(); ++i) {
    ok = absl::SimpleAtod(parts[i], &values[i]) && std::isfinite(values[i]);
  }
  if (!ok) {
    return absl::InvalidArgumentError(
        absl::StrCat("--", flag, " '", text, "' is not ", count, " comma-separated numbers"));
  }
  return values;
}

}  // namespace rim::rimctl
