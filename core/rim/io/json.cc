#include "rim/io/json.h"

#include <algorithm>
#include <cmath>
#include <cstddef>

#include "absl/strings/str_cat.h"

namespace rim::io {
namespace {

// Thrown from the parser callback to stop at the first value nested too deep.
struct TooDeep {};

int LineAt(absl::string_view text, size_t byte) {
  const size_t end = std::min(byte, text.size());
  return 1 + static_cast<int>(std::count(text.begin(), text.begin() + end, '\n'));
}

// nlohmann's messages start with "[json.exception.parse_error.N] parse error at line L, column C:
// "; the line is ours to say, so keep only what follows.
absl::string_view Reason(absl::string_view what) {
  const size_t colon = what.find(": ");
  return colon == absl::string_view::npos ? what : what.substr(colon + 2);
}

using ordered_json = nlohmann::ordered_json;

// nlohmann's own text for a number, string, boolean or null (a key too), escaped.
std::string DumpScalar(const ordered_json& v) {
  return v.dump(-1, ' ', false, ordered_json::error_handler_t::replace);
}

bool IsScalarArray(const ordered_json& v) {
  return v.is_array() &&
         std::none_of(v.begin(), v.end(), [](const ordered_json& e) { return e.is_structured(); });
}

void Dump(const ordered_json& v, int depth, int inline_depth, std::string* out) {
  if (!v.is_structured()) {
    *out += DumpScalar(v);
    return;
  }
  const bool one_line = depth >= inline_depth || IsScalarArray(v) || v.empty();
  const std::string pad(one_line ? 0 : 2 * (depth + 1), ' ');
  const char* sep = one_line ? ", " : ",\n";
  *out += v.is_object() ? "{" : "[";
  if (!one_line) *out += "\n";
  bool first = true;
  for (auto it = v.begin(); it != v.end(); ++it) {
    if (!first) *out += sep;
    first = false;
    *out += pad;
    if (v.is_object()) absl::StrAppend(out, DumpScalar(it.key()), ": ");
    Dump(it.value(), depth + 1, inline_depth, out);
  }
  if (!one_line) absl::StrAppend(out, "\n", std::string(2 * depth, ' '));
  *out += v.is_object() ? "}" : "]";
}

}  // namespace

std::string DumpJson(const nlohmann::ordered_json& value, int inline_depth) {
  std::string out;
  Dump(value, 0, inline_depth, &out);
  return out + "\n";
}

nlohmann::ordered_json JsonNumber(double v, int decimals) {
  if (!std::isfinite(v)) return nullptr;
  const double scale = std::pow(10.0, decimals);
  const double rounded = std::round(v * scale) / scale;
  // Too large to round (|v| * scale past 2^53): it has no digits there to drop.
  return std::isfinite(rounded) && std::abs(v * scale) < 9e15 ? rounded : v;
}

absl::StatusOr<nlohmann::json> ParseJson(absl::string_view text, const std::string& path) {
  const auto limit_depth = [](int depth, nlohmann::json::parse_event_t, nlohmann::json&) {
    if (depth > kMaxJsonDepth) throw TooDeep{};
    return true;
  };
  try {
    return nlohmann::json::parse(text.begin(), text.end(), limit_depth);
  } catch (const nlohmann::json::parse_error& e) {
    // e.byte counts from 1; it points at or just past the offending character.
    return absl::InvalidArgumentError(absl::StrCat(path, ":", LineAt(text, e.byte ? e.byte - 1 : 0),
                                                   ": bad JSON: ", Reason(e.what())));
  } catch (const TooDeep&) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": bad JSON: nested deeper than ", kMaxJsonDepth, " levels"));
  } catch (const nlohmann::json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": bad JSON: ", Reason(e.what())));
  }
}

}  // namespace rim::io
