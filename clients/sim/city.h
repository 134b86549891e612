// The procedural city: a grid of streets with buildings, trees, poles and parked cars, a car
// driving around a loop of streets, and optional pedestrians walking along the sidewalks.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "absl/status/status.h"
#include "sim/geometry.h"
#include "sim/scene.h"

namespace rim::sim {

// A closed rounded rectangle, travelled counter-clockwise seen from above. Arc length 0 is where
// the bottom straight starts (just after the bottom-left corner), heading +x.
class LoopPath {
 public:
  LoopPath() = default;
  LoopPath(const Vec2& center, const Vec2& half_extent, double corner_radius);

  double length() const { return length_; }
  // Position and heading (radians, 0 along +x, counter-clockwise) at arc length s, wrapped
  // around the loop.
  void Eval(double s, Vec2* position, double* heading) const;

 private:
  Vec2 center_ = Vec2::Zero();
  Vec2 half_ = Vec2::Ones();
  double radius_ = 0.0;
  double straight_x_ = 0.0, straight_y_ = 0.0, arc_ = 0.0;
  double length_ = 0.0;
};

// A pedestrian: an upright cylinder moving along a path at constant speed.
struct Walker {
  LoopPath path;
  double s0 = 0.0;     // arc length at time 0
  double speed = 0.0;  // m/s along the path, negative to walk against its direction
  double radius = 0.25;
  double height = 1.8;
};

// Street layout constants (metres), shared with the tests.
inline constexpr double kBlockPitch = 80.0;        // distance between parallel street centre lines
inline constexpr double kLaneOffset = 1.75;        // sensor path: right-hand lane of a 2-lane road
inline constexpr double kLoopCornerRadius = 10.0;  // street centre line at the loop's corners
inline constexpr double kFrameRateHz = 10.0;
// Buildings stand at least this far from a street centre line (plus their set-back).
inline constexpr double kFrontage = 9.5;

// The ranges buildings are drawn from, uniformly (metres). The set-back is how far a building's
// facades stand beyond the street frontage (kFrontage from the street centre line), on every
// street the building faces; the height is that of its roof above the ground.
struct BuildingOptions {
  double setback_min = 0.0, setback_max = 3.5;  // facades 9.5-13 m from the centre line
  double height_min = 4.0, height_max = 25.0;
};

struct CityOptions {
  uint64_t seed = 1;
  // Pedestrians, spread evenly at random over the sidewalks all round the drive loop (so that a
  // shorter run sees the same walkers as the start of a longer one).
  int walkers = 0;
  BuildingOptions buildings;
};

inline constexpr double kMaxBuildingSetback = 20.0;
inline constexpr double kMinBuildingHeight = 1.0, kMaxBuildingHeight = 100.0;

// InvalidArgument naming the field unless walkers >= 0 and the building ranges are finite with
// 0 <= setback_min <= setback_max <= kMaxBuildingSetback and
// kMinBuildingHeight <= height_min <= height_max <= kMaxBuildingHeight.
absl::Status ValidateCityOptions(const CityOptions& options);

struct City {
  // The static world: ground plane at z = 0 and every solid except the walkers.
  Scene scene;
  // The sensor's path: the right-hand lane around a 2 x 1 ring of blocks, driven
  // counter-clockwise, and the arc length of the first frame on it.
  LoopPath drive_path;
  double start_s = 0.0;
  std::vector<Walker> walkers;
};

// Deterministic for given options, which must pass ValidateCityOptions. The static scene depends
// on the seed and the building ranges only, so ground truth is the same whether or not walkers are
// added. The building ranges change the values drawn for each building, not how many are drawn.
City GenerateCity(const CityOptions& options);

// World-from-LiDAR poses (x forward, y left, z up) of `frames` frames, `step` metres apart along
// the drive path, sensor `sensor_height` above the ground.
std::vector<Eigen::Isometry3d> CityTrajectory(const City& city, int frames, double step,
                                              double sensor_height);

// The walkers at time t (seconds) as solids.
std::vector<Primitive> WalkersAt(const City& city, double t);

}  // namespace rim::sim
