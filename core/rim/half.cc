#include "rim/half.h"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace rim {

void FloatsToHalves(const float* in, size_t n, uint16_t* out) {
  // The scalar form on purpose: the hardware conversion turns a float beyond the half range into
  // infinity, where the store wants the largest finite half.
  for (size_t i = 0; i < n; ++i) out[i] = FloatToHalf(in[i]);
}

#if defined(__x86_64__)
namespace {
__attribute__((target("avx,f16c"))) void HalvesToFloatsF16c(const uint16_t* in, size_t n,
                                                            float* out) {
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m128i h = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + i));
    _mm256_storeu_ps(out + i, _mm256_cvtph_ps(h));
  }
  for (; i < n; ++i) out[i] = HalfToFloat(in[i]);
}
}  // namespace
#endif

void HalvesToFloats(const uint16_t* in, size_t n, float* out) {
#if defined(__x86_64__)
  static const bool f16c = __builtin_cpu_supports("f16c") && __builtin_cpu_supports("avx");
  if (f16c) {
    HalvesToFloatsF16c(in, n, out);
    return;
  }
#endif
  for (size_t i = 0; i < n; ++i) out[i] = HalfToFloat(in[i]);
}

}  // namespace rim
