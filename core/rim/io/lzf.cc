#include "rim/io/lzf.h"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <vector>

#include "absl/strings/str_cat.h"

namespace rim::io {
namespace {

constexpr size_t kMaxLiteral = 32;   // ctrl 0..31 -> 1..32 literal bytes
constexpr size_t kMaxOffset = 8192;  // 13 bits of offset, stored minus 1
constexpr size_t kMaxMatch = 264;    // (7 + 255) + 2
constexpr int kHashBits = 14;

uint32_t Hash3(const uint8_t* p) {
  const uint32_t v = (uint32_t{p[0]} << 16) | (uint32_t{p[1]} << 8) | p[2];
  return (v * 2654435761u) >> (32 - kHashBits);
}

void FlushLiterals(const uint8_t* in, size_t begin, size_t end, std::string* out) {
  while (begin < end) {
    const size_t n = std::min(kMaxLiteral, end - begin);
    out->push_back(static_cast<char>(n - 1));
    out->append(reinterpret_cast<const char*>(in + begin), n);
    begin += n;
  }
}

}  // namespace

std::string LzfCompress(absl::string_view input) {
  const uint8_t* in = reinterpret_cast<const uint8_t*>(input.data());
  const size_t n = input.size();
  std::string out;
  out.reserve(n + n / kMaxLiteral + 16);
  // Position + 1 of the last occurrence of each 3-byte hash; 0 means none.
  std::vector<size_t> table(size_t{1} << kHashBits, 0);
  size_t literal_start = 0;
  size_t i = 0;
  while (i + 2 < n) {
    const uint32_t h = Hash3(in + i);
    const size_t candidate = table[h];
    table[h] = i + 1;
    if (candidate != 0) {
      const size_t ref = candidate - 1;
      const size_t distance = i - ref;
      if (distance <= kMaxOffset && std::memcmp(in + ref, in + i, 3) == 0) {
        const size_t max_len = std::min(kMaxMatch, n - i);
        size_t len = 3;
        while (len < max_len && in[ref + len] == in[i + len]) ++len;
        FlushLiterals(in, literal_start, i, &out);
        const size_t offset = distance - 1;
        const size_t coded = len - 2;  // 1..262
        if (coded < 7) {
          out.push_back(static_cast<char>((coded << 5) | (offset >> 8)));
        } else {
          out.push_back(static_cast<char>((7 << 5) | (offset >> 8)));
          out.push_back(static_cast<char>(coded - 7));
        }
        out.push_back(static_cast<char>(offset & 0xff));
        for (size_t k = i + 1; k < i + len && k + 2 < n; ++k) table[Hash3(in + k)] = k + 1;
        i += len;
        literal_start = i;
        continue;
      }
    }
    ++i;
  }
  FlushLiterals(in, literal_start, n, &out);
  return out;
}

absl::StatusOr<std::string> LzfDecompress(absl::string_view input, size_t expected_size,
                                          absl::string_view context) {
  const uint8_t* in = reinterpret_cast<const uint8_t*>(input.data());
  const size_t n = input.size();
  if (expected_size > n * kLzfMaxExpansion) {
    return absl::DataLossError(
        absl::StrCat(context, ": LZF: ", n, " compressed bytes cannot expand to ", expected_size));
  }
  std::string out(expected_size, '\0');
  uint8_t* o = reinterpret_cast<uint8_t*>(out.data());
  size_t op = 0, ip = 0;
  auto error = [&](absl::string_view what) {
    return absl::DataLossError(absl::StrCat(context, ": LZF: ", what, " at input byte ", ip,
                                            " (output byte ", op, " of ", expected_size, ")"));
  };
  while (ip < n) {
    const size_t ctrl = in[ip++];
    if (ctrl < 32) {
      const size_t len = ctrl + 1;
      if (len > n - ip) return error("literal run past the end of the input");
      if (len > expected_size - op) return error("literal run past the expected size");
      std::memcpy(o + op, in + ip, len);
      ip += len;
      op += len;
      continue;
    }
    size_t len = ctrl >> 5;
    if (len == 7) {
      if (ip >= n) return error("truncated back-reference length");
      len += in[ip++];
    }
    if (ip >= n) return error("truncated back-reference offset");
    const size_t distance = ((ctrl & 0x1f) << 8) + in[ip++] + 1;
    if (distance > op) return error("back-reference before the start of the output");
    len += 2;
    if (len > expected_size - op) return error("back-reference past the expected size");
    const size_t ref = op - distance;
    for (size_t k = 0; k < len; ++k) o[op + k] = o[ref + k];  // ranges may overlap
    op += len;
  }
  if (op != expected_size) {
    return absl::DataLossError(
        absl::StrCat(context, ": LZF: stream ends after ", op, " bytes, expected ", expected_size));
  }
  return out;
}

}  // namespace rim::io
