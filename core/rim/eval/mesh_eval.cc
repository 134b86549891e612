#include "rim/eval/mesh_eval.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "rim/base/status_macros.h"
#include "rim/base/worker_pool.h"
#include "rim/eval/nearest_neighbors.h"

namespace rim::eval {
namespace {

using Triangle = std::array<Point3f, 3>;
using Box = std::array<Point3f, 2>;  // lower, upper corner

// Fixed-size blocks of triangles, each with its own random stream, make the samples independent of
// the thread count.
constexpr int64_t kTriangleBlock = 4096;
// Voxel keys pack three 21-bit indices, relative to the voxel of the GT box centre.
constexpr int kKeyBits = 21;
constexpr int64_t kKeyHalfRange = int64_t{1} << (kKeyBits - 1);

// SplitMix64: tiny, fast and good enough for uniform sampling; one generator per triangle block.
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}
  uint64_t Next() {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }  // [0, 1)

 private:
  uint64_t state_;
};

uint64_t StreamSeed(uint64_t seed, uint64_t stream, uint64_t block, uint64_t pass) {
  Rng mix(seed ^ (stream * 0xD6E8FEB86659FD93ull));
  Rng mix2(mix.Next() ^ (block * 0xA0761D6478BD642Full) ^ (pass * 0xE7037ED1A0B428DBull));
  return mix2.Next();
}

double TriangleArea(const Triangle& t) {
  const double ux = t[1][0] - t[0][0], uy = t[1][1] - t[0][1], uz = t[1][2] - t[0][2];
  const double vx = t[2][0] - t[0][0], vy = t[2][1] - t[0][1], vz = t[2][2] - t[0][2];
  const double cx = uy * vz - uz * vy, cy = uz * vx - ux * vz, cz = ux * vy - uy * vx;
  return 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
}

absl::StatusOr<std::vector<Triangle>> ToTriangles(const Mesh& mesh, const char* name) {
  std::vector<Triangle> tris;
  tris.reserve(mesh.faces.size());
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    Triangle t;
    for (int c = 0; c < 3; ++c) {
      const uint32_t v = mesh.faces[f][c];
      if (v >= mesh.vertices.size()) {
        return absl::InvalidArgumentError(absl::StrCat(
            name, " mesh: face ", f, " refers to vertex ", v, " of ", mesh.vertices.size()));
      }
      t[c] = mesh.vertices[v];
      if (!std::isfinite(t[c][0]) || !std::isfinite(t[c][1]) || !std::isfinite(t[c][2])) {
        return absl::InvalidArgumentError(
            absl::StrCat(name, " mesh: vertex ", v, " (of face ", f, ") is not finite"));
      }
    }
    tris.push_back(t);
  }
  return tris;
}

// A point cloud is a mesh with vertices and no faces.
bool IsPointCloud(const Mesh& mesh) { return mesh.faces.empty() && !mesh.vertices.empty(); }

absl::StatusOr<std::vector<Point3f>> ToPoints(const Mesh& cloud, const char* name) {
  for (size_t v = 0; v < cloud.vertices.size(); ++v) {
    const Point3f& p = cloud.vertices[v];
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) {
      return absl::InvalidArgumentError(
          absl::StrCat(name, " point cloud: point ", v, " is not finite"));
    }
  }
  return cloud.vertices;
}

bool InBox(const Point3f& p, const Box& box) {
  return p[0] >= box[0][0] && p[0] <= box[1][0] && p[1] >= box[0][1] && p[1] <= box[1][1] &&
         p[2] >= box[0][2] && p[2] <= box[1][2];
}

std::vector<Point3f> CropPoints(const std::vector<Point3f>& points, const Box& box) {
  std::vector<Point3f> out;
  for (const Point3f& p : points) {
    if (InBox(p, box)) out.push_back(p);
  }
  return out;
}

