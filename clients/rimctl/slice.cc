#include "rimctl/slice.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "rimctl/args.h"

namespace rim::rimctl {
namespace {

constexpr int kMaxSide = 4096;
constexpr std::array<uint8_t, 3> kUnobserved = {128, 128, 128};
constexpr std::array<uint8_t, 3> kZeroCrossing = {20, 20, 20};

}  // namespace

Vec3f SliceGrid::Point(int col, int row) const {
  std::array<double, 3> p = min;
  p[u_axis] += resolution_m * col;
  p[v_axis] += resolution_m * (height - 1 - row);
  return Vec3f(float(p[0]), float(p[1]), float(p[2]));
}

std::vector<Vec3f> SliceGrid::Points() const {
  std::vector<Vec3f> points;
  points.reserve(size_t(width) * height);
  for (int row = 0; row < height; ++row) {
    for (int col = 0; col < width; ++col) points.push_back(Point(col, row));
  }
  return points;
}

std::string SliceGrid::PlaneName() const {
  return absl::StrFormat("%c = %g m", "xyz"[flat_axis], min[flat_axis]);
}

absl::StatusOr<SliceGrid> ParseSliceGrid(const std::string& text) {
  auto v = ParseNumberList("grid", text, 7);
  if (!v.ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat(v.status().message(), " (x0,y0,z0,x1,y1,z1,res)"));
  }
  SliceGrid grid;
  grid.resolution_m = (*v)[6];
  if (!(grid.resolution_m > 0)) {
    return absl::InvalidArgumentError(absl::StrCat("--grid: resolution ", (*v)[6], " must be > 0"));
  }
  std::array<double, 3> extent;
  std::vector<int> flat, open;
  for (int a = 0; a < 3; ++a) {
    grid.min[a] = std::min((*v)[a], (*v)[a + 3]);
    extent[a] = std::abs((*v)[a + 3] - (*v)[a]);
    (extent[a] < 1e-9 ? flat : open).push_back(a);
  }
  if (flat.size() != 1) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "--grid '%s': exactly one extent must be flat for a slice picture (e.g. z0 == z1), "
        "found %d flat",
        text, flat.size()));
  }
  grid.flat_axis = flat[0];
  grid.u_axis = open[0];
  grid.v_axis = open[1];
  const double cells_u = std::floor(extent[grid.u_axis] / grid.resolution_m + 1e-9) + 1;
  const double cells_v = std::floor(extent[grid.v_axis] / grid.resolution_m + 1e-9) + 1;
  if (cells_u > kMaxSide || cells_v > kMaxSide) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "--grid '%s' is %.0f x %.0f cells; at most %d per side (use a coarser resolution)", text,
        cells_u, cells_v, kMaxSide));
  }
  grid.width = int(cells_u);
  grid.height = int(cells_v);
  return grid;
}

std::array<uint8_t, 3> DivergingColour(double t) {
  // Anchors of a blue-white-red diverging map at t = -1, -0.5, 0, 0.5, 1.
  static constexpr double kAnchors[5][3] = {
      {5, 48, 97}, {67, 147, 195}, {247, 247, 247}, {214, 96, 77}, {103, 0, 31}};
  t = std::clamp(std::isfinite(t) ? t : 0.0, -1.0, 1.0);
  const double x = (t + 1.0) * 2.0;  // in [0, 4]
  const int i = std::min(3, int(x));
  const double f = x - i;
  std::array<uint8_t, 3> c;
  for (int k = 0; k < 3; ++k) {
    c[k] = uint8_t(std::lround(kAnchors[i][k] * (1 - f) + kAnchors[i + 1][k] * f));
  }
  return c;
}

SliceImage RenderSlice(const SliceGrid& grid, const QueryResult& result, double range_m,
                       int min_side_px, double contour_m) {
  const int w = grid.width, h = grid.height;
  auto at = [&](int col, int row) { return size_t(row) * w + col; };
  SliceImage image;
  std::vector<float> magnitudes;
  for (size_t i = 0; i < size_t(w) * h; ++i) {
    if (result.observed[i]) magnitudes.push_back(std::abs(result.sdf[i]));
  }
  image.observed_cells = magnitudes.size();
  if (range_m <= 0) {
    range_m = 1.0;
    if (!magnitudes.empty()) {
      const size_t k = magnitudes.size() * 98 / 100;
      std::nth_element(magnitudes.begin(), magnitudes.begin() + long(k), magnitudes.end());
      range_m = std::max(0.05, double(magnitudes[std::min(k, magnitudes.size() - 1)]));
    }
  }
  image.range_m = range_m;

  const int scale = std::max(1, (min_side_px + std::max(w, h) - 1) / std::max(w, h));
  image.width = w * scale;
  image.height = h * scale;
  image.rgb.resize(size_t(image.width) * image.height * 3);
  for (int row = 0; row < h; ++row) {
    for (int col = 0; col < w; ++col) {
      const size_t i = at(col, row);
      std::array<uint8_t, 3> c = kUnobserved;
      if (result.observed[i]) {
        c = DivergingColour(result.sdf[i] / range_m);
        // The surface: an outside cell next to an observed inside cell. Drawing only the outside
        // side of each crossing keeps the line one cell wide.
        const bool inside = result.sdf[i] < 0;
        for (const auto& [dc, dr] :
             {std::pair{1, 0}, std::pair{0, 1}, std::pair{-1, 0}, std::pair{0, -1}}) {
          const int nc = col + dc, nr = row + dr;
          if (nc < 0 || nr < 0 || nc >= w || nr >= h) continue;
          const size_t j = at(nc, nr);
          if (result.observed[j] && (result.sdf[j] < 0) != inside && !inside) c = kZeroCrossing;
        }
        if (contour_m > 0 && c != kZeroCrossing) {
          const double band = std::floor(result.sdf[i] / contour_m);
          bool line = false;
          for (const auto& [dc, dr] :
               {std::pair{1, 0}, std::pair{0, 1}, std::pair{-1, 0}, std::pair{0, -1}}) {
            const int nc = col + dc, nr = row + dr;
            if (nc < 0 || nr < 0 || nc >= w || nr >= h) continue;
            const size_t j = at(nc, nr);
            line = line || (result.observed[j] && std::floor(result.sdf[j] / contour_m) < band);
          }
          if (line)
            for (uint8_t& k : c) k = uint8_t(k * 11 / 20);
        }
      }
      for (int y = 0; y < scale; ++y) {
        for (int x = 0; x < scale; ++x) {
          uint8_t* p = &image.rgb[(size_t(row * scale + y) * image.width + col * scale + x) * 3];
          p[0] = c[0];
          p[1] = c[1];
          p[2] = c[2];
        }
      }
    }
  }
  return image;
}

}  // namespace rim::rimctl
