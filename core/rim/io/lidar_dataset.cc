// The point-cloud layouts: KITTI odometry, PLY frames (MaiCity) and PCD frames.
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/io/dataset_internal.h"
#include "rim/io/file_util.h"
#include "rim/io/kitti.h"
#include "rim/io/pcd.h"
#include "rim/io/ply_points.h"
#include "rim/io/pose_file.h"

namespace rim::io::internal {
namespace {

class LidarFramesDataset : public Dataset {
 public:
  LidarFramesDataset(DatasetLayout layout, std::vector<std::string> frames,
                     std::vector<Eigen::Isometry3d> poses, std::vector<double> times)
      : layout_(layout),
        frames_(std::move(frames)),
        poses_(std::move(poses)),
        times_(std::move(times)) {}

  DatasetLayout layout() const override { return layout_; }
  size_t size() const override { return frames_.size(); }
  const std::vector<Eigen::Isometry3d>& poses() const override { return poses_; }

  absl::StatusOr<PosedScan> Read(size_t index) const override {
    if (index >= frames_.size()) {
      return absl::OutOfRangeError(
          absl::StrCat("frame ", index, " requested from a dataset of ", frames_.size()));
    }
    PointCloud cloud;
    switch (layout_) {
      case DatasetLayout::kKitti: {
        RIM_ASSIGN_OR_RETURN(cloud, ReadKittiBin(frames_[index]));
        break;
      }
      case DatasetLayout::kPlyFrames: {
        RIM_ASSIGN_OR_RETURN(cloud, ReadPlyPoints(frames_[index]));
        break;
      }
      default: {
        RIM_ASSIGN_OR_RETURN(cloud, ReadPcd(frames_[index]));
        break;
      }
    }
    DropNonFinitePoints(&cloud);
    PosedScan scan;
    scan.T_world_sensor = poses_[index];
    scan.points_S = std::move(cloud.points);
    scan.timestamp_s = times_[index];
    return scan;
  }

 private:
  DatasetLayout layout_;
  std::vector<std::string> frames_;  // paths
  std::vector<Eigen::Isometry3d> poses_;
  std::vector<double> times_;
};

absl::StatusOr<std::unique_ptr<Dataset>> OpenFrames(DatasetLayout layout, const std::string& dir,
                                                    const std::string& frames_dir,
                                                    const char* suffix, bool use_calib) {
  std::vector<std::string> frames = ListFiles(frames_dir, "", suffix);
  for (std::string& f : frames) f = JoinPath(frames_dir, f);
  const std::string poses_path = JoinPath(dir, "poses.txt");
  if (!IsRegularFile(poses_path)) {
    return absl::NotFoundError(absl::StrCat(poses_path, ": missing (", LayoutName(layout),
                                            " layout needs one 3x4 pose per line, one per frame)"));
  }
  RIM_ASSIGN_OR_RETURN(std::vector<Eigen::Isometry3d> poses, ReadPoses3x4File(poses_path));
  const std::string calib_path = JoinPath(dir, "calib.txt");
  if (use_calib && IsRegularFile(calib_path)) {
    // Without calib.txt the poses are taken as LiDAR poses already (Tr = identity).
    RIM_ASSIGN_OR_RETURN(const Eigen::Isometry3d tr, ReadCalibFile(calib_path));
    poses = CameraToLidarPoses(poses, tr);
  }
  if (poses.size() != frames.size()) {
    return absl::FailedPreconditionError(
        absl::StrCat(poses_path, " has ", poses.size(), " poses but ", frames_dir, " has ",
                     frames.size(), " ", suffix, " frames; they must match one to one"));
  }
  std::vector<double> times(frames.size());
  const std::string times_path = JoinPath(dir, "times.txt");
  if (IsRegularFile(times_path)) {
    RIM_ASSIGN_OR_RETURN(times, ReadTimesFile(times_path));
    if (times.size() != frames.size()) {
      return absl::FailedPreconditionError(absl::StrCat(times_path, " has ", times.size(),
                                                        " timestamps but ", frames_dir, " has ",
                                                        frames.size(), " frames"));
    }
  } else {
    for (size_t i = 0; i < times.size(); ++i) times[i] = i * kLidarFramePeriodS;
  }
  return std::make_unique<LidarFramesDataset>(layout, std::move(frames), std::move(poses),
                                              std::move(times));
}

}  // namespace

absl::StatusOr<std::unique_ptr<Dataset>> OpenKitti(const std::string& dir) {
  return OpenFrames(DatasetLayout::kKitti, dir, JoinPath(dir, "velodyne"), ".bin", true);
}

absl::StatusOr<std::unique_ptr<Dataset>> OpenPlyFrames(const std::string& dir,
                                                       const std::string& frames_dir) {
  return OpenFrames(DatasetLayout::kPlyFrames, dir, frames_dir, ".ply", true);
}

absl::StatusOr<std::unique_ptr<Dataset>> OpenPcdFrames(const std::string& dir) {
  return OpenFrames(DatasetLayout::kPcdFrames, dir, JoinPath(dir, "scans"), ".pcd", false);
}

}  // namespace rim::io::internal