Box PointBoundingBox(const std::vector<Point3f>& points) {
  Box box;
  box[0].fill(std::numeric_limits<float>::infinity());
  box[1].fill(-std::numeric_limits<float>::infinity());
  for (const Point3f& p : points) {
    for (int a = 0; a < 3; ++a) {
      box[0][a] = std::min(box[0][a], p[a]);
      box[1][a] = std::max(box[1][a], p[a]);
    }
  }
  return box;
}

Box BoundingBox(const std::vector<Triangle>& tris) {
  Box box;
  box[0].fill(std::numeric_limits<float>::infinity());
  box[1].fill(-std::numeric_limits<float>::infinity());
  for (const Triangle& t : tris) {
    for (const Point3f& p : t) {
      for (int a = 0; a < 3; ++a) {
        box[0][a] = std::min(box[0][a], p[a]);
        box[1][a] = std::max(box[1][a], p[a]);
      }
    }
  }
  return box;
}

// Sutherland–Hodgman against the six faces of the box; the clipped polygon is split into a fan.
void ClipTriangle(const Triangle& t, const Box& box, std::vector<Triangle>* out) {
  bool inside = true;
  for (int a = 0; a < 3; ++a) {
    const float lo = std::min({t[0][a], t[1][a], t[2][a]});
    const float hi = std::max({t[0][a], t[1][a], t[2][a]});
    if (hi < box[0][a] || lo > box[1][a]) return;
    inside = inside && lo >= box[0][a] && hi <= box[1][a];
  }
  if (inside) {
    out->push_back(t);
    return;
  }
  // A convex polygon gains at most one corner per plane (3 + 6); the headroom covers rounding.
  constexpr int kMaxCorners = 16;
  using P = std::array<double, 3>;
  P poly[kMaxCorners], next[kMaxCorners];
  int n = 3;
  for (int c = 0; c < 3; ++c) poly[c] = {t[c][0], t[c][1], t[c][2]};
  for (int a = 0; a < 3; ++a) {
    for (int side = 0; side < 2; ++side) {
      const double bound = box[side][a];
      auto in = [&](const P& p) { return side == 0 ? p[a] >= bound : p[a] <= bound; };
      int m = 0;
      for (int i = 0; i < n && m + 2 <= kMaxCorners; ++i) {
        const P& cur = poly[i];
        const P& nxt = poly[(i + 1) % n];
        if (in(cur)) next[m++] = cur;
        if (in(cur) != in(nxt)) {
          const double s = (bound - cur[a]) / (nxt[a] - cur[a]);
          P x;
          for (int k = 0; k < 3; ++k) x[k] = cur[k] + s * (nxt[k] - cur[k]);
          x[a] = bound;
          next[m++] = x;
        }
      }
      n = m;
      if (n < 3) return;
      std::copy(next, next + n, poly);
    }
  }
  auto to_float = [](const P& p) {
    return Point3f{static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2])};
  };
  for (int i = 1; i + 1 < n; ++i) {
    out->push_back({to_float(poly[0]), to_float(poly[i]), to_float(poly[i + 1])});
  }
}

// The points inside the box union, in their order.
std::vector<Point3f> KeepInside(const std::vector<Point3f>& points, const BoxUnion& box_union,
                                int threads) {
  std::vector<uint8_t> inside(points.size());
  ParallelFor(static_cast<int64_t>(points.size()), 65536, threads, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) inside[i] = box_union.Contains(points[i]);
  });
  std::vector<Point3f> out;
  for (size_t i = 0; i < points.size(); ++i) {
    if (inside[i]) out.push_back(points[i]);
  }
  return out;
}

std::vector<Triangle> CropTriangles(const std::vector<Triangle>& tris, const Box& box) {
  std::vector<Triangle> out;
  out.reserve(tris.size());
  for (const Triangle& t : tris) ClipTriangle(t, box, &out);
  return out;
}

