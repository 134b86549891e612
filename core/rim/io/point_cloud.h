// The point cloud that the LiDAR frame readers and writers exchange.
#pragma once

#include <cstddef>
#include <vector>

#include "rim/base/types.h"

namespace rim::io {

struct PointCloud {
  std::vector<Vec3f> points;
  // Per-point intensity: empty when the file has none, else the same size as `points`.
  std::vector<float> intensity;

  size_t size() const { return points.size(); }
};

// Removes points with a NaN or infinite coordinate (and their intensities); returns how many.
size_t DropNonFinitePoints(PointCloud* cloud);

}  // namespace rim::io
