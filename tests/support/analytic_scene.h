// Ground-truth scenes for the mapper's integration tests: analytic primitives with exact signed
// distances, a simulated spinning LiDAR that casts exact rays into them, and a mesh evaluator that
// scores a reconstruction against the analytic surface.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "rim/base/mesh.h"

namespace rim::testing_support {

// Solids are closed; the scene is their union. Coordinates are world frame, metres.
struct Box {
  Eigen::Vector3f min, max;
};

struct Sphere {
  Eigen::Vector3f center;
  float radius;
};

// Vertical (axis along z), with flat caps at z_min and z_max.
struct Cylinder {
  Eigen::Vector2f center_xy;
  float radius, z_min, z_max;
};

// Ground plane z = ground_z (solid below it) united with boxes, spheres and cylinders.
// Setting ground_z to -infinity removes the ground entirely, which lets tests isolate one object.
class AnalyticScene {
 public:
  float ground_z = 0.f;
  std::vector<Box> boxes;
  std::vector<Sphere> spheres;
  std::vector<Cylinder> cylinders;

  // Signed distance of the union, negative inside: the min over the exact per-primitive SDFs.
  // That is the exact distance outside the union and a lower bound on depth inside, which is
  // all the mapper tests need (they compare near the surface and in free space).
  float Sdf(const Eigen::Vector3f& p) const;

  // Unit outward normal of the closest primitive's surface (its analytic SDF gradient).
  Eigen::Vector3f Normal(const Eigen::Vector3f& p) const;

  // Distance along the unit `dir` to the first surface hit from `origin`, or +infinity when nothing
  // is hit within max_range. Returns 0 when the origin is already inside a solid.
  float Raycast(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir, float max_range) const;

  struct SurfacePoint {
    Eigen::Vector3f p, n;
    // True on planar patches (ground, box faces, cylinder caps), false on curved ones.
    bool on_flat_face;
  };

  // Up to `count` points uniform by area over the exposed surface inside the closed box
  // [region_min, region_max]: parts buried in another solid (or under it, e.g. ground beneath a
  // box) are excluded. Fewer points come back only if the region holds (almost) no exposed
  // surface. Deterministic for a given seed.
  std::vector<SurfacePoint> SampleSurface(const Eigen::Vector3f& region_min,
                                          const Eigen::Vector3f& region_max, int count,
                                          uint32_t seed) const;

  // Ground at z = 0 with buildings, small boxes, two spheres and two poles placed along a ~40 m
  // stretch of the +x axis, all within |y| <= 8 m and keeping the corridor |y| < 2 m free so a
  // sensor can drive along it. Solids are sunk slightly into the ground so that no two surfaces
  // coincide.
  static AnalyticScene Default();
};

// A spinning LiDAR with `beams` rings evenly spaced in elevation (inclusive of both limits) and
// `columns` azimuth steps over a full turn.
struct LidarModel {
  int beams = 32;
  int columns = 720;
  float elev_min_deg = -25.f, elev_max_deg = 15.f;
  float max_range_m = 30.f;
  // Gaussian noise added along the ray to each measured range.
  float noise_stddev_m = 0.f;
};

// Casts every beam from the sensor pose and returns the hits (true range <= max_range_m) in the
// SENSOR frame, ring-major order. Deterministic for a given seed.
std::vector<Eigen::Vector3f> SimulateScan(const AnalyticScene& scene, const LidarModel& lidar,
                                          const Eigen::Isometry3f& T_world_sensor, uint32_t seed);

// n sensor poses evenly spaced from x0 to x1 along +x at height sensor_height_m, with a few
// degrees of deterministic yaw wobble so consumers cannot get away with ignoring rotation.
std::vector<Eigen::Isometry3f> StraightTrajectory(float x0, float x1, int n, float sensor_height_m);

struct MeshErrors {
  // Mean |Sdf| of points sampled by area on the mesh (inside the region).
  double accuracy_m;
  // Mean distance from exposed scene-surface samples in the region to the nearest mesh sample.
  double completeness_m;
  // Mean of the two above.
  double chamfer_l1_m;
  // How many mesh samples fell inside the region and were used.
  size_t mesh_samples;
};

// Scores `mesh` against the scene inside the box [region_min, region_max], with `samples` points
// on each side. An empty mesh (or one entirely outside the region) scores +infinity.
// `truth_filter`, when given, keeps only the ground-truth surface points it accepts (e.g. those a
// sensor could have seen), so completeness is not charged for surfaces nobody observed.
MeshErrors EvaluateMesh(const Mesh& mesh, const AnalyticScene& scene,
                        const Eigen::Vector3f& region_min, const Eigen::Vector3f& region_max,
                        int samples, uint32_t seed,
                        const std::function<bool(const Eigen::Vector3f&)>& truth_filter = {});

}  // namespace rim::testing_support
