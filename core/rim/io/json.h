// JSON documents (such as Replica's cam_params.json), parsed by nlohmann-json behind a Status API,
// and the JSON files rim writes (rim_eval --json, rim_map's timing.json, run.json, probe.json),
// built as nlohmann::ordered_json and written by DumpJson. Nesting is limited (kMaxJsonDepth) so
// hostile input cannot make a deep tree.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace rim::io {

inline constexpr int kMaxJsonDepth = 64;

// Parses one JSON document (RFC 8259, UTF-8). Errors (InvalidArgument) name `path` and the line:
// "cam.json:2: bad JSON: ...".
absl::StatusOr<nlohmann::json> ParseJson(absl::string_view text, const std::string& path);

// `value` as JSON text ending in a newline: objects and arrays nested `inline_depth` levels or
// deeper, and arrays of numbers, strings, booleans and nulls at any depth, on one line; the
// others one member a line, indented by two spaces. Separators are ", " and ": ". Strings are
// escaped by nlohmann (every control character too), and invalid UTF-8 is replaced by U+FFFD
// rather than thrown on.
std::string DumpJson(const nlohmann::ordered_json& value, int inline_depth = 1);

// `v` rounded to `decimals` places (written as the shortest decimal that reads back the same:
// 20.0, 0.1235), or null when it is not finite, as JSON has no NaN or infinity.
nlohmann::ordered_json JsonNumber(double v, int decimals);

}  // namespace rim::io
