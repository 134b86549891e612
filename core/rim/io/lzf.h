// LZF compression, the codec of PCD's binary_compressed DATA, written from the format description
// (compatible with liblzf's lzf_compress/lzf_decompress streams).
//
// A stream is a sequence of chunks, each starting with a control byte `ctrl`:
//   ctrl < 32:  a literal run; the next ctrl + 1 bytes are copied to the output.
//   ctrl >= 32: a back-reference; len = ctrl >> 5 (if 7, add the next byte), then
//               offset = ((ctrl & 0x1f) << 8) + next byte + 1; copy len + 2 bytes starting `offset`
//               bytes before the current end of the output (the ranges may overlap).
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
// truncated streams, references before the start of the output, or output of another size;
// `context` (e.g. the file name) starts each message. Allocates at most `expected_size` bytes.
absl::StatusOr<std::string> LzfDecompress(absl::string_view input, size_t expected_size,
                                          absl::string_view context);

}  // namespace rim::io