// Step 2: about `samples` points, uniform by area. Triangle i gets floor(samples * a_i / A + u_i)
// points (u_i uniform), which has the expected count of i.i.d. area-weighted sampling but less
// variance, and fills blocks of triangles independently.
std::vector<Point3f> SampleTriangles(const std::vector<Triangle>& tris, int64_t samples,
                                     uint64_t seed, uint64_t stream, int threads, double* area_m2) {
  const int64_t n = static_cast<int64_t>(tris.size());
  const int64_t num_blocks = (n + kTriangleBlock - 1) / kTriangleBlock;
  std::vector<double> areas(n), block_area(num_blocks);
  ParallelFor(num_blocks, 1, threads, [&](int64_t b, int64_t) {
    double sum = 0;
    for (int64_t i = b * kTriangleBlock; i < std::min(n, (b + 1) * kTriangleBlock); ++i) {
      sum += areas[i] = TriangleArea(tris[i]);
    }
    block_area[b] = sum;
  });
  double total = 0;
  for (double a : block_area) total += a;
  *area_m2 = total;
  if (!(total > 0)) return {};
  const double density = static_cast<double>(samples) / total;

  std::vector<uint32_t> counts(n);
  std::vector<int64_t> block_start(num_blocks + 1, 0);
  ParallelFor(num_blocks, 1, threads, [&](int64_t b, int64_t) {
    Rng rng(StreamSeed(seed, stream, b, 0));
    int64_t sum = 0;
    for (int64_t i = b * kTriangleBlock; i < std::min(n, (b + 1) * kTriangleBlock); ++i) {
      sum += counts[i] = static_cast<uint32_t>(std::floor(density * areas[i] + rng.Uniform()));
    }
    block_start[b + 1] = sum;
  });
  for (int64_t b = 0; b < num_blocks; ++b) block_start[b + 1] += block_start[b];

  std::vector<Point3f> points(block_start[num_blocks]);
  ParallelFor(num_blocks, 1, threads, [&](int64_t b, int64_t) {
    Rng rng(StreamSeed(seed, stream, b, 1));
    int64_t out = block_start[b];
    for (int64_t i = b * kTriangleBlock; i < std::min(n, (b + 1) * kTriangleBlock); ++i) {
      const Triangle& t = tris[i];
      for (uint32_t k = 0; k < counts[i]; ++k) {
        // Uniform on the triangle: sqrt warps the first barycentric coordinate.
        const double s = std::sqrt(rng.Uniform()), r = rng.Uniform();
        const double wa = 1 - s, wb = s * (1 - r), wc = s * r;
        for (int a = 0; a < 3; ++a) {
          points[out][a] = static_cast<float>(wa * t[0][a] + wb * t[1][a] + wc * t[2][a]);
        }
        ++out;
      }
    }
  });
  return points;
}

// Sorts on `threads` threads: slices sorted in parallel, then merged pairwise.
template <typename T>
void ParallelSort(std::vector<T>& v, int threads) {
  const int64_t n = static_cast<int64_t>(v.size());
  const int64_t parts = std::max<int64_t>(1, std::min<int64_t>(threads, n / 65536));
  const int64_t slice = (n + parts - 1) / parts;
  ParallelFor(parts, 1, threads, [&](int64_t p, int64_t) {
    std::sort(v.begin() + std::min(n, p * slice), v.begin() + std::min(n, (p + 1) * slice));
  });
  for (int64_t width = slice; width < n; width *= 2) {
    const int64_t pairs = (n + 2 * width - 1) / (2 * width);
    ParallelFor(pairs, 1, threads, [&](int64_t p, int64_t) {
      const int64_t lo = p * 2 * width, mid = std::min(n, lo + width);
      const int64_t hi = std::min(n, lo + 2 * width);
      std::inplace_merge(v.begin() + lo, v.begin() + mid, v.begin() + hi);
    });
  }
}

