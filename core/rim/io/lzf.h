// LZF, the codec of PCD's binary_compressed DATA, through liblzf (Debian liblzf-dev), with the
// checks a reader of untrusted files needs and errors that name the file.
#pragma once

#include <cstddef>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace rim::io {

// The largest expansion a valid stream can have: a 3-byte back-reference yields at most 264 bytes.
inline constexpr size_t kLzfMaxExpansion = 88;

// Compresses `input`. Always succeeds; incompressible data grows by at most 1 byte in 32 (+1).
std::string LzfCompress(absl::string_view input);

// Decompresses `input`, which must produce exactly `expected_size` bytes. Errors (DataLoss) for
// corrupt or truncated streams, references before the start of the output, or output of another
// size; `context` (e.g. the file name) starts each message. Allocates at most `expected_size`
// bytes, and refuses sizes no stream of this length can produce before allocating.
absl::StatusOr<std::string> LzfDecompress(absl::string_view input, size_t expected_size,
                                          absl::string_view context);

}  // namespace rim::io
