// The metric distance field on surfels of known surfaces: exact distances and unit gradients,
// the bound and its flag, region replacement, and byte-exact persistence that refuses damage.
#include "rim/map/distance_field.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <map>
#include <random>
#include <set>

#include "rim/config/config.h"

namespace rim {
namespace {

class DistanceFieldTest : public ::testing::Test {
 protected:
  // Disks of 0.075 m cover a plane sampled on the 0.1 m voxel grid (the diagonal gap is 0.0707 m),
  // so distances to it are exact.
  DistanceFieldTest() : geometry_(TwentyMetreSubmaps()), field_(geometry_, kRadius) {}
  // Sub-maps of 20 × 20 × 6 m, so that the cases below can be written in round numbers: a box of
  // 19.6 × 19.6 × 5.6 m asked, one coarse voxel of 0.4 m more per axis (map_geometry.h).
  static GridConfig TwentyMetreSubmaps() {
    GridConfig g;
    g.half_extent_x_m = g.half_extent_y_m = 9.8f;
    g.z_min_m = -2.8f;
    g.z_max_m = 2.8f;
    return g;
  }
  static constexpr float kRadius = 0.075f;

  // One surfel per voxel column of the plane z = z0 (normal +z) over [x0, x1) × [y0, y1), as
  // extraction gives for a flat floor, sampled at voxel centres in x and y.
  std::vector<Surfel> Floor(const Int3& key, float z0, float x0, float x1, float y0,
                            float y1) const {
    std::vector<Surfel> out;
    const double s = geometry_.leaf_m();
    for (int i = int(std::floor(x0 / s)); (i + 0.5) * s < x1; ++i)
      for (int j = int(std::floor(y0 / s)); (j + 0.5) * s < y1; ++j) {
        const Int3 g(i, j, int(std::floor(z0 / s)));
        if (geometry_.SubmapOfLattice(0, g) != key) continue;
        Surfel sf{{float((i + 0.5) * s), float((j + 0.5) * s), z0}, {0, 0, 1}, 0};
        sf.voxel = field_.VoxelIndex(key, g);
        out.push_back(sf);
      }
    return out;
  }

  void Query(const std::vector<float>& xyz, std::vector<float>* sdf, std::vector<float>* grad,
             std::vector<uint8_t>* saturated, float max_d = 2.f) const {
    const size_t n = xyz.size() / 3;
    sdf->resize(n);
    grad->resize(3 * n);
    saturated->resize(n);
    field_.Query(xyz.data(), n, max_d, sdf->data(), grad->data(), saturated->data());
  }

