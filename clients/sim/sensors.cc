#include "sim/sensors.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "rim/base/worker_pool.h"
#include "sim/rng.h"

namespace rim::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
// Rays, and depth image rows, handed to a thread at a time (rim::ParallelFor): small enough that
// threads that drew cheap rays (sky) take more blocks than those that drew the city.
constexpr int kRayBlock = 1024, kRowBlock = 4;

// Gaussian sample for ray `index` of the stream `seed`.
double RayNoise(const NoiseOptions& noise, uint64_t index) {
  if (noise.stddev <= 0) return 0.0;
  Rng rng(HashSeed(noise.seed, index, 0x5EEDull));
  return noise.stddev * rng.Normal();
}

}  // namespace

Vec3 LidarRayDirection(const LidarModel& model, int ring, int column) {
  const double elev_deg = model.beams > 1
                              ? model.elev_max_deg - (model.elev_max_deg - model.elev_min_deg) *
                                                         ring / (model.beams - 1)
                              : model.elev_max_deg;
  const double elev = elev_deg * kPi / 180.0;
  const double az = 2.0 * kPi * column / model.columns;
  return Vec3(std::cos(elev) * std::cos(az), std::cos(elev) * std::sin(az), std::sin(elev));
}

std::vector<LidarPoint> SimulateLidarScan(const RayCaster& caster,
                                          const Eigen::Isometry3d& world_from_sensor,
                                          const LidarModel& model, const NoiseOptions& noise,
                                          int threads, std::vector<SensorTruth>* truth) {
  const int rays = model.beams * model.columns;
  // Per ray: a point or NaN for no return; compacted in ray order afterwards.
  std::vector<LidarPoint> grid(rays);
  std::vector<SensorTruth> truth_grid(truth != nullptr ? rays : 0);
  const Eigen::Matrix3d rot = world_from_sensor.linear();
  const Vec3 origin = world_from_sensor.translation();
  // Azimuth and elevation tables, shared by the workers.
  std::vector<Vec3> dirs(rays);
  for (int r = 0; r < model.beams; ++r) {
    for (int c = 0; c < model.columns; ++c)
      dirs[r * model.columns + c] = LidarRayDirection(model, r, c);
  }
  ParallelFor(rays, kRayBlock, threads, [&](int64_t begin, int64_t end) {
    RayHit hit;
    for (int i = int(begin); i < int(end); ++i) {
      const Vec3& ds = dirs[i];
      const Vec3 dw = rot * ds;
      LidarPoint& p = grid[i];
      if (!caster.Cast(origin, dw, 0.0, model.max_range, &hit) || hit.t < model.min_range) {
        p.x = std::numeric_limits<float>::quiet_NaN();
        continue;
      }
      const double range = std::max(hit.t + RayNoise(noise, static_cast<uint64_t>(i)), 1e-3);
      const double cos_inc = std::abs(hit.normal.dot(dw));
      p.x = static_cast<float>(range * ds.x());
      p.y = static_cast<float>(range * ds.y());
      p.z = static_cast<float>(range * ds.z());
      p.intensity = static_cast<float>(std::clamp(Reflectivity(hit.material) * cos_inc, 0.0, 1.0));
      if (truth != nullptr) truth_grid[i] = {origin + hit.t * dw, hit.primitive};
    }
  });
  std::vector<LidarPoint> out;
  out.reserve(rays);
  if (truth != nullptr) truth->clear();
  for (int i = 0; i < rays; ++i) {
    if (std::isnan(grid[i].x)) continue;
    out.push_back(grid[i]);
    if (truth != nullptr) truth->push_back(truth_grid[i]);
  }
  return out;
}

std::vector<float> RenderDepth(const RayCaster& caster, const Eigen::Isometry3d& world_from_camera,
                               const PinholeCamera& camera, const NoiseOptions& noise, int threads,
                               std::vector<SensorTruth>* truth) {
  const int pixels = camera.width * camera.height;
  std::vector<float> depth(pixels, 0.0f);
  std::vector<SensorTruth> truth_grid(truth != nullptr ? pixels : 0);
  const Eigen::Matrix3d rot = world_from_camera.linear();
  const Vec3 origin = world_from_camera.translation();
  ParallelFor(camera.height, kRowBlock, threads, [&](int64_t row_begin, int64_t row_end) {
    RayHit hit;
    for (int v = int(row_begin); v < int(row_end); ++v) {
      for (int u = 0; u < camera.width; ++u) {
        const Vec3 ray((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
        const double len = ray.norm();
        const Vec3 dc = ray / len;  // unit, camera frame; depth = t * dc.z()
        const Vec3 dw = rot * dc;
        const double max_t = camera.max_depth * len;
        if (!caster.Cast(origin, dw, 0.0, max_t, &hit)) continue;
        const int i = v * camera.width + u;
        double z = hit.t * dc.z();
        if (z < camera.min_depth) continue;
        if (truth != nullptr) truth_grid[i] = {origin + hit.t * dw, hit.primitive};
        z += RayNoise(noise, static_cast<uint64_t>(i));
        depth[i] = static_cast<float>(std::max(z, 1e-3));
      }
    }
  });
  if (truth != nullptr) {
    truth->clear();
    for (int i = 0; i < pixels; ++i) {
      if (depth[i] > 0) truth->push_back(truth_grid[i]);
    }
  }
  return depth;
}

}  // namespace rim::sim
