#include "rim/eval/nearest_neighbors.h"

#include <cmath>
#include <limits>
#include <nanoflann.hpp>

#include "rim/base/worker_pool.h"

namespace rim::eval {
namespace {

// nanoflann reads the points through this adaptor; they stay where NearestNeighbors keeps them.
struct PointsAdaptor {
  const std::vector<Point3f>* points;
  size_t kdtree_get_point_count() const { return points->size(); }
  float kdtree_get_pt(size_t i, size_t dim) const { return (*points)[i][dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;  // let nanoflann compute it
  }
};

using Tree = nanoflann::KDTreeSingleIndexAdaptor<
    nanoflann::L2_Simple_Adaptor<float, PointsAdaptor, float, uint32_t>, PointsAdaptor, 3,
    uint32_t>;

// Small leaves favour the 1-NN queries, which dominate, over build time.
constexpr size_t kMaxLeaf = 20;

}  // namespace

struct NearestNeighbors::Index {
  explicit Index(const std::vector<Point3f>* points)
      : adaptor{points}, tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(kMaxLeaf)) {}
  PointsAdaptor adaptor;
  Tree tree;
};

NearestNeighbors::NearestNeighbors(std::vector<Point3f> points)
    : points_(std::move(points)), index_(std::make_unique<Index>(&points_)) {}

NearestNeighbors::~NearestNeighbors() = default;

float NearestNeighbors::NearestSquaredDistance(const Point3f& q) const {
  if (points_.empty()) return std::numeric_limits<float>::infinity();
  uint32_t index = 0;
  float best_sq = std::numeric_limits<float>::infinity();
  index_->tree.knnSearch(q.data(), 1, &index, &best_sq);
  return best_sq;
}

std::vector<float> NearestNeighbors::NearestDistances(const std::vector<Point3f>& queries,
                                                      int threads) const {
  std::vector<float> out(queries.size());
  ParallelFor(static_cast<int64_t>(queries.size()), 4096, threads, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) out[i] = std::sqrt(NearestSquaredDistance(queries[i]));
  });
  return out;
}

}  // namespace rim::eval
