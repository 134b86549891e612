#include "rim/base/half.h"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace rim {

#if defined(__x86_64__)
namespace {
// Eight floats at a time with the CPU's conversion (round to nearest even, subnormals exact),
// which agrees with FloatToHalf below the saturation point. The hardware turns a float beyond
// the half range into infinity where the store wants the largest finite half, so a group of
// eight with any |x| ≥ 65520 (the first value that rounds past 65504), infinity or NaN goes
// through FloatToHalf instead.
__attribute__((target("avx,f16c"))) void FloatsToHalvesF16c(const float* in, size_t n,
                                                            uint16_t* out) {
  const __m256 sign = _mm256_set1_ps(-0.f);
  const __m256 limit = _mm256_set1_ps(65520.f);
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256 x = _mm256_loadu_ps(in + i);
    // Not less than the limit, or unordered (NaN).
    if (_mm256_movemask_ps(_mm256_cmp_ps(_mm256_andnot_ps(sign, x), limit, _CMP_NLT_UQ)) != 0) {
      for (size_t k = i; k < i + 8; ++k) out[k] = FloatToHalf(in[k]);
      continue;
    }
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i),
                     _mm256_cvtps_ph(x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
  }
  for (; i < n; ++i) out[i] = FloatToHalf(in[i]);
}

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

void FloatsToHalves(const float* in, size_t n, uint16_t* out) {
#if defined(__x86_64__)
  static const bool f16c = __builtin_cpu_supports("f16c") && __builtin_cpu_supports("avx");
  if (f16c) {
    FloatsToHalvesF16c(in, n, out);
    return;
  }
#endif
  for (size_t i = 0; i < n; ++i) out[i] = FloatToHalf(in[i]);
}

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
