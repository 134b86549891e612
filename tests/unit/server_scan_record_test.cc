#include <Eigen/Geometry>
#include <cstring>
#include <limits>
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/wal/scan_record.h"

namespace rim::server {
namespace {

using ::testing::HasSubstr;

PosedScan SampleScan(bool with_origins) {
  PosedScan scan;
  scan.timestamp_s = 1712345678.123456789;
  scan.T_world_sensor = Eigen::Translation3d(1.5, -2.25, 0.125) *
                        Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.2, -0.3, 0.9).normalized());
  for (int i = 0; i < 5; ++i) {
    scan.points_S.emplace_back(i * 0.1f, -i * 1.7f, 3.3f + i);
    if (with_origins) scan.origins_S.emplace_back(0.f, 0.01f * i, 0.f);
  }
  return scan;
}

TEST(ScanRecordTest, RoundTripIsBitExact) {
  for (bool with_origins : {false, true}) {
    const PosedScan scan = SampleScan(with_origins);
    std::string bytes;
    EncodeScanRecord(42, scan, &bytes);
    uint64_t seq = 0;
    PosedScan back;
    ASSERT_TRUE(DecodeScanRecord(bytes, "test", &seq, &back).ok());
    EXPECT_EQ(seq, 42u);
    EXPECT_EQ(std::memcmp(&back.timestamp_s, &scan.timestamp_s, sizeof(double)), 0);
    EXPECT_TRUE(back.T_world_sensor.matrix() == scan.T_world_sensor.matrix());
    EXPECT_EQ(back.points_S, scan.points_S);
    EXPECT_EQ(back.origins_S, scan.origins_S);
  }
}

TEST(ScanRecordTest, EncodeAppends) {
  std::string bytes = "prefix";
  EncodeScanRecord(1, SampleScan(false), &bytes);
  EXPECT_EQ(bytes.substr(0, 6), "prefix");
  uint64_t seq = 0;
  PosedScan back;
  EXPECT_TRUE(DecodeScanRecord(std::string_view(bytes).substr(6), "t", &seq, &back).ok());
}

TEST(ScanRecordTest, EveryTruncationIsDataLoss) {
  std::string bytes;
  EncodeScanRecord(7, SampleScan(true), &bytes);
  for (size_t n = 0; n < bytes.size(); ++n) {
    uint64_t seq = 0;
    PosedScan back;
    const absl::Status s =
        DecodeScanRecord(bytes.substr(0, n), "wal-x.log at offset 9", &seq, &back);
    ASSERT_EQ(s.code(), absl::StatusCode::kDataLoss) << n;
    EXPECT_THAT(s.message(), HasSubstr("wal-x.log at offset 9"));
  }
}

TEST(ScanRecordTest, TrailingBytesAreDataLoss) {
  std::string bytes;
  EncodeScanRecord(7, SampleScan(false), &bytes);
  bytes.push_back('\0');
  uint64_t seq = 0;
  PosedScan back;
  EXPECT_EQ(DecodeScanRecord(bytes, "t", &seq, &back).code(), absl::StatusCode::kDataLoss);
}

TEST(ScanRecordTest, HugeCountIsDataLossWithoutAllocating) {
  std::string bytes;
  EncodeScanRecord(7, SampleScan(false), &bytes);
  const size_t count_offset = 8 + 8 + 16 * 8;
  const uint64_t huge = std::numeric_limits<uint64_t>::max() / 2;
  std::memcpy(bytes.data() + count_offset, &huge, sizeof(huge));
  uint64_t seq = 0;
  PosedScan back;
  const absl::Status s = DecodeScanRecord(bytes, "t", &seq, &back);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(s.message(), HasSubstr("point count"));
}

TEST(ScanRecordTest, MismatchedOriginsAreRefused) {
  PosedScan scan = SampleScan(true);
  scan.origins_S.pop_back();
  EXPECT_EQ(CheckScanRecordable(scan).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(CheckScanRecordable(SampleScan(true)).ok());
  EXPECT_TRUE(CheckScanRecordable(SampleScan(false)).ok());
  // A record that says so anyway (written by a buggy writer) does not decode.
  std::string bytes;
  EncodeScanRecord(1, scan, &bytes);
  uint64_t seq = 0;
  PosedScan back;
  EXPECT_EQ(DecodeScanRecord(bytes, "t", &seq, &back).code(), absl::StatusCode::kDataLoss);
}

}  // namespace
}  // namespace rim::server