  MapGeometry geometry_;
  DistanceField field_;
};

TEST_F(DistanceFieldTest, VoxelIndicesRoundTrip) {
  for (const Int3& key : {Int3(0, 0, 0), Int3(-3, 2, -1), Int3(7, -9, 4)}) {
    const Int3 lo = key.cwiseProduct(geometry_.cells(0));
    for (const Int3& d : {Int3(0, 0, 0), Int3(199, 199, 59), Int3(5, 17, 33)})
      EXPECT_EQ(field_.VoxelOf(key, field_.VoxelIndex(key, lo + d)), lo + d);
  }
}

TEST_F(DistanceFieldTest, DistancesToAFloorAreExactWithUnitGradients) {
  const Int3 key(0, 0, 0);
  field_.Replace(key, {}, Floor(key, 0.3f, 1.f, 9.f, 1.f, 9.f));
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> xy(3.f, 7.f), z(-1.5f, 2.2f);
  std::vector<float> xyz;
  for (int i = 0; i < 2000; ++i) xyz.insert(xyz.end(), {xy(rng), xy(rng), z(rng)});
  std::vector<float> sdf, grad;
  std::vector<uint8_t> sat;
  Query(xyz, &sdf, &grad, &sat);
  for (size_t i = 0; i < sdf.size(); ++i) {
    const float truth = xyz[3 * i + 2] - 0.3f;
    if (std::abs(truth) >= 2.f) {
      EXPECT_EQ(sat[i], 1);
      EXPECT_EQ(sdf[i], 2.f);  // saturated reads +bound, whatever side
      EXPECT_EQ(grad[3 * i + 2], 0.f);
      continue;
    }
    EXPECT_EQ(sat[i], 0);
    EXPECT_NEAR(sdf[i], truth, 1e-5f) << "z " << xyz[3 * i + 2];
    // +z on both sides (toward larger values): over a disk, its normal.
    EXPECT_NEAR(grad[3 * i + 2], 1.f, 1e-5f);
    EXPECT_NEAR(grad[3 * i], 0.f, 1e-3f);
    EXPECT_NEAR(grad[3 * i + 1], 0.f, 1e-3f);
  }
}

TEST_F(DistanceFieldTest, BeyondAnEdgeTheGradientPointsAwayFromItAndMatchesFiniteDifferences) {
  // A floor that ends at x = 5: past it, the nearest surface is its edge.
  const Int3 key(0, 0, 0);
  field_.Replace(key, {}, Floor(key, 0.5f, 1.f, 5.f, 1.f, 9.f));
  std::vector<float> xyz;
  for (float x = 5.3f; x < 6.3f; x += 0.1f)
    for (float zz = 0.7f; zz < 1.8f; zz += 0.2f) xyz.insert(xyz.end(), {x, 4.05f, zz});
  std::vector<float> sdf, grad;
  std::vector<uint8_t> sat;
  Query(xyz, &sdf, &grad, &sat);
  const float edge = 4.95f + kRadius;  // last column's centre plus the disk radius
  for (size_t i = 0; i < sdf.size(); ++i) {
    const float dx = xyz[3 * i] - edge, dz = xyz[3 * i + 2] - 0.5f;
    const float truth = std::hypot(dx, dz);
    EXPECT_NEAR(sdf[i], truth, 1e-4f);
    // The rims of the edge's neighbouring disks, nearly as near, turn the gradient a little (by
    // design: it turns smoothly where several disks are about as near).
    EXPECT_NEAR(grad[3 * i], dx / truth, 5e-3f);
    EXPECT_NEAR(grad[3 * i + 2], dz / truth, 5e-3f);
    // Central differences of the field itself.
    const float h = 1e-3f;
    for (int a : {0, 2}) {
      std::vector<float> pm = {xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]};
      std::vector<float> pp = pm;
      pm[a] -= h;
      pp[a] += h;
      std::vector<float> vm, vp, g;
      std::vector<uint8_t> s;
      Query(pm, &vm, &g, &s);
      Query(pp, &vp, &g, &s);
      EXPECT_NEAR((vp[0] - vm[0]) / (2 * h), grad[3 * i + a], 6e-3f);
    }
  }
}

TEST_F(DistanceFieldTest, GapsAtVoxelCornersOfAPlaneReadThePlaneAndItsNormal) {
  // The default disks (0.6 voxel) leave a gap at each corner of a floor's voxels, 0.707 voxel
  // from the four centres around it. The floor runs on there: its distance and its normal, not
  // the distance to the nearest rim (up to 1 cm too far at the floor) and a sideways gradient.
  DistanceField field(geometry_, 0.6f * float(geometry_.leaf_m()));
  const Int3 key(0, 0, 0);
  field.Replace(key, {}, Floor(key, 0.3f, 1.f, 5.f, 1.f, 9.f));
  std::vector<float> xyz, truth;
  std::mt19937 rng(2);
  std::uniform_real_distribution<float> jitter(-0.012f, 0.012f);
  for (int i = 0; i < 300; ++i) {
    // A corner of the voxel grid inside the floor, and a point near it.
    const float cx = 0.1f * float(20 + i % 15), cy = 0.1f * float(20 + (i / 15) % 20);
    const float z = 0.3f + std::array<float, 6>{0.f, 0.001f, -0.004f, 0.01f, 0.03f, 0.08f}[i % 6];
    xyz.insert(xyz.end(), {cx + jitter(rng), cy + jitter(rng), z});
    truth.push_back(z - 0.3f);
  }
  std::vector<float> sdf(truth.size()), grad(3 * truth.size());
  std::vector<uint8_t> sat(truth.size());
  field.Query(xyz.data(), truth.size(), 2.f, sdf.data(), grad.data(), sat.data());
  for (size_t i = 0; i < truth.size(); ++i) {
    EXPECT_NEAR(sdf[i], truth[i], 1e-5f) << xyz[3 * i] << " " << xyz[3 * i + 1];
    EXPECT_NEAR(grad[3 * i + 2], 1.f, 1e-5f) << xyz[3 * i] << " " << xyz[3 * i + 1];
  }

  // Past the floor's end (its last centres at x = 4.95, their rims at 5.01), the edge is still
  // an edge: the distance and direction from the rim, also between two of its disks.
  xyz.clear();
  for (float y : {4.05f, 4.0f, 4.003f})
    for (float x : {5.02f, 5.04f})
      for (float dz : {0.002f, 0.005f, 0.02f}) xyz.insert(xyz.end(), {x, y, 0.3f + dz});
  const size_t n = xyz.size() / 3;
  sdf.resize(n);
  grad.resize(3 * n);
  sat.resize(n);
  field.Query(xyz.data(), n, 2.f, sdf.data(), grad.data(), sat.data());
  for (size_t i = 0; i < n; ++i) {
    EXPECT_GT(sdf[i], xyz[3 * i] - 5.01f - 1e-4f) << xyz[3 * i] << " " << xyz[3 * i + 1];
    EXPECT_GT(grad[3 * i], 0.25f) << xyz[3 * i] << " " << xyz[3 * i + 1] << " " << xyz[3 * i + 2]
                                  << " sdf " << sdf[i] << " g " << grad[3 * i + 2];
  }
}

TEST_F(DistanceFieldTest, TheNearestOfSeveralSubmapsWins) {
  // Two sub-maps side by side (x < 20 m and x >= 20 m) with floors at different heights.
  field_.Replace(Int3(0, 0, 0), {}, Floor(Int3(0, 0, 0), 0.2f, 15.f, 20.f, 1.f, 5.f));
  field_.Replace(Int3(1, 0, 0), {}, Floor(Int3(1, 0, 0), 0.6f, 20.f, 25.f, 1.f, 5.f));
  std::vector<float> sdf, grad;
  std::vector<uint8_t> sat;
  Query({19.95f, 3.05f, 1.f, 20.05f, 3.05f, 1.f, 30.f, 3.f, 1.f}, &sdf, &grad, &sat);
  // Above the lower floor's last column, the higher floor's first disk (0.025 m beyond its rim)
  // is nearer than the floor below.
  EXPECT_NEAR(sdf[0], std::hypot(0.4f, 0.1f - kRadius), 1e-5f);
  EXPECT_NEAR(sdf[1], 0.4f, 1e-5f);
  EXPECT_EQ(sat[2], 1);  // 5 m from both
  EXPECT_EQ(field_.Stats().submaps, 2);
}

// Fresh surfels get the normal of a plane fitted through the surfels of the 3×3×3 voxels around
// them (within their sub-map) where those are planar and agree with the field's normal. Compared
// with a plain reference of that rule (a lookup per neighbour), on a tilted wall cut by the
// sub-map's border, a sloped floor, a ridge and scattered surfels, with the field's normals
// tilted away from the true ones.
TEST_F(DistanceFieldTest, FreshNormalsArePlaneFitsOverTheirVoxelNeighbourhood) {
  const Int3 key(-1, 0, 0);
  const double s = geometry_.leaf_m();
  std::vector<Surfel> surfels;
  std::vector<Vec3f> truth;  // each surfel's true normal
  std::set<uint32_t> taken;
  auto add = [&](const Vec3f& p, const Vec3f& n) {
    const Int3 g(int(std::floor(p.x() / s)), int(std::floor(p.y() / s)),
                 int(std::floor(p.z() / s)));
    if (geometry_.SubmapOfLattice(0, g) != key) return;
    const uint32_t voxel = field_.VoxelIndex(key, g);
    if (!taken.insert(voxel).second) return;
    // The field's normal, tilted about 11° off the truth.
    const Vec3f tilt = (n + 0.2f * n.unitOrthogonal()).normalized();
    surfels.push_back({{p.x(), p.y(), p.z()}, {tilt.x(), tilt.y(), tilt.z()}, voxel});
    truth.push_back(n);
  };
  // A wall x = −0.3 + 0.15 (y − 1) leaning out of the sub-map across its border at x = 0.
  const Vec3f wall_n = Vec3f(1.f, -0.15f, 0.f).normalized();
  for (int j = 10; j < 40; ++j)
    for (int k = 5; k < 25; ++k) {
      const float y = float((j + 0.5) * s), z = float((k + 0.5) * s);
      add(Vec3f(-0.3f + 0.15f * (y - 1.f), y, z), wall_n);
    }
  // A floor z = 0.33 + 0.05 x.
  const Vec3f floor_n = Vec3f(-0.05f, 0.f, 1.f).normalized();
  for (int i = -50; i < -30; ++i)
    for (int j = 40; j < 60; ++j) {
      const float x = float((i + 0.5) * s), y = float((j + 0.5) * s);
      add(Vec3f(x, y, 0.33f + 0.05f * x), floor_n);
    }
  // A ridge z = 1 + 0.5 |x + 8|.
  for (int i = -90; i < -70; ++i)
    for (int j = 10; j < 25; ++j) {
      const float x = float((i + 0.5) * s), y = float((j + 0.5) * s);
      const float side = x < -8.f ? -1.f : 1.f;
      add(Vec3f(x, y, 1.f + 0.5f * std::abs(x + 8.f)), Vec3f(-0.5f * side, 0.f, 1.f).normalized());
    }
  // Scattered surfels with few neighbours.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> ux(-19.9f, -12.f), uy(0.f, 19.9f), uz(0.f, 5.9f);
  for (int i = 0; i < 300; ++i) add(Vec3f(ux(rng), uy(rng), uz(rng)), Vec3f(0.f, 0.f, 1.f));
  ASSERT_GT(surfels.size(), 1300u);

  // The reference: the rule with one lookup per neighbour voxel.
  std::map<uint32_t, size_t> by_voxel;
  for (size_t i = 0; i < surfels.size(); ++i) by_voxel[surfels[i].voxel] = i;
  std::map<uint32_t, Vec3f> expected;
  const Int3 lo = key.cwiseProduct(geometry_.cells(0));
  const Int3 hi = lo + geometry_.cells(0) - Int3::Ones();
  for (const Surfel& x : surfels) {
    const Int3 g = field_.VoxelOf(key, x.voxel);
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    Eigen::Matrix3d second = Eigen::Matrix3d::Zero();
    int count = 0;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const Int3 h = g + Int3(dx, dy, dz);
          if (!IntBox{lo, hi}.Contains(h)) continue;
          auto it = by_voxel.find(field_.VoxelIndex(key, h));
          if (it == by_voxel.end()) continue;
          const Surfel& o = surfels[it->second];
          const Eigen::Vector3d p(o.p[0], o.p[1], o.p[2]);
          mean += p;
          second += p * p.transpose();
          ++count;
        }
    Vec3f n(x.n[0], x.n[1], x.n[2]);
    if (count >= 5) {
      mean /= count;
      const Eigen::Matrix3d cov = second / count - mean * mean.transpose();
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
      eig.computeDirect(cov);
      const Eigen::Vector3d ev = eig.eigenvalues();
      Eigen::Vector3d fit = eig.eigenvectors().col(0);
      const Eigen::Vector3d field = n.cast<double>();
      if (fit.dot(field) < 0) fit = -fit;
      if (ev[0] < 1e-5 && ev[1] > 0.1 * s * s * 0.5 && fit.dot(field) >= 0.7) n = fit.cast<float>();
    }
    expected[x.voxel] = n;
  }

