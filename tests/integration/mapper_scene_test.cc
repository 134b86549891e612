// The mapper end to end on an analytic scene with exact ground truth: a simulated LiDAR drives
// along a corridor longer than the local map, so the map slides, slabs go to sub-maps, and
// queries and meshes read both the live grids and the sub-map store.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>

#include "rim/io/mesh_io.h"
#include "rim/map/submap_store.h"
#include "rim/mapper.h"
#include "rim/train/outlier_filter.h"
#include "rim/train/point_buffer.h"
#include "support/analytic_scene.h"

namespace rim {
namespace {

using testing_support::AnalyticScene;
using testing_support::LidarModel;

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

class MapperSceneTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new AnalyticScene(AnalyticScene::Default());
    auto config = MakePreset("maicity");
    ASSERT_TRUE(config.ok());
    // 20 iterations instead of 30 keeps the test within a couple of minutes on 2 cores.
    ASSERT_TRUE(ApplyOverrides({"train.iterations=20"}, &*config).ok());
    auto mapper = Mapper::Create(*config);
    ASSERT_TRUE(mapper.ok()) << mapper.status();
    mapper_ = mapper->release();
    LidarModel lidar;
    const auto poses = testing_support::StraightTrajectory(0.f, 30.f, 31, 1.6f);
    StageTimings sum;
    for (size_t i = 0; i < poses.size(); ++i) {
      PosedScan scan;
      scan.T_world_sensor = poses[i].cast<double>();
      for (const auto& p : testing_support::SimulateScan(*scene_, lidar, poses[i], 100 + i))
        scan.points_S.push_back(p);
      StageTimings t;
      absl::Status s = mapper_->IntegrateScan(scan, -1, &t);
      ASSERT_TRUE(s.ok()) << s;
      sum += t;
    }
    const double k = 1e3 / poses.size();
    std::printf(
        "integrated %zu frames, %.0f ms/frame (slide %.1f, preprocess %.1f, sample %.1f, encode "
        "%.1f, forward %.1f, backward %.1f, step %.1f)\n",
        poses.size(), k * sum.total_s, k * sum.slide_s, k * sum.preprocess_s, k * sum.sample_s,
        k * sum.encode_s, k * sum.forward_s, k * sum.backward_s, k * sum.step_s);
  }
  static void TearDownTestSuite() {
    delete mapper_;
    delete scene_;
  }

  // Surface points of the stretch the robot drove past, where the map was trained.
  std::vector<AnalyticScene::SurfacePoint> Surface(int count) const {
    return scene_->SampleSurface(Eigen::Vector3f(2, -8, -0.5f), Eigen::Vector3f(28, 8, 4.f), count,
                                 5);
  }

  static AnalyticScene* scene_;
  static Mapper* mapper_;
};
AnalyticScene* MapperSceneTest::scene_ = nullptr;
Mapper* MapperSceneTest::mapper_ = nullptr;

TEST_F(MapperSceneTest, MapSlidAndFilledSubmaps) {
  const MapperStats stats = mapper_->Stats();
  EXPECT_EQ(stats.frames, 31);
  // The robot moved 30 m with a 20 m box: sub-maps behind it hold saved slabs.
  EXPECT_GT(stats.submap_bytes, 0);
  EXPECT_GE(mapper_->ListTiles(0).size(), 2u);
}

TEST_F(MapperSceneTest, SdfAtSurfaceIsNearZero) {
  const auto surface = Surface(4000);
  std::vector<float> xyz;
  for (const auto& s : surface) xyz.insert(xyz.end(), {s.p.x(), s.p.y(), s.p.z()});
  QueryResult q;
  ASSERT_TRUE(mapper_->QuerySdf(xyz.data(), surface.size(), true, &q).ok());
  std::vector<double> err;
  int flat = 0, flat_ok = 0;
  for (size_t i = 0; i < surface.size(); ++i) {
    if (!q.observed[i]) continue;
    err.push_back(std::abs(q.sdf[i]));
    if (surface[i].on_flat_face) {
      Eigen::Vector3f g(q.gradient[3 * i], q.gradient[3 * i + 1], q.gradient[3 * i + 2]);
      const float angle = std::acos(std::clamp(g.normalized().dot(surface[i].n), -1.f, 1.f));
      ++flat;
      flat_ok += angle < 10.f * M_PI / 180.f;
    }
  }
  const double observed_fraction = double(err.size()) / surface.size();
  std::printf("observed %.1f%%, median |sdf| %.2f cm, normals within 10 deg %.1f%% of %d\n",
              100 * observed_fraction, 100 * Median(err), 100.0 * flat_ok / flat, flat);
  EXPECT_GT(observed_fraction, 0.6);
  EXPECT_LT(Median(err), 0.02);
  // "Within 10 degrees on flat faces": required of the large majority of samples; edges and
  // rarely seen faces are where the remainder sits.
  EXPECT_GT(double(flat_ok) / flat, 0.8);
}

