#include "rim/io/pose_file.h"

#include <Eigen/SVD>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/status_macros.h"
#include "rim/io/file_util.h"

namespace rim::io {
namespace {

absl::StatusOr<std::vector<Eigen::Isometry3d>> ParsePoseLines(absl::string_view data,
                                                              const std::string& path,
                                                              size_t per_line, const char* what) {
  std::vector<Eigen::Isometry3d> poses;
  for (const TextLine& line : SplitLines(data, '#')) {
    RIM_ASSIGN_OR_RETURN(std::vector<double> values,
                         ParseFiniteNumbers(line.text, per_line, path, line.number, what));
    RIM_ASSIGN_OR_RETURN(Eigen::Isometry3d pose, RigidFromRowMajor(values, path, line.number));
    poses.push_back(pose);
  }
  return poses;
}

}  // namespace

absl::StatusOr<Eigen::Isometry3d> RigidFromRowMajor(const std::vector<double>& values,
                                                    const std::string& path, int line) {
  if (values.size() != 12 && values.size() != 16) {
    return absl::InvalidArgumentError(absl::StrCat(path, ":", line, ": a pose needs 12 or 16 ",
                                                   "numbers, found ", values.size()));
  }
  for (size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) {
      return absl::InvalidArgumentError(absl::StrCat(path, ":", line, ": pose value ", i + 1,
                                                     " is not finite (", values[i], ")"));
    }
  }
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) R(r, c) = values[r * 4 + c];
    t[r] = values[r * 4 + 3];
  }
  if (values.size() == 16) {
    const double err = std::abs(values[12]) + std::abs(values[13]) + std::abs(values[14]) +
                       std::abs(values[15] - 1.0);
    if (err > 1e-6) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s:%d: last row of the 4x4 pose is [%g %g %g %g], expected [0 0 0 1]",
                          path, line, values[12], values[13], values[14], values[15]));
    }
  }
  const double ortho_err = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  const double det = R.determinant();
  if (!(ortho_err <= kRotationTolerance) || !(det > 0)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s:%d: rotation is not rigid (max |R^T R - I| = %.3g, det = %.6g; tolerance %g)", path,
        line, ortho_err, det, kRotationTolerance));
  }
  // Nearest rotation in the Frobenius norm.
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = svd.matrixU() * svd.matrixV().transpose();
  pose.translation() = t;
  return pose;
}

absl::StatusOr<std::vector<Eigen::Isometry3d>> ParsePoses3x4(absl::string_view data,
                                                             const std::string& path) {
  return ParsePoseLines(data, path, 12, "3x4 row-major pose");
}

absl::StatusOr<std::vector<Eigen::Isometry3d>> ReadPoses3x4File(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path));
  return ParsePoses3x4(data, path);
}

absl::StatusOr<std::vector<Eigen::Isometry3d>> ParsePoses4x4Lines(absl::string_view data,
                                                                  const std::string& path) {
  return ParsePoseLines(data, path, 16, "4x4 row-major pose");
}

absl::StatusOr<std::vector<Eigen::Isometry3d>> ReadPoses4x4LinesFile(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path));
  return ParsePoses4x4Lines(data, path);
}

absl::StatusOr<Eigen::Isometry3d> ReadPose4x4File(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path, 1 << 20));
  return ParsePose4x4(data, path);
}

absl::StatusOr<Eigen::Isometry3d> ParsePose4x4(absl::string_view data, const std::string& path) {
  std::vector<double> values;
  int last_line = 1;
  for (const TextLine& line : SplitLines(data, '#')) {
    RIM_ASSIGN_OR_RETURN(std::vector<double> row, ParseNumbers(line.text, path, line.number));
    for (size_t i = 0; i < row.size(); ++i) {
      if (!std::isfinite(row[i])) {
        return absl::InvalidArgumentError(absl::StrCat(path, ":", line.number, ": value ", i + 1,
                                                       " is not finite (", row[i], ")"));
      }
    }
    values.insert(values.end(), row.begin(), row.end());
    last_line = line.number;
    if (values.size() > 16) break;
  }
  if (values.size() != 16) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": expected 16 numbers (a 4x4 camera-to-world pose), found ", values.size()));
  }
  return RigidFromRowMajor(values, path, last_line);
}

absl::StatusOr<std::vector<double>> ReadTimesFile(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path));
  return ParseTimes(data, path);
}

absl::StatusOr<std::vector<double>> ParseTimes(absl::string_view data, const std::string& path) {
  std::vector<double> times;
  for (const TextLine& line : SplitLines(data, '#')) {
    RIM_ASSIGN_OR_RETURN(std::vector<double> v,
                         ParseFiniteNumbers(line.text, 1, path, line.number, "timestamp"));
    times.push_back(v[0]);
  }
  return times;
}

std::string FormatPose3x4(const Eigen::Isometry3d& pose) {
  std::string out;
  const Eigen::Matrix<double, 3, 4> m = pose.matrix().topRows<3>();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) {
      absl::StrAppendFormat(&out, "%s%.17g", (r == 0 && c == 0) ? "" : " ", m(r, c));
    }
  }
  return out;
}

absl::Status WritePosesFile(const std::string& path, const std::vector<Eigen::Isometry3d>& poses) {
  std::string out;
  for (const Eigen::Isometry3d& pose : poses) absl::StrAppend(&out, FormatPose3x4(pose), "\n");
  return WriteStringToFile(path, out);
}

}  // namespace rim::io
