// A classic projective TSDF mapper on OpenVDB: the reference that rim's meshes are compared with
// in benchmarks (tests/bench/README.md, "TSDF reference"). Not part of rim's product.
//
// Integration follows the usual projective scheme: every return walks the voxels along its ray
// (a 3D DDA), from `truncation` before the return to `truncation` beyond it, or with space carving
// from the sensor to `truncation` beyond it. A voxel's signed distance is the return's range minus
// the distance of the voxel centre along the ray, truncated to `truncation` (voxels more than
// `truncation` behind the return are left alone), and folds into a running average with weight 1
// per observation. Integration runs on one thread: the timings quote that.
//
// Extraction is marching cubes (rim's own, core/rim/mesh/marching_cubes.h) over the cubes whose 8
// corner voxels all hold a weight of at least `min_weight`: space never observed (or observed too
// rarely) makes no surface. Triangles are counter-clockwise seen from free space.
#pragma once

#include <openvdb/openvdb.h>

#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "rim/base/mesh.h"

namespace rim::bench {

struct TsdfOptions {
  double voxel_m = 0.10;
  double truncation_m = 0.30;
  // Also walk from the sensor to the return, pushing the free space it crosses towards
  // +truncation (things seen through later are averaged away).
  bool space_carving = false;
  // Default of Extract(): cubes with a corner weight below it are not meshed.
  float min_weight = 5.f;
  // Returns nearer than min_range_m or farther than max_range_m (from their ray's origin) are
  // skipped, as are non-finite ones.
  double min_range_m = 0.3;
  double max_range_m = 60.0;
};

class TsdfIntegrator {
 public:
  explicit TsdfIntegrator(const TsdfOptions& options);
  // The write accessors hold on to the grids' trees.
  TsdfIntegrator(const TsdfIntegrator&) = delete;
  TsdfIntegrator& operator=(const TsdfIntegrator&) = delete;

  const TsdfOptions& options() const { return options_; }

  // Folds one scan in: returns in the world frame, all from one sensor origin (world frame).
  void Integrate(const std::vector<Eigen::Vector3d>& points_W, const Eigen::Vector3d& origin_W);
  // One ray, from `origin_W` to the return `point_W`.
  void IntegrateRay(const Eigen::Vector3d& origin_W, const Eigen::Vector3d& point_W);

  // Marching cubes over the cubes whose 8 corners all have weight >= min_weight.
  Mesh Extract(float min_weight) const;
  Mesh Extract() const { return Extract(options_.min_weight); }

  // The grids: voxel (i, j, k) is centred at (i, j, k) * voxel_m in the world frame.
  const openvdb::FloatGrid& tsdf() const { return *tsdf_; }
  const openvdb::FloatGrid& weights() const { return *weights_; }
  // Bytes the two grids hold (openvdb memUsage()).
  size_t MemoryBytes() const;
  size_t ActiveVoxels() const;
  // Rays integrated and voxel updates made so far.
  size_t rays() const { return rays_; }
  size_t voxel_updates() const { return voxel_updates_; }

 private:
  TsdfOptions options_;
  openvdb::FloatGrid::Ptr tsdf_;
  openvdb::FloatGrid::Ptr weights_;
  openvdb::FloatGrid::Accessor tsdf_acc_;
  openvdb::FloatGrid::Accessor weight_acc_;
  size_t rays_ = 0;
  size_t voxel_updates_ = 0;
};

// Sum of the triangles' areas (m²).
double MeshArea(const Mesh& mesh);

}  // namespace rim::bench
