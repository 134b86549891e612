#include "rim/io/lzf.h"

#include <lzf.h>

#include <cerrno>
#include <limits>

#include "absl/strings/str_cat.h"

namespace rim::io {

std::string LzfCompress(absl::string_view input) {
  const size_t n = input.size();
  if (n == 0) return std::string();  // liblzf reports an empty result as a failure
  // liblzf emits literal runs of at most 32 bytes, each behind one control byte, so its output
  // never passes n + ceil(n / 32) bytes; its bounds checks are conservative by a few bytes, hence
  // the slack.
  std::string out(n + n / 32 + 16, '\0');
  const unsigned int used = lzf_compress(input.data(), static_cast<unsigned int>(n), out.data(),
                                         static_cast<unsigned int>(out.size()));
  out.resize(used);
  return out;
}

absl::StatusOr<std::string> LzfDecompress(absl::string_view input, size_t expected_size,
                                          absl::string_view context) {
  const size_t n = input.size();
  if (expected_size > n * kLzfMaxExpansion ||
      expected_size > std::numeric_limits<unsigned int>::max() ||
      n > std::numeric_limits<unsigned int>::max()) {
    return absl::DataLossError(
        absl::StrCat(context, ": LZF: ", n, " compressed bytes cannot expand to ", expected_size));
  }
  if (expected_size == 0) {
    if (n == 0) return std::string();
    return absl::DataLossError(
        absl::StrCat(context, ": LZF: ", n, " compressed bytes where 0 were expected"));
  }
  std::string out(expected_size, '\0');
  errno = 0;
  const unsigned int produced =
      lzf_decompress(input.data(), static_cast<unsigned int>(n), out.data(),
                     static_cast<unsigned int>(expected_size));
  if (produced == 0) {
    const char* what = errno == E2BIG ? "stream expands past the expected size"
                                      : "corrupt stream (bad back-reference or truncated data)";
    return absl::DataLossError(absl::StrCat(context, ": LZF: ", what, " (", n, " bytes in, ",
                                            expected_size, " expected)"));
  }
  if (produced != expected_size) {
    return absl::DataLossError(absl::StrCat(context, ": LZF: stream ends after ", produced,
                                            " bytes, expected ", expected_size));
  }
  return out;
}

}  // namespace rim::io
