#include "sim/city.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/status_macros.h"
#include "sim/city_internal.h"
#include "sim/rng.h"

namespace rim::sim {
using namespace city_internal;

absl::Status ValidateCityOptions(const CityOptions& options) {
  for (const auto& [name, value] : {std::pair<const char*, int>{"walkers", options.walkers},
                                    {"crossers", options.crossers},
                                    {"movers", options.movers},
                                    {"frames", options.frames}}) {
    if (value < 0) {
      return absl::InvalidArgumentError(
          absl::StrCat("CityOptions.", name, " must be >= 0, got ", value));
    }
  }
  if (!(std::isfinite(options.step) && options.step > 0)) {
    return absl::InvalidArgumentError(
        absl::StrCat("CityOptions.step must be finite and > 0, got ", options.step));
  }
  const BuildingOptions& b = options.buildings;
  auto check = [](const char* range, double min, double max, double lo, double hi) {
    if (std::isfinite(min) && std::isfinite(max) && lo <= min && min <= max && max <= hi) {
      return absl::OkStatus();
    }
    return absl::InvalidArgumentError(absl::StrFormat(
        "CityOptions.buildings.%s_min, %s_max must satisfy %g <= min <= max <= %g, got %g, %g",
        range, range, lo, hi, min, max));
  };
  RIM_RETURN_IF_ERROR(check("setback", b.setback_min, b.setback_max, 0.0, kMaxBuildingSetback));
  RIM_RETURN_IF_ERROR(
      check("height", b.height_min, b.height_max, kMinBuildingHeight, kMaxBuildingHeight));
  const CityFeatures& f = options.features;
  for (const auto& [name, value] : {std::pair<const char*, double>{"parked_cars", f.parked_cars},
                                    {"balconies", f.balconies},
                                    {"annexes", f.annexes},
                                    {"yawed", f.yawed},
                                    {"canopies", f.canopies}}) {
    if (!(std::isfinite(value) && value >= 0.0 && value <= 1.0)) {
      return absl::InvalidArgumentError(
          absl::StrCat("CityOptions.features.", name, " must be in [0, 1], got ", value));
    }
  }
  return absl::OkStatus();
}

City GenerateCity(const CityOptions& options) {
  City city;
  city.scene = BuildCityScene(options.seed, options.buildings, options.features);
  const Vec2 loop_center(kBlockPitch, 0.5 * kBlockPitch);
  const Vec2 loop_half(kBlockPitch, 0.5 * kBlockPitch);
  // Counter-clockwise travel keeps the right-hand lane on the outside of the loop.
  city.drive_path = LoopPath(loop_center, loop_half + Vec2::Constant(kLaneOffset),
                             kLoopCornerRadius + kLaneOffset);
  // Start 50 m before the first corner, so that even short runs include a turn.
  city.start_s = 2 * (loop_half.x() - kLoopCornerRadius) - 50.0;

  // Walkers: a separate random stream, so the static scene is the same with or without them.
  Rng rng(HashSeed(options.seed, 0xAA1Cull));
  for (int k = 0; k < options.walkers; ++k) {
    Walker w;
    const double lateral = rng.Uniform(kWalkerMin, kWalkerMax);
    const bool inside = rng.Bernoulli(0.5);  // inner or outer sidewalk of the loop
    const double offset = inside ? -lateral : lateral;
    w.path = LoopPath(loop_center, loop_half + Vec2::Constant(offset), kLoopCornerRadius + offset);
    w.s0 = rng.Uniform(0.0, w.path.length());
    w.speed = rng.Uniform(0.8, 1.6) * (rng.Bernoulli(0.5) ? 1.0 : -1.0);
    w.radius = rng.Uniform(0.22, 0.28);
    w.height = rng.Uniform(1.6, 1.9);
    city.walkers.push_back(w);
  }
  // Crossers and movers: a random stream each, too.
  PlaceCrossers(options, &city);
  PlaceMovers(options, loop_center, loop_half, &city);
  return city;
}

std::vector<Eigen::Isometry3d> CityTrajectory(const City& city, int frames, double step,
                                              double sensor_height) {
  std::vector<Eigen::Isometry3d> poses;
  poses.reserve(std::max(frames, 0));
  for (int k = 0; k < frames; ++k) {
    Vec2 p;
    double heading;
    city.drive_path.Eval(city.start_s + k * step, &p, &heading);
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = Eigen::AngleAxisd(heading, Vec3::UnitZ()).toRotationMatrix();
    pose.translation() = Vec3(p.x(), p.y(), city.scene.ground_z + sensor_height);
    poses.push_back(pose);
  }
  return poses;
}

}  // namespace rim::sim