  field_.Replace(key, {}, surfels);
  const auto got = field_.Surfels(key);
  ASSERT_TRUE(got);
  ASSERT_EQ(got->size(), surfels.size());
  std::map<uint32_t, Vec3f> true_normal;
  for (size_t i = 0; i < surfels.size(); ++i) true_normal[surfels[i].voxel] = truth[i];
  int refitted = 0, kept = 0;
  for (const Surfel& x : *got) {
    ASSERT_TRUE(expected.count(x.voxel)) << x.voxel;
    const Vec3f n(x.n[0], x.n[1], x.n[2]), want = expected[x.voxel];
    for (int a = 0; a < 3; ++a) ASSERT_NEAR(n[a], want[a], 1e-6f) << "voxel " << x.voxel;
    // On the planes' flat parts the fit is the true normal; elsewhere the field's stays.
    if (n.dot(true_normal[x.voxel]) > 0.99999f) ++refitted;
    if (n.dot(true_normal[x.voxel]) < 0.99f) ++kept;
  }
  EXPECT_GT(refitted, 1000);
  EXPECT_GT(kept, 300);
}

TEST_F(DistanceFieldTest, ReplaceTouchesOnlyItsRegion) {
  const Int3 key(0, 0, 0);
  field_.Replace(key, {}, Floor(key, 0.3f, 1.f, 9.f, 1.f, 9.f));
  const int64_t before = field_.Stats().surfels;
  // Lift the floor inside x, y in [3, 5) m (voxels 30..49) to 0.8 m.
  const IntBox region{Int3(30, 30, 0), Int3(49, 49, 59)};
  std::vector<Surfel> lifted = Floor(key, 0.8f, 3.01f, 5.f, 3.01f, 5.f);
  ASSERT_EQ(lifted.size(), 400u);
  field_.Replace(key, {region}, lifted);
  EXPECT_EQ(field_.Stats().surfels, before - 400 + 400);
  std::vector<float> sdf, grad;
  std::vector<uint8_t> sat;
  Query({4.f, 4.f, 1.f, 7.f, 7.f, 1.f}, &sdf, &grad, &sat);
  EXPECT_NEAR(sdf[0], 0.2f, 1e-5f);
  EXPECT_NEAR(sdf[1], 0.7f, 1e-5f);
  // Replacing a region with nothing empties it; an emptied sub-map is dropped.
  field_.Replace(key, {IntBox{Int3(0, 0, 0), Int3(199, 199, 59)}}, {});
  EXPECT_EQ(field_.Stats().submaps, 0);
}

