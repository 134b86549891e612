// The text files of the dataset layouts: KITTI poses.txt and calib.txt, Replica traj.txt, 7-Scenes
// frame-N.pose.txt and camera-intrinsics.txt, and times.txt. The first byte picks the parser, the
// rest is the file.
#include <Eigen/Geometry>
#include <cmath>

#include "fuzz_util.h"
#include "rim/io/depth.h"
#include "rim/io/kitti.h"
#include "rim/io/pose_file.h"

namespace {

// pose_file.h: accepted poses are finite rigid transforms, re-orthonormalised.
void CheckPose(const Eigen::Isometry3d& pose) {
  RIM_FUZZ_CHECK(pose.matrix().allFinite());
  const Eigen::Matrix3d R = pose.linear();
  RIM_FUZZ_CHECK((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-9);
  RIM_FUZZ_CHECK(R.determinant() > 0);
}

template <typename T>
void CheckPoses(const absl::StatusOr<std::vector<T>>& poses) {
  if (poses.ok())
    for (const auto& p : *poses) CheckPose(p);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const absl::string_view text = rim::fuzz::AbslBytes(data + 1, size - 1);
  switch (data[0] % 6) {
    case 0:
      CheckPoses(rim::io::ParsePoses3x4(text, "poses.txt"));
      break;
    case 1:
      CheckPoses(rim::io::ParsePoses4x4Lines(text, "traj.txt"));
      break;
    case 2:
      if (auto pose = rim::io::ParsePose4x4(text, "frame.pose.txt"); pose.ok()) CheckPose(*pose);
      break;
    case 3:
      if (auto tr = rim::io::ParseCalib(text, "calib.txt"); tr.ok()) CheckPose(*tr);
      break;
    case 4:
      if (auto K = rim::io::ParseIntrinsicsMatrix(text, "camera-intrinsics.txt"); K.ok()) {
        RIM_FUZZ_CHECK(K->fx > 0 && K->fy > 0 && std::isfinite(K->fx) && std::isfinite(K->fy));
        RIM_FUZZ_CHECK(std::isfinite(K->cx) && std::isfinite(K->cy));
      }
      break;
    default:
      if (auto times = rim::io::ParseTimes(text, "times.txt"); times.ok())
        for (double t : *times) RIM_FUZZ_CHECK(std::isfinite(t));
      break;
  }
  return 0;
}
