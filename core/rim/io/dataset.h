// Reading posed scans from the dataset layouts of DESIGN.md §4.1. The layout is detected from the
// folder; frames are read on demand, so a long sequence never sits in memory at once.
#pragma once

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "rim/base/scan.h"

namespace rim::io {

enum class DatasetLayout {
  kKitti,        // velodyne/NNNNNN.bin + poses.txt + calib.txt
  kPlyFrames,    // a folder of per-frame .ply + poses.txt (+ calib.txt)
  kPcdFrames,    // scans/NNNNNN.pcd + poses.txt
  kSevenScenes,  // frame-NNNNNN.depth.png + frame-NNNNNN.pose.txt + camera-intrinsics.txt
  kReplica,      // results/depthNNNNNN.png + traj.txt + cam_params.json
};

const char* LayoutName(DatasetLayout layout);

class Dataset {
 public:
  // Detects the layout of `path` and checks its index files (pose count against frame count, ...).
  // Errors name the file and, where it applies, the line.
  static absl::StatusOr<std::unique_ptr<Dataset>> Open(const std::string& path);
  virtual ~Dataset() = default;

  virtual DatasetLayout layout() const = 0;
  virtual size_t size() const = 0;
  // T_world_sensor of every frame (size() of them), as Read gives it, without reading a frame:
  // the index files are read by Open.
  virtual const std::vector<Eigen::Isometry3d>& poses() const = 0;
  // Reads frame `index`: points in the sensor frame (depth images become rays from the camera
  // centre) and T_world_sensor. Errors name the file.
  virtual absl::StatusOr<PosedScan> Read(size_t index) const = 0;
};

}  // namespace rim::io