TEST_F(DistanceFieldTest, SaveLoadIsByteExactAndDamageIsRefused) {
  field_.Replace(Int3(0, 0, 0), {}, Floor(Int3(0, 0, 0), 0.3f, 1.f, 6.f, 1.f, 6.f));
  field_.Replace(Int3(-1, 0, 0), {}, Floor(Int3(-1, 0, 0), 0.3f, -6.f, -1.f, 1.f, 6.f));
  ByteWriter w;
  field_.Serialize(&w);
  DistanceField loaded(geometry_, kRadius);
  {
    ByteReader r(w.data(), "field");
    ASSERT_TRUE(loaded.Deserialize(&r).ok());
    EXPECT_TRUE(r.ExpectEnd().ok());
  }
  ByteWriter again;
  loaded.Serialize(&again);
  EXPECT_EQ(again.data(), w.data());
  std::vector<float> a(1), b(1), g(3);
  std::vector<uint8_t> s(1);
  const float q[3] = {3.f, 3.f, 1.1f};
  field_.Query(q, 1, 2.f, a.data(), g.data(), s.data());
  loaded.Query(q, 1, 2.f, b.data(), g.data(), s.data());
  EXPECT_EQ(a, b);

  const size_t header = 4 + 8 + 12 + 8;  // radius, count, first key, first surfel count
  auto refused = [&](std::string bytes, const std::string& why) {
    DistanceField target(geometry_, kRadius);
    target.Replace(Int3(2, 2, 0), {}, Floor(Int3(2, 2, 0), 0.3f, 41.f, 42.f, 41.f, 42.f));
    ByteReader r(bytes, "field");
    const absl::Status st = target.Deserialize(&r);
    EXPECT_FALSE(st.ok()) << why;
    EXPECT_EQ(target.Stats().submaps, 1) << why << ": a refused load changed the field";
  };
  refused(w.data().substr(0, w.data().size() / 2), "truncated");
  std::string bad = w.data();
  float nan = std::nanf("");
  std::memcpy(&bad[header + 12], &nan, 4);  // first surfel's normal x
  refused(bad, "non-finite normal");
  bad = w.data();
  const uint32_t huge = 0xFFFFFFF0u;
  std::memcpy(&bad[header + 24], &huge, 4);  // first surfel's voxel
  refused(bad, "voxel out of range");
  bad = w.data();
  const float far = 1e5f;
  std::memcpy(&bad[header], &far, 4);  // first surfel's x, far from its voxel
  refused(bad, "surfel outside its voxel");
  DistanceField other_radius(geometry_, 0.1f);
  ByteReader r(w.data(), "field");
  EXPECT_FALSE(other_radius.Deserialize(&r).ok());
}

