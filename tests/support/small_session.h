// A session small enough for black-box server tests to train in a fraction of a second, and
// scans that fill it: a 4 m x 4 m x 2.4 m map and a LiDAR-like grid of returns on a ground plane
// 1 m below the sensor.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "rim/base/scan.h"

namespace rim::testing_support {

// CreateSession overrides: the small map, 5 iterations per frame (never fewer), 512 rays.
inline std::vector<std::pair<std::string, std::string>> SmallMapOverrides() {
  return {{"grid.half_extent_x_m", "2"},
          {"grid.half_extent_y_m", "2"},
          {"grid.z_min_m", "-1.2"},
          {"grid.z_max_m", "1.2"},
          {"train.iterations", "5"},
          {"train.min_iterations", "5"},
          {"sampler.rays_per_iteration", "512"}};
}

// n × n returns `spacing` apart on a floor `depth` below a sensor at (x, 0, 0), from
// −(n / 2)·spacing on each horizontal axis.
inline PosedScan FloorScan(double x, int n, float spacing, float depth) {
  PosedScan scan;
  scan.T_world_sensor = Eigen::Isometry3d::Identity();
  scan.T_world_sensor.translation() = Vec3d(x, 0, 0);
  const float start = -float(n / 2) * spacing;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      scan.points_S.emplace_back(start + spacing * i, start + spacing * j, -depth);
  return scan;
}

// 40 x 40 returns 7.5 cm apart on the ground 1 m below a sensor at (x, 0, 0).
inline PosedScan GroundScan(double x) { return FloorScan(x, 40, 0.075f, 1.f); }

// `n` ground scans 5 cm apart along x.
inline std::vector<PosedScan> GroundScans(int n) {
  std::vector<PosedScan> out;
  for (int i = 0; i < n; ++i) out.push_back(GroundScan(0.05 * i));
  return out;
}

}  // namespace rim::testing_support
