#include "tsdf/tsdf_reference.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "rim/base/types.h"
#include "rim/mesh/marching_cubes.h"

namespace rim::bench {
namespace {

openvdb::FloatGrid::Ptr MakeGrid(float background, double voxel_m, const char* name) {
  openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(background);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(voxel_m));
  grid->setName(name);
  return grid;
}

// Calls visit(ijk) for every voxel that the segment q0 -> q1 crosses, in order, both ends
// included. q is in voxel units shifted by half a voxel, so that voxel (i, j, k), centred at
// (i, j, k) * voxel_m, spans [i, i + 1) × [j, j + 1) × [k, k + 1): the voxel is floor(q).
// Amanatides and Woo's traversal.
template <typename Visit>
void WalkVoxels(const Eigen::Vector3d& q0, const Eigen::Vector3d& q1, Visit&& visit) {
  const Eigen::Vector3d d = q1 - q0;
  std::array<int, 3> cur, end, step;
  std::array<double, 3> t_max, t_delta;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  long steps_left = 1;
  for (int a = 0; a < 3; ++a) {
    cur[a] = int(std::floor(q0[a]));
    end[a] = int(std::floor(q1[a]));
    steps_left += std::abs(end[a] - cur[a]);
    if (d[a] > 0) {
      step[a] = 1;
      t_delta[a] = 1.0 / d[a];
      t_max[a] = (cur[a] + 1 - q0[a]) / d[a];
    } else if (d[a] < 0) {
      step[a] = -1;
      t_delta[a] = -1.0 / d[a];
      t_max[a] = (q0[a] - cur[a]) / -d[a];
    } else {
      step[a] = 0;
      t_delta[a] = kInf;
      t_max[a] = kInf;
    }
  }
  visit(openvdb::Coord(cur[0], cur[1], cur[2]));
  // Each step moves one axis one voxel towards `end`: at most the L1 distance of steps.
  while (--steps_left > 0 && cur != end) {
    int a = 0;
    if (t_max[1] < t_max[a]) a = 1;
    if (t_max[2] < t_max[a]) a = 2;
    if (t_max[a] > 1.0) break;
    cur[a] += step[a];
    t_max[a] += t_delta[a];
    visit(openvdb::Coord(cur[0], cur[1], cur[2]));
  }
}

}  // namespace

TsdfIntegrator::TsdfIntegrator(const TsdfOptions& options)
    : options_(options),
      tsdf_(MakeGrid(float(options.truncation_m), options.voxel_m, "tsdf")),
      weights_(MakeGrid(0.f, options.voxel_m, "weight")),
      tsdf_acc_(tsdf_->getAccessor()),
      weight_acc_(weights_->getAccessor()) {
  openvdb::initialize();
}

void TsdfIntegrator::Integrate(const std::vector<Eigen::Vector3d>& points_W,
                               const Eigen::Vector3d& origin_W) {
  for (const Eigen::Vector3d& p : points_W) IntegrateRay(origin_W, p);
}

void TsdfIntegrator::IntegrateRay(const Eigen::Vector3d& origin_W, const Eigen::Vector3d& point_W) {
  if (!origin_W.allFinite() || !point_W.allFinite()) return;
  const Eigen::Vector3d ray = point_W - origin_W;
  const double range = ray.norm();
  if (!(range > 0) || range < options_.min_range_m || range > options_.max_range_m) return;
  const Eigen::Vector3d dir = ray / range;
  const double trunc = options_.truncation_m;
  const double inv_voxel = 1.0 / options_.voxel_m;
  const Eigen::Vector3d start_W = options_.space_carving ? origin_W : point_W - trunc * dir;
  const Eigen::Vector3d end_W = point_W + trunc * dir;
  const Eigen::Vector3d half(0.5, 0.5, 0.5);
  ++rays_;
  WalkVoxels(start_W * inv_voxel + half, end_W * inv_voxel + half, [&](const openvdb::Coord& ijk) {
    const Eigen::Vector3d centre_W = options_.voxel_m * Eigen::Vector3d(ijk.x(), ijk.y(), ijk.z());
    const double sdf = range - (centre_W - origin_W).dot(dir);
    if (sdf < -trunc) return;  // far behind the return: nothing known there
    const float tsdf = float(std::min(sdf, trunc));
    const float w_old = weight_acc_.getValue(ijk);
    const float w_new = w_old + 1.f;
    const float d_old = w_old > 0.f ? tsdf_acc_.getValue(ijk) : 0.f;
    tsdf_acc_.setValue(ijk, (d_old * w_old + tsdf) / w_new);
    weight_acc_.setValue(ijk, w_new);
    ++voxel_updates_;
  });
}

Mesh TsdfIntegrator::Extract(float min_weight) const {
  // Accessors of our own: the members are for writing, and Extract is const.
  openvdb::FloatGrid::ConstAccessor tsdf = tsdf_->getConstAccessor();
  openvdb::FloatGrid::ConstAccessor weight = weights_->getConstAccessor();
  auto observed = [&](const openvdb::Coord& ijk) {
    float w = 0.f;
    return weight.probeValue(ijk, w) && w >= min_weight;
  };
  // The cubes to mesh: every cube (named by its minimum corner) whose 8 corners are observed and
  // whose values change sign. Any such cube has an observed minimum corner, so walking the active
  // voxels finds them all.
  std::vector<Int3> cells;
  for (auto it = weights_->cbeginValueOn(); it; ++it) {
    if (!(*it >= min_weight)) continue;
    // Tiles never appear here (voxels are set one at a time), but be safe with bounding boxes.
    openvdb::CoordBBox box;
    it.getBoundingBox(box);
    for (auto c = box.begin(); c; ++c) {
      const openvdb::Coord& g = *c;
      bool all = true, neg = false, pos = false;
      for (int corner = 0; corner < 8 && all; ++corner) {
        const openvdb::Coord q = g.offsetBy(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
        if (!observed(q)) {
          all = false;
          break;
        }
        (tsdf.getValue(q) < 0.f ? neg : pos) = true;
      }
      if (all && neg && pos) cells.emplace_back(g.x(), g.y(), g.z());
    }
  }
  GridSamples samples;
  samples.step_m = float(options_.voxel_m);
  samples.origin_m = Eigen::Vector3f::Zero();
  samples.lookup = [&](const Int3& g, float* value) {
    const openvdb::Coord ijk(g.x(), g.y(), g.z());
    if (!observed(ijk)) return false;
    *value = tsdf.getValue(ijk);
    return true;
  };
  return MarchingCubes(cells, samples);
}

size_t TsdfIntegrator::MemoryBytes() const {
  return size_t(tsdf_->memUsage()) + size_t(weights_->memUsage());
}

size_t TsdfIntegrator::ActiveVoxels() const { return size_t(weights_->activeVoxelCount()); }

double MeshArea(const Mesh& mesh) {
  double area = 0;
  for (const auto& f : mesh.faces) {
    const Eigen::Vector3d a(mesh.vertices[f[0]][0], mesh.vertices[f[0]][1], mesh.vertices[f[0]][2]);
    const Eigen::Vector3d b(mesh.vertices[f[1]][0], mesh.vertices[f[1]][1], mesh.vertices[f[1]][2]);
    const Eigen::Vector3d c(mesh.vertices[f[2]][0], mesh.vertices[f[2]][1], mesh.vertices[f[2]][2]);
    area += 0.5 * (b - a).cross(c - a).norm();
  }
  return area;
}

}  // namespace rim::bench
