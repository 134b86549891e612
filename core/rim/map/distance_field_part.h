// Internal to the distance field's sources (distance_field*.cc): a sub-map's surfels (or returns)
// with their k-d tree and bounds, as DistanceField::Part, and what it is built from.
#pragma once

#include <algorithm>
#include <cstdint>
#include <limits>
#include <nanoflann.hpp>
#include <vector>

#include "rim/base/types.h"
#include "rim/map/distance_field.h"

namespace rim {
namespace distance_field_internal {

// nanoflann reads surfel positions through this adaptor.
struct SurfelAdaptor {
  const std::vector<Surfel>* surfels;
  size_t kdtree_get_point_count() const { return surfels->size(); }
  float kdtree_get_pt(size_t i, size_t dim) const { return (*surfels)[i].p[dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

using Tree = nanoflann::KDTreeSingleIndexAdaptor<
    nanoflann::L2_Simple_Adaptor<float, SurfelAdaptor, float, uint32_t>, SurfelAdaptor, 3,
    uint32_t>;
constexpr size_t kMaxLeaf = 16;

inline float Dot(const float* a, const float* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

}  // namespace distance_field_internal

struct DistanceField::Part {
  Part(std::vector<Surfel> s, float r, float rb)
      : radius(r),
        blend(rb),
        surfels(std::move(s)),
        adaptor{&surfels},
        tree(3, adaptor,
             nanoflann::KDTreeSingleIndexAdaptorParams(distance_field_internal::kMaxLeaf)) {
    lo.setConstant(std::numeric_limits<float>::max());
    hi.setConstant(std::numeric_limits<float>::lowest());
    for (const Surfel& x : surfels)
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], x.p[a]);
        hi[a] = std::max(hi[a], x.p[a]);
      }
    if (radius == 0.f && !surfels.empty()) BuildNear();
  }

  // Points (returns) spread over a whole sub-map, so that their bounds do not tell a query
  // point in the street from one beside a facade. A grid of kNearCell cells over the bounds
  // marks the cells with a point in them or in a neighbouring cell: a query point whose cell is
  // unmarked has no point within kNearCell, and a search bounded by that can skip the tree.
  static constexpr float kNearCell = 0.5f;
  void BuildNear() {
    for (int a = 0; a < 3; ++a) dims[a] = int((hi[a] - lo[a]) / kNearCell) + 1;
    near.assign(size_t(dims.x()) * size_t(dims.y()) * size_t(dims.z()), 0);
    auto at = [&](int x, int y, int z) { return (size_t(x) * dims.y() + y) * dims.z() + z; };
    for (const Surfel& x : surfels) {
      Int3 c;
      for (int a = 0; a < 3; ++a)
        c[a] = std::min(dims[a] - 1, int((x.p[a] - lo[a]) * (1.f / kNearCell)));
      for (int dx = std::max(0, c.x() - 1); dx <= std::min(dims.x() - 1, c.x() + 1); ++dx)
        for (int dy = std::max(0, c.y() - 1); dy <= std::min(dims.y() - 1, c.y() + 1); ++dy)
          for (int dz = std::max(0, c.z() - 1); dz <= std::min(dims.z() - 1, c.z() + 1); ++dz)
            near[at(dx, dy, dz)] = 1;
    }
  }
  // False only when no point lies within kNearCell of q.
  bool MaybeNear(const float* q) const {
    Int3 c;
    for (int a = 0; a < 3; ++a) {
      const float t = (q[a] - lo[a]) * (1.f / kNearCell);
      if (!(t >= 0.f) || t >= float(dims[a])) return true;  // outside: the bounds decide
      c[a] = int(t);
    }
    return near[(size_t(c.x()) * dims.y() + c.y()) * dims.z() + c.z()] != 0;
  }

  float radius;  // of the disks (0: points)
  float blend;   // the radius BlendWidth takes for the gradient beside them
  std::vector<Surfel> surfels;
  distance_field_internal::SurfelAdaptor adaptor;
  distance_field_internal::Tree tree;
  Vec3f lo, hi;  // bounds of the surfel centres
  Int3 dims = Int3::Zero();
  std::vector<uint8_t> near;  // returns only: see BuildNear
};

}  // namespace rim