// Returns on a wall x = 12.4 (no surfels there), 0.2 m apart as the deferred store keeps them,
// each with its normal toward a sensor down the street.
std::vector<Surfel> Wall(float x0, float y0, float y1, float z0, float z1) {
  std::vector<Surfel> out;
  uint32_t voxel = 0;
  const int ny = int(std::lround((y1 - y0) / 0.2f)), nz = int(std::lround((z1 - z0) / 0.2f));
  for (int i = 0; i < ny; ++i)
    for (int j = 0; j < nz; ++j) {
      Surfel s{{x0, y0 + 0.2f * float(i), z0 + 0.2f * float(j)}, {-0.6f, -0.8f, 0.f}, voxel++};
      out.push_back(s);
    }
  return out;
}

TEST_F(DistanceFieldTest, ReturnsStandForSurfaceTheSurfelsLack) {
  field_.SetReturnsBlendRadius(0.1f);
  field_.Replace(Int3(0, 0, 0), {}, Floor(Int3(0, 0, 0), 0.f, 1.f, 12.f, 1.f, 9.f));
  const Int3 key(0, 0, 0);
  field_.ReplaceReturns(key, Wall(12.4f, 1.f, 9.f, 0.1f, 4.1f));
  EXPECT_EQ(field_.Stats().returns, 40 * 20);
  // Points in front of the wall, 0.3-1.9 m from it and higher above the floor than that: the wall
  // is the nearest surface. Points are 0.2 m apart, so a distance is at most sqrt(d^2 + 0.02) - d
  // too large (0.03 m at 0.3 m), never smaller than the truth, and the gradient is near -x.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> d(0.3f, 1.9f), y(3.f, 7.f);
  std::vector<float> xyz;
  std::vector<float> truth;
  for (int i = 0; i < 500; ++i) {
    const float t = d(rng);
    xyz.insert(xyz.end(), {12.4f - t, y(rng), 2.f});
    truth.push_back(t);
  }
  std::vector<float> sdf, grad;
  std::vector<uint8_t> sat;
  Query(xyz, &sdf, &grad, &sat);
  int within_10deg = 0;
  for (size_t i = 0; i < truth.size(); ++i) {
    EXPECT_EQ(sat[i], 0);
    EXPECT_GE(std::abs(sdf[i]), truth[i] - 1e-5f);
    EXPECT_LE(std::abs(sdf[i]), std::sqrt(truth[i] * truth[i] + 0.02f) + 1e-5f);
    const Vec3f g(&grad[3 * i]);
    EXPECT_NEAR(g.norm(), 1.f, 1e-4f);
    // Oriented toward larger values: away from the wall on the side the sdf's sign gives.
    EXPECT_GT(-g.x() * (sdf[i] < 0 ? -1.f : 1.f), 0.5f);
    if (std::abs(g.x()) >= std::cos(10.f * float(M_PI) / 180.f)) ++within_10deg;
  }
  EXPECT_GE(within_10deg, 400) << "the gradient beside points should blend toward the normal";
  // Near the floor the floor's disks are nearer and decide, as before.
  const float low[3] = {11.f, 5.f, 0.2f};
  float v, g3[3];
  uint8_t s;
  field_.Query(low, 1, 2.f, &v, g3, &s);
  EXPECT_NEAR(v, 0.2f, 1e-5f);
  EXPECT_NEAR(g3[2], 1.f, 1e-5f);

  // Persistence: byte-exact, and the same answers; damage is refused and changes nothing.
  ByteWriter w;
  field_.SerializeReturns(&w);
  DistanceField loaded(geometry_, kRadius);
  loaded.SetReturnsBlendRadius(0.1f);
  {
    ByteReader r(w.data(), "returns");
    ASSERT_TRUE(loaded.DeserializeReturns(&r).ok());
    EXPECT_TRUE(r.ExpectEnd().ok());
  }
  ByteWriter again;
  loaded.SerializeReturns(&again);
  EXPECT_EQ(again.data(), w.data());
  const float q[3] = {11.5f, 5.03f, 2.01f};
  float a1, a2, ga[3], gb[3];
  field_.Query(q, 1, 2.f, &a1, ga, &s);
  loaded.Query(q, 1, 2.f, &a2, gb, &s);
  EXPECT_NEAR(a1, 0.9f, 0.01f);
  EXPECT_EQ(a1, a2);
  EXPECT_EQ(std::vector<float>(ga, ga + 3), std::vector<float>(gb, gb + 3));
  const size_t first = 8 + 12 + 8;  // count, first key, first count
  for (const auto& [offset, why] : std::vector<std::pair<size_t, const char*>>{
           {first + 12, "a non-finite normal"}, {first + 4, "a non-finite position"}}) {
    std::string bad = w.data();
    const float nan = std::nanf("");
    std::memcpy(&bad[offset], &nan, 4);
    ByteReader r(bad, "returns");
    EXPECT_FALSE(loaded.DeserializeReturns(&r).ok()) << why;
    EXPECT_EQ(loaded.Stats().returns, 800) << why << ": a refused load changed the field";
  }
  {
    std::string bad = w.data();
    const uint32_t zero = 0;
    std::memcpy(&bad[first + 28 + 24], &zero, 4);  // the second return's voxel, out of order
    ByteReader r(bad, "returns");
    EXPECT_FALSE(loaded.DeserializeReturns(&r).ok());
    ByteReader t(w.data().substr(0, w.data().size() / 2), "returns");
    EXPECT_FALSE(loaded.DeserializeReturns(&t).ok());
  }
  // Replacing with none removes them.
  field_.ReplaceReturns(key, {});
  EXPECT_EQ(field_.Stats().returns, 0);
}