TEST_F(MapperSceneTest, SignIsRightInFreeSpace) {
  // Points in the free corridor above the ground, 0.3 m or more from any surface.
  std::vector<float> xyz;
  for (float x = 3; x < 28; x += 0.5f)
    for (float y = -1.5f; y <= 1.5f; y += 0.5f)
      for (float z = 0.3f; z < 2.5f; z += 0.4f)
        if (scene_->Sdf(Eigen::Vector3f(x, y, z)) > 0.3f) xyz.insert(xyz.end(), {x, y, z});
  QueryResult q;
  const size_t n = xyz.size() / 3;
  ASSERT_TRUE(mapper_->QuerySdf(xyz.data(), n, false, &q).ok());
  size_t positive = 0, below = 0, observed = 0;
  for (float v : q.sdf) positive += v > 0.f;
  // Below the sensor (1.6 m) every frame's downward beams crossed the corridor on their way to the
  // ground: seen free. Above it only beams that hit a building did, so only some of it is.
  for (size_t i = 0; i < n; ++i) {
    if (xyz[3 * i + 2] >= 1.6f) continue;
    ++below;
    observed += q.observed[i] != 0;
  }
  std::printf("free space: %zu of %zu positive; below the sensor %zu of %zu observed\n", positive,
              n, observed, below);
  EXPECT_GT(double(positive) / n, 0.98);
  EXPECT_GT(double(observed) / below, 0.98);
}

// Free-space points the sensor saw, scored against the scene's exact Euclidean distance: what a
// planner reads must be a distance, not the network's along-ray value (docs/core.md, "Metric
// distances"). The network's own values at the same points are printed for contrast.
TEST_F(MapperSceneTest, DistancesAreEuclideanWithUnitGradients) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> ux(3.f, 28.f), uy(-8.f, 8.f), uz(-0.3f, 3.f);
  std::vector<float> xyz, truth;
  while (truth.size() < 6000) {
    const Eigen::Vector3f p(ux(rng), uy(rng), uz(rng));
    const float d = scene_->Sdf(p);
    // Clear of the 2 m bound, where a reading a millimetre long is the saturated bound itself.
    if (d < 0.02f || d >= 1.95f) continue;
    xyz.insert(xyz.end(), {p.x(), p.y(), p.z()});
    truth.push_back(d);
  }
  const size_t n = truth.size();
  QueryResult q, net;
  ASSERT_TRUE(mapper_->QuerySdf(xyz.data(), n, true, &q).ok());
  ASSERT_TRUE(mapper_->QueryNeural(xyz.data(), n, false, &net).ok());
  ASSERT_EQ(q.saturated.size(), n);
  std::vector<double> near_err, far_err, near_net, far_net;
  size_t scored = 0, too_far = 0, wrong_sign = 0, grad_n = 0, grad_ok = 0;
  for (size_t i = 0; i < n; ++i) {
    if (q.observed[i] != QueryResult::kObservedFree) continue;  // seen free, off surface bands
    ++scored;
    const Eigen::Vector3f p(&xyz[3 * i]);
    const double e = double(q.sdf[i]) - truth[i];
    (truth[i] < 0.3f ? near_err : far_err).push_back(std::abs(e));
    (truth[i] < 0.3f ? near_net : far_net).push_back(std::abs(double(net.sdf[i]) - truth[i]));
    too_far += e > 0.1;
    wrong_sign += q.sdf[i] < 0;
    if (truth[i] < 0.1f) continue;
    Eigen::Vector3f fd;
    for (int a = 0; a < 3; ++a) {
      Eigen::Vector3f h = Eigen::Vector3f::Zero();
      h[a] = 1e-3f;
      fd[a] = (scene_->Sdf(p + h) - scene_->Sdf(p - h)) / 2e-3f;
    }
    const Eigen::Vector3f g(&q.gradient[3 * i]);
    EXPECT_NEAR(g.norm(), 1.f, 1e-3f);
    ++grad_n;
    grad_ok += g.dot(fd.normalized()) > std::cos(10.f * M_PI / 180.f);
  }
  std::printf(
      "metric distances at %zu seen-free points: median |error| %.2f cm within 0.3 m "
      "(network %.1f cm), %.2f cm at 0.3-2 m (network %.1f cm); %.2f%% > 10 cm too far, %.2f%% "
      "wrong sign, gradients within 10 deg %.1f%%\n",
      scored, 100 * Median(near_err), 100 * Median(near_net), 100 * Median(far_err),
      100 * Median(far_net), 100.0 * too_far / scored, 100.0 * wrong_sign / scored,
      100.0 * grad_ok / grad_n);
  ASSERT_GT(scored, 2000u);
  EXPECT_LT(Median(near_err), 0.02);
  EXPECT_LT(Median(far_err), 0.04);
  EXPECT_LT(double(too_far) / scored, 0.01);
  EXPECT_LT(double(wrong_sign) / scored, 0.01);
  EXPECT_GT(double(grad_ok) / grad_n, 0.9);
}

