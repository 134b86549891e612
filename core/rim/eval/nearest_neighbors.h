// Exact nearest-neighbour distances over a static 3D point set, for mesh evaluation (DESIGN.md
// §4.3 step 4): a nanoflann k-d tree (Debian libnanoflann-dev). Exact rather than approximate or
// bounded, because the strict metrics need the distance of every point, floaters metres away
// included, not only those within the drop distance.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

namespace rim::eval {

using Point3f = std::array<float, 3>;

class NearestNeighbors {
 public:
  // Takes the points and indexes them.
  explicit NearestNeighbors(std::vector<Point3f> points);
  ~NearestNeighbors();
  NearestNeighbors(const NearestNeighbors&) = delete;
  NearestNeighbors& operator=(const NearestNeighbors&) = delete;

  int64_t size() const { return static_cast<int64_t>(points_.size()); }

  // Squared distance from q to its nearest point; +inf when the set is empty.
  float NearestSquaredDistance(const Point3f& q) const;

  // Nearest-point distance (not squared) of every query, computed on `threads` threads.
  std::vector<float> NearestDistances(const std::vector<Point3f>& queries, int threads) const;

 private:
  struct Index;  // the nanoflann tree, kept out of this header

  std::vector<Point3f> points_;
  std::unique_ptr<Index> index_;
};

}  // namespace rim::eval