// A query for distances alone searches a tighter bound than one with the gradient (no ring of
// disks to blend): it must read the same distances, signs and saturation flags, bit for bit, over
// floors, a box's edges and corners, scattered tilted surfels, returns, and points beside and far
// from all of them.
TEST_F(DistanceFieldTest, DistancesAloneEqualThoseReadWithTheGradient) {
  field_.SetReturnsBlendRadius(0.1f);
  const Int3 key(0, 0, 0);
  std::vector<Surfel> surfels = Floor(key, 0.f, 1.f, 12.f, 1.f, 9.f);
  for (const Surfel& s : Floor(key, 0.8f, 4.f, 6.f, 3.f, 5.f)) surfels.push_back(s);  // a box top
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> ux(1.f, 12.f), uy(1.f, 9.f), uz(0.f, 2.f), un(-1.f, 1.f);
  for (int i = 0; i < 300; ++i) {
    const Vec3f n = Vec3f(un(rng), un(rng), un(rng)).normalized();
    const float p[3] = {ux(rng), uy(rng), uz(rng)};
    const double leaf = geometry_.leaf_m();
    const Int3 g(int(std::floor(p[0] / leaf)), int(std::floor(p[1] / leaf)),
                 int(std::floor(p[2] / leaf)));
    surfels.push_back({{p[0], p[1], p[2]}, {n.x(), n.y(), n.z()}, field_.VoxelIndex(key, g)});
  }
  std::sort(surfels.begin(), surfels.end(),
            [](const Surfel& a, const Surfel& b) { return a.voxel < b.voxel; });
  field_.Replace(key, {}, surfels);
  field_.ReplaceReturns(key, Wall(12.4f, 1.f, 9.f, 0.1f, 4.1f));
  std::uniform_real_distribution<float> qx(-1.f, 15.f), qy(-1.f, 11.f), qz(-1.f, 4.f);
  std::vector<float> xyz;
  std::vector<uint8_t> with_returns;
  for (int i = 0; i < 20000; ++i) {
    xyz.insert(xyz.end(), {qx(rng), qy(rng), qz(rng)});
    with_returns.push_back(uint8_t(i % 3 != 0));
  }
  const size_t n = xyz.size() / 3;
  for (float max_d : {2.f, 0.5f}) {
    std::vector<float> with_g(n), alone(n), grad(3 * n);
    std::vector<uint8_t> sat_g(n), sat_alone(n);
    field_.Query(xyz.data(), n, max_d, with_g.data(), grad.data(), sat_g.data(),
                 with_returns.data());
    field_.Query(xyz.data(), n, max_d, alone.data(), nullptr, sat_alone.data(),
                 with_returns.data());
    int differ = 0, saturated = 0;
    for (size_t i = 0; i < n; ++i) {
      differ += with_g[i] != alone[i] || sat_g[i] != sat_alone[i];
      saturated += sat_alone[i];
    }
    EXPECT_EQ(differ, 0) << "max distance " << max_d;
    // Both kinds of point are there: some read a surface, some the bound.
    EXPECT_GT(saturated, 100);
    EXPECT_LT(saturated, int(n) - 100);
  }
}

TEST(QueryConfigTest, BadMaxDistanceIsRefusedByName) {
  for (const char* bad :
       {"query.max_distance_m=0", "query.max_distance_m=-1", "query.max_distance_m=nan",
        "query.max_distance_m=inf", "query.max_distance_m=1000"}) {
    MapperConfig c;
    const absl::Status s = ApplyOverrides({bad}, &c);
    ASSERT_FALSE(s.ok()) << bad;
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(std::string(s.message()).find("query.max_distance_m"), std::string::npos) << s;
  }
  MapperConfig c;
  EXPECT_TRUE(ApplyOverrides({"query.max_distance_m=0.5"}, &c).ok());
  EXPECT_FALSE(ApplyOverrides({"query.refresh_frames=0"}, &c).ok());
  EXPECT_FALSE(ApplyOverrides({"query.surfel_radius_voxels=0.1"}, &c).ok());
}

}  // namespace
}  // namespace rim
