// The procedural city: a grid of streets with buildings, trees, poles and parked cars, a car
// driving around a loop of streets, and optional moving things: pedestrians walking along the
// sidewalks or crossing the street, and cars driving the opposite lane.
#pragma once

#include <Eigen/Geometry>
#include <array>
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
  const Vec2& center() const { return center_; }
  const Vec2& half_extent() const { return half_; }
  double corner_radius() const { return radius_; }
  // Position and heading (radians, 0 along +x, counter-clockwise) at arc length s, wrapped
  // around the loop.
  void Eval(double s, Vec2* position, double* heading) const;
  // Arc length, in [0, length()), of the point of the path nearest to p.
  double Nearest(const Vec2& p) const;

 private:
  // Where the straights start and the centres of the corner arcs, in travel order.
  void Segments(std::array<Vec2, 4>* straight_start, std::array<Vec2, 4>* arc_center) const;

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

// A pedestrian crossing a street: an upright cylinder walking back and forth across it, turning
// at each end, along the line through `center` perpendicular to the street. Its lateral position
// (see CrosserLateral) is measured from the street centre line along `across`, which points to
// the drive's lane: the sensor passes at lateral +kLaneOffset.
struct Crosser {
  Vec2 center = Vec2::Zero();    // where the crossing line meets the street centre line
  Vec2 street = Vec2::UnitX();   // unit direction of the street, that of the drive
  Vec2 across = -Vec2::UnitY();  // unit, perpendicular to the street, towards the drive's lane
  double drive_s = 0.0;          // arc length of the drive path where it crosses the line
  double half_span = 7.0;        // walks between lateral -half_span and +half_span
  double speed = 1.0;            // m/s
  double radius = 0.25;
  double height = 1.8;
  // Fraction of the back-and-forth cycle at time 0, in [0, 1): 0 at -half_span walking to
  // +half_span, 0.5 at +half_span walking back.
  double phase = 0.0;
};

// A car driving the opposite lane, against the drive: a box (yawed along its heading) whose centre
// moves clockwise along `path` at arc length s0 - speed * t at time t (seconds).
struct Mover {
  LoopPath path;  // counter-clockwise like every LoopPath; the mover runs it backwards
  double s0 = 0.0;
  double speed = 0.0;        // m/s, > 0
  Vec3 size = Vec3::Ones();  // length, width, height (m)
};

// Street layout constants (metres), shared with the tests.
inline constexpr double kBlockPitch = 80.0;        // distance between parallel street centre lines
inline constexpr double kLaneOffset = 1.75;        // sensor path: right-hand lane of a 2-lane road
inline constexpr double kLoopCornerRadius = 10.0;  // street centre line at the loop's corners
inline constexpr double kFrameRateHz = 10.0;
// Buildings stand at least this far from a street centre line (plus their set-back).
inline constexpr double kFrontage = 9.5;
// Crossers walk across the street between lateral -kCrossHalfSpan and +kCrossHalfSpan (from
// sidewalk to sidewalk). No parked car comes within kCrossCarGap of a crossing line, or, where
// the driven stretch has too few such lines for the crossers asked for, within kCrossCarGapMin
// (the crosser squeezes between parked cars). Crossing lines and the places where movers meet the
// sensor start kMovingAhead metres ahead of the first pose.
inline constexpr double kCrossHalfSpan = 7.0;
inline constexpr double kCrossCarGap = 1.5, kCrossCarGapMin = 0.7;
inline constexpr double kMovingAhead = 15.0;
// Movers: their centre keeps kMoverOffset from the street centre line on the side away from the
// drive's lane (which is at kLaneOffset on the other side).
inline constexpr double kMoverOffset = 1.3;
inline constexpr double kMoverLength = 4.4, kMoverWidth = 1.8, kMoverHeight = 1.5;

// The ranges buildings are drawn from, uniformly (metres). The set-back is how far a building's
// facades stand beyond the street frontage (kFrontage from the street centre line), on every
// street the building faces; the height is that of its roof above the ground.
struct BuildingOptions {
  double setback_min = 0.0, setback_max = 3.5;  // facades 9.5-13 m from the centre line
  double height_min = 4.0, height_max = 25.0;
};

