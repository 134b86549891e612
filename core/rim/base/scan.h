// A posed range scan: what robots stream and what dataset readers produce.
#pragma once

#include <Eigen/Geometry>
#include <vector>

#include "rim/base/types.h"

namespace rim {

struct PosedScan {
  Eigen::Isometry3d T_world_sensor = Eigen::Isometry3d::Identity();
  std::vector<Vec3f> points_S;   // ray endpoints, sensor frame
  std::vector<Vec3f> origins_S;  // per-point ray origins (sensor frame); empty: the sensor origin
  double timestamp_s = 0;
};

}  // namespace rim
