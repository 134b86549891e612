#include "rim/io/json.h"

#include <algorithm>
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

}  // namespace

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
