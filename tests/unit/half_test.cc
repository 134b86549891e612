// Half-float storage of the sub-map store (rim/base/half.h): exact round trips, round to nearest
// even, saturation instead of infinity, and agreement with the CPU's own conversion.
#include "rim/base/half.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "gtest/gtest.h"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace rim {
namespace {

uint32_t Bits(float f) {
  uint32_t b;
  std::memcpy(&b, &f, 4);
  return b;
}

bool IsNanHalf(uint16_t h) { return (h & 0x7c00u) == 0x7c00u && (h & 0x3ffu) != 0; }

TEST(HalfTest, EveryHalfWidensAndNarrowsBackToItself) {
  for (uint32_t h = 0; h < 65536; ++h) {
    const float f = HalfToFloat(uint16_t(h));
    if (IsNanHalf(uint16_t(h))) {
      EXPECT_TRUE(std::isnan(f)) << h;
      EXPECT_TRUE(IsNanHalf(FloatToHalf(f))) << h;
      continue;
    }
    ASSERT_EQ(FloatToHalf(f), uint16_t(h)) << "half 0x" << std::hex << h << " = " << f;
  }
}

TEST(HalfTest, KnownValuesRoundToNearestEvenAndSaturate) {
  EXPECT_EQ(FloatToHalf(0.f), 0x0000);
  EXPECT_EQ(FloatToHalf(-0.f), 0x8000);
  EXPECT_EQ(FloatToHalf(1.f), 0x3c00);
  EXPECT_EQ(FloatToHalf(-2.f), 0xc000);
  EXPECT_EQ(FloatToHalf(65504.f), 0x7bff);
  // Past the largest half: the largest half, never infinity.
  EXPECT_EQ(FloatToHalf(65519.f), 0x7bff);
  EXPECT_EQ(FloatToHalf(65520.f), 0x7bff);
  EXPECT_EQ(FloatToHalf(1e10f), 0x7bff);
  EXPECT_EQ(FloatToHalf(-1e30f), 0xfbff);
  EXPECT_EQ(FloatToHalf(std::numeric_limits<float>::infinity()), 0x7c00);
  EXPECT_EQ(FloatToHalf(-std::numeric_limits<float>::infinity()), 0xfc00);
  EXPECT_TRUE(IsNanHalf(FloatToHalf(std::numeric_limits<float>::quiet_NaN())));
  // Ties go to the even neighbour: 1 + 2^-11 is halfway between 1 and 1 + 2^-10.
  EXPECT_EQ(FloatToHalf(1.f + std::ldexp(1.f, -11)), 0x3c00);
  EXPECT_EQ(FloatToHalf(1.f + 3 * std::ldexp(1.f, -11)), 0x3c02);
  EXPECT_EQ(FloatToHalf(1.f + std::ldexp(1.f, -11) + std::ldexp(1.f, -20)), 0x3c01);
  // A carry out of the mantissa moves to the next binade.
  EXPECT_EQ(FloatToHalf(2.f - std::ldexp(1.f, -12)), 0x4000);
  // Subnormals: units of 2^-24.
  EXPECT_EQ(FloatToHalf(std::ldexp(1.f, -24)), 0x0001);
  EXPECT_EQ(FloatToHalf(std::ldexp(1.f, -25)), 0x0000);      // tie to even: 0
  EXPECT_EQ(FloatToHalf(3 * std::ldexp(1.f, -25)), 0x0002);  // 1.5 units: tie to 2
  EXPECT_EQ(FloatToHalf(-std::ldexp(1.f, -14)), 0x8400);     // smallest normal
  EXPECT_EQ(FloatToHalf(std::ldexp(1.f, -14) - std::ldexp(1.f, -26)), 0x0400);  // rounds up to it
  EXPECT_EQ(FloatToHalf(std::numeric_limits<float>::denorm_min()), 0x0000);
  EXPECT_EQ(HalfToFloat(0x0001), std::ldexp(1.f, -24));
  EXPECT_EQ(HalfToFloat(0x7bff), 65504.f);
  EXPECT_EQ(HalfToFloat(0xfc00), -std::numeric_limits<float>::infinity());
}

TEST(HalfTest, RelativeErrorIsAtMostHalfAnUlp) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> mag(-14.f, 15.9f);
  for (int i = 0; i < 200000; ++i) {
    const float x = std::exp2(mag(rng)) * (rng() & 1 ? 1.f : -1.f);
    const float r = RoundToHalf(x);
    ASSERT_LE(std::abs(r - x), std::ldexp(std::abs(x), -11)) << x;
  }
}

