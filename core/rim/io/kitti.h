// KITTI odometry pieces: velodyne/NNNNNN.bin scans and the calib.txt `Tr:` transform.
//
// A .bin scan is a flat array of little-endian float32 (x, y, z, intensity) records, 16 bytes per
// point, in the LiDAR frame. KITTI's poses.txt holds camera (cam0) poses P_k; calib.txt's `Tr`
// maps LiDAR coordinates into cam0 coordinates, so the LiDAR pose is
//   T_world_lidar = Tr^-1 * P_k * Tr
// (the world frame being the LiDAR frame of the first scan when P_0 = I).
#pragma once

#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "rim/io/point_cloud.h"

namespace rim::io {

// Reads a .bin scan. The file size must be a multiple of 16 bytes. Every point is returned, with
// intensities; non-finite points are kept (Dataset::Read drops them).
absl::StatusOr<PointCloud> ReadKittiBin(const std::string& path);

// Writes a .bin scan; missing intensities (cloud.intensity empty) are written as 0.
absl::Status WriteKittiBin(const std::string& path, const PointCloud& cloud);

// Reads the `Tr:` line of a KITTI calib.txt (12 numbers, 3x4 row-major LiDAR-to-cam0). Other
// lines (P0..P3, Tr_imu_velo, ...) are ignored. `Tr_velo_to_cam:` is accepted as a synonym.
// Errors if the line is missing, malformed or not a rigid transform.
absl::StatusOr<Eigen::Isometry3d> ReadCalibFile(const std::string& path);

// ReadKittiBin and ReadCalibFile on bytes already in memory; `path` is only used in messages.
absl::StatusOr<PointCloud> ParseKittiBin(absl::string_view data, const std::string& path);
absl::StatusOr<Eigen::Isometry3d> ParseCalib(absl::string_view data, const std::string& path);

// Writes a calib.txt with identity P0..P3 (3x4, no intrinsics) and the given `Tr:` line.
absl::Status WriteCalibFile(const std::string& path, const Eigen::Isometry3d& tr_lidar_to_cam);

// Converts camera poses P_k to LiDAR poses Tr^-1 * P_k * Tr.
std::vector<Eigen::Isometry3d> CameraToLidarPoses(const std::vector<Eigen::Isometry3d>& cam_poses,
                                                  const Eigen::Isometry3d& tr_lidar_to_cam);

}  // namespace rim::io
