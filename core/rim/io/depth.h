// Depth images: pinhole intrinsics, their files (7-Scenes camera-intrinsics.txt, Replica
// cam_params.json) and back-projection of depth pixels to points in the camera frame.
//
// Camera frame: OpenCV convention (x right, y down, z forward). Pixel (u, v) is column u, row v,
// 0-based, and the point of depth z (metres) is (x, y, z) with x = (u - cx) z / fx and
// y = (v - cy) z / fy.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "rim/base/types.h"
#include "rim/io/png_io.h"

namespace rim::io {

struct CameraIntrinsics {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  int width = 0, height = 0;  // 0: not given by the file (7-Scenes)
};

// The 7-Scenes / 3DMatch default when camera-intrinsics.txt is absent (Kinect v1, 640x480).
inline constexpr CameraIntrinsics kSevenScenesDefaultIntrinsics = {585.0, 585.0, 320.0,
                                                                   240.0, 0,     0};

// How raw depth values map to metres: z = value / units_per_metre. Value 0 is always invalid;
// 65535 is too when `max_is_invalid` (7-Scenes marks missing depth that way).
struct DepthEncoding {
  double units_per_metre = 1000.0;
  bool max_is_invalid = true;
};

// Points (camera frame, float) of every valid pixel, in row-major pixel order.
std::vector<Vec3f> BackProjectDepth(const Image16& depth, const CameraIntrinsics& K,
                                    const DepthEncoding& encoding);

// Reads a 3x3 K matrix (9 numbers, row-major, any line breaks): fx = K00, fy = K11, cx = K02,
// cy = K12. Requires zero skew and a last row of 0 0 1, fx and fy > 0.
absl::StatusOr<CameraIntrinsics> ReadIntrinsicsMatrixFile(const std::string& path);

// Replica (NICE-SLAM) cam_params.json: keys w, h, fx, fy, cx, cy, scale, inside a "camera"
// object or at the top level. `scale` is the depth units per metre.
struct ReplicaCamera {
  CameraIntrinsics intrinsics;
  double scale = 0;
};
absl::StatusOr<ReplicaCamera> ReadReplicaCamParams(const std::string& path);

// The two files above parsed from bytes already in memory; `path` is only used in messages.
absl::StatusOr<CameraIntrinsics> ParseIntrinsicsMatrix(absl::string_view data,
                                                       const std::string& path);
absl::StatusOr<ReplicaCamera> ParseReplicaCamParams(absl::string_view data,
                                                    const std::string& path);

}  // namespace rim::io
