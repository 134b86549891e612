#include "sim/city_frames.h"

#include <algorithm>
#include <thread>
#include <vector>

#include "sim/city.h"
#include "sim/rng.h"
#include "sim/scene.h"
#include "sim/sensors.h"

namespace rim::sim {
namespace {

// The constants rim_sim's city uses, so that the streamed frames match its KITTI output.
constexpr double kSensorHeight = 1.73;  // KITTI's Velodyne mount height
constexpr double kGridCell = 4.0;
constexpr uint64_t kNoiseStream = 0x7015Eull;

}  // namespace

struct CityFrames::State {
  CityFrameOptions options;
  City city;
  std::vector<Eigen::Isometry3d> poses;
  LidarModel lidar;
  std::unique_ptr<RayCaster> static_caster;  // when nothing moves from frame to frame
  int threads = 1;
};

CityFrames::CityFrames(const CityFrameOptions& options) : state_(std::make_unique<State>()) {
  State& s = *state_;
  s.options = options;
  CityOptions city_options;
  city_options.seed = options.seed;
  city_options.walkers = options.walkers;
  city_options.crossers = options.crossers;
  city_options.movers = options.movers;
  city_options.frames = options.frames;
  city_options.step = options.step;
  city_options.buildings = options.buildings;
  city_options.features = options.features;
  s.city = GenerateCity(city_options);
  s.poses = CityTrajectory(s.city, options.frames, options.step, kSensorHeight);
  s.lidar.columns = options.columns;
  if (s.city.walkers.empty() && s.city.crossers.empty() && s.city.movers.empty())
    s.static_caster = std::make_unique<RayCaster>(s.city.scene, kGridCell);
  s.threads = options.threads > 0
                  ? options.threads
                  : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

CityFrames::~CityFrames() = default;

size_t CityFrames::size() const { return state_->poses.size(); }

PosedScan CityFrames::Frame(size_t k) const {
  const State& s = *state_;
  const NoiseOptions noise{s.options.noise, HashSeed(s.options.seed, k, kNoiseStream)};
  std::vector<LidarPoint> points;
  if (s.static_caster) {
    points = SimulateLidarScan(*s.static_caster, s.poses[k], s.lidar, noise, s.threads);
  } else {
    Scene frame_scene = s.city.scene;
    for (Primitive& m : MovingAt(s.city, double(k) / kFrameRateHz))
      frame_scene.primitives.push_back(m);
    const RayCaster caster(frame_scene, kGridCell);
    points = SimulateLidarScan(caster, s.poses[k], s.lidar, noise, s.threads);
  }
  PosedScan scan;
  scan.T_world_sensor = s.poses[k];
  scan.timestamp_s = double(k) / kFrameRateHz;
  scan.points_S.reserve(points.size());
  for (const LidarPoint& p : points) scan.points_S.emplace_back(p.x, p.y, p.z);
  return scan;
}

}  // namespace rim::sim
