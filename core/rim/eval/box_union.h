// The union of equal axis-aligned boxes placed about a set of centres, e.g. the local mapping boxes
// about the sensor positions of a sequence: a point p is in the union when, for some centre c,
//   |p.x - c.x| < hx, |p.y - c.y| < hy and c.z + z_min <= p.z < c.z + z_max
// (world axes; the convention of rim_sim's --observed-box). rim_eval's --box crops both the
// prediction and the ground truth to it.
//
// Membership is fast for long sequences: the xy plane is cut into cells of hx by hy, each box is
// listed in every cell its footprint overlaps (at most 3 x 3), and a point checks only the boxes
// of its own cell, stopping at the first that holds it.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"

namespace rim::eval {

class BoxUnion {
 public:
  // InvalidArgument, naming the bad value, unless hx and hy are finite and > 0, z_min and z_max
  // are finite with z_min < z_max, there is at least one centre and every centre is finite, and
  // the cells over the centres' extent number fewer than 2^31 along each axis.
  static absl::StatusOr<BoxUnion> Create(double hx, double hy, double z_min, double z_max,
                                         const std::vector<Eigen::Vector3d>& centres);

  bool Contains(const std::array<float, 3>& p) const;

  double hx() const { return hx_; }
  double hy() const { return hy_; }
  double z_min() const { return z_min_; }
  double z_max() const { return z_max_; }
  size_t size() const { return centres_.size(); }  // boxes

  // Lower and upper corner of a box that holds the union (padded by a millimetre, so that float
  // rounding never leaves out a point of the union).
  const std::array<std::array<float, 3>, 2>& bounds() const { return bounds_; }

 private:
  BoxUnion() = default;
  // Cell of a coordinate along x (axis 0) or y (axis 1), relative to the grid's first cell.
  int64_t CellIndex(double v, int axis) const;

  double hx_ = 0, hy_ = 0, z_min_ = 0, z_max_ = 0;
  std::vector<Eigen::Vector3d> centres_;
  std::array<std::array<float, 3>, 2> bounds_{};
  std::array<double, 2> lower_xy_{};  // xy of the union's exact lower corner
  std::array<int64_t, 2> cells_{};    // grid size along x and y
  // Cells with boxes, in increasing key (x cell * cells_[1] + y cell), and the boxes of cell k:
  // box_index_[cell_start_[k], cell_start_[k + 1]).
  std::vector<int64_t> cell_keys_;
  std::vector<size_t> cell_start_;
  std::vector<uint32_t> box_index_;
};

}  // namespace rim::eval