// Step 3: every voxel's points replaced by their mean. The output is in voxel-key order, which
// keeps consecutive nearest-neighbour queries close in space. `counts`, when given, receives how
// many input points each output point stands for.
absl::StatusOr<std::vector<Point3f>> VoxelAverage(std::vector<Point3f> points, double voxel_m,
                                                  const Point3f& centre, int threads,
                                                  std::vector<uint32_t>* counts = nullptr) {
  if (voxel_m <= 0 || points.empty()) {
    if (counts != nullptr) counts->assign(points.size(), 1);
    return points;
  }
  std::array<int64_t, 3> origin;
  for (int a = 0; a < 3; ++a) origin[a] = static_cast<int64_t>(std::floor(centre[a] / voxel_m));
  std::vector<std::pair<uint64_t, uint32_t>> keyed(points.size());
  std::atomic<bool> out_of_range{false};
  ParallelFor(static_cast<int64_t>(points.size()), 65536, threads, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) {
      uint64_t key = 0;
      for (int a = 0; a < 3; ++a) {
        const int64_t idx =
            static_cast<int64_t>(std::floor(points[i][a] / voxel_m)) - origin[a] + kKeyHalfRange;
        if (idx < 0 || idx >= 2 * kKeyHalfRange) out_of_range = true;
        key = (key << kKeyBits) | (static_cast<uint64_t>(idx) & ((1u << kKeyBits) - 1));
      }
      keyed[i] = {key, static_cast<uint32_t>(i)};
    }
  });
  if (out_of_range) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "points lie more than %.0f m from the GT box centre along an axis: too far for voxel "
        "averaging at %g m (crop the prediction, or use a larger voxel)",
        kKeyHalfRange * voxel_m, voxel_m));
  }
  ParallelSort(keyed, threads);
  std::vector<Point3f> averaged;
  if (counts != nullptr) counts->clear();
  for (size_t i = 0; i < keyed.size();) {
    double sum[3] = {0, 0, 0};
    size_t j = i;
    for (; j < keyed.size() && keyed[j].first == keyed[i].first; ++j) {
      for (int a = 0; a < 3; ++a) sum[a] += points[keyed[j].second][a];
    }
    const double count = static_cast<double>(j - i);
    averaged.push_back({static_cast<float>(sum[0] / count), static_cast<float>(sum[1] / count),
                        static_cast<float>(sum[2] / count)});
    if (counts != nullptr) counts->push_back(static_cast<uint32_t>(j - i));
    i = j;
  }
  return averaged;
}

// Steps 5–6 over the distances of both directions; `strict` leaves out the drop and the cap.
Metrics ComputeMetrics(const std::vector<float>& pred_to_gt, const std::vector<float>& gt_to_pred,
                       const EvalOptions& options, bool strict) {
  double acc_sum = 0;
  int64_t kept = 0, pred_inliers = 0;
  for (float d : pred_to_gt) {
    if (!strict && d >= options.drop_m) continue;
    acc_sum += d;
    ++kept;
    pred_inliers += d < options.fscore_m;
  }
  double comp_sum = 0;
  int64_t gt_inliers = 0;
  for (float d : gt_to_pred) {
    comp_sum += strict ? d : std::min<double>(d, options.cap_m);
    gt_inliers += d < options.fscore_m;
  }
  Metrics m;
  m.accuracy_m = kept > 0 ? acc_sum / kept : std::numeric_limits<double>::quiet_NaN();
  m.completeness_m = comp_sum / static_cast<double>(gt_to_pred.size());
  m.chamfer_l1_m = 0.5 * (m.accuracy_m + m.completeness_m);
  m.precision = kept > 0 ? static_cast<double>(pred_inliers) / kept : 0.0;
  m.recall = static_cast<double>(gt_inliers) / static_cast<double>(gt_to_pred.size());
  m.fscore =
      m.precision + m.recall > 0 ? 2 * m.precision * m.recall / (m.precision + m.recall) : 0.0;
  return m;
}

}  // namespace

const char* InputKindName(InputKind kind) { return kind == InputKind::kPoints ? "points" : "mesh"; }

