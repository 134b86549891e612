#include "rim/io/point_cloud.h"

namespace rim::io {

size_t DropNonFinitePoints(PointCloud* cloud) {
  const bool has_intensity = cloud->intensity.size() == cloud->points.size();
  size_t kept = 0;
  for (size_t i = 0; i < cloud->points.size(); ++i) {
    if (!cloud->points[i].allFinite()) continue;
    cloud->points[kept] = cloud->points[i];
    if (has_intensity) cloud->intensity[kept] = cloud->intensity[i];
    ++kept;
  }
  const size_t dropped = cloud->points.size() - kept;
  cloud->points.resize(kept);
  if (has_intensity) cloud->intensity.resize(kept);
  return dropped;
}

}  // namespace rim::io
