// JSON documents (such as Replica's cam_params.json), parsed by nlohmann-json behind a Status API.
// Nesting is limited (kMaxJsonDepth) so hostile input cannot make a deep tree.
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

}  // namespace rim::io
