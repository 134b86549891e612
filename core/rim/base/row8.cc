#include "rim/base/row8.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace rim {

void EncodeRows8(const float* in, size_t rows, int dim, int8_t* out) {
  for (size_t r = 0; r < rows; ++r, in += dim, out += Row8Bytes(dim)) {
    float m = 0.f;
    for (int k = 0; k < dim; ++k)
      if (std::abs(in[k]) > m) m = std::abs(in[k]);  // NaN never compares greater
    int e = -128;
    if (m > 0.f) {
      // m = f · 2^x with f in [0.5, 1): m / 2^(x-7) = 128 f is in [64, 128), and one more in the
      // exponent when that would round past 127.
      int x;
      const float f = std::frexp(std::min(m, 1e38f), &x);
      e = x - 7 + (f * 128.f > 127.5f ? 1 : 0);
      e = std::clamp(e, -128, 127);
    }
    out[0] = int8_t(e);
    for (int k = 0; k < dim; ++k) {
      const float v = std::isnan(in[k]) ? 0.f : std::ldexp(in[k], -e);
      out[1 + k] = int8_t(std::clamp(std::round(v), -127.f, 127.f));
    }
  }
}

namespace {
// 2^e: built from its bits where it is a normal float (every exponent the encoder picks for
// rows of magnitude 2^-119 and up), a libm call below.
inline float Pow2(int e) {
  if (e < -126) return std::ldexp(1.f, e);
  const uint32_t bits = uint32_t(e + 127) << 23;
  float f;
  std::memcpy(&f, &bits, 4);
  return f;
}
}  // namespace

void DecodeRows8(const int8_t* in, size_t rows, int dim, float* out) {
  for (size_t r = 0; r < rows; ++r, in += Row8Bytes(dim), out += dim) {
    const float scale = Pow2(in[0]);
    for (int k = 0; k < dim; ++k) out[k] = float(in[1 + k]) * scale;
  }
}

void SanitizeRows8(int8_t* rows, size_t count, int dim) {
  // 127 · 2^121 < FLT_MAX < 127 · 2^122.
  constexpr int8_t kMaxExponent = 121;
  for (size_t r = 0; r < count; ++r, rows += Row8Bytes(dim)) {
    rows[0] = std::min(rows[0], kMaxExponent);
    for (int k = 1; k <= dim; ++k) rows[k] = std::max(rows[k], int8_t(-127));
  }
}

void RoundRow8(float* row, int dim) {
  int8_t bytes[256];
  if (Row8Bytes(dim) > sizeof(bytes)) return;
  EncodeRows8(row, 1, dim, bytes);
  DecodeRows8(bytes, 1, dim, row);
}

}  // namespace rim