// What the streets hold besides the buildings' main boxes, each a share in [0, 1]. The defaults
// are a realistic mix; 0 leaves a feature out (and `yawed` = 0.25 with the others at 0 gives the
// city rim_sim made before these options existed, bit for bit).
struct CityFeatures {
  // Share of each kerb (between the intersections' clear zones) taken by rows of cars parked
  // right at the kerb, their sides 3-15 cm from it, bumper to bumper 0.5-3 m apart: sedans,
  // SUVs and vans, a body box with a cabin box on it (hood and boot lower than the cabin). The
  // rest of the kerb keeps the scattered parked cars.
  double parked_cars = 0.5;
  // Share of buildings with balconies: slabs 0.15-0.2 m thick, 1-1.5 m deep and 2-4 m wide on the
  // street facade at every floor from about 3 m up (they may overhang the frontage by up to
  // kMaxBalconyDepth, never lower than kLowestBalcony).
  double balconies = 0.4;
  // Share of buildings with an annex: a lower box (2.5-4.5 m tall) on the street side or at the
  // street corner of the building (shop front, porch, entrance), behind the street frontage.
  double annexes = 0.3;
  // Share of buildings yawed off the street by up to +-35 degrees (the rest by up to +-4).
  double yawed = 0.35;
  // Share of street trees with a broad, low crown: a flat-bottomed disc 2.5-3.5 m up, radius 2-4 m
  // where there is room (it keeps 0.3 m from buildings, balconies and street lights, and its edge
  // stays 2 m or more from the street centre line, past the sensor's path), with a conical top; it
  // overhangs the sidewalk and the parking lane and hides part of the facades behind it.
  double canopies = 0.5;
};

inline constexpr double kMaxBalconyDepth = 1.5;
inline constexpr double kLowestBalcony = 2.8;  // the underside of the lowest balcony, at least

struct CityOptions {
  uint64_t seed = 1;
  // Pedestrians, spread evenly at random over the sidewalks all round the drive loop (so that a
  // shorter run sees the same walkers as the start of a longer one).
  int walkers = 0;
  // Pedestrians crossing the drive's street back and forth, and cars driving its opposite lane
  // against the drive. Both are laid out for the run of `frames` frames `step` metres apart (as
  // CityTrajectory draws it): the crossing lines, and the places where the movers meet the sensor,
  // are spread along the part of the loop that the run drives.
  int crossers = 0;
  int movers = 0;
  int frames = 100;
  double step = 1.0;
  BuildingOptions buildings;
  CityFeatures features;
};

inline constexpr double kMaxBuildingSetback = 20.0;
inline constexpr double kMinBuildingHeight = 1.0, kMaxBuildingHeight = 100.0;

// InvalidArgument naming the field unless walkers, crossers, movers and frames are >= 0, step is
// finite and > 0, and the building ranges are finite with
// 0 <= setback_min <= setback_max <= kMaxBuildingSetback and
// kMinBuildingHeight <= height_min <= height_max <= kMaxBuildingHeight, and every share in
// `features` is finite and in [0, 1].
absl::Status ValidateCityOptions(const CityOptions& options);

struct City {
  // The static world: ground plane at z = 0 and every solid except the moving ones.
  Scene scene;
  // The sensor's path: the right-hand lane around a 2 x 1 ring of blocks, driven
  // counter-clockwise, and the arc length of the first frame on it.
  LoopPath drive_path;
  double start_s = 0.0;
  std::vector<Walker> walkers;
  std::vector<Crosser> crossers;
  std::vector<Mover> movers;
};

// Deterministic for given options, which must pass ValidateCityOptions. The static scene depends
// on the seed, the building ranges and the features only, so ground truth is the same whether or
// not moving things are added; each kind of them has a random stream of its own, so adding one kind
// leaves the others as they were. The building ranges change the values drawn for each building,
// not how many are drawn. No crosser or mover ever meets a static solid or the sensor.
City GenerateCity(const CityOptions& options);

// World-from-LiDAR poses (x forward, y left, z up) of `frames` frames, `step` metres apart along
// the drive path, sensor `sensor_height` above the ground.
std::vector<Eigen::Isometry3d> CityTrajectory(const City& city, int frames, double step,
                                              double sensor_height);

// The walkers at time t (seconds) as solids.
std::vector<Primitive> WalkersAt(const City& city, double t);

// A crosser's lateral position at time t (seconds), in [-half_span, half_span].
double CrosserLateral(const Crosser& crosser, double t);

// The crossers and the movers at time t (seconds) as solids.
std::vector<Primitive> CrossersAt(const City& city, double t);
std::vector<Primitive> MoversAt(const City& city, double t);

// Every moving solid at time t: the walkers, then the crossers, then the movers.
std::vector<Primitive> MovingAt(const City& city, double t);

}  // namespace rim::sim