absl::Status ValidateEvalOptions(const EvalOptions& o) {
  auto bad = [](const char* field, const std::string& why) {
    return absl::InvalidArgumentError(absl::StrCat("EvalOptions.", field, " ", why));
  };
  if (o.samples < 1 || o.samples > 1'000'000'000) {
    return bad("samples", absl::StrCat("must be in [1, 1e9], got ", o.samples));
  }
  auto check = [&](const char* field, double v, bool allow_zero) -> absl::Status {
    if (!std::isfinite(v) || v < 0 || (!allow_zero && v == 0)) {
      return bad(field, absl::StrCat(allow_zero ? "must be >= 0" : "must be > 0", ", got ", v));
    }
    return absl::OkStatus();
  };
  RIM_RETURN_IF_ERROR(check("voxel_m", o.voxel_m, true));
  RIM_RETURN_IF_ERROR(check("drop_m", o.drop_m, false));
  RIM_RETURN_IF_ERROR(check("cap_m", o.cap_m, false));
  RIM_RETURN_IF_ERROR(check("fscore_m", o.fscore_m, false));
  RIM_RETURN_IF_ERROR(check("crop_margin_m", o.crop_margin_m, true));
  RIM_RETURN_IF_ERROR(check("floater_m", o.floater_m, false));
  if (o.threads < 1 || o.threads > 1024) {
    return bad("threads", absl::StrCat("must be in [1, 1024], got ", o.threads));
  }
  return absl::OkStatus();
}

Mesh CropMeshToBox(const Mesh& mesh, const std::array<float, 3>& lower,
                   const std::array<float, 3>& upper) {
  if (mesh.faces.empty()) {
    Mesh out;
    out.vertices = CropPoints(mesh.vertices, {lower, upper});
    return out;
  }
  std::vector<Triangle> tris;
  for (const auto& f : mesh.faces) {
    if (f[0] < mesh.vertices.size() && f[1] < mesh.vertices.size() && f[2] < mesh.vertices.size()) {
      tris.push_back({mesh.vertices[f[0]], mesh.vertices[f[1]], mesh.vertices[f[2]]});
    }
  }
  Mesh out;
  for (const Triangle& t : CropTriangles(tris, {lower, upper})) {
    const uint32_t base = static_cast<uint32_t>(out.vertices.size());
    out.vertices.insert(out.vertices.end(), t.begin(), t.end());
    out.faces.push_back({base, base + 1, base + 2});
  }
  return out;
}

