// The synthetic city's LiDAR frames in memory, one at a time: what `rim_sim --scene city` writes to
// disk (same scene, trajectory, sensor and noise for the same options), for tools that stream the
// city straight to a server (`rimctl stream ROBOT sim:city`) without writing files.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>

#include "rim/base/scan.h"
#include "sim/city.h"

namespace rim::sim {

struct CityFrameOptions {
  int frames = 100;
  uint64_t seed = 1;
  double step = 1.0;          // metres between frames along the drive
  int columns = 1800;         // LiDAR azimuth steps per revolution (64 beams)
  double noise = 0.0;         // Gaussian range noise, standard deviation in metres
  int walkers = 0;            // pedestrians on the sidewalks
  int crossers = 0;           // pedestrians crossing the drive's street
  int movers = 0;             // cars driving the opposite lane
  int threads = 0;            // ray-casting threads; 0: all hardware threads
  BuildingOptions buildings;  // set-backs and heights (the defaults are rim_sim's)
  CityFeatures features;      // parked cars, balconies, ... (the defaults are rim_sim's)
};

class CityFrames {
 public:
  // Builds the city and its trajectory (a fraction of a second); frames are cast on demand.
  explicit CityFrames(const CityFrameOptions& options);
  ~CityFrames();

  size_t size() const;
  // Frame k (< size()): returns in the sensor frame, T_world_sensor, timestamp k / 10 s.
  PosedScan Frame(size_t k) const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace rim::sim
