// The depth-image layouts: 7-Scenes / 3DMatch and Replica (NICE-SLAM).
#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/io/dataset_internal.h"
#include "rim/io/depth.h"
#include "rim/io/file_util.h"
#include "rim/io/png_io.h"
#include "rim/io/pose_file.h"

namespace rim::io::internal {
namespace {

class DepthDataset : public Dataset {
 public:
  DepthDataset(DatasetLayout layout, std::vector<std::string> frames,
               std::vector<Eigen::Isometry3d> poses, CameraIntrinsics intrinsics,
               DepthEncoding encoding)
      : layout_(layout),
        frames_(std::move(frames)),
        poses_(std::move(poses)),
        intrinsics_(intrinsics),
        encoding_(encoding) {}

  DatasetLayout layout() const override { return layout_; }
  size_t size() const override { return frames_.size(); }
  const std::vector<Eigen::Isometry3d>& poses() const override { return poses_; }

  absl::StatusOr<PosedScan> Read(size_t index) const override {
    if (index >= frames_.size()) {
      return absl::OutOfRangeError(
          absl::StrCat("frame ", index, " requested from a dataset of ", frames_.size()));
    }
    RIM_ASSIGN_OR_RETURN(const Image16 depth, ReadPng16(frames_[index]));
    if (intrinsics_.width > 0 &&
        (depth.width != intrinsics_.width || depth.height != intrinsics_.height)) {
      return absl::FailedPreconditionError(absl::StrCat(
          frames_[index], ": depth image is ", depth.width, "x", depth.height,
          " but the camera parameters say ", intrinsics_.width, "x", intrinsics_.height));
    }
    PosedScan scan;
    scan.T_world_sensor = poses_[index];
    scan.points_S = BackProjectDepth(depth, intrinsics_, encoding_);
    scan.timestamp_s = index * kDepthFramePeriodS;
    return scan;
  }

 private:
  DatasetLayout layout_;
  std::vector<std::string> frames_;  // depth image paths
  std::vector<Eigen::Isometry3d> poses_;
  CameraIntrinsics intrinsics_;
  DepthEncoding encoding_;
};

std::string ParentDir(const std::string& dir) {
  std::filesystem::path p(dir);
  if (!p.has_filename()) p = p.parent_path();  // "a/b/" -> "a/b"
  return p.parent_path().string();
}

// `name` in `dir`, else in its parent (3DMatch and NICE-SLAM keep camera files one level up);
// empty if in neither.
std::string FindHereOrParent(const std::string& dir, const std::string& name) {
  for (const std::string& d : {dir, ParentDir(dir)}) {
    if (d.empty()) continue;
    const std::string path = JoinPath(d, name);
    if (IsRegularFile(path)) return path;
  }
  return "";
}

}  // namespace

absl::StatusOr<std::unique_ptr<Dataset>> OpenSevenScenes(const std::string& dir) {
  static constexpr char kDepthSuffix[] = ".depth.png";
  std::vector<std::string> frames = ListFiles(dir, "frame-", kDepthSuffix);
  std::vector<Eigen::Isometry3d> poses;
  poses.reserve(frames.size());
  for (std::string& frame : frames) {
    const std::string stem = frame.substr(0, frame.size() - (sizeof(kDepthSuffix) - 1));
    const std::string pose_path = JoinPath(dir, stem + ".pose.txt");
    frame = JoinPath(dir, frame);
    if (!IsRegularFile(pose_path)) {
      return absl::NotFoundError(
          absl::StrCat(pose_path, ": missing (pose of ", frame, "; 4x4 camera-to-world)"));
    }
    RIM_ASSIGN_OR_RETURN(const Eigen::Isometry3d pose, ReadPose4x4File(pose_path));
    poses.push_back(pose);
  }
  CameraIntrinsics K = kSevenScenesDefaultIntrinsics;
  const std::string k_path = FindHereOrParent(dir, "camera-intrinsics.txt");
  if (!k_path.empty()) {
    RIM_ASSIGN_OR_RETURN(K, ReadIntrinsicsMatrixFile(k_path));
  }
  return std::make_unique<DepthDataset>(DatasetLayout::kSevenScenes, std::move(frames),
                                        std::move(poses), K, DepthEncoding{1000.0, true});
}

absl::StatusOr<std::unique_ptr<Dataset>> OpenReplica(const std::string& dir) {
  const std::string results = JoinPath(dir, "results");
  std::vector<std::string> frames = ListFiles(results, "depth", ".png");
  for (std::string& f : frames) f = JoinPath(results, f);
  const std::string traj_path = JoinPath(dir, "traj.txt");
  if (!IsRegularFile(traj_path)) {
    return absl::NotFoundError(absl::StrCat(
        traj_path, ": missing (Replica layout needs one 4x4 camera-to-world pose per line)"));
  }
  RIM_ASSIGN_OR_RETURN(std::vector<Eigen::Isometry3d> poses, ReadPoses4x4LinesFile(traj_path));
  if (poses.size() != frames.size()) {
    return absl::FailedPreconditionError(
        absl::StrCat(traj_path, " has ", poses.size(), " poses but ", results, " has ",
                     frames.size(), " depth*.png frames; they must match one to one"));
  }
  const std::string cam_path = FindHereOrParent(dir, "cam_params.json");
  if (cam_path.empty()) {
    return absl::NotFoundError(absl::StrCat(
        JoinPath(dir, "cam_params.json"),
        ": missing (also looked in the parent folder); Replica depth needs w, h, fx, fy, cx, cy "
        "and scale"));
  }
  RIM_ASSIGN_OR_RETURN(const ReplicaCamera cam, ReadReplicaCamParams(cam_path));
  return std::make_unique<DepthDataset>(DatasetLayout::kReplica, std::move(frames),
                                        std::move(poses), cam.intrinsics,
                                        DepthEncoding{cam.scale, false});
}

}  // namespace rim::io::internal