TEST_F(MapperSceneTest, FarFromEverySurfaceTheBoundIsFlagged) {
  // 5 m above the ground in the middle of the drive, and far away where nothing was mapped.
  std::vector<float> xyz = {15.f, 0.f, 5.f, 500.f, 0.f, 1.f};
  QueryResult q;
  ASSERT_TRUE(mapper_->QuerySdf(xyz.data(), 2, true, &q).ok());
  const float bound = mapper_->config().query.max_distance_m;
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(q.saturated[i], 1);
    EXPECT_EQ(q.sdf[i], bound);
    EXPECT_EQ(q.gradient[3 * i + 2], 0.f);
  }
}

TEST_F(MapperSceneTest, UnseenSpaceIsNotObserved) {
  // Deep under the ground (behind every surface) and far to the side of the drive, beyond the
  // sensor's reach: no ray saw these, whatever the network extrapolates there.
  std::vector<float> xyz;
  for (float x = 3; x < 28; x += 1.f) {
    xyz.insert(xyz.end(), {x, 0.f, -2.5f});
    xyz.insert(xyz.end(), {x, 150.f, 1.f});
  }
  QueryResult q;
  ASSERT_TRUE(mapper_->QuerySdf(xyz.data(), xyz.size() / 3, false, &q).ok());
  for (size_t i = 0; i < q.observed.size(); ++i)
    EXPECT_EQ(q.observed[i], 0) << "point " << xyz[3 * i] << "," << xyz[3 * i + 1] << ","
                                << xyz[3 * i + 2];
}

