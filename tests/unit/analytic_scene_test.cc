#include "support/analytic_scene.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <random>
#include <utility>
#include <vector>

namespace rim::testing_support {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kPi = 3.14159265f;

// One primitive of each kind, spread apart so each point's closest surface is unambiguous.
AnalyticScene SmallScene() {
  AnalyticScene s;
  s.ground_z = 0.f;
  s.spheres = {{{0.f, 0.f, 5.f}, 1.f}};
  s.boxes = {{{10.f, -1.f, 2.f}, {12.f, 1.f, 4.f}}};
  s.cylinders = {{{20.f, 0.f}, 0.5f, 1.f, 3.f}};
  return s;
}

Eigen::Vector3f RandomUnit(std::mt19937* rng) {
  std::normal_distribution<float> g(0.f, 1.f);
  Eigen::Vector3f v;
  do {
    v = Eigen::Vector3f(g(*rng), g(*rng), g(*rng));
  } while (v.norm() < 1e-3f);
  return v.normalized();
}

float Uniform(std::mt19937* rng, float lo, float hi) {
  return std::uniform_real_distribution<float>(lo, hi)(*rng);
}

// Geodesic sphere: an icosahedron subdivided `levels` times with vertices pushed to the sphere.
Mesh Icosphere(const Eigen::Vector3f& center, float radius, int levels) {
  const float t = (1.f + std::sqrt(5.f)) / 2.f;
  std::vector<Eigen::Vector3f> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                                    {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                                    {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (auto& p : v) p.normalize();
  std::vector<std::array<uint32_t, 3>> f = {
      {0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
      {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
      {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
    auto midpoint = [&](uint32_t a, uint32_t b) {
      const auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      const uint32_t id = static_cast<uint32_t>(v.size() - 1);
      mid.emplace(key, id);
      return id;
    };
    std::vector<std::array<uint32_t, 3>> next;
    for (const auto& tri : f) {
      const uint32_t a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]),
                     c = midpoint(tri[2], tri[0]);
      next.push_back({tri[0], a, c});
      next.push_back({tri[1], b, a});
      next.push_back({tri[2], c, b});
      next.push_back({a, b, c});
    }
    f = std::move(next);
  }
  Mesh mesh;
  for (const auto& p : v) {
    const Eigen::Vector3f q = center + radius * p;
    mesh.vertices.push_back({q.x(), q.y(), q.z()});
  }
  mesh.faces = f;
  return mesh;
}

TEST(AnalyticSceneTest, SdfMatchesDefinitionsAtKnownPoints) {
  const AnalyticScene s = SmallScene();
  // Sphere: surface, centre, outside.
  EXPECT_NEAR(s.Sdf({0.f, 0.f, 6.f}), 0.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({1.f, 0.f, 5.f}), 0.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({0.f, 0.f, 5.f}), -1.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({0.f, 0.f, 7.5f}), 1.5f, 1e-6f);
  // Box: face, edge and corner regions outside, and depth inside.
  EXPECT_NEAR(s.Sdf({13.f, 0.f, 3.f}), 1.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({13.f, 2.f, 3.f}), std::sqrt(2.f), 1e-6f);
  EXPECT_NEAR(s.Sdf({13.f, 2.f, 5.f}), std::sqrt(3.f), 1e-6f);
  EXPECT_NEAR(s.Sdf({11.f, 0.f, 3.f}), -1.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({10.2f, 0.f, 3.f}), -0.2f, 1e-6f);
  EXPECT_NEAR(s.Sdf({12.f, 0.5f, 3.5f}), 0.f, 1e-6f);
  // Cylinder: side, outside radially, above the cap, past the rim, inside.
  EXPECT_NEAR(s.Sdf({20.5f, 0.f, 2.f}), 0.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({21.f, 0.f, 2.f}), 0.5f, 1e-6f);
  EXPECT_NEAR(s.Sdf({20.f, 0.f, 4.f}), 1.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({20.f, 1.f, 4.f}), std::hypot(0.5f, 1.f), 1e-6f);
  EXPECT_NEAR(s.Sdf({20.f, 0.f, 2.f}), -0.5f, 1e-6f);
  EXPECT_NEAR(s.Sdf({20.f, 0.f, 2.9f}), -0.1f, 1e-6f);
  // Ground: above, on, below.
  EXPECT_NEAR(s.Sdf({30.f, 0.f, 2.f}), 2.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({30.f, 0.f, 0.f}), 0.f, 1e-6f);
  EXPECT_NEAR(s.Sdf({30.f, 0.f, -1.f}), -1.f, 1e-6f);
  // Union: the closer of ground (0.5) and cylinder bottom cap (0.5 below it).
  EXPECT_NEAR(s.Sdf({20.f, 0.f, 0.5f}), 0.5f, 1e-6f);
  EXPECT_NEAR(s.Sdf({20.f, 0.f, 0.6f}), 0.4f, 1e-6f);

  // Without ground, far below everything is positive.
  AnalyticScene no_ground = s;
  no_ground.ground_z = -kInf;
  EXPECT_NEAR(no_ground.Sdf({0.f, 0.f, 2.f}), 2.f, 1e-6f);
}

// Outside the solids the union's SDF must equal the distance to the nearest surface point; a dense
// surface sample gives that distance up to the sample spacing.
TEST(AnalyticSceneTest, SdfMatchesBruteForceDistanceToSurfaceSamples) {
  const AnalyticScene s = SmallScene();
  const Eigen::Vector3f lo(-3.f, -3.f, -0.5f), hi(23.f, 3.f, 6.5f);
  const auto surface = s.SampleSurface(lo, hi, 300000, 11);
  ASSERT_EQ(surface.size(), 300000u);
  std::mt19937 rng(3);
  int checked = 0;
  while (checked < 200) {
    const Eigen::Vector3f q(Uniform(&rng, lo.x(), hi.x()), Uniform(&rng, lo.y(), hi.y()),
                            Uniform(&rng, 0.f, hi.z()));
    const float d = s.Sdf(q);
    // The nearest surface point must lie inside the sampled region.
    const float margin =
        std::min({q.x() - lo.x(), hi.x() - q.x(), q.y() - lo.y(), hi.y() - q.y(), hi.z() - q.z()});
    if (d <= 0.f || d >= margin) continue;
    float best = kInf;
    for (const auto& sp : surface) best = std::min(best, (sp.p - q).norm());
    EXPECT_GE(best, d - 1e-4f) << q.transpose();
    EXPECT_NEAR(best, d, 0.04f) << q.transpose();
    ++checked;
  }
}

TEST(AnalyticSceneTest, RaycastKnownRays) {
  const AnalyticScene s = SmallScene();
  EXPECT_NEAR(s.Raycast({30.f, 0.f, 1.8f}, {0.f, 0.f, -1.f}, 30.f), 1.8f, 1e-6f);
  EXPECT_EQ(s.Raycast({30.f, 0.f, 1.8f}, {0.f, 0.f, 1.f}, 30.f), kInf);
  EXPECT_EQ(s.Raycast({30.f, 0.f, 1.8f}, {0.f, 0.f, -1.f}, 1.f), kInf);
  EXPECT_NEAR(s.Raycast({-5.f, 0.f, 5.f}, {1.f, 0.f, 0.f}, 30.f), 4.f, 1e-5f);
  // Box entered through its face, with the origin level with the box's top face plane.
  EXPECT_NEAR(s.Raycast({5.f, 0.f, 4.f}, {1.f, 0.f, 0.f}, 30.f), 5.f, 1e-5f);
  EXPECT_NEAR(s.Raycast({5.f, 0.f, 3.f}, {1.f, 0.f, 0.f}, 30.f), 5.f, 1e-5f);
  // Cylinder side, then its top cap from above.
  EXPECT_NEAR(s.Raycast({15.f, 0.f, 2.f}, {1.f, 0.f, 0.f}, 30.f), 4.5f, 1e-5f);
  EXPECT_NEAR(s.Raycast({20.1f, 0.1f, 5.f}, {0.f, 0.f, -1.f}, 30.f), 2.f, 1e-5f);
  // Starting inside a solid reports an immediate hit.
  EXPECT_EQ(s.Raycast({0.f, 0.f, 5.f}, {1.f, 0.f, 0.f}, 30.f), 0.f);
  EXPECT_EQ(s.Raycast({30.f, 0.f, -1.f}, {0.f, 0.f, 1.f}, 30.f), 0.f);
}

TEST(AnalyticSceneTest, RaycastHitsAreOnSurfaceWithNothingCloser) {
  const AnalyticScene s = AnalyticScene::Default();
  std::mt19937 rng(5);
  const float max_range = 30.f;
  int hits = 0, misses = 0;
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3f o(Uniform(&rng, -2.f, 42.f), Uniform(&rng, -1.8f, 1.8f),
                            Uniform(&rng, 0.2f, 3.f));
    ASSERT_GT(s.Sdf(o), 0.f);
    const Eigen::Vector3f d = RandomUnit(&rng);
    const float t = s.Raycast(o, d, max_range);
    const float t_end = std::isfinite(t) ? t - 1e-3f : max_range;
    if (std::isfinite(t)) {
      ++hits;
      ASSERT_LE(t, max_range);
      EXPECT_LT(std::abs(s.Sdf(o + t * d)), 1e-4f)
          << "origin " << o.transpose() << " dir " << d.transpose() << " t " << t;
    } else {
      ++misses;
    }
    // March: no point before the hit lies inside a solid.
    for (float u = 0.f; u < t_end; u += 1e-2f) {
      ASSERT_GT(s.Sdf(o + u * d), -1e-5f)
          << "origin " << o.transpose() << " dir " << d.transpose() << " t " << t << " u " << u;
    }
    // Sphere tracing never steps past the first surface, so it cannot stop beyond the hit.
    float u = 0.f;
    for (int k = 0; k < 100000 && u < max_range; ++k) {
      const float step = s.Sdf(o + u * d);
      if (step < 1e-5f) break;
      u += step;
    }
    if (u < max_range) {
      EXPECT_LE(u, t + 1e-3f) << "origin " << o.transpose() << " dir " << d.transpose();
    }
  }
  EXPECT_GT(hits, 500);
  EXPECT_GT(misses, 50);
}

TEST(AnalyticSceneTest, NormalMatchesFiniteDifferencesAwayFromEdges) {
  const AnalyticScene s = AnalyticScene::Default();
  std::mt19937 rng(9);
  const float h = 1e-3f;
  int used = 0, tried = 0;
  while (tried < 5000) {
    const Eigen::Vector3f p(Uniform(&rng, -2.f, 42.f), Uniform(&rng, -9.f, 9.f),
                            Uniform(&rng, 0.f, 5.f));
    const float d = s.Sdf(p);
    if (d < 0.02f) continue;
    ++tried;
    Eigen::Vector3f central, forward, backward;
    for (int a = 0; a < 3; ++a) {
      const Eigen::Vector3f e = Eigen::Vector3f::Unit(a) * h;
      const float fp = s.Sdf(p + e), fm = s.Sdf(p - e);
      central[a] = (fp - fm) / (2.f * h);
      forward[a] = (fp - d) / h;
      backward[a] = (d - fm) / h;
    }
    // One-sided slopes disagree across a kink (where two primitives are equally close).
    if ((forward - backward).cwiseAbs().maxCoeff() > 0.02f) continue;
    ++used;
    const Eigen::Vector3f n = s.Normal(p);
    EXPECT_NEAR(n.norm(), 1.f, 1e-5f);
    EXPECT_GT(n.dot(central.normalized()), 0.999f)
        << p.transpose() << " n " << n.transpose() << " fd " << central.transpose();
  }
  EXPECT_GT(used, 4500);
}

TEST(AnalyticSceneTest, NormalInsideAndOnFaces) {
  const AnalyticScene s = SmallScene();
  EXPECT_TRUE(s.Normal({12.f, 0.f, 3.f}).isApprox(Eigen::Vector3f::UnitX()));
  EXPECT_TRUE(s.Normal({11.9f, 0.f, 3.f}).isApprox(Eigen::Vector3f::UnitX()));
  EXPECT_TRUE(s.Normal({20.f, 0.f, 2.9f}).isApprox(Eigen::Vector3f::UnitZ()));
  EXPECT_TRUE(s.Normal({20.f, 0.4f, 2.f}).isApprox(Eigen::Vector3f::UnitY()));
  EXPECT_TRUE(s.Normal({20.f, 0.f, 0.9f}).isApprox(-Eigen::Vector3f::UnitZ()));
  EXPECT_TRUE(s.Normal({30.f, 0.f, 1.f}).isApprox(Eigen::Vector3f::UnitZ()));
  EXPECT_TRUE(s.Normal({0.f, -2.f, 5.f}).isApprox(-Eigen::Vector3f::UnitY()));
}

TEST(AnalyticSceneTest, SampleSurfaceLiesOnExposedSurface) {
  const AnalyticScene s = AnalyticScene::Default();
  const Eigen::Vector3f lo(-2.f, -9.f, -1.f), hi(42.f, 9.f, 5.f);
  const auto pts = s.SampleSurface(lo, hi, 20000, 7);
  ASSERT_EQ(pts.size(), 20000u);
  int normal_agrees = 0, flat = 0, ground = 0;
  for (const auto& sp : pts) {
    ASSERT_LT(std::abs(s.Sdf(sp.p)), 1e-4f) << sp.p.transpose();
    ASSERT_TRUE((sp.p.array() >= lo.array()).all() && (sp.p.array() <= hi.array()).all());
    ASSERT_NEAR(sp.n.norm(), 1.f, 1e-5f);
    // Nothing buried below ground.
    ASSERT_GE(sp.p.z(), -1e-4f);
    // Stepping out along the normal leads into free space (a short step: in the crease where a
    // sphere meets the ground, exposed points sit within millimetres of the other surface).
    ASSERT_GT(s.Sdf(sp.p + 1e-3f * sp.n), 0.f) << sp.p.transpose() << " n " << sp.n.transpose();
    if (s.Normal(sp.p).dot(sp.n) > 0.99f) ++normal_agrees;
    if (sp.on_flat_face) {
      ++flat;
      ASSERT_NEAR(sp.n.cwiseAbs().maxCoeff(), 1.f, 1e-6f);
    }
    if (sp.n.z() > 0.99f && std::abs(sp.p.z()) < 1e-4f) {
      ++ground;
      for (const Box& b : s.boxes) {
        ASSERT_FALSE(sp.p.x() > b.min.x() && sp.p.x() < b.max.x() && sp.p.y() > b.min.y() &&
                     sp.p.y() < b.max.y())
            << "ground sample under a box at " << sp.p.transpose();
      }
      for (const Cylinder& c : s.cylinders) {
        ASSERT_GT((sp.p.head<2>() - c.center_xy).norm(), c.radius);
      }
    }
  }
  // Concave edges are the only places where the closest primitive can differ.
  EXPECT_GT(normal_agrees, 19900);
  EXPECT_GT(flat, 15000);
  EXPECT_GT(ground, 10000);

  // Deterministic per seed.
  const auto again = s.SampleSurface(lo, hi, 20000, 7);
  const auto other = s.SampleSurface(lo, hi, 20000, 8);
  ASSERT_EQ(again.size(), pts.size());
  for (size_t i = 0; i < pts.size(); ++i) ASSERT_EQ(again[i].p, pts[i].p);
  EXPECT_NE(other[0].p, pts[0].p);
}

TEST(AnalyticSceneTest, SampleSurfaceIsUniformByArea) {
  AnalyticScene s;
  s.ground_z = -kInf;
  s.spheres = {{{0.f, 0.f, 0.f}, 2.f}};
  s.boxes = {{{10.f, 0.f, 0.f}, {11.f, 1.f, 3.f}}};  // area 14 vs sphere 16 pi
  const auto pts = s.SampleSurface({-5.f, -5.f, -5.f}, {15.f, 5.f, 5.f}, 40000, 1);
  ASSERT_EQ(pts.size(), 40000u);
  int upper = 0, on_box = 0, box_top = 0;
  for (const auto& sp : pts) {
    if (sp.p.x() > 5.f) {
      ++on_box;
      if (sp.n.z() > 0.5f) ++box_top;
    } else if (sp.p.z() > 0.f) {
      ++upper;
    }
  }
  const double box_share = 14.0 / (14.0 + 16.0 * double(kPi));
  EXPECT_NEAR(on_box / 40000.0, box_share, 0.01);
  EXPECT_NEAR(double(upper) / (40000 - on_box), 0.5, 0.015);
  EXPECT_NEAR(double(box_top) / on_box, 1.0 / 14.0, 0.01);

  // A region that cuts the sphere in half keeps only the half inside it.
  const auto half = s.SampleSurface({-5.f, -5.f, 0.f}, {5.f, 5.f, 5.f}, 1000, 2);
  ASSERT_EQ(half.size(), 1000u);
  for (const auto& sp : half) EXPECT_GE(sp.p.z(), 0.f);

  // An empty region yields nothing rather than looping.
  EXPECT_TRUE(s.SampleSurface({100.f, 100.f, 100.f}, {101.f, 101.f, 101.f}, 10, 3).empty());
}

TEST(AnalyticSceneTest, DefaultSceneLeavesCorridorFree) {
  const AnalyticScene s = AnalyticScene::Default();
  EXPECT_EQ(s.ground_z, 0.f);
  EXPECT_GE(s.boxes.size(), 3u);
  EXPECT_EQ(s.spheres.size(), 2u);
  EXPECT_EQ(s.cylinders.size(), 2u);
  for (float x = -5.f; x <= 45.f; x += 0.25f) {
    for (float y = -1.99f; y <= 1.99f; y += 0.1f) {
      for (float z = 0.05f; z <= 5.f; z += 0.25f) {
        ASSERT_GT(s.Sdf({x, y, z}), 0.f) << x << " " << y << " " << z;
      }
    }
  }
  for (const Box& b : s.boxes) {
    EXPECT_LE(b.max.y(), 8.f);
    EXPECT_GE(b.min.y(), -8.f);
  }
}

TEST(SimulateScanTest, HitsLieOnSurfaceInSensorFrame) {
  const AnalyticScene s = AnalyticScene::Default();
  const LidarModel lidar;
  Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
  T.linear() = Eigen::AngleAxisf(0.5f, Eigen::Vector3f::UnitZ()).toRotationMatrix() *
               Eigen::AngleAxisf(0.05f, Eigen::Vector3f::UnitX()).toRotationMatrix();
  T.translation() = Eigen::Vector3f(10.f, 0.5f, 1.8f);
  const auto pts = SimulateScan(s, lidar, T, 1);
  ASSERT_GT(pts.size(), 10000u);
  ASSERT_LE(pts.size(), size_t(lidar.beams) * lidar.columns);
  for (const auto& p : pts) {
    ASSERT_LE(p.norm(), lidar.max_range_m + 1e-4f);
    ASSERT_LT(std::abs(s.Sdf(T * p)), 1e-4f) << p.transpose();
  }
  // The lowest ring (-25 deg) sees the ground in every direction from 1.8 m up.
  EXPECT_NEAR(pts.front().z() / pts.front().norm(), std::sin(-25.f * kPi / 180.f), 1e-5f);

  auto start = std::chrono::steady_clock::now();
  const int reps = 20;
  size_t total = 0;
  for (int i = 0; i < reps; ++i) total += SimulateScan(s, lidar, T, i).size();
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count() /
      reps;
  std::printf("SimulateScan 32x720: %.3f ms per scan (%zu hits)\n", ms, total / reps);
  // Generous so that unoptimised and sanitiser builds still pass; the -O2 target is << 50 ms.
  EXPECT_LT(ms, 1000.0);
}

TEST(SimulateScanTest, NoiseChangesRangesByAboutTheStddev) {
  const AnalyticScene s = AnalyticScene::Default();
  LidarModel lidar;
  Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
  T.translation() = Eigen::Vector3f(20.f, 0.f, 1.8f);
  const auto clean = SimulateScan(s, lidar, T, 1);
  lidar.noise_stddev_m = 0.05f;
  const auto noisy = SimulateScan(s, lidar, T, 1);
  ASSERT_EQ(clean.size(), noisy.size());
  double sum = 0.0, sum_sq = 0.0;
  for (size_t i = 0; i < clean.size(); ++i) {
    // Noise acts along the ray only.
    ASSERT_GT(clean[i].normalized().dot(noisy[i].normalized()), 1.f - 1e-5f);
    const double e = double(noisy[i].norm()) - clean[i].norm();
    sum += e;
    sum_sq += e * e;
  }
  const double n = double(clean.size());
  const double mean = sum / n, stddev = std::sqrt(sum_sq / n - mean * mean);
  EXPECT_NEAR(mean, 0.0, 0.003);
  EXPECT_NEAR(stddev, 0.05, 0.003);

  const auto same = SimulateScan(s, lidar, T, 1);
  const auto different = SimulateScan(s, lidar, T, 2);
  EXPECT_EQ(same, noisy);
  EXPECT_NE(different, noisy);
}

TEST(StraightTrajectoryTest, DrivesAlongXWithSmallYawWobble) {
  const auto poses = StraightTrajectory(0.f, 40.f, 41, 1.8f);
  ASSERT_EQ(poses.size(), 41u);
  EXPECT_TRUE(poses.front().translation().isApprox(Eigen::Vector3f(0.f, 0.f, 1.8f)));
  EXPECT_TRUE(poses.back().translation().isApprox(Eigen::Vector3f(40.f, 0.f, 1.8f)));
  float max_yaw = 0.f;
  for (size_t i = 0; i < poses.size(); ++i) {
    const Eigen::Matrix3f R = poses[i].linear();
    ASSERT_TRUE((R.transpose() * R).isIdentity(1e-5f));
    ASSERT_NEAR(R.determinant(), 1.f, 1e-5f);
    // Yaw only: the z axis stays vertical.
    ASSERT_TRUE(R.col(2).isApprox(Eigen::Vector3f::UnitZ(), 1e-6f));
    EXPECT_NEAR(poses[i].translation().x(), float(i), 1e-4f);
    const float yaw = std::atan2(R(1, 0), R(0, 0));
    EXPECT_LE(std::abs(yaw), 5.f * kPi / 180.f);
    max_yaw = std::max(max_yaw, std::abs(yaw));
  }
  EXPECT_GT(max_yaw, 2.f * kPi / 180.f);
  EXPECT_EQ(StraightTrajectory(0.f, 1.f, 1, 1.f).size(), 1u);
  EXPECT_TRUE(StraightTrajectory(0.f, 1.f, 0, 1.f).empty());
}

TEST(EvaluateMeshTest, ExactSphereMeshScoresNearZeroAndOffsetOneScoresOffset) {
  AnalyticScene s;  // keeps the ground, which the region below excludes
  s.spheres = {{{0.f, 0.f, 5.f}, 1.f}};
  const Eigen::Vector3f lo(-2.f, -2.f, 3.5f), hi(2.f, 2.f, 6.5f);
  const Mesh exact = Icosphere({0.f, 0.f, 5.f}, 1.f, 6);
  ASSERT_EQ(exact.faces.size(), 20u * 4096u);

  auto start = std::chrono::steady_clock::now();
  const MeshErrors e = EvaluateMesh(exact, s, lo, hi, 100000, 1);
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  std::printf("EvaluateMesh 100k samples: %.1f ms\n", ms);
  std::printf("exact: accuracy %.5f completeness %.5f chamfer %.5f samples %zu\n", e.accuracy_m,
              e.completeness_m, e.chamfer_l1_m, e.mesh_samples);
  EXPECT_EQ(e.mesh_samples, 100000u);
  EXPECT_LT(e.accuracy_m, 1e-3);
  // Limited by the mesh sample spacing (~1 cm at 100k samples on 12.6 m^2).
  EXPECT_LT(e.completeness_m, 8e-3);
  EXPECT_NEAR(e.chamfer_l1_m, 0.5 * (e.accuracy_m + e.completeness_m), 1e-12);
  EXPECT_LT(ms, 10000.0);

  const Mesh inflated = Icosphere({0.f, 0.f, 5.f}, 1.03f, 6);
  const MeshErrors f = EvaluateMesh(inflated, s, lo, hi, 100000, 1);
  std::printf("offset 3 cm: accuracy %.5f completeness %.5f chamfer %.5f\n", f.accuracy_m,
              f.completeness_m, f.chamfer_l1_m);
  EXPECT_NEAR(f.accuracy_m, 0.03, 1.5e-3);
  EXPECT_NEAR(f.completeness_m, 0.03, 4e-3);
  EXPECT_NEAR(f.chamfer_l1_m, 0.03, 3e-3);

  // A mesh covering only half the object scores much worse on completeness, not accuracy.
  const Eigen::Vector3f upper_lo(-2.f, -2.f, 5.f);
  const MeshErrors g = EvaluateMesh(exact, s, upper_lo, hi, 20000, 2);
  Mesh half = exact;
  half.faces.clear();
  for (const auto& tri : exact.faces) {
    if (exact.vertices[tri[0]][0] > 0.f) half.faces.push_back(tri);
  }
  const MeshErrors h = EvaluateMesh(half, s, upper_lo, hi, 20000, 2);
  EXPECT_LT(h.accuracy_m, 1e-3);
  EXPECT_GT(h.completeness_m, 10.0 * g.completeness_m);
}

TEST(EvaluateMeshTest, EmptyMeshScoresInfinity) {
  const AnalyticScene s = AnalyticScene::Default();
  const MeshErrors e = EvaluateMesh(Mesh{}, s, {0.f, -5.f, -1.f}, {10.f, 5.f, 4.f}, 1000, 1);
  EXPECT_EQ(e.mesh_samples, 0u);
  EXPECT_TRUE(std::isinf(e.accuracy_m));
  EXPECT_TRUE(std::isinf(e.chamfer_l1_m));
}

}  // namespace
}  // namespace rim::testing_support
