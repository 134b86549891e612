// Exact nearest-neighbour distances over a static 3D point set, for mesh evaluation (DESIGN.md
// §4.3 step 4). A k-d tree rather than a hash grid because the strict metrics need the exact
// distance of every point, floaters metres away included, not only those within the drop distance.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace rim::eval {

using Point3f = std::array<float, 3>;

// Calls fn(begin, end) on consecutive blocks of `block` items that cover [0, n), on `threads`
// threads (the caller's included). Blocks are handed out on demand, so uneven blocks balance.
void ParallelFor(int64_t n, int64_t block, int threads,
                 const std::function<void(int64_t begin, int64_t end)>& fn);

// A balanced k-d tree: every internal node splits its points at the median of their widest axis,
// so the tree shape depends only on the point count and needs no child pointers (heap order).
// Every node keeps the tight bounding box of its points, which prunes far better than the split
// planes for points on surfaces: a query 1 m above a ground plane is 1 m from every ground cell's
// box, whereas the split planes (all vertical) would bound the cells by their horizontal offsets.
class KdTree {
 public:
  // Takes the points (reordered in place) and builds on up to `threads` threads.
  KdTree(std::vector<Point3f> points, int threads);

  int64_t size() const { return static_cast<int64_t>(points_.size()); }

  // Squared distance from q to its nearest point; +inf when the tree is empty.
  float NearestSquaredDistance(const Point3f& q) const;

  // Nearest-point distance (not squared) of every query, computed on `threads` threads.
  std::vector<float> NearestDistances(const std::vector<Point3f>& queries, int threads) const;

 private:
  struct Box {
    Point3f lower, upper;
    float SquaredDistance(const Point3f& q) const;
  };

  void Build(int64_t node, int64_t lo, int64_t hi, int level, int threads);
  void Search(int64_t node, int64_t lo, int64_t hi, int level, const Point3f& q,
              float& best_sq) const;

  std::vector<Point3f> points_;  // in tree order: every leaf is a contiguous range
  std::vector<Box> boxes_;       // per node, heap order (children of n: 2n + 1, 2n + 2)
  int depth_ = 0;                // levels of internal nodes; leaves hold at most kMaxLeaf points
};

}  // namespace rim::eval