TEST_F(MapperSceneTest, MeshIsAccurateAndTilesAreSeamless) {
  Mesh merged;
  std::map<std::array<int, 3>, Mesh> tiles;
  for (const TileInfo& t : mapper_->ListTiles(0)) {
    auto mesh = mapper_->ExtractMeshTile(t.key);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    tiles[{t.key.x(), t.key.y(), t.key.z()}] = *mesh;
    AppendMesh(*mesh, &merged);
  }
  ASSERT_FALSE(merged.empty());
  // Completeness counts only surfaces the LiDAR saw from inside the local box of some pose:
  // roofs above the beams and back faces were never observed, so no mapper could have them.
  const auto poses = testing_support::StraightTrajectory(0.f, 30.f, 31, 1.6f);
  auto visible = [&](const Eigen::Vector3f& p) {
    for (const auto& T : poses) {
      const Eigen::Vector3f o = T.translation(), d = p - o;
      const float dist = d.norm();
      const float elev = std::asin(d.z() / dist) * 180.f / float(M_PI);
      if (dist > 29.f || std::abs(d.x()) > 9.9f || elev < -25.f || elev > 15.f) continue;
      if (scene_->Raycast(o, d / dist, 30.f) >= dist - 0.02f) return true;
    }
    return false;
  };
  const auto errors =
      testing_support::EvaluateMesh(merged, *scene_, Eigen::Vector3f(2, -8, -0.5f),
                                    Eigen::Vector3f(28, 8, 4.f), 200000, 9, visible);
  std::printf("mesh: %zu faces, accuracy %.2f cm, completeness %.2f cm, chamfer-L1 %.2f cm\n",
              merged.faces.size(), 100 * errors.accuracy_m, 100 * errors.completeness_m,
              100 * errors.chamfer_l1_m);
  EXPECT_LT(errors.chamfer_l1_m, 0.03);

  // Seams: tiles are meshed independently, so a seam would show as open mesh boundary along the
  // tile border plane x = 20 m, on every surface crossing it. After welding bit-identical
  // vertices, the border plane must have no more boundary edges than ordinary grid planes near it
  // (whose boundary edges come only from where observation ends).
  const Mesh welded = WeldIdenticalVertices(merged);
  std::map<std::pair<uint32_t, uint32_t>, int> edge_use;
  for (const auto& f : welded.faces)
    for (int e = 0; e < 3; ++e) {
      uint32_t a = f[e], b = f[(e + 1) % 3];
      edge_use[{std::min(a, b), std::max(a, b)}]++;
    }
  const double step = 0.05;
  std::map<long, int> boundary_per_plane;  // keyed by x / step
  for (const auto& [e, uses] : edge_use) {
    if (uses != 1) continue;
    const float xa = welded.vertices[e.first][0], xb = welded.vertices[e.second][0];
    const double k = std::round(xa / step);
    if (xa == xb && std::abs(xa - k * step) < 1e-4) boundary_per_plane[long(k)]++;
  }
  std::vector<double> others;
  // Observation ends on finest-voxel faces, so compare with those planes (every 0.1 m).
  for (long k = long(std::round(15 / step)); k <= long(std::round(25 / step)); k += 2)
    if (k != long(std::round(20 / step))) others.push_back(boundary_per_plane[k]);
  const int border = boundary_per_plane[long(std::round(20 / step))];
  size_t crossing = 0;
  for (const auto& v : welded.vertices) crossing += v[0] == 20.f;
  std::printf(
      "x=20 m tile border: %d open edges, %zu vertices; median voxel-face plane: %.0f open edges\n",
      border, crossing, Median(others));
  EXPECT_GT(crossing, 100u);
  EXPECT_LE(border, 2 * Median(others) + 10);

  // No crack along any straight line: every voxel-face plane x = const and y = const across the
  // mapped stretch, the faces of the last box included (it ends at x = 30 m, box [20, 40) x
  // [-10, 10)), has no more open edges than a few times the median plane. A crack (cells left
  // out of the mesh along a plane) opens edges on both sides of it over every surface it crosses.
  for (int axis = 0; axis < 2; ++axis) {
    std::map<long, int> per_plane;
    for (const auto& [e, uses] : edge_use) {
      if (uses != 1) continue;
      const float a = welded.vertices[e.first][axis], b = welded.vertices[e.second][axis];
      const double k = std::round(a / 0.1);
      if (a == b && std::abs(a - k * 0.1) < 1e-4) per_plane[long(k)]++;
    }
    const long first = axis == 0 ? 30 : -80, last = axis == 0 ? 400 : 80;
    // Planes that hold a face of the scene's boxes have open edges along them by nature (where
    // the ground meets a wall, where a wall's observed part ends): they are left out.
    auto on_a_face = [&](long k) {
      for (const auto& b : scene_->boxes)
        if (std::abs(k * 0.1 - b.min[axis]) < 0.15 || std::abs(k * 0.1 - b.max[axis]) < 0.15)
          return true;
      return false;
    };
    std::vector<double> counts;
    long worst = -1000000;
    for (long k = first; k <= last; ++k) {
      if (on_a_face(k)) continue;
      counts.push_back(per_plane[k]);
      if (worst == -1000000 || per_plane[k] > per_plane[worst]) worst = k;
    }
    const double median = Median(counts);
    std::printf("%c planes %.1f..%.1f m: median %.0f open edges, worst %d at %.1f m\n", "xy"[axis],
                first * 0.1, last * 0.1, median, per_plane[worst], worst * 0.1);
    EXPECT_LE(per_plane[worst], 4 * median + 20) << "a straight crack at "
                                                 << "xy"[axis] << " = " << worst * 0.1 << " m";
  }
}