absl::StatusOr<EvalResult> EvaluateMeshes(const Mesh& pred, const Mesh& gt,
                                          const EvalOptions& options) {
  RIM_RETURN_IF_ERROR(ValidateEvalOptions(options));
  const int threads = options.threads;
  EvalResult result;
  result.gt_kind = IsPointCloud(gt) ? InputKind::kPoints : InputKind::kMesh;
  result.pred_kind = IsPointCloud(pred) ? InputKind::kPoints : InputKind::kMesh;
  // Exactly one of each pair is used, as the kind says.
  std::vector<Triangle> gt_tris, pred_tris;
  std::vector<Point3f> gt_points, pred_points;
  if (result.gt_kind == InputKind::kPoints) {
    RIM_ASSIGN_OR_RETURN(gt_points, ToPoints(gt, "GT"));
  } else {
    RIM_ASSIGN_OR_RETURN(gt_tris, ToTriangles(gt, "GT"));
    if (gt_tris.empty())
      return absl::InvalidArgumentError("GT mesh has no triangles and no points");
  }
  if (result.pred_kind == InputKind::kPoints) {
    RIM_ASSIGN_OR_RETURN(pred_points, ToPoints(pred, "prediction"));
  } else {
    RIM_ASSIGN_OR_RETURN(pred_tris, ToTriangles(pred, "prediction"));
  }

  // Step 1.
  const Box gt_box =
      result.gt_kind == InputKind::kPoints ? PointBoundingBox(gt_points) : BoundingBox(gt_tris);
  if (options.crop_to_gt) {
    Box padded = gt_box;
    for (int a = 0; a < 3; ++a) {
      padded[0][a] -= static_cast<float>(options.crop_margin_m);
      padded[1][a] += static_cast<float>(options.crop_margin_m);
    }
    if (result.pred_kind == InputKind::kPoints) {
      pred_points = CropPoints(pred_points, padded);
    } else {
      pred_tris = CropTriangles(pred_tris, padded);
    }
  }

  // Meshes are clipped to the box union's bounding box, so that the samples land near it.
  const BoxUnion* box_union = options.box_union.get();
  if (box_union != nullptr) {
    if (result.gt_kind == InputKind::kMesh) gt_tris = CropTriangles(gt_tris, box_union->bounds());
    if (result.pred_kind == InputKind::kMesh) {
      pred_tris = CropTriangles(pred_tris, box_union->bounds());
    }
  }

  // Steps 2–3. Different streams, so that a mesh against itself is not sampled identically. A
  // point cloud is taken as it is. Then the box union, if any.
  if (result.gt_kind == InputKind::kMesh) {
    gt_points =
        SampleTriangles(gt_tris, options.samples, options.seed, 1, threads, &result.gt_area_m2);
    if (gt_points.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat("GT mesh has no area",
                       box_union != nullptr ? " inside the box union's bounding box" : ""));
    }
  }
  if (box_union != nullptr) {
    gt_points = KeepInside(gt_points, *box_union, threads);
    if (gt_points.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat("GT has no ", result.gt_kind == InputKind::kMesh ? "samples" : "points",
                       " inside the box union (", box_union->size(), " boxes)"));
    }
  }
  if (result.pred_kind == InputKind::kMesh) {
    pred_points =
        SampleTriangles(pred_tris, options.samples, options.seed, 0, threads, &result.pred_area_m2);
    if (pred_points.empty()) {
      std::vector<std::string> where;
      if (options.crop_to_gt) where.push_back("the (padded) GT box");
      if (box_union != nullptr) where.push_back("the box union's bounding box");
      return absl::InvalidArgumentError(absl::StrCat(
          "prediction mesh has no area", where.empty() ? "" : " inside ",
          absl::StrJoin(where, " and "), ": ", pred.faces.size(), " triangles before cropping"));
    }
  } else if (pred_points.empty()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "prediction point cloud has no points inside the (padded) GT box: ", pred.vertices.size(),
        " points before cropping"));
  }
  // The prediction's area per sample: the mesh area drawn on over the samples drawn (before the
  // box union keeps its part of them).
  const double pred_area_per_sample =
      result.pred_kind == InputKind::kMesh
          ? result.pred_area_m2 / static_cast<double>(pred_points.size())
          : 0.0;
  if (box_union != nullptr) {
    pred_points = KeepInside(pred_points, *box_union, threads);
    if (pred_points.empty()) {
      return absl::InvalidArgumentError(absl::StrCat(
          "prediction has no ", result.pred_kind == InputKind::kMesh ? "samples" : "points",
          " inside the box union (", box_union->size(), " boxes)"));
    }
  }
  result.gt_samples = static_cast<int64_t>(gt_points.size());
  result.pred_samples = static_cast<int64_t>(pred_points.size());
  Point3f centre;
  for (int a = 0; a < 3; ++a) centre[a] = 0.5f * (gt_box[0][a] + gt_box[1][a]);
  RIM_ASSIGN_OR_RETURN(gt_points,
                       VoxelAverage(std::move(gt_points), options.voxel_m, centre, threads));
  std::vector<uint32_t> pred_counts;  // the samples each averaged prediction point stands for
  RIM_ASSIGN_OR_RETURN(pred_points, VoxelAverage(std::move(pred_points), options.voxel_m, centre,
                                                 threads, &pred_counts));
  result.gt_points = static_cast<int64_t>(gt_points.size());
  result.pred_points = static_cast<int64_t>(pred_points.size());

  // Step 4. Each tree takes a copy, because the query order (voxel-key order) is the fast one.
  // nanoflann builds a tree on one thread, so the two trees are built side by side.
  std::unique_ptr<NearestNeighbors> gt_index, pred_index;
  ParallelFor(2, 1, threads, [&](int64_t i, int64_t) {
    if (i == 0) {
      gt_index = std::make_unique<NearestNeighbors>(gt_points);
    } else {
      pred_index = std::make_unique<NearestNeighbors>(pred_points);
    }
  });
  std::vector<float> pred_to_gt = gt_index->NearestDistances(pred_points, threads);
  std::vector<float> gt_to_pred = pred_index->NearestDistances(gt_points, threads);

  // Steps 5–6.
  result.standard = ComputeMetrics(pred_to_gt, gt_to_pred, options, /*strict=*/false);
  result.strict = ComputeMetrics(pred_to_gt, gt_to_pred, options, /*strict=*/true);
  for (float d : pred_to_gt) result.pred_dropped += d >= options.drop_m;
  for (float d : gt_to_pred) result.gt_capped += d > options.cap_m;

  // Floaters. The samples are uniform by area, so a share of them is a share of the area. Each
  // sample counts at the distance of its voxel's mean, which lies within a voxel diagonal
  // (1.7 cm at 1 cm voxels) of the sample: only samples that close to the threshold can fall on
  // the other side of it. Querying every sample instead would add up to `samples` searches.
  int64_t floater_samples = 0;
  for (size_t i = 0; i < pred_to_gt.size(); ++i) {
    if (pred_to_gt[i] > options.floater_m) floater_samples += pred_counts[i];
  }
  result.floater_share =
      static_cast<double>(floater_samples) / static_cast<double>(result.pred_samples);
  result.floater_area_m2 = static_cast<double>(floater_samples) * pred_area_per_sample;
  if (options.present != nullptr) {
    // The surfaces present at the end, sampled as densely as the prediction was (a point cloud
    // as it is), and the floaters' distance to them.
    std::vector<Point3f> present_points;
    if (IsPointCloud(*options.present)) {
      RIM_ASSIGN_OR_RETURN(present_points, ToPoints(*options.present, "present"));
    } else {
      RIM_ASSIGN_OR_RETURN(std::vector<Triangle> tris, ToTriangles(*options.present, "present"));
      double area = 0;
      for (const Triangle& t : tris) area += TriangleArea(t);
      const double density = result.pred_kind == InputKind::kMesh && result.pred_area_m2 > 0
                                 ? static_cast<double>(options.samples) / result.pred_area_m2
                                 : 1e4;  // a sample a square centimetre
      const int64_t want = static_cast<int64_t>(std::ceil(std::max(density, 1e4) * area));
      double unused = 0;
      present_points = SampleTriangles(tris, want, options.seed, 2, threads, &unused);
    }
    std::vector<Point3f> floating;
    std::vector<uint32_t> floating_counts;
    for (size_t i = 0; i < pred_to_gt.size(); ++i) {
      if (pred_to_gt[i] <= options.floater_m) continue;
      floating.push_back(pred_points[i]);
      floating_counts.push_back(pred_counts[i]);
    }
    int64_t ghost_samples = 0;
    if (!present_points.empty()) {
      const NearestNeighbors present_index(std::move(present_points));
      const std::vector<float> to_present = present_index.NearestDistances(floating, threads);
      for (size_t k = 0; k < floating.size(); ++k)
        if (to_present[k] > options.floater_m) ghost_samples += floating_counts[k];
    } else {
      for (uint32_t c : floating_counts) ghost_samples += c;
    }
    result.has_present = true;
    result.ghost_share =
        static_cast<double>(ghost_samples) / static_cast<double>(result.pred_samples);
    result.ghost_area_m2 = static_cast<double>(ghost_samples) * pred_area_per_sample;
  }
  if (options.keep_outliers) {
    for (size_t i = 0; i < gt_to_pred.size(); ++i) {
      if (gt_to_pred[i] > options.fscore_m) {
        result.misses.push_back({gt_points[i][0], gt_points[i][1], gt_points[i][2], gt_to_pred[i]});
      }
    }
    for (size_t i = 0; i < pred_to_gt.size(); ++i) {
      if (pred_to_gt[i] > options.floater_m) {
        result.floaters.push_back(
            {pred_points[i][0], pred_points[i][1], pred_points[i][2], pred_to_gt[i]});
      }
    }
  }
  return result;
}

}  // namespace rim::eval
