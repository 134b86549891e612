// Internal to core/rim/io: the Dataset implementations behind Dataset::Open.
#pragma once

#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "rim/io/dataset.h"

namespace rim::io::internal {

// Frames that are point-cloud files (KITTI .bin, PLY, PCD) in `frames_dir`, with poses.txt (and
// optional times.txt) in `dir`. KITTI and PLY frames apply calib.txt's Tr when present.
absl::StatusOr<std::unique_ptr<Dataset>> OpenKitti(const std::string& dir);
absl::StatusOr<std::unique_ptr<Dataset>> OpenPlyFrames(const std::string& dir,
                                                       const std::string& frames_dir);
absl::StatusOr<std::unique_ptr<Dataset>> OpenPcdFrames(const std::string& dir);

absl::StatusOr<std::unique_ptr<Dataset>> OpenSevenScenes(const std::string& dir);
absl::StatusOr<std::unique_ptr<Dataset>> OpenReplica(const std::string& dir);

// Nominal frame periods used as timestamps when a dataset has no times.txt.
inline constexpr double kLidarFramePeriodS = 0.1;         // 10 Hz spinning LiDAR
inline constexpr double kDepthFramePeriodS = 1.0 / 30.0;  // 30 Hz depth camera

}  // namespace rim::io::internal
