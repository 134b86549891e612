// Geometry shared by the local map, the sub-map store and the mesher: level voxel sizes, box
// extents in voxels, where the box sits for a robot position, and which sub-map owns a voxel.
//
// Conventions. Level l has voxel size h_l = s·2^l (§3.1). Features live on the lattice points
// g·h_l (g integer, world frame). The local box spans `cells(l)` voxels per axis at every level
// and its lattice holds cells(l)+1 points per axis, so that every point inside the box has all 8
// trilinear corners in it. Sub-maps tile the world without overlap, each the size of the local
// box (§3.3): sub-map K owns lattice points K·cells(l) .. (K+1)·cells(l)−1 of level l.
#pragma once

#include <cmath>

#include "rim/base/types.h"
#include "rim/config/config.h"

namespace rim {

inline constexpr int kMaxLevels = 6;

class MapGeometry {
 public:
  explicit MapGeometry(const GridConfig& grid)
      : levels_(grid.levels), feature_dim_(grid.feature_dim), leaf_m_(grid.leaf_size_m) {
    coarse_m_ = leaf_m_ * double(1 << (levels_ - 1));
    // The box moves in whole coarse voxels, so a box of exactly the configured extent would
    // leave up to one coarse voxel of it uncovered on one side of the robot: a robot driving
    // along a street would never map the strip of facade or parked cars there. One more coarse
    // voxel per axis, with the origin taken by floor, makes the box always hold
    // [position - half extent, position + half extent].
    const auto cells = [&](double extent) { return int(std::ceil(extent / coarse_m_ - 1e-6)) + 1; };
    coarse_cells_ = Int3(cells(2.0 * grid.half_extent_x_m), cells(2.0 * grid.half_extent_y_m),
                         cells(double(grid.z_max_m) - grid.z_min_m));
    box_offset_m_ = Vec3d(-grid.half_extent_x_m, -grid.half_extent_y_m, grid.z_min_m);
  }

  int levels() const { return levels_; }
  int feature_dim() const { return feature_dim_; }
  int encoding_dim() const { return levels_ * feature_dim_; }
  double leaf_m() const { return leaf_m_; }
  double voxel_m(int level) const { return leaf_m_ * double(1 << level); }
  // Levels below the coarsest have 2^(L-1-l) voxels per coarse voxel.
  int scale_to_coarse(int level) const { return 1 << (levels_ - 1 - level); }
  Int3 cells(int level) const { return coarse_cells_ * scale_to_coarse(level); }
  Int3 lattice_points(int level) const { return cells(level) + Int3::Ones(); }
  Vec3d extent_m() const { return coarse_cells_.cast<double>() * coarse_m_; }

  // Coarse-lattice index of the box's minimum corner when the robot is at `position_W`. The box
  // moves in whole coarse voxels (§3.2), so every level's lattice stays aligned; it holds the
  // configured box about the robot whole (see the constructor).
  Int3 BoxOriginFor(const Vec3d& position_W) const {
    Vec3d min_m = (position_W + box_offset_m_) / coarse_m_;
    return Int3(int(std::floor(min_m.x() + 1e-9)), int(std::floor(min_m.y() + 1e-9)),
                int(std::floor(min_m.z() + 1e-9)));
  }
  Int3 LevelOrigin(const Int3& coarse_origin, int level) const {
    return coarse_origin * scale_to_coarse(level);
  }

  // The sub-map that owns lattice point g of a level.
  Int3 SubmapOfLattice(int level, const Int3& g) const { return FloorDiv(g, cells(level)); }
  Int3 SubmapOfPoint(const Vec3d& p_W) const {
    Vec3d e = extent_m();
    return Int3(int(std::floor(p_W.x() / e.x())), int(std::floor(p_W.y() / e.y())),
                int(std::floor(p_W.z() / e.z())));
  }
  Vec3d SubmapMin(const Int3& key) const { return key.cast<double>().cwiseProduct(extent_m()); }

 private:
  int levels_;
  int feature_dim_;
  double leaf_m_;
  double coarse_m_;
  Int3 coarse_cells_;
  Vec3d box_offset_m_;
};

// An inclusive integer box [lo, hi].
struct IntBox {
  Int3 lo, hi;
  bool Contains(const Int3& g) const {
    return (g.array() >= lo.array()).all() && (g.array() <= hi.array()).all();
  }
  int64_t Count() const {
    Int3 d = hi - lo + Int3::Ones();
    return (d.array() > 0).all() ? int64_t(d.x()) * d.y() * d.z() : 0;
  }
};

// Calls fn(start, n) for runs along z that together cover every point of `a` not in `b`, once
// each: points start, start + ẑ, ..., start + (n − 1)·ẑ, n ≥ 1. These are the slabs that leave
// (or enter) when a box moves; only the difference is visited, never the whole box.
template <typename Fn>
void ForEachRunInDifference(const IntBox& a, const IntBox& b, Fn&& fn) {
  for (int x = a.lo.x(); x <= a.hi.x(); ++x) {
    const bool x_in = x >= b.lo.x() && x <= b.hi.x();
    for (int y = a.lo.y(); y <= a.hi.y(); ++y) {
      const bool y_in = y >= b.lo.y() && y <= b.hi.y();
      if (x_in && y_in) {
        // Only z slabs can differ here.
        const int below_end = std::min(a.hi.z(), b.lo.z() - 1);
        if (below_end >= a.lo.z()) fn(Int3(x, y, a.lo.z()), below_end - a.lo.z() + 1);
        const int above_start = std::max(a.lo.z(), b.hi.z() + 1);
        if (above_start <= a.hi.z()) fn(Int3(x, y, above_start), a.hi.z() - above_start + 1);
      } else if (a.hi.z() >= a.lo.z()) {
        fn(Int3(x, y, a.lo.z()), a.hi.z() - a.lo.z() + 1);
      }
    }
  }
}

}  // namespace rim