TEST_F(MapperSceneTest, OutlierRemovalDropsPlantedOutliersAndKeepsSurface) {
  // The robot ended at x = 30: its box covers x in [20, 40). Surface points there that the map
  // observed, and planted "returns" floating in the free corridor (a person who walked away).
  std::vector<Vec3f> points, origins;
  QueryResult q;
  std::vector<float> xyz;
  const auto surface =
      scene_->SampleSurface(Eigen::Vector3f(21, -8, -0.5f), Eigen::Vector3f(29, 8, 4.f), 3000, 11);
  for (const auto& s : surface) xyz.insert(xyz.end(), {s.p.x(), s.p.y(), s.p.z()});
  ASSERT_TRUE(mapper_->QuerySdf(xyz.data(), surface.size(), false, &q).ok());
  for (size_t i = 0; i < surface.size(); ++i)
    if (q.observed[i]) points.push_back(surface[i].p);
  const size_t n_surface = points.size();
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> ux(21, 29), uy(-1.5f, 1.5f), uz(0.4f, 2.5f);
  while (points.size() < n_surface + 500) {
    const Vec3f p(ux(rng), uy(rng), uz(rng));
    if (scene_->Sdf(p) > 0.3f) points.push_back(p);
  }
  origins.assign(points.size(), Vec3f(30, 0, 1.6f));
  BufferConfig config;
  config.max_points_per_frame = int(points.size());
  PointBuffer buffer(config, 1);
  buffer.AddFrame(points, origins);
  ASSERT_EQ(buffer.size(), points.size());
  RemoveOutliers(mapper_->local_map(), mapper_->decoder(), 0.05f, &buffer);
  size_t kept_surface = 0, kept_outliers = 0;
  for (const Vec3f& p : buffer.points()) (scene_->Sdf(p) > 0.3f ? kept_outliers : kept_surface)++;
  std::printf("outlier removal: kept %zu of %zu surface points, %zu of 500 outliers\n",
              kept_surface, n_surface, kept_outliers);
  ASSERT_GT(n_surface, 500u);
  EXPECT_GT(double(kept_surface) / n_surface, 0.9);
  EXPECT_LT(kept_outliers, 15u);  // 3 % of the planted ones; 9-11 seen
}

TEST_F(MapperSceneTest, SaveLoadGivesIdenticalAnswers) {
  const std::string dir = ::testing::TempDir() + "/rim_mapper_scene_save";
  ASSERT_TRUE(mapper_->Save(dir).ok());
  auto loaded = Mapper::Load(dir);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  std::vector<float> xyz;
  for (const auto& s : Surface(500)) xyz.insert(xyz.end(), {s.p.x(), s.p.y(), s.p.z()});
  for (float x = -5; x < 40; x += 1.f) xyz.insert(xyz.end(), {x, 0.5f, 1.f});  // beyond the map too
  const size_t n = xyz.size() / 3;
  QueryResult a, b;
  ASSERT_TRUE(mapper_->QuerySdf(xyz.data(), n, true, &a).ok());
  ASSERT_TRUE((*loaded)->QuerySdf(xyz.data(), n, true, &b).ok());
  EXPECT_EQ(a.sdf, b.sdf);
  EXPECT_EQ(a.gradient, b.gradient);
  EXPECT_EQ(a.observed, b.observed);
  EXPECT_EQ(a.saturated, b.saturated);
  EXPECT_EQ(a.map_version, b.map_version);
  EXPECT_EQ((*loaded)->frames(), mapper_->frames());
}

}  // namespace
}  // namespace rim
