// What the city's files share (city.cc, city_builder.cc, city_moving.cc): the cross-section of a
// street, and the pieces GenerateCity puts together. Not for use outside clients/sim/city*.cc.
#pragma once

#include <cstdint>

#include "sim/city.h"
#include "sim/geometry.h"
#include "sim/scene.h"

namespace rim::sim::city_internal {

inline constexpr double kPi = 3.14159265358979323846;

// Cross-section of a street, lateral distance from its centre line.
inline constexpr double kRoadHalfWidth = 4.5;
inline constexpr double kParkOffset = 3.45;  // parked car centre
inline constexpr double kPoleOffset = 4.9;
inline constexpr double kTreeOffset = 5.2;
inline constexpr double kWalkerMin = 6.0, kWalkerMax = 7.8;  // sidewalk band walkers use
// Lateral half extent of a parked car: half its width (at most 0.95 m) grown by its yaw jitter
// (at most 2 degrees, over half a length of at most 2.4 m).
inline constexpr double kParkReach = 1.04;
// Tree crowns start at least this high; pole arms are higher still.
inline constexpr double kLowestCrown = 2.2;
// Street furniture stays this far (along the street) from intersection centres.
inline constexpr double kIntersectionClear = 14.0;
// Streets (centre lines) at x = i * pitch for i in [kMinI, kMaxI], y = j * pitch for j in
// [kMinJ, kMaxJ]; the drive loop goes round the blocks [0, 2 pitch] x [0, pitch].
inline constexpr int kMinI = -1, kMaxI = 3, kMinJ = -1, kMaxJ = 2;
inline constexpr double kSink =
    0.03;  // solids reach this far below the ground so that nothing floats
// The cross-section must leave the sensor's lane, parked cars and sidewalk objects apart.
static_assert(kLaneOffset + 0.5 < kParkOffset - 0.95, "parked cars too close to the lane");
static_assert(kParkOffset + 0.95 < kRoadHalfWidth, "parked cars must stay on the road");
static_assert(kRoadHalfWidth < kPoleOffset && kTreeOffset + 0.5 < kWalkerMin,
              "poles and trees stand on the sidewalk, clear of the walkers");
static_assert(kWalkerMax + 0.3 < kFrontage, "walkers stay clear of the buildings");
static_assert(0.95 * 0.99939 + 2.4 * 0.03490 < kParkReach, "parked car half width with yaw");

// The static world (city_builder.cc): the ground, the buildings with their balconies and annexes,
// the street furniture and the parked cars, drawn from their own random streams of `seed`.
Scene BuildCityScene(uint64_t seed, const BuildingOptions& buildings, const CityFeatures& features);

// The crossers and the movers of `options` for the drive of `city` (city_moving.cc), each kind from
// a random stream of its own; the static scene and the drive path must be in place.
void PlaceCrossers(const CityOptions& options, City* city);
void PlaceMovers(const CityOptions& options, const Vec2& loop_center, const Vec2& loop_half,
                 City* city);

}  // namespace rim::sim::city_internal
