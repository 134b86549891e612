#include "server/service/scan_convert.h"

#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "rim/mapper.h"

namespace rim::server {
namespace {

bool Finite(double v) { return std::isfinite(v); }

absl::StatusOr<Eigen::Isometry3d> ConvertPose(const rim::v1::Scan& scan) {
  if (!scan.has_pose()) return absl::InvalidArgumentError("scan.pose is missing");
  const rim::v1::Vec3& t = scan.pose().translation();
  if (!Finite(t.x()) || !Finite(t.y()) || !Finite(t.z()))
    return absl::InvalidArgumentError("scan.pose.translation is not finite");
  const rim::v1::Quaternion& q = scan.pose().rotation();
  if (!Finite(q.w()) || !Finite(q.x()) || !Finite(q.y()) || !Finite(q.z()))
    return absl::InvalidArgumentError("scan.pose.rotation is not finite");
  const Eigen::Quaterniond quat(q.w(), q.x(), q.y(), q.z());
  const double norm = quat.norm();
  if (!(std::abs(norm - 1.0) <= 1e-3))
    return absl::InvalidArgumentError(
        absl::StrCat("scan.pose.rotation is not a unit quaternion (norm ", norm, ")"));
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = quat.normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(t.x(), t.y(), t.z());
  return T;
}

absl::Status ConvertDepth(const rim::v1::DepthImage& depth, size_t max_points, PosedScan* out) {
  size_t bytes_per_pixel = 0;
  if (depth.encoding() == rim::v1::DepthImage::UINT16) {
    bytes_per_pixel = 2;
  } else if (depth.encoding() == rim::v1::DepthImage::FLOAT32) {
    bytes_per_pixel = 4;
  } else {
    return absl::InvalidArgumentError("scan.depth.encoding must be UINT16 or FLOAT32");
  }
  if (depth.width() == 0 || depth.height() == 0)
    return absl::InvalidArgumentError("scan.depth.width and scan.depth.height must be > 0");
  const size_t pixels = size_t(depth.width()) * size_t(depth.height());
  if (depth.data().size() != pixels * bytes_per_pixel)
    return absl::InvalidArgumentError(absl::StrCat("scan.depth.data has ", depth.data().size(),
                                                   " bytes; width*height*", bytes_per_pixel, " = ",
                                                   pixels * bytes_per_pixel));
  if (!Finite(depth.fx()) || !Finite(depth.fy()) || depth.fx() <= 0 || depth.fy() <= 0)
    return absl::InvalidArgumentError("scan.depth.fx and scan.depth.fy must be finite and > 0");
  if (!Finite(depth.cx()) || !Finite(depth.cy()))
    return absl::InvalidArgumentError("scan.depth.cx and scan.depth.cy must be finite");
  if (!Finite(depth.scale()) || depth.scale() <= 0)
    return absl::InvalidArgumentError("scan.depth.scale must be finite and > 0");
  if (pixels > max_points)
    return absl::ResourceExhaustedError(absl::StrCat("scan.depth has ", pixels,
                                                     " pixels, over the limit of ", max_points,
                                                     " points per scan (--max-points-per-scan)"));
  const char* data = depth.data().data();
  out->points_S.reserve(pixels);
  for (uint32_t v = 0; v < depth.height(); ++v) {
    for (uint32_t u = 0; u < depth.width(); ++u) {
      const size_t i = size_t(v) * depth.width() + u;
      double d = 0;
      if (bytes_per_pixel == 2) {
        uint16_t raw;
        std::memcpy(&raw, data + 2 * i, 2);
        if (raw == 0 || raw == 65535) continue;
        d = raw;
      } else {
        float raw;
        std::memcpy(&raw, data + 4 * i, 4);
        if (!std::isfinite(raw) || raw <= 0) continue;
        d = raw;
      }
      const double z = d / depth.scale();
      out->points_S.emplace_back(float((u - depth.cx()) * z / depth.fx()),
                                 float((v - depth.cy()) * z / depth.fy()), float(z));
    }
  }
  if (out->points_S.empty()) return absl::InvalidArgumentError("scan.depth has no valid pixels");
  return absl::OkStatus();
}

// The mapper's own checks last (e.g. a pose beyond 1e6 m): a scan accepted here goes into the
// write-ahead log, and one that training then refused would also fail every replay of the log.
absl::StatusOr<PosedScan> Validated(PosedScan scan) {
  if (absl::Status s = Mapper::ValidateScan(scan); !s.ok()) return s;
  return scan;
}

}  // namespace

absl::StatusOr<std::vector<float>> UnpackXyz(const std::string& bytes, const std::string& field,
                                             size_t max_points, const std::string& limit_flag) {
  if (bytes.empty()) return absl::InvalidArgumentError(absl::StrCat(field, " is empty"));
  if (bytes.size() % 12 != 0)
    return absl::InvalidArgumentError(
        absl::StrCat(field, " has ", bytes.size(), " bytes, not a multiple of 12 (float32 xyz)"));
  const size_t n = bytes.size() / 12;
  if (n > max_points)
    return absl::ResourceExhaustedError(absl::StrCat(
        field, " has ", n, " points, over the limit of ", max_points, " (", limit_flag, ")"));
  std::vector<float> xyz(3 * n);
  std::memcpy(xyz.data(), bytes.data(), bytes.size());
  for (size_t i = 0; i < xyz.size(); ++i) {
    if (!std::isfinite(xyz[i]))
      return absl::InvalidArgumentError(
          absl::StrCat(field, " has a non-finite value at point ", i / 3));
  }
  return xyz;
}

absl::StatusOr<PosedScan> ConvertScan(const rim::v1::Scan& scan, size_t max_points) {
  PosedScan out;
  auto pose = ConvertPose(scan);
  if (!pose.ok()) return pose.status();
  out.T_world_sensor = *pose;
  if (!Finite(scan.timestamp_s()))
    return absl::InvalidArgumentError("scan.timestamp_s is not finite");
  out.timestamp_s = scan.timestamp_s();
  switch (scan.data_case()) {
    case rim::v1::Scan::kPointsXyz: {
      auto xyz =
          UnpackXyz(scan.points_xyz(), "scan.points_xyz", max_points, "--max-points-per-scan");
      if (!xyz.ok()) return xyz.status();
      const size_t n = xyz->size() / 3;
      if (!scan.origins_xyz().empty()) {
        if (scan.origins_xyz().size() != scan.points_xyz().size())
          return absl::InvalidArgumentError(
              absl::StrCat("scan.origins_xyz has ", scan.origins_xyz().size(),
                           " bytes; it must be empty or as long as scan.points_xyz (",
                           scan.points_xyz().size(), ")"));
        auto origins =
            UnpackXyz(scan.origins_xyz(), "scan.origins_xyz", max_points, "--max-points-per-scan");
        if (!origins.ok()) return origins.status();
        out.origins_S.resize(n);
        for (size_t i = 0; i < n; ++i)
          out.origins_S[i] = Vec3f((*origins)[3 * i], (*origins)[3 * i + 1], (*origins)[3 * i + 2]);
      }
      out.points_S.resize(n);
      for (size_t i = 0; i < n; ++i)
        out.points_S[i] = Vec3f((*xyz)[3 * i], (*xyz)[3 * i + 1], (*xyz)[3 * i + 2]);
      return Validated(std::move(out));
    }
    case rim::v1::Scan::kDepth: {
      if (!scan.origins_xyz().empty())
        return absl::InvalidArgumentError("scan.origins_xyz must be empty for a depth image");
      absl::Status s = ConvertDepth(scan.depth(), max_points, &out);
      if (!s.ok()) return s;
      return Validated(std::move(out));
    }
    default:
      return absl::InvalidArgumentError("scan.points_xyz or scan.depth must be set");
  }
}

}  // namespace rim::server
