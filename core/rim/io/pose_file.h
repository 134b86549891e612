// Pose text files of the dataset layouts: KITTI-style poses.txt (one 3x4 row-major [R|t] per
// line), Replica traj.txt (one 4x4 row-major matrix per line), 7-Scenes frame-N.pose.txt (a 4x4
// matrix over four lines) and times.txt (one timestamp per line).
//
// Every pose is checked: all values finite, R orthonormal with det(R) = +1 to within
// kRotationTolerance (max |R^T R - I|), and for 4x4 matrices a last row of 0 0 0 1. Accepted
// rotations are re-orthonormalised (nearest rotation, by SVD) so that text rounding in the file
// (KITTI prints 6-10 digits) does not leave a slightly non-rigid Isometry3d. Errors name the file
// and the 1-based line.
#pragma once

#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace rim::io {

inline constexpr double kRotationTolerance = 1e-3;

// Builds a rigid transform from 12 (3x4) or 16 (4x4) row-major values, checking it as above.
// `path` and `line` are only used in error messages.
absl::StatusOr<Eigen::Isometry3d> RigidFromRowMajor(const std::vector<double>& values,
                                                    const std::string& path, int line);

// poses.txt: one pose per non-empty line, 12 numbers each.
absl::StatusOr<std::vector<Eigen::Isometry3d>> ReadPoses3x4File(const std::string& path);

// traj.txt (Replica): one pose per non-empty line, 16 numbers each.
absl::StatusOr<std::vector<Eigen::Isometry3d>> ReadPoses4x4LinesFile(const std::string& path);

// A single 4x4 pose written as 16 numbers over any number of lines (7-Scenes uses four).
absl::StatusOr<Eigen::Isometry3d> ReadPose4x4File(const std::string& path);

// times.txt: one finite timestamp (seconds) per non-empty line.
absl::StatusOr<std::vector<double>> ReadTimesFile(const std::string& path);

// The same four formats parsed from bytes already in memory (the Read* functions read the file
// and call these); `path` is only used in messages.
absl::StatusOr<std::vector<Eigen::Isometry3d>> ParsePoses3x4(absl::string_view data,
                                                             const std::string& path);
absl::StatusOr<std::vector<Eigen::Isometry3d>> ParsePoses4x4Lines(absl::string_view data,
                                                                  const std::string& path);
absl::StatusOr<Eigen::Isometry3d> ParsePose4x4(absl::string_view data, const std::string& path);
absl::StatusOr<std::vector<double>> ParseTimes(absl::string_view data, const std::string& path);

// Writes poses as 3x4 row-major lines with 17 significant digits (exact double round trip).
absl::Status WritePosesFile(const std::string& path, const std::vector<Eigen::Isometry3d>& poses);

// Formats one pose as 12 numbers (3x4 row-major) separated by spaces, 17 significant digits.
std::string FormatPose3x4(const Eigen::Isometry3d& pose);

}  // namespace rim::io
