#include "rim/eval/mesh_eval.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "rim/eval/box_union.h"
#include "rim/eval/nearest_neighbors.h"
#include "rim/io/mesh_io.h"

namespace rim::eval {
namespace {

// An axis-aligned rectangle split into n x n quads. `axis` is its normal (0 = x, 1 = y, 2 = z),
// `offset` its coordinate along the normal, [a0, a1] x [b0, b1] its extent in the other two.
Mesh Rectangle(int axis, float offset, float a0, float a1, float b0, float b1, int n = 8) {
  Mesh mesh;
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  for (int i = 0; i <= n; ++i) {
    for (int j = 0; j <= n; ++j) {
      std::array<float, 3> p;
      p[axis] = offset;
      p[u] = a0 + (a1 - a0) * i / n;
      p[v] = b0 + (b1 - b0) * j / n;
      mesh.vertices.push_back(p);
    }
  }
  for (uint32_t i = 0; i < static_cast<uint32_t>(n); ++i) {
    for (uint32_t j = 0; j < static_cast<uint32_t>(n); ++j) {
      const uint32_t k = i * (n + 1) + j;
      mesh.faces.push_back({k, k + static_cast<uint32_t>(n) + 1, k + 1});
      mesh.faces.push_back(
          {k + 1, k + static_cast<uint32_t>(n) + 1, k + static_cast<uint32_t>(n) + 2});
    }
  }
  return mesh;
}

Mesh PlaneZ(float z, float x0, float x1, float y0, float y1) {
  return Rectangle(2, z, x0, x1, y0, y1);
}

// The six faces of the cube [-h, h]^3.
Mesh CubeSurface(float h) {
  Mesh mesh;
  for (int axis = 0; axis < 3; ++axis) {
    for (float side : {-h, h}) AppendMesh(Rectangle(axis, side, -h, h, -h, h), &mesh);
  }
  return mesh;
}

Mesh Merged(const Mesh& a, const Mesh& b) {
  Mesh out = a;
  AppendMesh(b, &out);
  return out;
}

EvalOptions SmallOptions(int64_t samples = 200'000) {
  EvalOptions options;
  options.samples = samples;
  options.threads = 2;
  return options;
}

double Area(const Mesh& mesh) {
  double area = 0;
  for (const auto& f : mesh.faces) {
    const auto& a = mesh.vertices[f[0]];
    const auto& b = mesh.vertices[f[1]];
    const auto& c = mesh.vertices[f[2]];
    const double ux = b[0] - a[0], uy = b[1] - a[1], uz = b[2] - a[2];
    const double vx = c[0] - a[0], vy = c[1] - a[1], vz = c[2] - a[2];
    area += 0.5 * std::sqrt(std::pow(uy * vz - uz * vy, 2) + std::pow(uz * vx - ux * vz, 2) +
                            std::pow(ux * vy - uy * vx, 2));
  }
  return area;
}

TEST(NearestNeighborsTest, MatchesBruteForce) {
  std::mt19937 rng(7);
  std::normal_distribution<float> cluster(0.0f, 0.05f);
  std::uniform_real_distribution<float> centre(-2.0f, 2.0f);
  std::vector<Point3f> points;
  // Clusters with duplicates and ties, plus a flat sheet: the shapes that break split logic.
  for (int c = 0; c < 40; ++c) {
    const Point3f m = {centre(rng), centre(rng), centre(rng)};
    for (int i = 0; i < 200; ++i)
      points.push_back({m[0] + cluster(rng), m[1] + cluster(rng), m[2]});
    for (int i = 0; i < 20; ++i) points.push_back(m);
  }
  for (int i = 0; i < 3000; ++i) points.push_back({centre(rng), centre(rng), 0.5f});
  std::vector<Point3f> queries;
  for (int i = 0; i < 3000; ++i) queries.push_back({2 * centre(rng), 2 * centre(rng), centre(rng)});
  queries.insert(queries.end(), points.begin(), points.begin() + 500);

  for (int n : {1, 5, 8, 9, 100, static_cast<int>(points.size())}) {
    std::vector<Point3f> subset(points.begin(), points.begin() + n);
    const NearestNeighbors tree(subset);
    const std::vector<float> fast = tree.NearestDistances(queries, 2);
    for (size_t q = 0; q < queries.size(); ++q) {
      float best = INFINITY;
      for (const Point3f& p : subset) {
        const float dx = p[0] - queries[q][0], dy = p[1] - queries[q][1], dz = p[2] - queries[q][2];
        best = std::min(best, dx * dx + dy * dy + dz * dz);
      }
      ASSERT_EQ(fast[q], std::sqrt(best)) << "n=" << n << " query " << q;
    }
  }
  EXPECT_EQ(NearestNeighbors({}).NearestSquaredDistance({0, 0, 0}), INFINITY);
}

TEST(MeshEvalTest, MeshAgainstItselfIsNearZero) {
  const Mesh cube = CubeSurface(0.1f);  // 0.24 m^2: ~80 samples per 1 cm voxel
  const auto r = EvaluateMeshes(cube, cube, SmallOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_LT(r->standard.accuracy_m, 0.001);
  EXPECT_LT(r->standard.completeness_m, 0.001);
  EXPECT_LT(r->strict.chamfer_l1_m, 0.001);
  EXPECT_EQ(r->standard.fscore, 1.0);
  EXPECT_EQ(r->strict.fscore, 1.0);
  EXPECT_EQ(r->pred_dropped, 0);
  EXPECT_NEAR(r->gt_area_m2, 0.24, 1e-5);
  // About `samples` points before averaging, at most one per occupied voxel after.
  EXPECT_NEAR(r->pred_samples, 200'000, 2'000);
  EXPECT_LT(r->pred_points, 0.3 * 200'000);
}

TEST(MeshEvalTest, PlaneShiftedBy3cm) {
  const auto r = EvaluateMeshes(PlaneZ(0.03f, 0, 2, 0, 2), PlaneZ(0, 0, 2, 0, 2), SmallOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->standard.accuracy_m, 0.03, 0.002);
  EXPECT_NEAR(r->standard.completeness_m, 0.03, 0.002);
  EXPECT_NEAR(r->standard.chamfer_l1_m, 0.03, 0.002);
  EXPECT_EQ(r->standard.fscore, 1.0);
  EXPECT_EQ(r->strict.accuracy_m, r->standard.accuracy_m);  // nothing dropped or capped
  EXPECT_EQ(r->strict.completeness_m, r->standard.completeness_m);
}

TEST(MeshEvalTest, PlaneShiftedBy15cm) {
  const auto r = EvaluateMeshes(PlaneZ(0.15f, 0, 2, 0, 2), PlaneZ(0, 0, 2, 0, 2), SmallOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->standard.accuracy_m, 0.15, 0.002);  // below the 20 cm drop: kept
  EXPECT_NEAR(r->standard.completeness_m, 0.15, 0.002);
  EXPECT_EQ(r->standard.precision, 0.0);
  EXPECT_EQ(r->standard.recall, 0.0);
  EXPECT_EQ(r->standard.fscore, 0.0);
  EXPECT_EQ(r->pred_dropped, 0);
}

TEST(MeshEvalTest, PlaneShiftedBeyondTheDropHasNoStandardAccuracy) {
  // Every prediction point is dropped: accuracy is undefined (NaN), precision and F-score 0.
  EvalOptions options = SmallOptions();
  options.crop_margin_m = 1.0;
  const auto r = EvaluateMeshes(PlaneZ(0.5f, 0, 2, 0, 2), PlaneZ(0, 0, 2, 0, 2), options);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(std::isnan(r->standard.accuracy_m));
  EXPECT_EQ(r->standard.fscore, 0.0);
  EXPECT_NEAR(r->strict.accuracy_m, 0.5, 0.002);
  EXPECT_EQ(r->pred_dropped, r->pred_points);
}

TEST(MeshEvalTest, FarFloaterIsDroppedByStandardAndCountedByStrict) {
  const Mesh gt = CubeSurface(5.0f);  // 600 m^2
  // A 2 m x 2 m floater at the cube centre: 4 to 5 m from every face.
  const Mesh pred = Merged(gt, PlaneZ(0, -1, 1, -1, 1));
  const auto r = EvaluateMeshes(pred, gt, SmallOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  const double floater = static_cast<double>(r->pred_dropped) / r->pred_points;
  EXPECT_NEAR(floater, 4.0 / 604.0, 0.002);
  EXPECT_GT(r->standard.precision, 0.999);
  EXPECT_LT(r->standard.accuracy_m, 0.03);  // sampling spacing only (~330 points per m^2)
  // Strict: the floater points count at 4 to 5 m each.
  const double rest = (1 - floater) * r->standard.accuracy_m;
  EXPECT_GT(r->strict.accuracy_m, rest + 4.0 * floater);
  EXPECT_LT(r->strict.accuracy_m, rest + 5.0 * floater);
  EXPECT_NEAR(r->strict.precision, r->standard.precision * (1 - floater), 1e-9);
  EXPECT_LT(r->strict.fscore, r->standard.fscore);
  // The GT side does not see the floater.
  EXPECT_EQ(r->strict.completeness_m, r->standard.completeness_m);
  EXPECT_EQ(r->strict.recall, r->standard.recall);
}

TEST(MeshEvalTest, MissingHalfLowersRecallAndCapsCompleteness) {
  const Mesh gt = PlaneZ(0, 0, 10, 0, 1);
  const Mesh pred = PlaneZ(0, 0, 5, 0, 1);
  const auto r = EvaluateMeshes(pred, gt, SmallOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  // GT points with x < 5.1 are inliers.
  EXPECT_NEAR(r->standard.recall, 0.51, 0.01);
  EXPECT_EQ(r->standard.precision, 1.0);
  // A GT point at x > 5 is x - 5 away. Capped at 2 m: (∫0..2 t dt + 3 * 2) / 10 = 0.8 m.
  EXPECT_NEAR(r->standard.completeness_m, 0.8, 0.01);
  // Strict: ∫0..5 t dt / 10 = 1.25 m.
  EXPECT_NEAR(r->strict.completeness_m, 1.25, 0.01);
  EXPECT_NEAR(static_cast<double>(r->gt_capped) / r->gt_points, 0.3, 0.01);
  EXPECT_LT(r->standard.accuracy_m, 0.006);  // 2 to 4 samples per voxel: in-plane jitter
}

TEST(MeshEvalTest, PredictionOutsideTheGtBoxIsCropped) {
  const Mesh gt = PlaneZ(0, 0, 2, 0, 2);
  const Mesh pred = PlaneZ(0.03f, 0, 2, 0, 2);
  // 3 m above the GT box (padded by 20 cm), and 3 m beside it.
  const Mesh outside = Merged(PlaneZ(3.0f, 0, 2, 0, 2), PlaneZ(0, 5, 7, 0, 2));
  const auto plain = EvaluateMeshes(pred, gt, SmallOptions());
  const auto cropped = EvaluateMeshes(Merged(pred, outside), gt, SmallOptions());
  ASSERT_TRUE(plain.ok()) << plain.status();
  ASSERT_TRUE(cropped.ok()) << cropped.status();
  // The crop leaves exactly the triangles of `pred`, so the samples are identical.
  EXPECT_EQ(cropped->pred_samples, plain->pred_samples);
  EXPECT_EQ(cropped->strict.accuracy_m, plain->strict.accuracy_m);
  EXPECT_EQ(cropped->strict.fscore, plain->strict.fscore);
  EXPECT_NEAR(cropped->pred_area_m2, 4.0, 1e-4);

  EvalOptions no_crop = SmallOptions();
  no_crop.crop_to_gt = false;
  const auto uncropped = EvaluateMeshes(Merged(pred, outside), gt, no_crop);
  ASSERT_TRUE(uncropped.ok()) << uncropped.status();
  EXPECT_NEAR(uncropped->pred_area_m2, 12.0, 1e-4);
  EXPECT_GT(uncropped->strict.accuracy_m, 1.0);  // two thirds of the points are ~3 m off
  EXPECT_NEAR(uncropped->standard.accuracy_m, 0.03, 0.002);
}

TEST(MeshEvalTest, CropClipsTrianglesExactly) {
  Mesh tri;
  tri.vertices = {{0, 0, 0}, {2, 0, 0}, {0, 2, 0}};
  tri.faces = {{0, 1, 2}};
  // The box keeps the unit square of the triangle (area 2 in all).
  EXPECT_NEAR(Area(CropMeshToBox(tri, {0, 0, -1}, {1, 1, 1})), 1.0, 1e-6);
  // A box across the hypotenuse keeps the triangle x + y <= 2 of [0.5, 1.5]^2 (area 0.5).
  EXPECT_NEAR(Area(CropMeshToBox(tri, {0.5f, 0.5f, -1}, {1.5f, 1.5f, 1})), 0.5, 1e-6);
  EXPECT_TRUE(CropMeshToBox(tri, {3, 3, -1}, {4, 4, 1}).faces.empty());
  EXPECT_EQ(CropMeshToBox(tri, {-1, -1, -1}, {3, 3, 1}).faces.size(), 1u);
  // A cube cut in half by a box.
  EXPECT_NEAR(Area(CropMeshToBox(CubeSurface(1), {-2, -2, -2}, {0, 2, 2})), 12.0, 1e-4);
}

TEST(MeshEvalTest, ResultsDoNotDependOnThreads) {
  const Mesh gt = CubeSurface(1.0f);
  const Mesh pred = Merged(Rectangle(0, 1.02f, -1, 1, -1, 1), PlaneZ(0.3f, -0.5f, 0.5f, -1, 1));
  EvalOptions one = SmallOptions(50'000), three = SmallOptions(50'000);
  one.threads = 1;
  three.threads = 3;
  const auto a = EvaluateMeshes(pred, gt, one);
  const auto b = EvaluateMeshes(pred, gt, three);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->pred_points, b->pred_points);
  EXPECT_EQ(a->standard.accuracy_m, b->standard.accuracy_m);
  EXPECT_EQ(a->strict.completeness_m, b->strict.completeness_m);
  EXPECT_EQ(a->strict.fscore, b->strict.fscore);
  // Another seed gives other samples but about the same numbers.
  one.seed = 2;
  const auto c = EvaluateMeshes(pred, gt, one);
  ASSERT_TRUE(c.ok());
  EXPECT_NE(c->standard.accuracy_m, a->standard.accuracy_m);
  EXPECT_NEAR(c->standard.accuracy_m, a->standard.accuracy_m, 0.002);
}

TEST(MeshEvalTest, EmptyOrInvalidInputsAreErrors) {
  const Mesh gt = PlaneZ(0, 0, 2, 0, 2);
  const auto empty_pred = EvaluateMeshes(Mesh{}, gt, SmallOptions());
  EXPECT_EQ(empty_pred.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(empty_pred.status().message().find("prediction"), std::string::npos);
  // Nothing inside the GT box is the same as nothing at all.
  const auto outside = EvaluateMeshes(PlaneZ(5, 0, 2, 0, 2), gt, SmallOptions());
  EXPECT_EQ(outside.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(outside.status().message().find("GT box"), std::string::npos);
  EXPECT_EQ(EvaluateMeshes(gt, Mesh{}, SmallOptions()).status().code(),
            absl::StatusCode::kInvalidArgument);
  Mesh degenerate;
  degenerate.vertices = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}};
  degenerate.faces = {{0, 1, 2}};
  EXPECT_EQ(EvaluateMeshes(gt, degenerate, SmallOptions()).status().code(),
            absl::StatusCode::kInvalidArgument);
  Mesh bad_index = gt;
  bad_index.faces.push_back({0, 1, 100000});
  EXPECT_EQ(EvaluateMeshes(bad_index, gt, SmallOptions()).status().code(),
            absl::StatusCode::kInvalidArgument);
  Mesh nan_vertex = gt;
  nan_vertex.vertices[0][1] = NAN;
  EXPECT_EQ(EvaluateMeshes(gt, nan_vertex, SmallOptions()).status().code(),
            absl::StatusCode::kInvalidArgument);

  EvalOptions options = SmallOptions();
  options.voxel_m = -1;
  const auto bad_option = EvaluateMeshes(gt, gt, options);
  EXPECT_EQ(bad_option.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bad_option.status().message().find("voxel_m"), std::string::npos);
  options = SmallOptions();
  options.samples = 0;
  EXPECT_FALSE(ValidateEvalOptions(options).ok());
}

// --- Point clouds (a Mesh with vertices and no faces)
// ---------------------------------------------

// A point cloud on the plane z = `z` over [x0, x1] x [y0, y1]: a grid `spacing` apart, offset by
// half a spacing, so that with a spacing dividing 1 cm every 1 cm voxel averages to its centre.
Mesh GridCloudZ(float z, float x0, float x1, float y0, float y1, float spacing) {
  Mesh cloud;
  const int nx = static_cast<int>(std::lround((x1 - x0) / spacing));
  const int ny = static_cast<int>(std::lround((y1 - y0) / spacing));
  for (int i = 0; i < nx; ++i) {
    for (int j = 0; j < ny; ++j) {
      cloud.vertices.push_back({x0 + (i + 0.5f) * spacing, y0 + (j + 0.5f) * spacing, z});
    }
  }
  return cloud;
}

TEST(MeshEvalPointsTest, DensePointGtOfAPlaneAgainstThePlaneIsNearZero) {
  const Mesh gt_cloud = GridCloudZ(0, 0, 1, 0, 1, 0.0025f);  // 16 points per 1 cm voxel
  const Mesh plane = PlaneZ(0, 0, 1, 0, 1);
  // Dense prediction samples (~100 per voxel) also average to near the voxel centres.
  const auto r = EvaluateMeshes(plane, gt_cloud, SmallOptions(1'000'000));
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->gt_kind, InputKind::kPoints);
  EXPECT_EQ(r->pred_kind, InputKind::kMesh);
  EXPECT_STREQ(InputKindName(r->gt_kind), "points");
  EXPECT_EQ(r->gt_area_m2, 0.0);
  EXPECT_EQ(r->gt_samples, 400 * 400);  // the points as given, no sampling
  EXPECT_EQ(r->gt_points, 100 * 100);   // then one per voxel
  EXPECT_LT(r->standard.accuracy_m, 0.001);
  EXPECT_LT(r->standard.completeness_m, 0.001);
  EXPECT_EQ(r->standard.fscore, 1.0);
  EXPECT_EQ(r->pred_dropped, 0);
  // The same as the mesh GT it was taken from, to within the averaging jitter.
  const auto mesh_gt = EvaluateMeshes(plane, plane, SmallOptions(1'000'000));
  ASSERT_TRUE(mesh_gt.ok()) << mesh_gt.status();
  EXPECT_EQ(mesh_gt->gt_kind, InputKind::kMesh);
  EXPECT_NEAR(r->standard.chamfer_l1_m, mesh_gt->standard.chamfer_l1_m, 0.001);
  // The samples option does not touch a point GT.
  const auto fewer = EvaluateMeshes(plane, gt_cloud, SmallOptions(500'000));
  ASSERT_TRUE(fewer.ok());
  EXPECT_EQ(fewer->gt_samples, r->gt_samples);
}

TEST(MeshEvalPointsTest, PlaneShiftedBy3cmAgainstAPointGt) {
  const Mesh gt_cloud = GridCloudZ(0, 0, 2, 0, 2, 0.005f);
  const auto r = EvaluateMeshes(PlaneZ(0.03f, 0, 2, 0, 2), gt_cloud, SmallOptions(1'000'000));
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->gt_kind, InputKind::kPoints);
  EXPECT_NEAR(r->standard.accuracy_m, 0.03, 0.002);
  EXPECT_NEAR(r->standard.completeness_m, 0.03, 0.002);
  EXPECT_NEAR(r->standard.chamfer_l1_m, 0.03, 0.002);
  EXPECT_EQ(r->standard.fscore, 1.0);
  EXPECT_EQ(r->strict.accuracy_m, r->standard.accuracy_m);
  // Beyond the F-score threshold: 15 cm gives no inliers.
  const auto far = EvaluateMeshes(PlaneZ(0.15f, 0, 2, 0, 2), gt_cloud, SmallOptions());
  ASSERT_TRUE(far.ok()) << far.status();
  EXPECT_NEAR(far->standard.completeness_m, 0.15, 0.002);
  EXPECT_EQ(far->standard.fscore, 0.0);
}

TEST(MeshEvalPointsTest, RegionCropKeepsThePointsInside) {
  const Mesh gt_cloud = GridCloudZ(0, 0, 2, 0, 2, 0.005f);  // 400 x 400 points
  const std::array<float, 3> lower = {0, 0, -1}, upper = {1, 2, 1};
  const Mesh cropped = CropMeshToBox(gt_cloud, lower, upper);
  EXPECT_TRUE(cropped.faces.empty());
  ASSERT_EQ(cropped.vertices.size(), 200u * 400u);
  for (const auto& p : cropped.vertices) ASSERT_LE(p[0], 1.0f);
  // A point exactly on the box is kept; a region above the plane keeps nothing.
  Mesh edge;
  edge.vertices = {{1, 1, 0}, {1.0001f, 1, 0}};
  EXPECT_EQ(CropMeshToBox(edge, lower, upper).vertices.size(), 1u);
  EXPECT_TRUE(CropMeshToBox(gt_cloud, {0, 0, 0.5f}, {2, 2, 1}).vertices.empty());

  // The prediction covers only x < 1: the full GT finds half of it missing, the region does not.
  const Mesh pred = PlaneZ(0, 0, 1, 0, 2);
  const auto full = EvaluateMeshes(pred, gt_cloud, SmallOptions(1'000'000));
  ASSERT_TRUE(full.ok()) << full.status();
  EXPECT_NEAR(full->standard.recall, 0.55, 0.01);  // GT points with x < 1.1 are inliers
  const auto region =
      EvaluateMeshes(CropMeshToBox(pred, lower, upper), cropped, SmallOptions(1'000'000));
  ASSERT_TRUE(region.ok()) << region.status();
  EXPECT_EQ(region->gt_kind, InputKind::kPoints);
  EXPECT_EQ(region->gt_samples, 200 * 400);
  EXPECT_EQ(region->standard.recall, 1.0);
  EXPECT_EQ(region->standard.fscore, 1.0);
  EXPECT_LT(region->standard.completeness_m, 0.005);
}

TEST(MeshEvalPointsTest, PointCloudPredictionIsCroppedAndUsedAsGiven) {
  const Mesh gt = PlaneZ(0, 0, 2, 0, 2);
  Mesh pred = GridCloudZ(0.03f, 0, 2, 0, 2, 0.005f);
  const size_t inside = pred.vertices.size();
  pred.vertices.push_back({1, 1, 3});  // 3 m above the GT box: cropped away
  const auto r = EvaluateMeshes(pred, gt, SmallOptions(1'000'000));
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->pred_kind, InputKind::kPoints);
  EXPECT_EQ(r->gt_kind, InputKind::kMesh);
  EXPECT_EQ(r->pred_samples, static_cast<int64_t>(inside));
  EXPECT_EQ(r->pred_area_m2, 0.0);
  EXPECT_NEAR(r->strict.accuracy_m, 0.03, 0.002);
  EXPECT_NEAR(r->standard.completeness_m, 0.03, 0.002);
  // Points against points.
  const auto both = EvaluateMeshes(pred, GridCloudZ(0, 0, 2, 0, 2, 0.005f), SmallOptions());
  ASSERT_TRUE(both.ok()) << both.status();
  EXPECT_NEAR(both->standard.chamfer_l1_m, 0.03, 0.001);
}

TEST(MeshEvalPointsTest, BadPointCloudsAreErrors) {
  const Mesh gt = GridCloudZ(0, 0, 1, 0, 1, 0.01f);
  Mesh nan_point = gt;
  nan_point.vertices[5][2] = NAN;
  const auto bad_gt = EvaluateMeshes(PlaneZ(0, 0, 1, 0, 1), nan_point, SmallOptions());
  EXPECT_EQ(bad_gt.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bad_gt.status().message().find("GT point cloud: point 5"), std::string::npos)
      << bad_gt.status();
  EXPECT_EQ(EvaluateMeshes(nan_point, gt, SmallOptions()).status().code(),
            absl::StatusCode::kInvalidArgument);
  // A point prediction with nothing inside the padded GT box.
  const auto outside = EvaluateMeshes(GridCloudZ(5, 0, 1, 0, 1, 0.01f), gt, SmallOptions());
  EXPECT_EQ(outside.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(outside.status().message().find("GT box"), std::string::npos) << outside.status();
}

// --- Box unions ----------------------------------------------------------------------------------

bool InUnionBruteForce(const Point3f& p, const std::vector<Eigen::Vector3d>& centres, double hx,
                       double hy, double z_min, double z_max) {
  const double x = p[0], y = p[1], z = p[2];
  for (const Eigen::Vector3d& c : centres) {
    if (std::abs(x - c.x()) < hx && std::abs(y - c.y()) < hy && z >= c.z() + z_min &&
        z < c.z() + z_max) {
      return true;
    }
  }
  return false;
}

TEST(BoxUnionTest, MatchesBruteForce) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> step(-1.0, 1.0), unit(0.0, 1.0);
  for (const auto& [hx, hy] : {std::pair{10.0, 10.0}, {0.7, 3.0}, {25.0, 0.4}}) {
    // A drive: a random walk with some height change, and repeated positions.
    std::vector<Eigen::Vector3d> centres = {{100, -40, 1.7}};
    for (int i = 1; i < 300; ++i) {
      centres.push_back(centres.back() +
                        Eigen::Vector3d(2 * step(rng), 2 * step(rng), 0.1 * step(rng)));
      if (i % 50 == 0) centres.push_back(centres.back());
    }
    const double z_min = -3, z_max = 3;
    const auto u = BoxUnion::Create(hx, hy, z_min, z_max, centres);
    ASSERT_TRUE(u.ok()) << u.status();
    EXPECT_EQ(u->size(), centres.size());
    const auto& b = u->bounds();
    std::vector<Point3f> points;
    for (int i = 0; i < 100000; ++i) {  // over the bounds and beyond
      Point3f p;
      for (int a = 0; a < 3; ++a) {
        const double span = b[1][a] - b[0][a];
        p[a] = static_cast<float>(b[0][a] - 0.2 * span + 1.4 * span * unit(rng));
      }
      points.push_back(p);
    }
    for (int i = 0; i < 20000; ++i) {  // on and about the boxes' faces
      const Eigen::Vector3d& c = centres[rng() % centres.size()];
      const double face[3] = {c.x() + (rng() % 2 ? hx : -hx), c.y() + (rng() % 2 ? hy : -hy),
                              c.z() + (rng() % 2 ? z_max : z_min)};
      Point3f p = {static_cast<float>(c.x() + hx * step(rng)),
                   static_cast<float>(c.y() + hy * step(rng)),
                   static_cast<float>(c.z() + z_min + (z_max - z_min) * unit(rng))};
      const int a = static_cast<int>(rng() % 3);
      p[a] = std::nextafter(static_cast<float>(face[a]), rng() % 2 ? INFINITY : -INFINITY);
      if (rng() % 3 == 0) p[a] = static_cast<float>(face[a]);
      points.push_back(p);
    }
    int inside = 0;
    for (const Point3f& p : points) {
      const bool want = InUnionBruteForce(p, centres, hx, hy, z_min, z_max);
      ASSERT_EQ(u->Contains(p), want)
          << "hx " << hx << " point " << p[0] << " " << p[1] << " " << p[2];
      inside += want;
      if (want) {
        for (int a = 0; a < 3; ++a) ASSERT_TRUE(p[a] >= b[0][a] && p[a] <= b[1][a]);
      }
    }
    EXPECT_GT(inside, 10000) << "hx " << hx;
    EXPECT_LT(inside, static_cast<int>(points.size()) - 10000) << "hx " << hx;
  }
  EXPECT_FALSE(BoxUnion::Create(1, 1, 0, 1, {{0, 0, 0}})->Contains({NAN, 0, 0.5f}));
}

TEST(BoxUnionTest, BadArgumentsNameTheProblem) {
  const std::vector<Eigen::Vector3d> one = {{0, 0, 0}};
  auto message = [](const absl::StatusOr<BoxUnion>& u) {
    EXPECT_EQ(u.status().code(), absl::StatusCode::kInvalidArgument);
    return std::string(u.status().message());
  };
  EXPECT_NE(message(BoxUnion::Create(0, 1, -1, 1, one)).find("hx must be > 0"), std::string::npos);
  EXPECT_NE(message(BoxUnion::Create(1, NAN, -1, 1, one)).find("hy must be > 0"),
            std::string::npos);
  EXPECT_NE(message(BoxUnion::Create(1, 1, 1, 1, one)).find("z_min must be < z_max"),
            std::string::npos);
  EXPECT_NE(message(BoxUnion::Create(1, 1, -1, 1, {})).find("no centres"), std::string::npos);
  EXPECT_NE(message(BoxUnion::Create(1, 1, -1, 1, {{0, 0, 0}, {0, INFINITY, 0}}))
                .find("centre 1 is not finite"),
            std::string::npos);
  EXPECT_NE(message(BoxUnion::Create(1e-9, 1, -1, 1, {{0, 0, 0}, {1e3, 0, 0}})).find("2^31"),
            std::string::npos);
}

TEST(MeshEvalBoxUnionTest, CropEqualsEvaluatingPreCroppedClouds) {
  const Mesh gt = GridCloudZ(0, 0, 4, 0, 4, 0.005f);
  Mesh pred = GridCloudZ(0.03f, 0, 4, 0, 4, 0.02f);
  pred.vertices.push_back({3, 3, 1.5f});        // a floater inside the third box, which holds no GT
  pred.vertices.push_back({0.5f, 0.5f, 1.5f});  // one above the first box
  const std::vector<Eigen::Vector3d> centres = {{1, 1, 0}, {1.8, 1.3, 0}, {3, 3, 1}};
  auto u = BoxUnion::Create(0.6, 0.4, -0.5, 0.7, centres);
  ASSERT_TRUE(u.ok()) << u.status();
  auto crop = [&](const Mesh& cloud) {
    Mesh out;
    for (const Point3f& p : cloud.vertices) {
      if (InUnionBruteForce(p, centres, 0.6, 0.4, -0.5, 0.7)) out.vertices.push_back(p);
    }
    return out;
  };
  // Without the crop to the GT box, so that the floater stays.
  EvalOptions options = SmallOptions();
  options.crop_to_gt = false;
  EvalOptions with_union = options;
  with_union.box_union = std::make_shared<const BoxUnion>(*std::move(u));
  const auto cropped = EvaluateMeshes(pred, gt, with_union);
  ASSERT_TRUE(cropped.ok()) << cropped.status();
  const auto pre_cropped = EvaluateMeshes(crop(pred), crop(gt), options);
  ASSERT_TRUE(pre_cropped.ok()) << pre_cropped.status();
  EXPECT_EQ(cropped->gt_samples, pre_cropped->gt_samples);
  EXPECT_EQ(cropped->pred_samples, pre_cropped->pred_samples);
  EXPECT_EQ(cropped->gt_points, pre_cropped->gt_points);
  EXPECT_EQ(cropped->pred_points, pre_cropped->pred_points);
  EXPECT_EQ(cropped->pred_dropped, 1);  // the floater in the third box
  for (const auto& [a, b] : {std::pair{cropped->standard, pre_cropped->standard},
                             {cropped->strict, pre_cropped->strict}}) {
    EXPECT_DOUBLE_EQ(a.accuracy_m, b.accuracy_m);
    EXPECT_DOUBLE_EQ(a.completeness_m, b.completeness_m);
    EXPECT_DOUBLE_EQ(a.precision, b.precision);
    EXPECT_DOUBLE_EQ(a.recall, b.recall);
  }
  EXPECT_NEAR(cropped->standard.accuracy_m, 0.03, 0.002);
  EXPECT_GT(cropped->strict.accuracy_m, cropped->standard.accuracy_m);
}

TEST(MeshEvalBoxUnionTest, MeshesAreSampledInsideTheUnion) {
  // The prediction covers [0, 4]^2, the GT only x < 2: half the prediction is a false positive.
  const Mesh pred = PlaneZ(0.03f, 0, 4, 0, 4);
  const Mesh gt = PlaneZ(0, 0, 2, 0, 4);
  EvalOptions uncropped = SmallOptions();
  uncropped.crop_to_gt = false;
  const auto full = EvaluateMeshes(pred, gt, uncropped);
  ASSERT_TRUE(full.ok()) << full.status();
  EXPECT_LT(full->strict.precision, 0.6);
  // Boxes along x = 0.5 cover [0, 1] x [0, 4]: inside them both are complete and 3 cm apart.
  auto u = BoxUnion::Create(0.5, 1.0, -0.5, 0.5, {{0.5, 1, 0}, {0.5, 3, 0}});
  ASSERT_TRUE(u.ok()) << u.status();
  EvalOptions options = SmallOptions();
  options.box_union = std::make_shared<const BoxUnion>(*std::move(u));
  const auto r = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->pred_area_m2, 4.0, 0.02);  // clipped to the union's bounds first
  EXPECT_NEAR(r->gt_area_m2, 4.0, 0.02);
  EXPECT_GT(r->pred_samples, 0.99 * 200'000);  // nearly every sample is inside the union
  EXPECT_NEAR(r->strict.accuracy_m, 0.03, 0.002);
  EXPECT_NEAR(r->strict.completeness_m, 0.03, 0.002);
  EXPECT_EQ(r->strict.fscore, 1.0);

  // A union away from the GT leaves nothing to score.
  auto away = BoxUnion::Create(0.5, 0.5, -0.5, 0.5, {{3, 3, 0}});
  ASSERT_TRUE(away.ok());
  options.box_union = std::make_shared<const BoxUnion>(*std::move(away));
  auto none = EvaluateMeshes(pred, gt, options);
  EXPECT_EQ(none.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(none.status().message().find("GT mesh has no area inside the box union"),
            std::string::npos)
      << none.status();
  none = EvaluateMeshes(pred, GridCloudZ(0, 0, 2, 0, 4, 0.01f), options);
  EXPECT_NE(none.status().message().find("GT has no points inside the box union (1 boxes)"),
            std::string::npos)
      << none.status();
}

// --- Floaters ------------------------------------------------------------------------------------

// The square [1, 2] x [1, 2] at height z: 1 m^2.
Mesh PatchZ(float z) { return PlaneZ(z, 1, 2, 1, 2); }

TEST(MeshEvalFloaterTest, PatchAboveAPlaneIsItsAreaShare) {
  const Mesh gt = PlaneZ(0, 0, 4, 0, 4);  // 16 m^2
  EvalOptions options = SmallOptions();
  options.crop_margin_m = 1.0;  // keeps the patch inside the padded box of the flat GT
  const auto r = EvaluateMeshes(Merged(gt, PatchZ(0.5f)), gt, options);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->pred_area_m2, 17.0, 1e-4);
  EXPECT_NEAR(r->floater_share, 1.0 / 17.0, 0.02 / 17.0);
  EXPECT_NEAR(r->floater_area_m2, 1.0, 0.02);
  // Without a box union every drawn sample is kept: the area is the share of pred_area_m2.
  EXPECT_NEAR(r->floater_area_m2, r->floater_share * r->pred_area_m2, 1e-9);
}

TEST(MeshEvalFloaterTest, ShareIsOfAreaNotOfAveragedPoints) {
  // A patch at 45 degrees crosses more voxels per square metre than the ground does, so the
  // averaged points over-count it: the share must weigh each by the samples it stands for.
  const Mesh gt = PlaneZ(0, 0, 4, 0, 4);
  // From z = 0.525 to 1.525 over [1, 2] x [1, 2]: sqrt(2) m^2, crossing two voxels per column
  // (half a voxel off the voxel corners, where it would cross one).
  Mesh tilted;
  tilted.vertices = {{1, 1, 0.525f}, {2, 1, 0.525f}, {2, 2, 1.525f}, {1, 2, 1.525f}};
  tilted.faces = {{0, 1, 2}, {0, 2, 3}};
  EvalOptions options = SmallOptions();
  options.crop_margin_m = 2.0;
  options.voxel_m = 0.05;  // ~20 samples per voxel on the patch
  const auto r = EvaluateMeshes(Merged(gt, tilted), gt, options);
  ASSERT_TRUE(r.ok()) << r.status();
  const double want = std::sqrt(2.0) / (16 + std::sqrt(2.0));
  EXPECT_NEAR(r->floater_share, want, 0.02 * want);
  EXPECT_NEAR(r->floater_area_m2, std::sqrt(2.0), 0.02 * std::sqrt(2.0));
  // The plain count of averaged points beyond 20 cm (all of the patch) is well off.
  const double point_share = static_cast<double>(r->pred_dropped) / r->pred_points;
  EXPECT_GT(point_share, 1.2 * want);
}

TEST(MeshEvalFloaterTest, NoFloatersWhenThePredictionIsTheGt) {
  const Mesh gt = Merged(PlaneZ(0, 0, 4, 0, 4), Rectangle(0, 4, 0, 4, 0, 2));  // ground and wall
  const auto r = EvaluateMeshes(gt, gt, SmallOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->floater_share, 0.0);
  EXPECT_EQ(r->floater_area_m2, 0.0);
}

TEST(MeshEvalFloaterTest, ThresholdDecides) {
  const Mesh gt = PlaneZ(0, 0, 4, 0, 4);
  const Mesh pred = Merged(gt, PatchZ(0.1f));
  // 10 cm above: not a floater at 20 cm.
  const auto near = EvaluateMeshes(pred, gt, SmallOptions());
  ASSERT_TRUE(near.ok()) << near.status();
  EXPECT_EQ(near->floater_share, 0.0);
  EXPECT_EQ(near->floater_area_m2, 0.0);
  // At 5 cm it is.
  EvalOptions options = SmallOptions();
  options.floater_m = 0.05;
  const auto strict = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(strict.ok()) << strict.status();
  EXPECT_NEAR(strict->floater_share, 1.0 / 17.0, 0.02 / 17.0);
  EXPECT_NEAR(strict->floater_area_m2, 1.0, 0.02);
}

TEST(MeshEvalFloaterTest, CroppedAsTheOtherMetrics) {
  const Mesh gt = PlaneZ(0, 0, 4, 0, 4);
  const Mesh pred = Merged(gt, PatchZ(0.5f));
  // The default crop pads the flat GT's box by 20 cm: the patch 50 cm up is outside it.
  const auto cropped = EvaluateMeshes(pred, gt, SmallOptions());
  ASSERT_TRUE(cropped.ok()) << cropped.status();
  EXPECT_NEAR(cropped->pred_area_m2, 16.0, 1e-4);
  EXPECT_EQ(cropped->floater_share, 0.0);

  // Boxes over [0, 2]^2 and [2, 4]^2: 8 m^2 of the ground and the whole patch. The samples are
  // drawn over the union's bounds (17 m^2) and those outside the boxes left out.
  auto u = BoxUnion::Create(1, 1, -1, 1, {{1, 1, 0}, {3, 3, 0}});
  ASSERT_TRUE(u.ok()) << u.status();
  EvalOptions options = SmallOptions();
  options.crop_margin_m = 1.0;
  options.box_union = std::make_shared<const BoxUnion>(*std::move(u));
  const auto r = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->pred_area_m2, 17.0, 1e-4);
  EXPECT_NEAR(r->pred_samples, 200'000 * 9.0 / 17.0, 2'000);
  EXPECT_NEAR(r->floater_share, 1.0 / 9.0, 0.02 / 9.0);
  EXPECT_NEAR(r->floater_area_m2, 1.0, 0.02);
  // A union beside the patch leaves it out.
  auto beside = BoxUnion::Create(1, 1, -1, 1, {{3, 3, 0}});
  ASSERT_TRUE(beside.ok()) << beside.status();
  options.box_union = std::make_shared<const BoxUnion>(*std::move(beside));
  const auto none = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_EQ(none->floater_share, 0.0);
}

TEST(MeshEvalFloaterTest, PointCloudPredictionCountsItsPoints) {
  // 4 points per 1 cm voxel on both parts: 160000 on the ground, 40000 on the patch.
  Mesh pred = GridCloudZ(0.03f, 0, 2, 0, 2, 0.005f);
  AppendMesh(GridCloudZ(0.5f, 0.5f, 1.5f, 0.5f, 1.5f, 0.005f), &pred);
  EvalOptions options = SmallOptions();
  options.crop_margin_m = 1.0;
  const auto r = EvaluateMeshes(pred, PlaneZ(0, 0, 2, 0, 2), options);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->pred_kind, InputKind::kPoints);
  EXPECT_EQ(r->pred_samples, 200'000);
  EXPECT_DOUBLE_EQ(r->floater_share, 0.2);
  EXPECT_EQ(r->floater_area_m2, 0.0);  // a point cloud has no area
}

// Surfaces present at the end (a person standing in the last scans) are floaters but no ghosts.
TEST(MeshEvalFloaterTest, WhatIsPresentAtTheEndIsNoGhost) {
  const Mesh gt = PlaneZ(0, 0, 4, 0, 4);  // 16 m^2
  // Two 1 m^2 patches 50 cm up; the first stands where something was at the end.
  const Mesh pred = Merged(Merged(gt, PatchZ(0.5f)), PlaneZ(0.5f, 3, 4, 3, 4));
  EvalOptions options = SmallOptions();
  options.crop_margin_m = 1.0;
  const auto plain = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(plain.ok()) << plain.status();
  EXPECT_FALSE(plain->has_present);
  // Present 10 cm above the first patch: within the floater distance of it, so it is no ghost.
  options.present = std::make_shared<const Mesh>(PlaneZ(0.6f, 1, 2, 1, 2));
  const auto r = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->has_present);
  EXPECT_NEAR(r->floater_share, 2.0 / 18.0, 0.04 / 18.0);
  EXPECT_NEAR(r->floater_area_m2, 2.0, 0.04);
  EXPECT_NEAR(r->ghost_share, 1.0 / 18.0, 0.02 / 18.0);
  EXPECT_NEAR(r->ghost_area_m2, 1.0, 0.02);
  // Nothing else moves: the standard and strict measures are the plain run's.
  EXPECT_EQ(r->floater_share, plain->floater_share);
  EXPECT_EQ(r->strict.accuracy_m, plain->strict.accuracy_m);
  EXPECT_EQ(r->standard.chamfer_l1_m, plain->standard.chamfer_l1_m);
  // Present 30 cm away: beyond the floater distance, every floater is a ghost.
  options.present = std::make_shared<const Mesh>(PlaneZ(0.8f, 1, 2, 1, 2));
  const auto far = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(far.ok()) << far.status();
  EXPECT_EQ(far->ghost_share, far->floater_share);
  // As a point cloud (its points as they are), over both patches: no ghost at all.
  Mesh cloud = GridCloudZ(0.5f, 1, 2, 1, 2, 0.01f);
  AppendMesh(GridCloudZ(0.5f, 3, 4, 3, 4, 0.01f), &cloud);
  options.present = std::make_shared<const Mesh>(cloud);
  const auto points = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(points.ok()) << points.status();
  EXPECT_EQ(points->ghost_share, 0.0);
  // A bad one is named.
  Mesh bad = PlaneZ(0.5f, 1, 2, 1, 2);
  bad.vertices[0][0] = NAN;
  options.present = std::make_shared<const Mesh>(bad);
  const auto error = EvaluateMeshes(pred, gt, options);
  EXPECT_EQ(error.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(error.status().message().find("present"), std::string::npos) << error.status();
}

TEST(MeshEvalFloaterTest, BadThresholdIsNamed) {
  const Mesh gt = PlaneZ(0, 0, 2, 0, 2);
  for (double bad : {-0.2, 0.0, static_cast<double>(NAN), static_cast<double>(INFINITY)}) {
    EvalOptions options = SmallOptions();
    options.floater_m = bad;
    const absl::Status s = ValidateEvalOptions(options);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(s.message().find("EvalOptions.floater_m must be > 0"), std::string::npos) << s;
    const auto r = EvaluateMeshes(gt, gt, options);
    EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(r.status().message().find("floater_m"), std::string::npos) << r.status();
  }
  EvalOptions options = SmallOptions();
  options.floater_m = 0.01;
  EXPECT_TRUE(ValidateEvalOptions(options).ok());
}

// --- The rim_eval command line -------------------------------------------------------------------

// rim_eval's --json output parsed by nlohmann (keys in their order), or a discarded value when it
// is not one valid JSON document.
nlohmann::ordered_json ParseOut(const std::string& out) {
  return nlohmann::ordered_json::parse(out, nullptr, /*allow_exceptions=*/false);
}

// The keys of an object, in their order.
std::vector<std::string> Keys(const nlohmann::ordered_json& object) {
  std::vector<std::string> keys;
  for (auto it = object.begin(); it != object.end(); ++it) keys.push_back(it.key());
  return keys;
}

// The rim_eval binary sits in clients/ of the same build tree (RIM_EVAL_BIN overrides).
std::string RimEvalPath() {
  if (const char* env = std::getenv("RIM_EVAL_BIN")) return env;
  char self[4096];
  const ssize_t n = readlink("/proc/self/exe", self, sizeof(self) - 1);
  if (n <= 0) return "";
  std::string dir(self, n);
  dir = dir.substr(0, dir.rfind('/'));
  return dir + "/../clients/rim_eval";
}

struct RunResult {
  int exit_code = -1;
  std::string out;  // stdout and stderr
};

RunResult RunRimEval(const std::string& args) {
  RunResult r;
  FILE* pipe = popen((RimEvalPath() + " " + args + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return r;
  char buf[4096];
  for (size_t n; (n = fread(buf, 1, sizeof(buf), pipe)) > 0;) r.out.append(buf, n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

class RimEvalCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (access(RimEvalPath().c_str(), X_OK) != 0) {
      GTEST_SKIP() << "rim_eval not built at " << RimEvalPath() << " (build target rim_eval)";
    }
    pred_ = ::testing::TempDir() + "/rim_mesh_eval_pred.ply";
    gt_ = ::testing::TempDir() + "/rim_mesh_eval_gt.ply";
    ASSERT_TRUE(WriteMeshPly(pred_, PlaneZ(0.03f, 0, 2, 0, 2)).ok());
    ASSERT_TRUE(WriteMeshPly(gt_, PlaneZ(0, 0, 2, 0, 2)).ok());
  }
  std::string pred_, gt_;
};

TEST_F(RimEvalCliTest, PrintsTable) {
  const RunResult r = RunRimEval(pred_ + " " + gt_ + " --samples 20000");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  for (const char* want : {"Acc [cm]", "Comp [cm]", "C-L1 [cm]", "F [%]", "standard", "strict"}) {
    EXPECT_NE(r.out.find(want), std::string::npos) << want << " missing from:\n" << r.out;
  }
}

TEST_F(RimEvalCliTest, PrintsJson) {
  const RunResult r = RunRimEval(pred_ + " " + gt_ + " --json --samples=20000 --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const nlohmann::ordered_json j = ParseOut(r.out);
  ASSERT_TRUE(j.is_object()) << r.out;
  EXPECT_EQ(Keys(j),
            (std::vector<std::string>{"prediction", "ground_truth", "pred_kind", "gt_kind",
                                      "standard", "strict", "points", "area_m2", "protocol", "box",
                                      "seconds", "floater_share", "floater_area_m2"}))
      << r.out;
  for (const char* side : {"standard", "strict"}) {
    EXPECT_EQ(Keys(j[side]),
              (std::vector<std::string>{"accuracy_cm", "completeness_cm", "chamfer_l1_cm",
                                        "precision_pct", "recall_pct", "fscore_pct"}))
        << r.out;
  }
  EXPECT_EQ(j["prediction"], pred_);
  EXPECT_EQ(j["standard"]["fscore_pct"], 100.0) << r.out;
  // 3 cm off (a little more after voxel averaging), rounded as before to 4 decimals of a cm.
  const double accuracy = j["standard"]["accuracy_cm"];
  EXPECT_NEAR(accuracy, 3.0, 0.25) << r.out;
  EXPECT_EQ(accuracy, std::round(accuracy * 1e4) / 1e4) << r.out;
  // Each top-level key on its own line, the objects within on one.
  EXPECT_NE(r.out.find("\n  \"area_m2\": {\"pred\": "), std::string::npos) << r.out;
}

TEST_F(RimEvalCliTest, WritesMissesAndFloaters) {
  // The prediction covers x < 1 of the GT's [0, 2]^2, plus a patch 50 cm up (kept: --no-crop).
  const std::string pred = ::testing::TempDir() + "/rim_mesh_eval_half.ply";
  ASSERT_TRUE(
      WriteMeshPly(pred, Merged(PlaneZ(0, 0, 1, 0, 2), PlaneZ(0.5f, 0.2f, 0.6f, 0.2f, 0.6f))).ok());
  const std::string misses = ::testing::TempDir() + "/rim_mesh_eval_misses.csv";
  const std::string floaters = ::testing::TempDir() + "/rim_mesh_eval_floaters.csv";
  const RunResult r = RunRimEval(pred + " " + gt_ + " --samples 40000 --no-crop --misses " +
                                 misses + " --floaters=" + floaters);
  ASSERT_EQ(r.exit_code, 0) << r.out;
  for (const auto& [path, lo, hi, z] :
       {std::tuple{misses, 1.09, 2.0, 0.0}, std::tuple{floaters, 0.2, 0.6, 0.5}}) {
    std::ifstream in(path);
    std::string line;
    ASSERT_TRUE(std::getline(in, line)) << path;
    EXPECT_EQ(line, "x,y,z,distance_m");
    int rows = 0;
    while (std::getline(in, line)) {
      double x, y, zz, d;
      ASSERT_EQ(std::sscanf(line.c_str(), "%lf,%lf,%lf,%lf", &x, &y, &zz, &d), 4) << line;
      EXPECT_TRUE(x >= lo && x <= hi) << path << ": " << line;
      EXPECT_NEAR(zz, z, 0.01) << line;
      ++rows;
    }
    EXPECT_GT(rows, 100) << path;
  }
  const RunResult bad = RunRimEval(pred + " " + gt_ + " --misses /nonexistent/dir/m.csv");
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.out.find("cannot write /nonexistent/dir/m.csv"), std::string::npos) << bad.out;
}

// The number after `key` in `out`, NaN when `key` is missing.
double NumberAfter(const std::string& out, const std::string& key) {
  const size_t at = out.find(key);
  return at == std::string::npos ? NAN : std::strtod(out.c_str() + at + key.size(), nullptr);
}

TEST_F(RimEvalCliTest, ReportsFloaters) {
  // The 3 cm shifted plane has none.
  RunResult r = RunRimEval(pred_ + " " + gt_ + " --samples 20000");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("Floaters (> 20 cm): 0.00 % of predicted area (0.00 m^2)\n"),
            std::string::npos)
      << r.out;
  r = RunRimEval(pred_ + " " + gt_ + " --json --samples 20000");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  nlohmann::ordered_json j = ParseOut(r.out);
  ASSERT_TRUE(j.is_object()) << r.out;
  EXPECT_EQ(Keys(j["protocol"]).back(), "floater_cm") << r.out;
  EXPECT_EQ(j["protocol"]["floater_cm"], 20.0) << r.out;
  EXPECT_EQ(j["floater_share"], 0.0) << r.out;
  EXPECT_EQ(j["floater_area_m2"], 0.0) << r.out;
  // The keys before them are unchanged, in their order; the new ones come last.
  std::vector<std::string> keys = Keys(j);
  ASSERT_GE(keys.size(), 3u);
  EXPECT_EQ(std::vector<std::string>(keys.end() - 3, keys.end()),
            (std::vector<std::string>{"seconds", "floater_share", "floater_area_m2"}))
      << r.out;

  // A 1 m^2 patch 50 cm above the 4 m^2 ground: a fifth of the area (uncropped, as the GT is
  // flat).
  const std::string floating = ::testing::TempDir() + "/rim_mesh_eval_floating.ply";
  ASSERT_TRUE(WriteMeshPly(floating, Merged(PlaneZ(0.03f, 0, 2, 0, 2), PatchZ(0.5f))).ok());
  r = RunRimEval(floating + " " + gt_ + " --json --no-crop --samples 20000 --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  j = ParseOut(r.out);
  ASSERT_TRUE(j.is_object()) << r.out;
  EXPECT_NEAR(j["floater_share"].get<double>(), 0.2, 0.004) << r.out;
  EXPECT_NEAR(j["floater_area_m2"].get<double>(), 1.0, 0.02) << r.out;
  r = RunRimEval(floating + " " + gt_ + " --no-crop --samples 20000");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const std::string line = "Floaters (> 20 cm): ";
  EXPECT_NEAR(NumberAfter(r.out, line), 20.0, 0.4) << r.out;
  EXPECT_NE(r.out.find(" % of predicted area ("), std::string::npos) << r.out;
  EXPECT_NEAR(NumberAfter(r.out, " % of predicted area ("), 1.0, 0.02) << r.out;
}

TEST_F(RimEvalCliTest, ReportsGhostsBesideWhatIsPresent) {
  const std::string floating = ::testing::TempDir() + "/rim_mesh_eval_floating2.ply";
  const std::string present = ::testing::TempDir() + "/rim_mesh_eval_present.ply";
  ASSERT_TRUE(WriteMeshPly(floating, Merged(PlaneZ(0.03f, 0, 2, 0, 2), PatchZ(0.5f))).ok());
  ASSERT_TRUE(WriteMeshPly(present, PlaneZ(0.55f, 1, 2, 1, 2)).ok());
  RunResult r =
      RunRimEval(floating + " " + gt_ + " --json --no-crop --samples 20000 --present " + present);
  ASSERT_EQ(r.exit_code, 0) << r.out;
  nlohmann::ordered_json j = ParseOut(r.out);
  ASSERT_TRUE(j.is_object()) << r.out;
  std::vector<std::string> keys = Keys(j);
  ASSERT_GE(keys.size(), 5u);
  EXPECT_EQ(std::vector<std::string>(keys.end() - 5, keys.end()),
            (std::vector<std::string>{"floater_share", "floater_area_m2", "present", "ghost_share",
                                      "ghost_area_m2"}))
      << r.out;
  EXPECT_NEAR(j["floater_share"].get<double>(), 0.2, 0.004) << r.out;
  EXPECT_EQ(j["ghost_share"], 0.0) << r.out;
  r = RunRimEval(floating + " " + gt_ + " --no-crop --samples 20000 --present " + present);
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("Ghosts (floaters > 20 cm from " + present +
                       " too): 0.00 % of predicted "
                       "area (0.00 m^2)"),
            std::string::npos)
      << r.out;
  // Without --present, no ghost keys.
  r = RunRimEval(floating + " " + gt_ + " --json --no-crop --samples 20000");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_FALSE(ParseOut(r.out).contains("ghost_share")) << r.out;
  // A missing file names the flag.
  r = RunRimEval(floating + " " + gt_ + " --present /nonexistent/present.ply");
  EXPECT_NE(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("--present"), std::string::npos) << r.out;
}

// A PLY with a vertex element only: no face element at all.
void WritePointPly(const std::string& path, const Mesh& cloud) {
  FILE* f = std::fopen(path.c_str(), "wb");
  ASSERT_NE(f, nullptr) << path;
  std::fprintf(f,
               "ply\nformat binary_little_endian 1.0\nelement vertex %zu\nproperty float x\n"
               "property float y\nproperty float z\nend_header\n",
               cloud.vertices.size());
  std::fwrite(cloud.vertices.data(), 12, cloud.vertices.size(), f);
  std::fclose(f);
}

TEST_F(RimEvalCliTest, PointCloudGroundTruth) {
  const std::string gt_points = ::testing::TempDir() + "/rim_mesh_eval_gt_points.ply";
  WritePointPly(gt_points, GridCloudZ(0, 0, 2, 0, 2, 0.005f));
  RunResult r = RunRimEval(pred_ + " " + gt_points + " --json --samples 200000 --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  nlohmann::ordered_json j = ParseOut(r.out);
  ASSERT_TRUE(j.is_object()) << r.out;
  EXPECT_EQ(j["gt_kind"], "points") << r.out;
  EXPECT_EQ(j["pred_kind"], "mesh") << r.out;
  EXPECT_TRUE(j["area_m2"]["gt"].is_null()) << "no GT area: " << r.out;
  EXPECT_EQ(j["points"]["gt_samples"], 160000) << r.out;
  EXPECT_EQ(j["standard"]["fscore_pct"], 100.0) << r.out;

  // --region clips the point GT too: half the plane.
  r = RunRimEval(pred_ + " " + gt_points + " --json --samples 200000 --region 0,0,-1,1,2,1");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("\"gt_samples\": 80000"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("\"gt_kind\": \"points\""), std::string::npos) << r.out;

  r = RunRimEval(pred_ + " " + gt_points + " --samples 20000");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("ground truth: " + gt_points + " (point cloud)"), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("GT 160000 points as given"), std::string::npos) << r.out;

  // A mesh GT says so.
  r = RunRimEval(pred_ + " " + gt_ + " --json --samples 20000");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("\"gt_kind\": \"mesh\""), std::string::npos) << r.out;
}

TEST_F(RimEvalCliTest, BoxUnionAlongASequence) {
  // A KITTI-layout sequence of two frames (the frames are never read, only the poses).
  const std::string seq = ::testing::TempDir() + "/rim_mesh_eval_seq";
  ASSERT_EQ(std::system(("rm -rf " + seq + " && mkdir -p " + seq + "/velodyne").c_str()), 0);
  for (const char* frame : {"/velodyne/000000.bin", "/velodyne/000001.bin"}) {
    std::fclose(std::fopen((seq + frame).c_str(), "wb"));
  }
  FILE* poses = std::fopen((seq + "/poses.txt").c_str(), "w");
  ASSERT_NE(poses, nullptr);
  std::fputs("1 0 0 0.5 0 1 0 0.5 0 0 1 0\n1 0 0 1.5 0 1 0 0.5 0 0 1 0\n", poses);
  std::fclose(poses);
  // The boxes cover [0, 2] x [0, 1] of the 2 x 2 m planes: half the samples of each side.
  RunResult r =
      RunRimEval(pred_ + " " + gt_ + " --json --samples 20000 --box 0.5,0.5,-1,1 --seq " + seq);
  ASSERT_EQ(r.exit_code, 0) << r.out;
  nlohmann::ordered_json j = ParseOut(r.out);
  ASSERT_TRUE(j.is_object()) << r.out;
  EXPECT_EQ(
      j["box"],
      nlohmann::ordered_json(
          {{"hx", 0.5}, {"hy", 0.5}, {"z_min", -1.0}, {"z_max", 1.0}, {"frames", 2}, {"seq", seq}}))
      << r.out;
  EXPECT_EQ(j["standard"]["fscore_pct"], 100.0) << r.out;
  r = RunRimEval(pred_ + " " + gt_ + " --samples 20000 --box=0.5,0.5,-1,1 --seq=" + seq);
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("box union: |x - sx| < 0.5, |y - sy| < 0.5, sz -1 <= z < sz +1 m about "
                       "the 2 sensor positions of " +
                       seq),
            std::string::npos)
      << r.out;
  r = RunRimEval(pred_ + " " + gt_ + " --json --samples 20000");
  EXPECT_NE(r.out.find("\"box\": null"), std::string::npos) << r.out;

  const std::vector<std::pair<std::string, std::string>> bad = {
      {"--box 1,1,-1,1", "--box needs --seq DIR"},
      {"--seq " + seq, "--seq needs --box HX,HY,ZMIN,ZMAX"},
      {"--box 0,1,-1,1 --seq " + seq,
       "--box HX,HY,ZMIN,ZMAX needs HX > 0, HY > 0 and ZMIN < ZMAX, got '0,1,-1,1'"},
      {"--box 1,-1,-1,1 --seq " + seq, "--box HX,HY,ZMIN,ZMAX needs HX > 0"},
      {"--box 1,1,1,-1 --seq " + seq, "--box HX,HY,ZMIN,ZMAX needs HX > 0"},
      {"--box 1,1,1 --seq " + seq, "bad value for --box: '1,1,1'"},
      {"--box 1,nan,-1,1 --seq " + seq, "bad value for --box: '1,nan,-1,1'"},
      {"--box 1,1,-1,1 --seq", "--seq needs a value"},
  };
  for (const auto& [args, message] : bad) {
    r = RunRimEval(pred_ + " " + gt_ + " " + args);
    EXPECT_EQ(r.exit_code, 2) << args;
    EXPECT_NE(r.out.find("rim_eval: " + message), std::string::npos) << args << ":\n" << r.out;
  }
  r = RunRimEval(pred_ + " " + gt_ + " --box 1,1,-1,1 --seq /nonexistent/seq");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.out.find("rim_eval: cannot place --box along --seq /nonexistent/seq: "),
            std::string::npos)
      << r.out;
}

TEST_F(RimEvalCliTest, FailsClearlyOnBadInput) {
  RunResult r = RunRimEval(pred_ + " /nonexistent/gt.ply");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.out.find("/nonexistent/gt.ply"), std::string::npos) << r.out;
  r = RunRimEval(pred_);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.out.find("usage"), std::string::npos) << r.out;
  r = RunRimEval(pred_ + " " + gt_ + " --samples lots --frobnicate");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.out.find("bad value for --samples: 'lots'"), std::string::npos) << r.out;
}

