#include "rim/eval/distance_probe.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <nanoflann.hpp>
#include <random>
#include <unordered_set>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/status_macros.h"
#include "rim/base/types.h"
#include "rim/io/json.h"

namespace rim::eval {
namespace {

using V3 = Eigen::Vector3f;

// Nearest point of triangle abc to p, by the region of the triangle's plane that p projects
// into (vertex, edge or face region), from the barycentric conditions of each region.
V3 ClosestOnTriangle(const V3& p, const V3& a, const V3& b, const V3& c) {
  const V3 ab = b - a, ac = c - a, ap = p - a;
  const float d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const V3 bp = p - b;
  const float d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  const V3 cp = p - c;
  const float d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const float denom = 1.f / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

struct Triangle {
  V3 a, b, c;
};

struct CentroidAdaptor {
  const std::vector<V3>* centroids;
  size_t kdtree_get_point_count() const { return centroids->size(); }
  float kdtree_get_pt(size_t i, size_t dim) const { return (*centroids)[i][int(dim)]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};
using CentroidTree = nanoflann::KDTreeSingleIndexAdaptor<
    nanoflann::L2_Simple_Adaptor<float, CentroidAdaptor, float, uint32_t>, CentroidAdaptor, 3,
    uint32_t>;

// Keeps the nearest triangle: one whose centroid is farther than best + r_max cannot hold a
// nearer point.
struct NearestTriangle {
  const std::vector<Triangle>* triangles;
  V3 q;
  float r_max;
  float best = std::numeric_limits<float>::infinity();
  V3 nearest = V3::Zero();
  float worstDist() const {
    const float w = best + r_max;
    return std::isfinite(w) ? w * w : std::numeric_limits<float>::max();
  }
  bool full() const { return true; }
  bool addPoint(float, uint32_t i) {
    const Triangle& t = (*triangles)[i];
    const V3 c = ClosestOnTriangle(q, t.a, t.b, t.c);
    const float d = (q - c).norm();
    if (d < best) {
      best = d;
      nearest = c;
    }
    return true;
  }
};

constexpr float kMaxEdge = 0.4f;  // triangles are split until no edge is longer

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, size_t(q * double(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + long(k), v.end());
  return v[k];
}

}  // namespace

struct MeshDistance::Index {
  std::vector<Triangle> triangles;
  std::vector<V3> centroids;
  float r_max = 0;
  CentroidAdaptor adaptor{&centroids};
  std::unique_ptr<CentroidTree> tree;
};

MeshDistance::MeshDistance(const Mesh& mesh) : index_(std::make_unique<Index>()) {
  std::vector<Triangle> todo;
  for (const auto& f : mesh.faces) {
    Triangle t;
    t.a = V3(mesh.vertices[f[0]].data());
    t.b = V3(mesh.vertices[f[1]].data());
    t.c = V3(mesh.vertices[f[2]].data());
    todo.push_back(t);
  }
  // Splitting into four at the edge midpoints keeps the surface exactly as it was.
  while (!todo.empty()) {
    const Triangle t = todo.back();
    todo.pop_back();
    const float e = std::max({(t.b - t.a).norm(), (t.c - t.b).norm(), (t.a - t.c).norm()});
    if (e <= kMaxEdge) {
      index_->triangles.push_back(t);
      continue;
    }
    const V3 ab = 0.5f * (t.a + t.b), bc = 0.5f * (t.b + t.c), ca = 0.5f * (t.c + t.a);
    todo.push_back({t.a, ab, ca});
    todo.push_back({ab, t.b, bc});
    todo.push_back({ca, bc, t.c});
    todo.push_back({ab, bc, ca});
  }
  for (const Triangle& t : index_->triangles) {
    const V3 c = (t.a + t.b + t.c) / 3.f;
    index_->centroids.push_back(c);
    index_->r_max = std::max({index_->r_max, (t.a - c).norm(), (t.b - c).norm(), (t.c - c).norm()});
  }
  if (!index_->triangles.empty())
    index_->tree = std::make_unique<CentroidTree>(3, index_->adaptor,
                                                  nanoflann::KDTreeSingleIndexAdaptorParams(16));
}

MeshDistance::~MeshDistance() = default;

float MeshDistance::Nearest(const std::array<float, 3>& q, std::array<float, 3>* nearest) const {
  if (!index_->tree) return std::numeric_limits<float>::infinity();
  NearestTriangle search{&index_->triangles, V3(q.data()), index_->r_max};
  index_->tree->findNeighbors(search, q.data(), nanoflann::SearchParams());
  if (nearest) *nearest = {search.nearest.x(), search.nearest.y(), search.nearest.z()};
  return search.best;
}

absl::StatusOr<ProbeReport> RunDistanceProbe(const io::Dataset& dataset, const Mesh& gt,
                                             const std::vector<std::array<float, 3>>& seen,
                                             const ProbeQuery& query, const ProbeOptions& options) {
  const std::vector<float>& edges = options.bin_edges_m;
  if (edges.size() < 2 || options.points_per_bin < 1 || options.frame_stride < 1 ||
      !(options.seen_radius_m > 0))
    return absl::InvalidArgumentError("probe options: bins, counts and radius must be positive");
  const size_t n_bins = edges.size() - 1;
  const MeshDistance truth(gt);
  // Cells of the seen radius that hold a return: a surface point counts as seen when a return
  // lies in its cell or a neighbouring one.
  const float cell = options.seen_radius_m;
  std::unordered_set<Int3, Int3Hash, Int3Equal> seen_cells;
  auto cell_of = [&](const V3& p) {
    return Int3(int(std::floor(p.x() / cell)), int(std::floor(p.y() / cell)),
                int(std::floor(p.z() / cell)));
  };
  for (const auto& p : seen) seen_cells.insert(cell_of(V3(p.data())));
  auto was_seen = [&](const V3& p) {
    const Int3 c = cell_of(p);
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz)
          if (seen_cells.count(c + Int3(dx, dy, dz))) return true;
    return false;
  };

  struct Sample {
    V3 p, truth_dir;
    float truth;
    size_t bin;
  };
  std::vector<Sample> samples;
  std::vector<int> per_bin(n_bins, 0);
  std::mt19937_64 rng(options.seed);
  ProbeReport report;
  auto all_full = [&] {
    for (int c : per_bin)
      if (c < options.points_per_bin) return false;
    return true;
  };
  constexpr int kDrawsPerFrame = 3000;
  for (size_t f = 0; f < dataset.size() && !all_full(); f += size_t(options.frame_stride)) {
    RIM_ASSIGN_OR_RETURN(PosedScan scan, dataset.Read(f));
    if (scan.points_S.empty()) continue;
    const Eigen::Isometry3f T = scan.T_world_sensor.cast<float>();
    std::uniform_int_distribution<size_t> pick(0, scan.points_S.size() - 1);
    std::uniform_real_distribution<float> unit(0.f, 1.f);
    for (int k = 0; k < kDrawsPerFrame; ++k) {
      const size_t i = pick(rng);
      const V3 hit = T * scan.points_S[i];
      const V3 origin = scan.origins_S.empty() ? V3(T.translation()) : V3(T * scan.origins_S[i]);
      const float range = (hit - origin).norm();
      if (!(range > 0.5f)) continue;
      // Back from the return, log-uniform from 2 cm to most of the ray, so that every distance
      // bin gets points.
      const float lo = 0.02f, hi = std::min(0.9f * range, 8.f);
      if (hi <= lo) continue;
      const float back = lo * std::pow(hi / lo, unit(rng));
      const V3 p = hit + (origin - hit) * (back / range);
      ++report.drawn;
      std::array<float, 3> near;
      const float d = truth.Nearest({p.x(), p.y(), p.z()}, &near);
      if (!(d < edges.back()) || d < edges.front()) continue;
      const size_t bin =
          size_t(std::upper_bound(edges.begin(), edges.end(), d) - edges.begin()) - 1;
      if (per_bin[bin] >= options.points_per_bin) continue;
      const V3 nv(near.data());
      if (!was_seen(nv)) {
        ++report.unseen_surface;
        continue;
      }
      const V3 dir = d > 1e-6f ? V3((p - nv) / d) : V3::Zero();
      samples.push_back({p, dir, d, bin});
      ++per_bin[bin];
    }
  }

  std::vector<float> xyz(3 * samples.size()), sdf, grad;
  std::vector<uint8_t> observed;
  for (size_t i = 0; i < samples.size(); ++i)
    for (int a = 0; a < 3; ++a) xyz[3 * i + a] = samples[i].p[a];
  RIM_RETURN_IF_ERROR(query(xyz, &sdf, &grad, &observed));
  if (sdf.size() != samples.size() || grad.size() != 3 * samples.size() ||
      observed.size() != samples.size())
    return absl::InternalError("the map answered the wrong number of values");

  std::vector<std::vector<double>> abs_err(n_bins), angle(n_bins);
  std::vector<int64_t> far(n_bins, 0), wrong(n_bins, 0), sat(n_bins, 0), within(n_bins, 0),
      beyond(n_bins, 0), wrong_beyond(n_bins, 0);
  for (size_t i = 0; i < samples.size(); ++i) {
    if (!observed[i]) {
      ++report.unobserved;
      continue;
    }
    const Sample& s = samples[i];
    const double e = double(sdf[i]) - s.truth;
    abs_err[s.bin].push_back(std::abs(e));
    if (e > 0.1) ++far[s.bin];
    if (sdf[i] < 0) ++wrong[s.bin];
    if (s.truth >= 0.02f) {
      ++beyond[s.bin];
      if (sdf[i] < 0) ++wrong_beyond[s.bin];
    }
    const V3 g(&grad[3 * i]);
    if (g.squaredNorm() < 1e-12f) ++sat[s.bin];
    double deg = 180.0;
    if (g.squaredNorm() > 1e-12f && s.truth_dir.squaredNorm() > 0.5f)
      deg =
          std::acos(std::clamp(double(g.normalized().dot(s.truth_dir)), -1.0, 1.0)) * 180.0 / M_PI;
    angle[s.bin].push_back(deg);
    if (deg <= 10.0) ++within[s.bin];
  }
  for (size_t b = 0; b < n_bins; ++b) {
    ProbeBin bin;
    bin.lo_m = edges[b];
    bin.hi_m = edges[b + 1];
    bin.points = int64_t(abs_err[b].size());
    const double n = std::max<double>(1, double(bin.points));
    bin.median_abs_error_m = Quantile(abs_err[b], 0.5);
    bin.p90_abs_error_m = Quantile(abs_err[b], 0.9);
    bin.share_too_far = double(far[b]) / n;
    bin.share_wrong_sign = double(wrong[b]) / n;
    bin.share_wrong_sign_beyond_2cm = double(wrong_beyond[b]) / std::max<double>(1, beyond[b]);
    bin.share_saturated = double(sat[b]) / n;
    bin.gradient_median_deg = Quantile(angle[b], 0.5);
    bin.gradient_p95_deg = Quantile(angle[b], 0.95);
    bin.gradient_within_10deg = double(within[b]) / n;
    report.bins.push_back(bin);
  }
  return report;
}

std::string ProbeReportJson(const ProbeReport& r) {
  using io::JsonNumber;
  nlohmann::ordered_json bins = nlohmann::ordered_json::array();
  for (const ProbeBin& b : r.bins) {
    bins.push_back({{"lo_m", JsonNumber(b.lo_m, 3)},
                    {"hi_m", JsonNumber(b.hi_m, 3)},
                    {"points", b.points},
                    {"median_abs_error_m", JsonNumber(b.median_abs_error_m, 5)},
                    {"p90_abs_error_m", JsonNumber(b.p90_abs_error_m, 5)},
                    {"share_too_far", JsonNumber(b.share_too_far, 5)},
                    {"share_wrong_sign", JsonNumber(b.share_wrong_sign, 5)},
                    {"share_wrong_sign_beyond_2cm", JsonNumber(b.share_wrong_sign_beyond_2cm, 5)},
                    {"share_saturated", JsonNumber(b.share_saturated, 5)},
                    {"gradient_median_deg", JsonNumber(b.gradient_median_deg, 3)},
                    {"gradient_p95_deg", JsonNumber(b.gradient_p95_deg, 3)},
                    {"gradient_within_10deg", JsonNumber(b.gradient_within_10deg, 5)}});
  }
  // One bin a line.
  return io::DumpJson({{"drawn", r.drawn},
                       {"unseen_surface", r.unseen_surface},
                       {"unobserved", r.unobserved},
                       {"bins", bins}},
                      2);
}

std::string ProbeReportTable(const ProbeReport& r) {
  std::string out =
      "true distance   points  |err| median  p90     >10cm far  wrong sign (>=2cm)     grad median "
      " "
      "p95   within 10deg\n";
  for (const ProbeBin& b : r.bins)
    absl::StrAppendFormat(&out,
                          "%4.2f-%4.2f m  %8d  %8.1f cm  %5.1f cm  %8.2f %%  %6.2f %% (%5.2f %%)  "
                          "%6.1f deg  %5.1f  %8.1f %%\n",
                          b.lo_m, b.hi_m, b.points, 100 * b.median_abs_error_m,
                          100 * b.p90_abs_error_m, 100 * b.share_too_far, 100 * b.share_wrong_sign,
                          100 * b.share_wrong_sign_beyond_2cm, b.gradient_median_deg,
                          b.gradient_p95_deg, 100 * b.gradient_within_10deg);
  absl::StrAppendFormat(&out, "drawn %d, left out: %d near an unseen surface, %d unobserved\n",
                        r.drawn, r.unseen_surface, r.unobserved);
  return out;
}

}  // namespace rim::eval
