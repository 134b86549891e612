// File writers for rim_sim's output layouts: KITTI odometry (LiDAR) and 7-Scenes (depth).
// These are deliberately self-contained (no dependency on core/rim/io).
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "sim/sensors.h"

namespace rim::sim {

// Writes `content` to `path`, replacing it. The error names the file.
absl::Status WriteTextFile(const std::string& path, const std::string& content);

// KITTI velodyne scan: float32 x, y, z, intensity per point, little-endian, no header.
absl::Status WriteKittiScan(const std::string& path, const std::vector<LidarPoint>& points);

// A point cloud as a binary_little_endian PLY: one vertex element with float x, y, z and no faces.
absl::Status WritePointCloudPly(const std::string& path,
                                const std::vector<std::array<float, 3>>& points);

// KITTI poses.txt: one line per frame with the 12 entries of the top 3x4 of the pose, row-major.
absl::Status WriteKittiPoses(const std::string& path, const std::vector<Eigen::Isometry3d>& poses);

// KITTI calib.txt with KITTI-like P0..P3 and an identity `Tr:`, so that the "camera" frame of
// poses.txt is the LiDAR frame itself.
absl::Status WriteKittiCalib(const std::string& path);

// KITTI times.txt: one timestamp (seconds) per frame.
absl::Status WriteKittiTimes(const std::string& path, int frames, double frame_rate_hz);

// 16-bit grayscale PNG (values written as-is, big-endian in the file as PNG requires).
absl::Status WritePng16(const std::string& path, int width, int height,
                        const std::vector<uint16_t>& pixels);

struct Png16 {
  int width = 0, height = 0;
  std::vector<uint16_t> pixels;  // row-major
};
// Reads a 16-bit grayscale PNG written by WritePng16 (other formats are an error).
absl::StatusOr<Png16> ReadPng16(const std::string& path);

// Depth in metres to uint16 millimetres: rounded; 0 (no return) for 0, non-finite or values that
// do not fit below 65535 (which 7-Scenes also treats as invalid).
std::vector<uint16_t> DepthToMillimetres(const std::vector<float>& depth);

// 7-Scenes pose file: the 4x4 camera-to-world matrix, one row per line.
absl::Status WritePoseMatrix(const std::string& path, const Eigen::Isometry3d& pose);

// camera-intrinsics.txt (3DMatch style): the 3x3 K, one row per line.
absl::Status WriteIntrinsics(const std::string& path, const PinholeCamera& camera);

// Removes what an earlier rim_sim run may have left in `dir`, so that a shorter run or a run of
// the other scene cannot leave an inconsistent dataset: velodyne/NNNNNN.bin (and velodyne/ itself
// once empty), frame-NNNNNN.{depth.png,pose.txt,color.png}, and poses.txt, calib.txt, times.txt,
// camera-intrinsics.txt, gt.ply, gt_observed.ply, gt_moving_last.ply, scene.json, README.txt.
// Nothing else is touched.
absl::Status RemovePreviousOutput(const std::string& dir);

}  // namespace rim::sim
