#include "rim/eval/kd_tree.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <thread>
#include <utility>

namespace rim::eval {
namespace {

// Small leaves favour the 1-NN queries (which dominate) over build time.
constexpr int64_t kMaxLeaf = 8;

}  // namespace

void ParallelFor(int64_t n, int64_t block, int threads,
                 const std::function<void(int64_t begin, int64_t end)>& fn) {
  if (n <= 0) return;
  block = std::max<int64_t>(block, 1);
  const int64_t num_blocks = (n + block - 1) / block;
  std::atomic<int64_t> next{0};
  auto worker = [&] {
    for (int64_t b = next.fetch_add(1); b < num_blocks; b = next.fetch_add(1)) {
      fn(b * block, std::min(n, (b + 1) * block));
    }
  };
  const int64_t helpers = std::min<int64_t>(std::max(threads, 1), num_blocks) - 1;
  std::vector<std::thread> pool;
  pool.reserve(helpers);
  for (int64_t i = 0; i < helpers; ++i) pool.emplace_back(worker);
  worker();
  for (std::thread& t : pool) t.join();
}

KdTree::KdTree(std::vector<Point3f> points, int threads) : points_(std::move(points)) {
  const int64_t n = size();
  // The smallest depth whose leaves (ceil(n / 2^depth) points at most) fit kMaxLeaf.
  while (((n + (int64_t{1} << depth_) - 1) >> depth_) > kMaxLeaf) ++depth_;
  if (n == 0) return;
  boxes_.resize((int64_t{2} << depth_) - 1);
  Build(0, 0, n, 0, std::max(threads, 1));
}

float KdTree::Box::SquaredDistance(const Point3f& q) const {
  float sum = 0.0f;
  for (int a = 0; a < 3; ++a) {
    const float d = std::max({lower[a] - q[a], 0.0f, q[a] - upper[a]});
    sum += d * d;
  }
  return sum;
}

void KdTree::Build(int64_t node, int64_t lo, int64_t hi, int level, int threads) {
  Box& box = boxes_[node];
  box.lower.fill(std::numeric_limits<float>::infinity());
  box.upper.fill(-std::numeric_limits<float>::infinity());
  for (int64_t i = lo; i < hi; ++i) {
    for (int a = 0; a < 3; ++a) {
      box.lower[a] = std::min(box.lower[a], points_[i][a]);
      box.upper[a] = std::max(box.upper[a], points_[i][a]);
    }
  }
  if (level == depth_) return;
  // Split the widest axis: surfaces are 2D in 3D, so cycling the axes would waste levels
  // splitting across a wall's thickness.
  int axis = 0;
  for (int a = 1; a < 3; ++a) {
    if (box.upper[a] - box.lower[a] > box.upper[axis] - box.lower[axis]) axis = a;
  }
  const int64_t mid = lo + (hi - lo) / 2;
  std::nth_element(points_.begin() + lo, points_.begin() + mid, points_.begin() + hi,
                   [axis](const Point3f& a, const Point3f& b) { return a[axis] < b[axis]; });
  if (threads > 1) {
    std::thread left([&] { Build(2 * node + 1, lo, mid, level + 1, threads / 2); });
    Build(2 * node + 2, mid, hi, level + 1, threads - threads / 2);
    left.join();
  } else {
    Build(2 * node + 1, lo, mid, level + 1, 1);
    Build(2 * node + 2, mid, hi, level + 1, 1);
  }
}

float KdTree::NearestSquaredDistance(const Point3f& q) const {
  float best_sq = std::numeric_limits<float>::infinity();
  if (!points_.empty()) Search(0, 0, size(), 0, q, best_sq);
  return best_sq;
}

// Depth-first, nearer child box first; a child is entered only if its box is closer than the
// best point so far.
void KdTree::Search(int64_t node, int64_t lo, int64_t hi, int level, const Point3f& q,
                    float& best_sq) const {
  if (level == depth_) {
    for (int64_t i = lo; i < hi; ++i) {
      const float dx = points_[i][0] - q[0];
      const float dy = points_[i][1] - q[1];
      const float dz = points_[i][2] - q[2];
      best_sq = std::min(best_sq, dx * dx + dy * dy + dz * dz);
    }
    return;
  }
  const int64_t mid = lo + (hi - lo) / 2;
  const int64_t left = 2 * node + 1, right = 2 * node + 2;
  const float left_sq = boxes_[left].SquaredDistance(q);
  const float right_sq = boxes_[right].SquaredDistance(q);
  if (left_sq <= right_sq) {
    if (left_sq < best_sq) Search(left, lo, mid, level + 1, q, best_sq);
    if (right_sq < best_sq) Search(right, mid, hi, level + 1, q, best_sq);
  } else {
    if (right_sq < best_sq) Search(right, mid, hi, level + 1, q, best_sq);
    if (left_sq < best_sq) Search(left, lo, mid, level + 1, q, best_sq);
  }
}

std::vector<float> KdTree::NearestDistances(const std::vector<Point3f>& queries,
                                            int threads) const {
  std::vector<float> out(queries.size());
  ParallelFor(static_cast<int64_t>(queries.size()), 4096, threads, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) out[i] = std::sqrt(NearestSquaredDistance(queries[i]));
  });
  return out;
}

}  // namespace rim::eval
