// IEEE 754 binary16 ("half") storage for features that are no longer trained: the sub-map store
// keeps the global map at half the bytes of float. Conversions round to nearest, ties to even;
// a finite float beyond the half range saturates to ±65504 instead of becoming infinite, so a
// stored feature is always usable. NaN stays NaN, ±0 and ±inf are kept.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>

namespace rim {

inline uint16_t FloatToHalf(float value) {
  uint32_t x;
  std::memcpy(&x, &value, 4);
  const uint16_t sign = uint16_t((x >> 16) & 0x8000u);
  const uint32_t ax = x & 0x7fffffffu;
  if (ax >= 0x7f800000u) {  // inf, or NaN (kept quiet, with the top payload bits)
    return uint16_t(sign | 0x7c00u | (ax > 0x7f800000u ? 0x200u | ((ax >> 13) & 0x3ffu) : 0u));
  }
  if (ax >= 0x477fe000u) return uint16_t(sign | 0x7bffu);  // ≥ 65504: the largest half
  if (ax < 0x38800000u) {
    // Below 2^-14, the smallest normal half: a subnormal, round(|value| · 2^24) units of 2^-24.
    // Adding and removing 2^23 rounds to an integer in the current (nearest-even) mode; 1024
    // units come out as the smallest normal's encoding, as they should.
    float a;
    std::memcpy(&a, &ax, 4);
    volatile float t = a * 16777216.f + 8388608.f;  // volatile: keep the rounding step
    return uint16_t(sign | uint32_t(t - 8388608.f));
  }
  // Normal: rebias the exponent (127 → 15), keep 10 of 23 mantissa bits, round the other 13.
  uint32_t h = ((ax >> 23) - 112u) << 10 | ((ax >> 13) & 0x3ffu);
  const uint32_t rest = ax & 0x1fffu;
  if (rest > 0x1000u || (rest == 0x1000u && (h & 1u))) ++h;  // a carry into the exponent is right
  return uint16_t(sign | h);
}

inline float HalfToFloat(uint16_t h) {
  const uint32_t sign = uint32_t(h & 0x8000u) << 16;
  const uint32_t e = (h >> 10) & 0x1fu, m = h & 0x3ffu;
  uint32_t x;
  if (e == 0) {  // zero or subnormal: m · 2^-24, exact in float
    const float v = float(m) * (1.f / 16777216.f);
    std::memcpy(&x, &v, 4);
    x |= sign;
  } else if (e == 31) {
    x = sign | 0x7f800000u | (m << 13);
  } else {
    x = sign | ((e + 112u) << 23) | (m << 13);
  }
  float out;
  std::memcpy(&out, &x, 4);
  return out;
}

// The float a value reads back as after a trip through half storage.
inline float RoundToHalf(float value) { return HalfToFloat(FloatToHalf(value)); }

// Bulk forms. Both use the CPU's conversion instructions (F16C) where it has them, and give the
// scalar forms' bits either way: widening is exact; narrowing rounds to nearest even in both,
// and a group of eight floats holding a value that the hardware would turn into infinity (or a
// NaN) is narrowed by FloatToHalf.
void FloatsToHalves(const float* in, size_t n, uint16_t* out);
void HalvesToFloats(const uint16_t* in, size_t n, float* out);

}  // namespace rim
