// The planner probe (docs/testing.md, "Metric distances"): how far the distances a map answers
// are from the truth, at free-space points a sensor really crossed.
//
// Points are drawn on the sensor rays of a sequence, in front of their returns, and scored
// against their exact Euclidean distance to the ground-truth mesh (point-triangle distance) and
// the direction away from its nearest point. Points whose nearest ground-truth point the sensor
// never saw (no return within `seen_radius_m` of it) are left out: no map can know those
// surfaces. Results are binned by true distance.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "rim/base/mesh.h"
#include "rim/io/dataset.h"

namespace rim::eval {

// Exact distance from points to a triangle mesh: triangles are split until small, indexed by
// centroid in a k-d tree, and every triangle that can hold the nearest point is tested.
class MeshDistance {
 public:
  explicit MeshDistance(const Mesh& mesh);
  ~MeshDistance();
  // Distance from q to the mesh and the nearest mesh point; +inf when the mesh is empty.
  float Nearest(const std::array<float, 3>& q, std::array<float, 3>* nearest) const;

 private:
  struct Index;
  std::unique_ptr<Index> index_;
};

struct ProbeOptions {
  int points_per_bin = 4000;  // drawn until every bin has this many (or the rays run out)
  int frame_stride = 5;       // rays of every this many-th frame
  float seen_radius_m = 0.1f;
  uint64_t seed = 1;
  std::vector<float> bin_edges_m = {0.f, 0.1f, 0.3f, 1.f, 2.f};
  int threads = 2;
};

struct ProbeBin {
  float lo_m = 0, hi_m = 0;
  int64_t points = 0;
  double median_abs_error_m = 0, p90_abs_error_m = 0;
  double share_too_far = 0;     // reported more than 0.1 m farther than the truth
  double share_wrong_sign = 0;  // reported negative (the points are all in free space)
  // The same among points at least 2 cm from the truth: within that, the mapped surface's own
  // error (C-L1 ~1 cm) decides the side more than the distance field does.
  double share_wrong_sign_beyond_2cm = 0;
  double share_saturated = 0;
  double gradient_median_deg = 0, gradient_p95_deg = 0;
  double gradient_within_10deg = 0;  // share of points with the gradient within 10° of the truth
};

struct ProbeReport {
  std::vector<ProbeBin> bins;
  int64_t drawn = 0, unseen_surface = 0, unobserved = 0;
};

// What the probe asks of a map: sdf, gradient (3 per point) and observed flags at points.
using ProbeQuery =
    std::function<absl::Status(const std::vector<float>& xyz, std::vector<float>* sdf,
                               std::vector<float>* gradient, std::vector<uint8_t>* observed)>;

absl::StatusOr<ProbeReport> RunDistanceProbe(const io::Dataset& dataset, const Mesh& gt,
                                             const std::vector<std::array<float, 3>>& seen,
                                             const ProbeQuery& query, const ProbeOptions& options);

std::string ProbeReportJson(const ProbeReport& report);
std::string ProbeReportTable(const ProbeReport& report);

}  // namespace rim::eval
