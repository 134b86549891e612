// 8-bit feature rows of the sub-map store (rim/base/row8.h): the error bound, exact decoding,
// byte-identical re-encoding (save → load → save), and zeros, infinities and NaN.
#include "rim/base/row8.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace rim {
namespace {

TEST(Row8Test, ErrorIsAtMostHalfAStepAndUnderOnePercentOfTheRowMaximum) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> mantissa(-1.f, 1.f);
  std::uniform_int_distribution<int> exponent(-30, 30);
  constexpr int D = 8;
  for (int trial = 0; trial < 20000; ++trial) {
    std::vector<float> row(D);
    const int e = exponent(rng);
    for (float& v : row) v = std::ldexp(mantissa(rng), e);
    float m = 0.f;
    for (float v : row) m = std::max(m, std::abs(v));
    std::vector<int8_t> q(Row8Bytes(D));
    EncodeRows8(row.data(), 1, D, q.data());
    std::vector<float> back(D);
    DecodeRows8(q.data(), 1, D, back.data());
    const float step = std::ldexp(1.f, q[0]);
    for (int k = 0; k < D; ++k) {
      ASSERT_LE(std::abs(back[k] - row[k]), 0.5f * step * (1 + 1e-6f)) << trial;
      ASSERT_LE(std::abs(back[k] - row[k]), m / 127.f) << trial;
      ASSERT_EQ(back[k], float(q[1 + k]) * step);  // exact
    }
    // The largest magnitude uses at least 64 of the 127 steps: no precision is wasted.
    int largest = 0;
    for (int k = 0; k < D; ++k) largest = std::max(largest, std::abs(int(q[1 + k])));
    ASSERT_GE(largest, 64) << trial;
  }
}

TEST(Row8Test, ReencodingADecodedRowGivesTheSameBytes) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> value(-4.f, 4.f);
  constexpr int D = 8, kRows = 5000;
  std::vector<float> rows(size_t(kRows) * D);
  for (float& v : rows) v = value(rng) * std::ldexp(1.f, int(rng() % 20) - 10);
  std::vector<int8_t> q(kRows * Row8Bytes(D)), again(q.size());
  EncodeRows8(rows.data(), kRows, D, q.data());
  std::vector<float> back(rows.size());
  DecodeRows8(q.data(), kRows, D, back.data());
  EncodeRows8(back.data(), kRows, D, again.data());
  EXPECT_EQ(q, again);
  // RoundRow8 is the same trip, one row at a time.
  for (int r = 0; r < 50; ++r) {
    std::vector<float> row(rows.begin() + r * D, rows.begin() + (r + 1) * D);
    RoundRow8(row.data(), D);
    for (int k = 0; k < D; ++k) ASSERT_EQ(row[k], back[size_t(r) * D + k]);
  }
}

TEST(Row8Test, ZerosInfinitiesAndNan) {
  constexpr int D = 4;
  const float inf = std::numeric_limits<float>::infinity();
  std::vector<float> zeros(D, 0.f), special = {inf, -inf, std::nanf(""), 1.f};
  RoundRow8(zeros.data(), D);
  EXPECT_EQ(zeros, std::vector<float>(D, 0.f));
  RoundRow8(special.data(), D);
  for (float v : special) EXPECT_TRUE(std::isfinite(v));  // a stored feature is always usable
  EXPECT_GT(special[0], 1e37f);
  EXPECT_LT(special[1], -1e37f);
  EXPECT_EQ(special[2], 0.f);
  // Exact values that fit in 7 bits keep them.
  std::vector<float> exact = {42.f, -1.f, 0.5f, 127.f};
  RoundRow8(exact.data(), D);
  EXPECT_EQ(exact, (std::vector<float>{42.f, -1.f, 1.f, 127.f}));  // 0.5: a tie, away from 0
}

}  // namespace
}  // namespace rim
