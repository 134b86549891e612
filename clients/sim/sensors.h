// Simulated range sensors: a spinning multi-beam LiDAR and a pinhole depth camera.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "sim/scene.h"

namespace rim::sim {

// A spinning LiDAR: `beams` rings evenly spaced in elevation from elev_max_deg (ring 0) down to
// elev_min_deg, and `columns` azimuth steps per revolution starting at +x (forward) and turning
// counter-clockwise. Sensor frame: x forward, y left, z up.
struct LidarModel {
  int beams = 64;
  int columns = 1800;
  double elev_max_deg = 2.0;
  double elev_min_deg = -25.0;
  double max_range = 80.0;
  double min_range = 0.5;
};

// One return in the sensor frame; intensity in [0, 1].
struct LidarPoint {
  float x, y, z, intensity;
};

// The noise-free truth behind one return: where its ray met the scene (world frame) and what it
// met (index into the ray caster's Scene::primitives, -1 for the ground plane).
struct SensorTruth {
  Vec3 world = Vec3::Zero();
  int primitive = -1;
};

struct NoiseOptions {
  // Standard deviation of the Gaussian noise added to each range (LiDAR) or depth (camera), m.
  double stddev = 0.0;
  // Seed of the noise; each ray's noise depends only on (seed, ray index), not on threading.
  uint64_t seed = 0;
};

// Unit ray direction of (ring, column) in the sensor frame.
Vec3 LidarRayDirection(const LidarModel& model, int ring, int column);

// One revolution from a single pose (a motion-compensated scan: every ray leaves from the pose).
// Returns the hits ring by ring, columns in order within a ring; rays with no surface within
// [min_range, max_range] give no point. Noise is added along the ray after the hit test, so the
// same rays return with and without noise, in the same order. When `truth` is given it receives,
// for each returned point in the same order, the noise-free hit.
std::vector<LidarPoint> SimulateLidarScan(const RayCaster& caster,
                                          const Eigen::Isometry3d& world_from_sensor,
                                          const LidarModel& model, const NoiseOptions& noise,
                                          int threads, std::vector<SensorTruth>* truth = nullptr);

// Pinhole depth camera: x right, y down, z forward. Pixel (u, v) looks along
// ((u - cx) / fx, (v - cy) / fy, 1), i.e. pixel centres at integer coordinates.
struct PinholeCamera {
  int width = 320;
  int height = 240;
  double fx = 300.0, fy = 300.0;
  double cx = 160.0, cy = 120.0;
  double min_depth = 0.1;
  double max_depth = 10.0;
};

// Depth (z along the optical axis, metres) per pixel, row-major; 0 where there is no surface
// with depth in [min_depth, max_depth] (judged before noise is added). When `truth` is given it
// receives the noise-free hit of every pixel with a depth, in row-major pixel order.
std::vector<float> RenderDepth(const RayCaster& caster, const Eigen::Isometry3d& world_from_camera,
                               const PinholeCamera& camera, const NoiseOptions& noise, int threads,
                               std::vector<SensorTruth>* truth = nullptr);

}  // namespace rim::sim