// --- Outlier lists (rim_eval --misses / --floaters)
// ------------------------------------------------

TEST(MeshEvalOutlierTest, ListsTheMissedGtAndTheFloatingPrediction) {
  // GT: ground [0, 4]^2. Prediction: the ground's half x < 2 and a patch 50 cm above it.
  const Mesh gt = PlaneZ(0, 0, 4, 0, 4);
  const Mesh pred = Merged(PlaneZ(0, 0, 2, 0, 4), PatchZ(0.5f));
  EvalOptions options = SmallOptions();
  options.crop_margin_m = 1.0;
  const auto quiet = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(quiet.ok()) << quiet.status();
  EXPECT_TRUE(quiet->misses.empty());  // only kept when asked
  EXPECT_TRUE(quiet->floaters.empty());
  options.keep_outliers = true;
  const auto r = EvaluateMeshes(pred, gt, options);
  ASSERT_TRUE(r.ok()) << r.status();
  // Every GT point farther than 10 cm from the prediction, and only those, is a miss: the ground
  // at x > 2.1 (the patch covers none of it).
  ASSERT_FALSE(r->misses.empty());
  for (const auto& m : r->misses) {
    EXPECT_GT(m.x, 2.09f);
    EXPECT_GT(m.distance_m, 0.1f);
    EXPECT_NEAR(m.distance_m, m.x - 2.0f, 0.02f);
  }
  EXPECT_NEAR(static_cast<double>(r->misses.size()) / r->gt_points, 1.9 / 4.0, 0.03);
  EXPECT_NEAR(1.0 - static_cast<double>(r->misses.size()) / r->gt_points, r->standard.recall, 1e-9);
  // The floaters are the patch's points, 50 cm above the ground.
  ASSERT_FALSE(r->floaters.empty());
  for (const auto& f : r->floaters) {
    EXPECT_NEAR(f.z, 0.5f, 0.01f);
    EXPECT_NEAR(f.distance_m, 0.5f, 0.01f);
    EXPECT_TRUE(f.x >= 1 && f.x <= 2 && f.y >= 1 && f.y <= 2);
  }
  // The metrics are the same whether or not the lists are kept.
  EXPECT_EQ(r->standard.recall, quiet->standard.recall);
  EXPECT_EQ(r->floater_share, quiet->floater_share);
}

}  // namespace
}  // namespace rim::eval
