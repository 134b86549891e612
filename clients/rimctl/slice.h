// `rimctl query --grid`: an SDF slice picture on an axis-aligned plane of the map.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "client/client.h"
#include "rim/base/types.h"

namespace rim::rimctl {

// A regular grid of cells on the plane where one of the box's extents is flat.
struct SliceGrid {
  int flat_axis = 2;           // 0 x, 1 y, 2 z
  int u_axis = 0, v_axis = 1;  // image columns run along u, rows along v (up = +v)
  std::array<double, 3> min = {0, 0, 0};
  double resolution_m = 0.1;
  int width = 0, height = 0;  // cells along u and v

  // World position of cell (col, row); row 0 is the top of the image (the largest v).
  Vec3f Point(int col, int row) const;
  // The cell centres, row-major from the top-left.
  std::vector<Vec3f> Points() const;
  // E.g. "z = 0.5 m".
  std::string PlaneName() const;
};

// Parses "x0,y0,z0,x1,y1,z1,res": a box with exactly one flat extent (z0 == z1 for a horizontal
// slice) and a cell size res > 0. InvalidArgument naming --grid when the numbers do not parse,
// no extent or more than one extent is flat, or the grid would exceed 4096 cells per side.
absl::StatusOr<SliceGrid> ParseSliceGrid(const std::string& text);

// A diverging colour for t in [-1, 1]: blue inside (negative), near-white at zero, red outside.
std::array<uint8_t, 3> DivergingColour(double t);

struct SliceImage {
  int width = 0, height = 0;
  std::vector<uint8_t> rgb;  // row-major, 3 bytes per pixel
  double range_m = 0;        // |sdf| that maps to the ends of the colour scale
  size_t observed_cells = 0;
};

// Colours each cell by its sdf over [-range_m, range_m] (range_m <= 0: the 98th percentile of
// |sdf| over observed cells, at least 5 cm), draws the zero crossing (outside cells with an
// observed inside neighbour) dark and never-observed cells mid grey, and scales the picture up
// by a whole factor until its longer side is at least min_side_px pixels. With contour_m > 0,
// also draws contour lines every contour_m metres of distance: a cell whose neighbour lies in a
// lower band, darkened (one cell wide, on the far side of each line).
SliceImage RenderSlice(const SliceGrid& grid, const QueryResult& result, double range_m,
                       int min_side_px = 256, double contour_m = 0);

}  // namespace rim::rimctl
