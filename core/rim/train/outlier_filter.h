// Periodic outlier removal (§3.4 step 2): buffered endpoints lie on surfaces, so the map's SDF
// there should be about zero. Points where |SDF| exceeds ε are returns from things that are no
// longer there (people walking by) or noise, and stop supervising the map.
#pragma once

#include "rim/map/local_map.h"
#include "rim/model/decoder.h"
#include "rim/train/point_buffer.h"

namespace rim {

// Drops buffered points whose |SDF| in the live local map exceeds threshold_m; returns how many
// were dropped. Points must lie in the box (the buffer only holds such points).
size_t RemoveOutliers(const LocalMap& map, const Decoder& decoder, float threshold_m,
                      PointBuffer* buffer);

}  // namespace rim
