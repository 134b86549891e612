#include "rim/eval/box_union.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"

namespace rim::eval {
namespace {

constexpr int64_t kMaxCells = int64_t{1} << 31;
constexpr float kBoundsPad = 1e-3f;

}  // namespace

absl::StatusOr<BoxUnion> BoxUnion::Create(double hx, double hy, double z_min, double z_max,
                                          const std::vector<Eigen::Vector3d>& centres) {
  auto bad = [](const std::string& why) {
    return absl::InvalidArgumentError(absl::StrCat("box union: ", why));
  };
  if (!std::isfinite(hx) || !(hx > 0)) return bad(absl::StrCat("hx must be > 0, got ", hx));
  if (!std::isfinite(hy) || !(hy > 0)) return bad(absl::StrCat("hy must be > 0, got ", hy));
  if (!std::isfinite(z_min) || !std::isfinite(z_max) || !(z_min < z_max)) {
    return bad(absl::StrCat("z_min must be < z_max (both finite), got ", z_min, " and ", z_max));
  }
  if (centres.empty()) return bad("no centres (a sequence without poses?)");
  if (centres.size() >= (size_t{1} << 31)) return bad(absl::StrCat(centres.size(), " centres"));
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (size_t i = 0; i < centres.size(); ++i) {
    if (!centres[i].allFinite()) return bad(absl::StrCat("centre ", i, " is not finite"));
    lo = lo.cwiseMin(centres[i]);
    hi = hi.cwiseMax(centres[i]);
  }
  BoxUnion u;
  u.hx_ = hx;
  u.hy_ = hy;
  u.z_min_ = z_min;
  u.z_max_ = z_max;
  u.centres_ = centres;
  const std::array<double, 3> lower = {lo.x() - hx, lo.y() - hy, lo.z() + z_min};
  const std::array<double, 3> upper = {hi.x() + hx, hi.y() + hy, hi.z() + z_max};
  for (int a = 0; a < 3; ++a) {
    u.bounds_[0][a] = static_cast<float>(lower[a]) - kBoundsPad;
    u.bounds_[1][a] = static_cast<float>(upper[a]) + kBoundsPad;
  }
  u.lower_xy_ = {lower[0], lower[1]};
  const double h[2] = {hx, hy};
  for (int a = 0; a < 2; ++a) {
    const double cells = std::floor((upper[a] - lower[a]) / h[a]) + 1;
    if (!(cells < kMaxCells)) {
      return bad(absl::StrCat("boxes of half-size ", h[a], " m over ", upper[a] - lower[a],
                              " m need more than 2^31 grid cells along ", a == 0 ? "x" : "y"));
    }
    u.cells_[a] = static_cast<int64_t>(cells);
  }

  // Every box in each cell its footprint overlaps, with a little to spare so that rounding in
  // CellIndex can never leave a box out of the cell of a point it holds.
  std::vector<std::pair<int64_t, uint32_t>> entries;
  for (size_t i = 0; i < centres.size(); ++i) {
    int64_t first[2], last[2];
    for (int a = 0; a < 2; ++a) {
      const double c = centres[i][a];
      const double tol = 1e-9 * (std::abs(c) + h[a]) + 1e-9;
      first[a] = u.CellIndex(c - h[a] - tol, a);
      last[a] = u.CellIndex(c + h[a] + tol, a);
    }
    for (int64_t x = first[0]; x <= last[0]; ++x) {
      for (int64_t y = first[1]; y <= last[1]; ++y) {
        entries.emplace_back(x * u.cells_[1] + y, static_cast<uint32_t>(i));
      }
    }
  }
  std::sort(entries.begin(), entries.end());
  for (size_t e = 0; e < entries.size(); ++e) {
    if (e == 0 || entries[e].first != entries[e - 1].first) {
      u.cell_keys_.push_back(entries[e].first);
      u.cell_start_.push_back(e);
    }
    u.box_index_.push_back(entries[e].second);
  }
  u.cell_start_.push_back(entries.size());
  return u;
}

int64_t BoxUnion::CellIndex(double v, int axis) const {
  const double cell = std::floor((v - lower_xy_[axis]) / (axis == 0 ? hx_ : hy_));
  return static_cast<int64_t>(std::clamp(cell, 0.0, static_cast<double>(cells_[axis] - 1)));
}

bool BoxUnion::Contains(const std::array<float, 3>& p) const {
  for (int a = 0; a < 3; ++a) {
    if (!(p[a] >= bounds_[0][a] && p[a] <= bounds_[1][a])) return false;  // NaN too
  }
  const double x = p[0], y = p[1], z = p[2];
  const int64_t key = CellIndex(x, 0) * cells_[1] + CellIndex(y, 1);
  const auto it = std::lower_bound(cell_keys_.begin(), cell_keys_.end(), key);
  if (it == cell_keys_.end() || *it != key) return false;
  const size_t k = static_cast<size_t>(it - cell_keys_.begin());
  for (size_t e = cell_start_[k]; e < cell_start_[k + 1]; ++e) {
    const Eigen::Vector3d& c = centres_[box_index_[e]];
    if (std::abs(x - c.x()) < hx_ && std::abs(y - c.y()) < hy_ && z >= c.z() + z_min_ &&
        z < c.z() + z_max_) {
      return true;
    }
  }
  return false;
}

}  // namespace rim::eval
