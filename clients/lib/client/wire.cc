#include "client/wire.h"

#include <cstring>

#include "absl/strings/str_cat.h"

namespace rim {
namespace {

// The wire is little-endian; so are the hosts rim supports (x86-64, aarch64), which lets packing
// be a memcpy.
static_assert(sizeof(float) == 4, "float32 wire arrays");

template <typename Point>
std::string PackPoints(const std::vector<Point>& points) {
  std::string out(points.size() * 12, '\0');
  for (size_t i = 0; i < points.size(); ++i) {
    const float xyz[3] = {points[i][0], points[i][1], points[i][2]};
    std::memcpy(&out[12 * i], xyz, 12);
  }
  return out;
}

absl::StatusOr<std::vector<Vec3f>> UnpackPoints(const std::string& bytes,
                                                const std::string& field) {
  if (bytes.size() % 12 != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(field, " has ", bytes.size(), " bytes, not a multiple of 12 (float32 xyz)"));
  }
  std::vector<Vec3f> points(bytes.size() / 12);
  for (size_t i = 0; i < points.size(); ++i) std::memcpy(points[i].data(), &bytes[12 * i], 12);
  return points;
}

}  // namespace

std::string PackXyz(const std::vector<Vec3f>& points) { return PackPoints(points); }

std::string PackXyz(const std::vector<std::array<float, 3>>& points) { return PackPoints(points); }

absl::StatusOr<std::vector<float>> UnpackFloats(const std::string& bytes, size_t count,
                                                const std::string& field) {
  if (bytes.size() != 4 * count) {
    return absl::InvalidArgumentError(absl::StrCat(field, " has ", bytes.size(),
                                                   " bytes, expected ", 4 * count, " (", count,
                                                   " float32 values)"));
  }
  std::vector<float> values(count);
  if (count > 0) std::memcpy(values.data(), bytes.data(), bytes.size());
  return values;
}

rim::v1::Scan ScanToProto(const PosedScan& scan, const std::string& robot_id, uint64_t sequence) {
  rim::v1::Scan out;
  out.set_robot_id(robot_id);
  out.set_sequence(sequence);
  out.set_timestamp_s(scan.timestamp_s);
  const Eigen::Vector3d t = scan.T_world_sensor.translation();
  const Eigen::Quaterniond q = Eigen::Quaterniond(scan.T_world_sensor.rotation()).normalized();
  auto* pose = out.mutable_pose();
  pose->mutable_translation()->set_x(t.x());
  pose->mutable_translation()->set_y(t.y());
  pose->mutable_translation()->set_z(t.z());
  pose->mutable_rotation()->set_w(q.w());
  pose->mutable_rotation()->set_x(q.x());
  pose->mutable_rotation()->set_y(q.y());
  pose->mutable_rotation()->set_z(q.z());
  out.set_points_xyz(PackXyz(scan.points_S));
  if (!scan.origins_S.empty()) out.set_origins_xyz(PackXyz(scan.origins_S));
  return out;
}

absl::StatusOr<PosedScan> ScanFromProto(const rim::v1::Scan& scan) {
  if (scan.has_depth()) {
    return absl::InvalidArgumentError("scan.depth: only point scans can be read back");
  }
  PosedScan out;
  out.timestamp_s = scan.timestamp_s();
  const auto& t = scan.pose().translation();
  const auto& r = scan.pose().rotation();
  out.T_world_sensor = Eigen::Isometry3d::Identity();
  out.T_world_sensor.linear() =
      Eigen::Quaterniond(r.w(), r.x(), r.y(), r.z()).normalized().toRotationMatrix();
  out.T_world_sensor.translation() = Eigen::Vector3d(t.x(), t.y(), t.z());
  auto points = UnpackPoints(scan.points_xyz(), "scan.points_xyz");
  if (!points.ok()) return points.status();
  out.points_S = std::move(*points);
  auto origins = UnpackPoints(scan.origins_xyz(), "scan.origins_xyz");
  if (!origins.ok()) return origins.status();
  if (!origins->empty() && origins->size() != out.points_S.size()) {
    return absl::InvalidArgumentError(absl::StrCat("scan.origins_xyz has ", origins->size(),
                                                   " points, expected one per point (",
                                                   out.points_S.size(), ")"));
  }
  out.origins_S = std::move(*origins);
  return out;
}

}  // namespace rim
