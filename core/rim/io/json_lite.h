// A small JSON parser for configuration files such as Replica's cam_params.json. It builds a
// tree of values; nesting is limited (kMaxJsonDepth) so hostile input cannot exhaust the stack.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace rim::io {

inline constexpr int kMaxJsonDepth = 64;

struct JsonValue {
  enum class Type { kNull, kBool, kNumber, kString, kArray, kObject };
  Type type = Type::kNull;
  bool boolean = false;
  double number = 0;
  std::string string;
  std::vector<JsonValue> items;                            // kArray
  std::vector<std::pair<std::string, JsonValue>> members;  // kObject, in file order

  // The member named `key` of an object (the first one if repeated), or nullptr.
  const JsonValue* Find(absl::string_view key) const;
};

// Parses one JSON document (RFC 8259; \u escapes outside ASCII become UTF-8). Errors name `path`
// and the line.
absl::StatusOr<JsonValue> ParseJson(absl::string_view text, const std::string& path);

}  // namespace rim::io
