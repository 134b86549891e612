// File-system and text helpers shared by the dataset readers and writers: whole-file reads with a
// size cap, plain writes, directory listings in natural order, and line-oriented number parsing
// whose errors name the file and line.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace rim::io {

// Largest file any reader loads: bigger files are rejected instead of read.
inline constexpr uint64_t kMaxInputFileBytes = uint64_t{1} << 31;  // 2 GiB

// Reads a whole file. NotFound if it does not exist; FailedPrecondition if it is larger than
// `max_bytes`; DataLoss on read errors. Messages start with the path.
absl::StatusOr<std::string> ReadFileToString(const std::string& path,
                                             uint64_t max_bytes = kMaxInputFileBytes);

// Writes (creates or truncates) a file with `data`. Errors name the path.
absl::Status WriteStringToFile(const std::string& path, absl::string_view data);

bool IsDirectory(const std::string& path);
bool IsRegularFile(const std::string& path);

// "a/b" from "a" and "b" (no separator doubling).
std::string JoinPath(const std::string& dir, const std::string& name);

// Orders names with digit runs compared as numbers ("frame2" < "frame10"); ties fall back to
// plain string order so the order is total.
bool NaturalLess(absl::string_view a, absl::string_view b);

// Names (not paths) of the regular files in `dir` that start with `prefix` and end with
// `suffix`, in natural order. An unreadable or missing directory gives an empty list.
std::vector<std::string> ListFiles(const std::string& dir, absl::string_view prefix,
                                   absl::string_view suffix);

// One line of a text file, with its 1-based line number; '\r' and surrounding whitespace removed.
struct TextLine {
  int number = 0;
  absl::string_view text;
};

// Splits `data` into lines, dropping empty (whitespace-only) lines and, if `comment` is non-zero,
// lines whose first non-blank character is `comment`. The views point into `data`.
std::vector<TextLine> SplitLines(absl::string_view data, char comment = 0);

// Parses every token of `text` (separated by spaces, tabs or commas) as a double; "nan" and "inf"
// parse. Errors name `path`, `line` and the offending token.
absl::StatusOr<std::vector<double>> ParseNumbers(absl::string_view text, const std::string& path,
                                                 int line);

// ParseNumbers, then checks that there are exactly `count` finite values; `what` (e.g. "3x4
// row-major pose") says in errors what the line should hold.
absl::StatusOr<std::vector<double>> ParseFiniteNumbers(absl::string_view text, size_t count,
                                                       const std::string& path, int line,
                                                       absl::string_view what);

}  // namespace rim::io
