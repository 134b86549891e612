// The client library's pieces that need no server: scan packing, wire arrays, status mapping.
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

#include "client/status.h"
#include "client/wire.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/service/status_mapping.h"

namespace rim {
namespace {

using ::testing::HasSubstr;

PosedScan MakeScan() {
  PosedScan scan;
  scan.timestamp_s = 12.5;
  scan.T_world_sensor = Eigen::Isometry3d::Identity();
  scan.T_world_sensor.linear() =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.3, -0.2, 0.9).normalized()).toRotationMatrix();
  scan.T_world_sensor.translation() = Eigen::Vector3d(10.5, -3.25, 1.73);
  for (int i = 0; i < 50; ++i)
    scan.points_S.emplace_back(0.1f * float(i), -0.5f + 0.01f * float(i), 2.0f - 0.03f * float(i));
  return scan;
}

TEST(ClientWireTest, ScanToProtoPacksPoseAndPoints) {
  const PosedScan scan = MakeScan();
  const rim::v1::Scan wire = ScanToProto(scan, "robot_7", 42);
  EXPECT_EQ(wire.robot_id(), "robot_7");
  EXPECT_EQ(wire.sequence(), 42u);
  EXPECT_EQ(wire.timestamp_s(), 12.5);
  ASSERT_EQ(wire.points_xyz().size(), 50u * 12);
  EXPECT_TRUE(wire.origins_xyz().empty());
  float third[3];
  std::memcpy(third, wire.points_xyz().data() + 2 * 12, 12);
  EXPECT_EQ(third[0], scan.points_S[2].x());
  EXPECT_EQ(third[1], scan.points_S[2].y());
  EXPECT_EQ(third[2], scan.points_S[2].z());
  const auto& q = wire.pose().rotation();
  EXPECT_NEAR(q.w() * q.w() + q.x() * q.x() + q.y() * q.y() + q.z() * q.z(), 1.0, 1e-12);
  EXPECT_EQ(wire.pose().translation().x(), 10.5);
  EXPECT_EQ(wire.pose().translation().z(), 1.73);
}

TEST(ClientWireTest, ScanRoundTripsThroughProto) {
  PosedScan scan = MakeScan();
  scan.origins_S.assign(scan.points_S.size(), Vec3f(0.f, 0.1f, -0.2f));
  auto back = ScanFromProto(ScanToProto(scan, "r", 0));
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->points_S, scan.points_S);
  EXPECT_EQ(back->origins_S, scan.origins_S);
  EXPECT_EQ(back->timestamp_s, scan.timestamp_s);
  EXPECT_TRUE(back->T_world_sensor.isApprox(scan.T_world_sensor, 1e-12));
}

TEST(ClientWireTest, ScanToProtoNormalisesADriftedRotation) {
  // A rotation scaled by 1.01 (accumulated float drift) still goes out as a unit quaternion,
  // which the server requires within 1e-3.
  PosedScan scan = MakeScan();
  scan.T_world_sensor.linear() *= 1.01;
  // The message is kept whole: a reference into a temporary's pose would dangle (ASan caught it).
  const rim::v1::Scan wire = ScanToProto(scan, "r", 0);
  const rim::v1::Quaternion& q = wire.pose().rotation();
  EXPECT_NEAR(std::sqrt(q.w() * q.w() + q.x() * q.x() + q.y() * q.y() + q.z() * q.z()), 1.0, 1e-9);
}

TEST(ClientWireTest, MalformedArraysAreNamed) {
  rim::v1::Scan wire = ScanToProto(MakeScan(), "r", 0);
  wire.set_points_xyz(wire.points_xyz().substr(0, 13));
  auto bad = ScanFromProto(wire);
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(bad.status().message(), HasSubstr("scan.points_xyz"));

  wire = ScanToProto(MakeScan(), "r", 0);
  wire.set_origins_xyz(std::string(24, '\0'));  // two origins for 50 points
  bad = ScanFromProto(wire);
  EXPECT_THAT(bad.status().message(), HasSubstr("scan.origins_xyz"));

  auto floats = UnpackFloats(std::string(10, '\0'), 3, "QuerySdfResponse.sdf");
  EXPECT_EQ(floats.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(floats.status().message(), HasSubstr("QuerySdfResponse.sdf"));
  floats = UnpackFloats(std::string(12, '\0'), 3, "x");
  ASSERT_TRUE(floats.ok());
  EXPECT_EQ(*floats, std::vector<float>(3, 0.f));
}

TEST(ClientStatusTest, KeepsTheServersCodeAndMessage) {
  const absl::Status s =
      FromGrpc(grpc::Status(grpc::StatusCode::NOT_FOUND, "no session 'x'"), "GetSession x");
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(s.message(), "GetSession x: no session 'x'");
  EXPECT_TRUE(FromGrpc(grpc::Status::OK, "anything").ok());
}

TEST(ClientStatusTest, UnknownCodesNeverReadAsOk) {
  // 31, not a larger number: grpc::StatusCode has no fixed underlying type, so only values that
  // fit its enumerators' bits (-32..31) are valid; making a larger one is undefined behaviour.
  const absl::Status s = FromGrpc(grpc::Status(static_cast<grpc::StatusCode>(31), "future"));
  EXPECT_EQ(s.code(), absl::StatusCode::kUnknown);
  EXPECT_EQ(s.message(), "future");
}

TEST(ClientStatusTest, AgreesWithTheServersMappingForEveryCode) {
  // The server maps absl -> gRPC at its edge; the client must map every code back to where it
  // started, so an error means the same on both sides.
  for (int code = 1; code <= 16; ++code) {
    const absl::Status original(static_cast<absl::StatusCode>(code), "m");
    const absl::Status back = FromGrpc(server::ToGrpcStatus(original));
    EXPECT_EQ(back.code(), original.code()) << "code " << code;
    EXPECT_EQ(back.message(), "m");
    EXPECT_EQ(back.code(), server::FromGrpcStatus(server::ToGrpcStatus(original)).code());
  }
}

}  // namespace
}  // namespace rim
