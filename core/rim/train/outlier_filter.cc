#include "rim/train/outlier_filter.h"

#include <cmath>

#include "rim/model/encoder.h"

namespace rim {

size_t RemoveOutliers(const LocalMap& map, const Decoder& decoder, float threshold_m,
                      PointBuffer* buffer) {
  const size_t n = buffer->size();
  if (n == 0) return 0;
  const int F = map.geometry().encoding_dim();
  std::vector<float> xyz(n * 3), features(n * F), sdf(n);
  for (size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) xyz[3 * i + a] = buffer->points()[i][a];
  LocalEncoding enc;
  EncodeLocal(map, xyz.data(), int(n), &enc, features.data());
  decoder.Forward(features.data(), int(n), sdf.data());
  std::vector<bool> keep(n);
  size_t dropped = 0;
  for (size_t i = 0; i < n; ++i) {
    keep[i] = std::abs(sdf[i]) <= threshold_m;
    dropped += !keep[i];
  }
  buffer->Filter(keep);
  return dropped;
}

}  // namespace rim
