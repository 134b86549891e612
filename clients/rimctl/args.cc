#include "rimctl/args.h"

#include <cmath>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace rim::rimctl {

absl::StatusOr<Args> Args::Parse(const std::vector<std::string>& words,
                                 const std::vector<FlagSpec>& specs) {
  Args args;
  bool flags_done = false;
  for (size_t i = 0; i < words.size(); ++i) {
    const std::string& word = words[i];
    if (flags_done || word == "-" || word.rfind("-", 0) != 0) {
      args.positional_.push_back(word);
      continue;
    }
    if (word == "--") {
      flags_done = true;
      continue;
    }
    if (word == "-h" || word == "--help") {
      args.help_ = true;
      continue;
    }
    if (word.rfind("--", 0) != 0) {
      return absl::InvalidArgumentError(absl::StrCat("unknown flag '", word, "'"));
    }
    std::string name = word.substr(2), value;
    const size_t eq = name.find('=');
    const bool inline_value = eq != std::string::npos;
    if (inline_value) {
      value = name.substr(eq + 1);
      name = name.substr(0, eq);
    }
    const FlagSpec* spec = nullptr;
    for (const FlagSpec& s : specs) {
      if (s.name == name) spec = &s;
    }
    if (spec == nullptr)
      return absl::InvalidArgumentError(absl::StrCat("unknown flag '--", name, "'"));
    if (spec->kind == FlagKind::kBool) {
      if (inline_value) {
        return absl::InvalidArgumentError(absl::StrCat("--", name, " takes no value"));
      }
      value = "true";
    } else if (!inline_value) {
      if (i + 1 >= words.size()) {
        return absl::InvalidArgumentError(absl::StrCat("--", name, " needs a value"));
      }
      value = words[++i];
    }
    std::vector<std::string>& slot = args.values_[name];
    if (spec->kind == FlagKind::kValue && !slot.empty()) {
      return absl::InvalidArgumentError(absl::StrCat("--", name, " given more than once"));
    }
    slot.push_back(value);
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