#if defined(__x86_64__)
__attribute__((target("f16c"))) uint16_t HardwareHalf(float x) {
  return uint16_t(_cvtss_sh(x, _MM_FROUND_TO_NEAREST_INT));
}

TEST(HalfTest, MatchesTheCpuConversionInsideTheHalfRange) {
  if (!__builtin_cpu_supports("f16c")) GTEST_SKIP() << "this CPU has no F16C instructions";
  std::mt19937 rng(4);
  // Random bit patterns of every float below the saturation point, subnormals included.
  for (int i = 0; i < 2000000; ++i) {
    uint32_t b = rng() % 0x477fe000u;
    if (rng() & 1) b |= 0x80000000u;
    float x;
    std::memcpy(&x, &b, 4);
    ASSERT_EQ(FloatToHalf(x), HardwareHalf(x)) << "float bits 0x" << std::hex << Bits(x);
  }
}
#endif

TEST(HalfTest, BulkConversionsEqualTheScalarOnes) {
  std::vector<uint16_t> all(65536);
  for (uint32_t h = 0; h < 65536; ++h) all[h] = uint16_t(h);
  std::vector<float> wide(all.size());
  HalvesToFloats(all.data(), all.size(), wide.data());  // the F16C path where the CPU has it
  for (uint32_t h = 0; h < 65536; ++h) {
    const float f = HalfToFloat(uint16_t(h));
    if (std::isnan(f)) {
      EXPECT_TRUE(std::isnan(wide[h])) << h;
    } else {
      ASSERT_EQ(Bits(wide[h]), Bits(f)) << h;
    }
  }
  // Lengths that are not a multiple of the vector width use the scalar tail.
  std::vector<float> tail(13, -7.f);
  HalvesToFloats(all.data() + 0x3c00, 13, tail.data());
  for (int i = 0; i < 13; ++i) EXPECT_EQ(tail[i], HalfToFloat(uint16_t(0x3c00 + i)));

  const std::vector<float> in = {0.f, -1.5f, 1e6f, 3.14159f, std::ldexp(1.f, -20), -65504.f};
  std::vector<uint16_t> out(in.size());
  FloatsToHalves(in.data(), in.size(), out.data());
  for (size_t i = 0; i < in.size(); ++i) EXPECT_EQ(out[i], FloatToHalf(in[i])) << in[i];

  // Narrowing in bulk (the F16C path where the CPU has it) against FloatToHalf: random bit
  // patterns of every class (subnormals, the saturation edge, infinities, NaNs) mixed into
  // groups of eight, so that some groups hold one value the hardware would get wrong.
  std::mt19937 rng(5);
  std::vector<float> mixed(100003);
  const uint32_t edges[] = {0x477fe000u, 0x477fdfffu, 0x477fe001u, 0x7f800000u,
                            0x7fc00001u, 0x7f800001u, 0x38800000u, 0x387fffffu};
  for (size_t i = 0; i < mixed.size(); ++i) {
    uint32_t b = rng();
    if (i % 97 == 0)
      b = edges[(i / 97) % 8] | (rng() & 0x80000000u);
    else if (rng() % 4 != 0)
      b = (rng() % 0x477fe000u) | (rng() & 0x80000000u);  // in range
    std::memcpy(&mixed[i], &b, 4);
  }
  std::vector<uint16_t> narrow(mixed.size());
  FloatsToHalves(mixed.data(), mixed.size(), narrow.data());
  for (size_t i = 0; i < mixed.size(); ++i)
    ASSERT_EQ(narrow[i], FloatToHalf(mixed[i])) << "float bits 0x" << std::hex << Bits(mixed[i]);
}

}  // namespace
}  // namespace rim
