#include "rim/io/kitti.h"

#include <cmath>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "absl/strings/string_view.h"
#include "rim/base/status_macros.h"
#include "rim/io/file_util.h"
#include "rim/io/pose_file.h"

namespace rim::io {

absl::StatusOr<PointCloud> ReadKittiBin(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path));
  return ParseKittiBin(data, path);
}

absl::StatusOr<PointCloud> ParseKittiBin(absl::string_view data, const std::string& path) {
  if (data.size() % 16 != 0) {
    return absl::DataLossError(absl::StrCat(path, ": size ", data.size(),
                                            " bytes is not a multiple of 16 (float32 x, y, z, "
                                            "intensity per point): truncated or not a KITTI scan"));
  }
  const size_t n = data.size() / 16;
  PointCloud cloud;
  cloud.points.resize(n);
  cloud.intensity.resize(n);
  for (size_t i = 0; i < n; ++i) {
    float rec[4];
    std::memcpy(rec, data.data() + 16 * i, 16);
    cloud.points[i] = Vec3f(rec[0], rec[1], rec[2]);
    cloud.intensity[i] = rec[3];
  }
  return cloud;
}

absl::Status WriteKittiBin(const std::string& path, const PointCloud& cloud) {
  const bool has_intensity = !cloud.intensity.empty();
  if (has_intensity && cloud.intensity.size() != cloud.points.size()) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": ", cloud.intensity.size(), " intensities for ", cloud.points.size(), " points"));
  }
  std::string out(cloud.points.size() * 16, '\0');
  for (size_t i = 0; i < cloud.points.size(); ++i) {
    const float rec[4] = {cloud.points[i].x(), cloud.points[i].y(), cloud.points[i].z(),
                          has_intensity ? cloud.intensity[i] : 0.0f};
    std::memcpy(out.data() + 16 * i, rec, 16);
  }
  return WriteStringToFile(path, out);
}

absl::StatusOr<Eigen::Isometry3d> ReadCalibFile(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path, 1 << 20));
  return ParseCalib(data, path);
}

absl::StatusOr<Eigen::Isometry3d> ParseCalib(absl::string_view data, const std::string& path) {
  for (const TextLine& line : SplitLines(data, '#')) {
    absl::string_view text = line.text;
    const size_t colon = text.find(':');
    if (colon == absl::string_view::npos) continue;
    const absl::string_view key = text.substr(0, colon);
    if (key != "Tr" && key != "Tr_velo_to_cam") continue;
    RIM_ASSIGN_OR_RETURN(std::vector<double> values,
                         ParseFiniteNumbers(text.substr(colon + 1), 12, path, line.number,
                                            "Tr, 3x4 row-major LiDAR-to-camera transform"));
    return RigidFromRowMajor(values, path, line.number);
  }
  return absl::InvalidArgumentError(
      absl::StrCat(path, ": no 'Tr:' line (3x4 LiDAR-to-camera transform)"));
}

absl::Status WriteCalibFile(const std::string& path, const Eigen::Isometry3d& tr_lidar_to_cam) {
  const std::string identity = FormatPose3x4(Eigen::Isometry3d::Identity());
  std::string out;
  for (int i = 0; i < 4; ++i) absl::StrAppend(&out, "P", i, ": ", identity, "\n");
  absl::StrAppend(&out, "Tr: ", FormatPose3x4(tr_lidar_to_cam), "\n");
  return WriteStringToFile(path, out);
}

std::vector<Eigen::Isometry3d> CameraToLidarPoses(const std::vector<Eigen::Isometry3d>& cam_poses,
                                                  const Eigen::Isometry3d& tr_lidar_to_cam) {
  const Eigen::Isometry3d tr_inv = tr_lidar_to_cam.inverse();
  std::vector<Eigen::Isometry3d> out;
  out.reserve(cam_poses.size());
  for (const Eigen::Isometry3d& p : cam_poses) out.push_back(tr_inv * p * tr_lidar_to_cam);
  return out;
}

}  // namespace rim::io
