// Unit tests of the multi-resolution trilinear encoding (§3.1 "Decoding a point"): EncodeLocal
// against a direct reference, the sparse feature-gradient scatter against finite differences, and
// FeatureReader (local map + sub-map store) against EncodeLocal, finite differences and a
// reference world.
#include "rim/model/encoder.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <random>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "rim/base/row8.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/map/map_geometry.h"
#include "rim/map/submap_store.h"
#include "rim/train/trainer.h"

namespace rim {
namespace {

// maicity (s = 0.1 m, L = 3, D = 8) shrunk to a ±2 m × ±2 m × [−1.2, 1.2] m box: 10 × 10 × 6 coarse
// voxels of 0.4 m, small enough to fill and re-encode many times.
MapperConfig SmallConfig() {
  absl::StatusOr<MapperConfig> c = MakePreset("maicity");
  EXPECT_TRUE(c.ok()) << c.status();
  absl::Status s = ApplyOverrides(
      {"grid.half_extent_x_m=2", "grid.half_extent_y_m=2", "grid.z_min_m=-1.2", "grid.z_max_m=1.2"},
      &*c);
  EXPECT_TRUE(s.ok()) << s;
  return *c;
}

bool LoadNothing(int, const Int3&, float*, uint8_t*) { return false; }

// Places the box at `coarse_origin` and fills every level's features with Uniform(−1, 1).
void PlaceAndFill(LocalMap* map, const Int3& coarse_origin, uint32_t seed) {
  map->MoveTo(coarse_origin, LocalMap::SaveFn(), LoadNothing);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (int l = 0; l < map->geometry().levels(); ++l)
    for (int64_t s = 0; s < map->level(l).slots(); ++s)
      for (int d = 0; d < map->geometry().feature_dim(); ++d) map->level(l).features(s)[d] = u(rng);
}

// n points uniformly inside the box, kept a millimetre away from its faces.
std::vector<float> RandomPointsInBox(const LocalMap& map, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Vec3d lo = map.min_m() + Vec3d::Constant(1e-3);
  const Vec3d span = map.max_m() - map.min_m() - Vec3d::Constant(2e-3);
  std::vector<float> xyz;
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) xyz.push_back(float(lo[a] + u(rng) * span[a]));
  return xyz;
}

// One trilinear corner of a point at a level: world lattice index and weight.
struct Corner {
  Int3 g;
  double w;
};

// The 8 corners g = floor(p / h) + c, c ∈ {0,1}³, with weights Π (c ? t : 1 − t), in double.
std::vector<Corner> ReferenceCorners(const Vec3d& p, double h) {
  Int3 base;
  Vec3d t;
  for (int a = 0; a < 3; ++a) {
    const double u = p[a] / h;
    base[a] = int(std::floor(u));
    t[a] = u - std::floor(u);
  }
  std::vector<Corner> corners;
  for (int cx = 0; cx < 2; ++cx)
    for (int cy = 0; cy < 2; ++cy)
      for (int cz = 0; cz < 2; ++cz) {
        const double w =
            (cx ? t.x() : 1 - t.x()) * (cy ? t.y() : 1 - t.y()) * (cz ? t.z() : 1 - t.z());
        corners.push_back({base + Int3(cx, cy, cz), w});
      }
  return corners;
}

// Reference encoding of one point against the live local map (all corners must be in the box).
std::vector<double> ReferenceEncode(const LocalMap& map, const Vec3d& p) {
  const MapGeometry& geo = map.geometry();
  const int L = geo.levels(), D = geo.feature_dim();
  std::vector<double> out(size_t(L) * D, 0.0);
  for (int l = 0; l < L; ++l) {
    for (const Corner& c : ReferenceCorners(p, geo.voxel_m(l))) {
      EXPECT_TRUE(map.InBox(l, c.g)) << "level " << l << " corner " << c.g.transpose();
      const float* f = map.level(l).features(map.Slot(l, c.g));
      for (int d = 0; d < D; ++d) out[size_t(l) * D + d] += c.w * f[d];
    }
  }
  return out;
}

Vec3d PointAt(const std::vector<float>& xyz, int i) {
  return Vec3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
}

class EncoderTest : public ::testing::Test {
 protected:
  EncoderTest() : config_(SmallConfig()), geo_(config_.grid), map_(geo_) {}

  // Encodes the points of `xyz` and scatters an upstream gradient drawn from Uniform(−1, 1)
  // (encoding_dim values per point, returned) as a new iteration's sparse feature gradient.
  std::vector<float> EncodeAndScatter(const std::vector<float>& xyz, std::mt19937* rng,
                                      LocalEncoding* enc, std::vector<float>* features,
                                      SparseGradient* sg) {
    const int n = int(xyz.size() / 3);
    std::uniform_real_distribution<float> u(-1.f, 1.f);
    std::vector<float> upstream(size_t(n) * geo_.encoding_dim());
    for (float& g : upstream) g = u(*rng);
    features->assign(size_t(n) * geo_.encoding_dim(), 0.f);
    EncodeLocal(map_, xyz.data(), n, enc, features->data());
    sg->Reset(map_);
    sg->BeginIteration(&map_);
    sg->Scatter(&map_, *enc, upstream.data());
    return upstream;
  }

  MapperConfig config_;
  MapGeometry geo_;
  LocalMap map_;
};

TEST_F(EncoderTest, GeometryIsTheSmallBox) {
  EXPECT_EQ(geo_.levels(), 3);
  EXPECT_EQ(geo_.feature_dim(), 8);
  EXPECT_EQ(geo_.cells(2), Int3(11, 11, 7));  // one coarse voxel more than asked per axis
  EXPECT_EQ(geo_.cells(0), Int3(44, 44, 28));
}

TEST_F(EncoderTest, EncodeLocalMatchesDirectReference) {
  // A negative origin makes every level's ring buffer wrap inside the box (e.g. level 0 x spans
  // lattice −12..32, slots 33..44 then 0..32), so PosMod and the upper-corner wrap are exercised.
  PlaceAndFill(&map_, Int3(-3, 2, -1), 1);
  const int n = 500, F = geo_.encoding_dim();
  const std::vector<float> xyz = RandomPointsInBox(map_, n, 2);
  LocalEncoding enc;
  std::vector<float> features(size_t(n) * F, -99.f);
  EncodeLocal(map_, xyz.data(), n, &enc, features.data());
  ASSERT_EQ(enc.points, n);
  ASSERT_EQ(enc.slots.size(), size_t(n) * geo_.levels() * 8);
  ASSERT_EQ(enc.weights.size(), enc.slots.size());
  for (int i = 0; i < n; ++i) {
    const std::vector<double> ref = ReferenceEncode(map_, PointAt(xyz, i));
    for (int k = 0; k < F; ++k)
      ASSERT_NEAR(features[size_t(i) * F + k], ref[k], 1e-6) << "point " << i << " feature " << k;
    // The recorded slots/weights are those of the reference corners (same c order: x major).
    for (int l = 0; l < geo_.levels(); ++l) {
      const std::vector<Corner> corners = ReferenceCorners(PointAt(xyz, i), geo_.voxel_m(l));
      double wsum = 0;
      for (int c = 0; c < 8; ++c) {
        const size_t idx = (size_t(i) * geo_.levels() + l) * 8 + c;
        EXPECT_EQ(enc.slots[idx], map_.Slot(l, corners[c].g));
        EXPECT_NEAR(enc.weights[idx], corners[c].w, 1e-6);
        wsum += enc.weights[idx];
      }
      EXPECT_NEAR(wsum, 1.0, 1e-6);
    }
  }
}

TEST_F(EncoderTest, EncodeLocalAtLatticePointReturnsThatPointsFeatures) {
  PlaceAndFill(&map_, Int3(1, -2, 0), 3);
  const int D = geo_.feature_dim(), F = geo_.encoding_dim();
  // A leaf lattice point that is also a lattice point of every level (a coarse corner).
  const Int3 gc = map_.coarse_origin() + Int3(3, 4, 2);
  const Vec3d p = gc.cast<double>() * geo_.voxel_m(2);
  const float xyz[3] = {float(p.x()), float(p.y()), float(p.z())};
  LocalEncoding enc;
  std::vector<float> features(F);
  EncodeLocal(map_, xyz, 1, &enc, features.data());
  for (int l = 0; l < geo_.levels(); ++l) {
    // float(p)/h may land a hair below the lattice point; either way the value is the point's.
    const Int3 g = gc * geo_.scale_to_coarse(l);
    const float* f = map_.level(l).features(map_.Slot(l, g));
    for (int d = 0; d < D; ++d) EXPECT_NEAR(features[size_t(l) * D + d], f[d], 1e-5);
  }
}

TEST_F(EncoderTest, SparseGradientMatchesReferenceAndFiniteDifferences) {
  PlaceAndFill(&map_, Int3(-3, 2, -1), 4);
  const int n = 20, L = geo_.levels(), D = geo_.feature_dim(), F = geo_.encoding_dim();
  const std::vector<float> xyz = RandomPointsInBox(map_, n, 5);
  std::mt19937 rng(6);
  LocalEncoding enc;
  std::vector<float> features;
  SparseGradient sg;
  const std::vector<float> upstream = EncodeAndScatter(xyz, &rng, &enc, &features, &sg);

  // d/d feature[l][slot][d] of Σ upstream · features = Σ_{points, corners at slot} w · upstream.
  for (int l = 0; l < L; ++l) {
    std::map<int64_t, std::vector<double>> ref;
    for (int i = 0; i < n; ++i)
      for (const Corner& c : ReferenceCorners(PointAt(xyz, i), geo_.voxel_m(l))) {
        std::vector<double>& row = ref[map_.Slot(l, c.g)];
        row.resize(D, 0.0);
        for (int d = 0; d < D; ++d) row[d] += c.w * upstream[size_t(i) * F + size_t(l) * D + d];
      }
    SparseGradient::Level& lv = sg.level(l);
    ASSERT_GE(lv.grad.size(), lv.touched.size() * D);
    const std::set<int64_t> unique(lv.touched.begin(), lv.touched.end());
    EXPECT_EQ(unique.size(), lv.touched.size()) << "level " << l << ": duplicate rows";
    EXPECT_EQ(lv.touched.size(), ref.size()) << "level " << l;
    for (size_t r = 0; r < lv.touched.size(); ++r) {
      const int64_t slot = lv.touched[r];
      auto it = ref.find(slot);
      ASSERT_NE(it, ref.end()) << "level " << l << ": slot " << slot << " touched by no point";
      EXPECT_EQ(sg.RowOf(map_, l, slot), int32_t(r));
      for (int d = 0; d < D; ++d) EXPECT_NEAR(lv.grad[r * D + d], it->second[d], 1e-5);
    }
  }

  // Finite differences of the scalar loss Σ upstream · features. It is linear in the features,
  // so a power-of-two step (exact perturbation) gives the derivative up to float rounding of the
  // few features that change: |error| ≲ n·8·2⁻²⁴ / (2·0.25) ≪ 1e-5.
  auto loss = [&]() {
    LocalEncoding e;
    std::vector<float> f(size_t(n) * F);
    EncodeLocal(map_, xyz.data(), n, &e, f.data());
    double s = 0;
    for (size_t k = 0; k < f.size(); ++k) s += double(upstream[k]) * f[k];
    return s;
  };
  const float step = 0.25f;
  for (int l = 0; l < L; ++l) {
    SparseGradient::Level& lv = sg.level(l);
    const std::set<int64_t> touched(lv.touched.begin(), lv.touched.end());
    std::vector<int64_t> probe;
    for (size_t r = 0; r < lv.touched.size(); r += std::max<size_t>(1, lv.touched.size() / 6))
      probe.push_back(lv.touched[r]);
    // Untouched slots: their finite difference must be zero.
    const int64_t slots = map_.level(l).slots();
    for (int64_t s = 0, found = 0; s < slots && found < 3; s += 97)
      if (!touched.count(s)) probe.push_back(s), ++found;
    for (int64_t slot : probe) {
      const int d = int(slot % D);
      float& f = map_.level(l).features(slot)[d];
      const float f0 = f;
      f = f0 + step;
      const double lp = loss();
      f = f0 - step;
      const double lm = loss();
      f = f0;
      const double fd = (lp - lm) / (2.0 * step);
      double analytic = 0;
      if (touched.count(slot)) analytic = lv.grad[size_t(sg.RowOf(map_, l, slot)) * D + d];
      EXPECT_NEAR(analytic, fd, 1e-5) << "level " << l << " slot " << slot << " d " << d;
    }
  }

  // A new iteration forgets the previous rows: only the slots of the new batch appear, once.
  const std::vector<float> xyz2 = RandomPointsInBox(map_, 1, 7);
  EncodeLocal(map_, xyz2.data(), 1, &enc, features.data());
  sg.BeginIteration(&map_);
  sg.Scatter(&map_, enc, upstream.data());
  for (int l = 0; l < L; ++l) {
    std::set<int64_t> expect;
    for (const Corner& c : ReferenceCorners(PointAt(xyz2, 0), geo_.voxel_m(l)))
      expect.insert(map_.Slot(l, c.g));
    const std::set<int64_t> got(sg.level(l).touched.begin(), sg.level(l).touched.end());
    EXPECT_EQ(got, expect) << "level " << l;
    EXPECT_EQ(sg.level(l).touched.size(), 8u);
  }
}

// The trainer's lazy Adam pass over the touched rows (vectorised for D = 8) against the plain
// per-element AdamUpdateRow, bit for bit, from non-zero moments and mixed step counts; rows that
// no point touched do not move.
TEST_F(EncoderTest, TouchedRowsUpdateIsThePlainAdamRowBitForBit) {
  PlaceAndFill(&map_, Int3(-3, 2, -1), 12);
  const int n = 300, L = geo_.levels(), D = geo_.feature_dim(), F = geo_.encoding_dim();
  std::mt19937 rng(13);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::uniform_int_distribution<int> steps(0, 40);
  for (int l = 0; l < L; ++l) {
    LocalMap::Level& lv = map_.level(l);
    for (int64_t s = 0; s < lv.slots(); ++s) {
      for (int d = 0; d < D; ++d) {
        lv.adam_m(s)[d] = 1e-2f * u(rng);
        lv.adam_v(s)[d] = 1e-4f * std::abs(u(rng));
      }
      lv.adam_steps(s) = steps(rng);
    }
  }
  const std::vector<float> xyz = RandomPointsInBox(map_, n, 14);
  LocalEncoding enc;
  std::vector<float> features;
  SparseGradient sg;
  EncodeAndScatter(xyz, &rng, &enc, &features, &sg);

  const AdamHyper h{1e-2f, 0.9f, 0.999f, 1e-15f};
  const AdamBiasTable bias(h);
  for (int l = 0; l < L; ++l) {
    LocalMap::Level& lv = map_.level(l);
    const std::vector<float> f0 = lv.FeatureCopy();
    std::vector<float> m0(size_t(lv.slots()) * D), v0(m0.size());
    std::vector<int32_t> t0(size_t(lv.slots()));
    for (int64_t s = 0; s < lv.slots(); ++s) {
      std::copy_n(lv.adam_m(s), D, &m0[size_t(s) * D]);
      std::copy_n(lv.adam_v(s), D, &v0[size_t(s) * D]);
      t0[size_t(s)] = lv.adam_steps(s);
    }
    const SparseGradient::Level& g = sg.level(l);
    ASSERT_GT(g.touched.size(), 8u);
    // Two ranges, as the trainer's chunks split them.
    const size_t mid = g.touched.size() / 3;
    UpdateTouchedRows(h, bias, g, 0, mid, &lv);
    UpdateTouchedRows(h, bias, g, mid, g.touched.size(), &lv);

    std::vector<float> f1 = f0, m1 = m0, v1 = v0;
    std::vector<int32_t> t1 = t0;
    for (size_t r = 0; r < g.touched.size(); ++r) {
      const size_t s = size_t(g.touched[r]);
      float step_size, inv_sqrt_bc2;
      bias.Get(++t1[s], &step_size, &inv_sqrt_bc2);
      AdamUpdateRow(h, step_size, inv_sqrt_bc2, D, &g.grad[r * D], &f1[s * D], &m1[s * D],
                    &v1[s * D]);
    }
    const std::vector<float> f2 = lv.FeatureCopy();
    size_t diff = 0;
    for (int64_t s = 0; s < lv.slots(); ++s) {
      const size_t o = size_t(s) * D;
      if (std::memcmp(&f2[o], &f1[o], D * sizeof(float)) != 0 ||
          std::memcmp(lv.adam_m(s), &m1[o], D * sizeof(float)) != 0 ||
          std::memcmp(lv.adam_v(s), &v1[o], D * sizeof(float)) != 0 ||
          lv.adam_steps(s) != t1[size_t(s)])
        ++diff;
    }
    EXPECT_EQ(diff, 0u) << "level " << l << ": slots that differ from the plain Adam row";
    // The update did move the touched rows.
    const size_t s0 = size_t(g.touched[0]) * D;
    EXPECT_NE(std::memcmp(&f2[s0], &f0[s0], D * sizeof(float)), 0) << "level " << l;
  }
}

TEST_F(EncoderTest, FeatureReaderEncodeEqualsEncodeLocalInsideTheBox) {
  PlaceAndFill(&map_, Int3(-3, 2, -1), 8);
  SubmapStore store(geo_, config_.submap);
  FeatureReader reader(map_, store);
  const int n = 200, F = geo_.encoding_dim();
  const std::vector<float> xyz = RandomPointsInBox(map_, n, 9);
  LocalEncoding enc;
  std::vector<float> local(size_t(n) * F);
  EncodeLocal(map_, xyz.data(), n, &enc, local.data());
  std::vector<float> f(F), jac(size_t(F) * 3);
  for (int i = 0; i < n; ++i) {
    reader.Encode(PointAt(xyz, i), f.data(), jac.data());
    for (int k = 0; k < F; ++k) ASSERT_NEAR(f[k], local[size_t(i) * F + k], 1e-6) << i << " " << k;
    // Without a jacobian the features are the same.
    std::vector<float> f2(F);
    reader.Encode(PointAt(xyz, i), f2.data(), nullptr);
    EXPECT_EQ(f, f2);
  }
}

TEST_F(EncoderTest, FeatureReaderJacobianMatchesFiniteDifferences) {
  PlaceAndFill(&map_, Int3(-3, 2, -1), 10);
  SubmapStore store(geo_, config_.submap);
  FeatureReader reader(map_, store);
  const int F = geo_.encoding_dim();
  const double step = 1e-4;  // metres
  // Within one voxel of every level, each feature is linear along each axis (trilinear), so the
  // central difference is exact in real arithmetic; only rounding remains. The features are
  // float: the weights carry ≈ 2⁻²⁴ relative error and the 8 corner values are ≤ 1, so a feature
  // is off by ≲ 8·2·6e-8 ≈ 1e-6, and the difference quotient by ≲ 2·1e-6 / (2·1e-4) = 1e-2 in the
  // worst case (typically ~1e-3). Jacobian entries are up to 2/h = 20 per metre, so 1e-2 absolute
  // is still a 0.05 % check that any sign, 1/h factor or axis mix-up would fail by orders.
  const double tol = 1e-2;
  const std::vector<float> raw = RandomPointsInBox(map_, 400, 11);
  int checked = 0;
  std::vector<float> f(F), jac(size_t(F) * 3), fp(F), fm(F);
  for (int i = 0; i < 400 && checked < 60; ++i) {
    const Vec3d p = PointAt(raw, i);
    // Keep away from voxel faces of every level, so that p ± step stays in the same voxel.
    bool away = true;
    for (int l = 0; l < geo_.levels(); ++l)
      for (int a = 0; a < 3; ++a) {
        const double t = p[a] / geo_.voxel_m(l) - std::floor(p[a] / geo_.voxel_m(l));
        away = away && t > 0.02 && t < 0.98;
      }
    if (!away) continue;
    ++checked;
    reader.Encode(p, f.data(), jac.data());
    for (int a = 0; a < 3; ++a) {
      Vec3d dp = Vec3d::Zero();
      dp[a] = step;
      reader.Encode(p + dp, fp.data(), nullptr);
      reader.Encode(p - dp, fm.data(), nullptr);
      for (int k = 0; k < F; ++k) {
        const double fd = (double(fp[k]) - fm[k]) / (2 * step);
        ASSERT_NEAR(jac[size_t(k) * 3 + a], fd, tol)
            << "point " << i << " feature " << k << " axis " << a;
      }
    }
  }
  EXPECT_GE(checked, 30);
}

TEST_F(EncoderTest, FeatureReaderJacobianMatchesReferenceDerivative) {
  // The exact derivative of the reference interpolation, in double: a tight check of the
  // jacobian everywhere, faces included.
  PlaceAndFill(&map_, Int3(0, 0, 0), 12);
  SubmapStore store(geo_, config_.submap);
  FeatureReader reader(map_, store);
  const int D = geo_.feature_dim(), F = geo_.encoding_dim();
  const std::vector<float> raw = RandomPointsInBox(map_, 100, 13);
  std::vector<float> f(F), jac(size_t(F) * 3);
  for (int i = 0; i < 100; ++i) {
    const Vec3d p = PointAt(raw, i);
    reader.Encode(p, f.data(), jac.data());
    for (int l = 0; l < geo_.levels(); ++l) {
      const double h = geo_.voxel_m(l);
      const Int3 base(int(std::floor(p.x() / h)), int(std::floor(p.y() / h)),
                      int(std::floor(p.z() / h)));
      const Vec3d t = p / h - base.cast<double>();
      std::vector<double> ref(size_t(D) * 3, 0.0);
      for (int c = 0; c < 8; ++c) {
        const Int3 cc(c >> 2 & 1, c >> 1 & 1, c & 1);
        const float* feat = map_.level(l).features(map_.Slot(l, base + cc));
        Vec3d fac, dfac;
        for (int a = 0; a < 3; ++a) {
          fac[a] = cc[a] ? t[a] : 1 - t[a];
          dfac[a] = (cc[a] ? 1.0 : -1.0) / h;
        }
        const Vec3d dw(dfac.x() * fac.y() * fac.z(), fac.x() * dfac.y() * fac.z(),
                       fac.x() * fac.y() * dfac.z());
        for (int d = 0; d < D; ++d)
          for (int a = 0; a < 3; ++a) ref[size_t(d) * 3 + a] += dw[a] * feat[d];
      }
      // Each entry sums 8 float terms of size ≤ 1/h (|feature| ≤ 1): rounding ≲ 8·4·2⁻²⁴/h.
      for (int k = 0; k < D * 3; ++k)
        ASSERT_NEAR(jac[size_t(l) * D * 3 + k], ref[k], 2e-6 / h)
            << "point " << i << " level " << l << " entry " << k;
    }
  }
}

TEST_F(EncoderTest, FeatureReaderReadsTheStoreOutsideTheBoxAndZerosWhereUnknown) {
  // Box at coarse origin 0: [0, 4) × [0, 4) × [0, 2.4) m.
  PlaceAndFill(&map_, Int3(0, 0, 0), 14);
  for (int64_t s = 0; s < map_.level(0).slots(); ++s) map_.level(0).flags(s) = 0;
  const int L = geo_.levels(), D = geo_.feature_dim(), F = geo_.encoding_dim();
  SubmapStore store(geo_, config_.submap);

  // A reference world of lattice points outside the box around the query region, written to the
  // store; every 5th point (by index sum) is left unknown and must read as zeros.
  const Vec3d q_lo(3.7, 1.0, 0.5), q_hi(5.1, 2.3, 1.5);
  std::map<std::tuple<int, int, int, int>, std::vector<float>> world;
  std::map<std::tuple<int, int, int>, uint8_t> world_observed;
  std::mt19937 rng(15);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (int l = 0; l < L; ++l) {
    const double h = geo_.voxel_m(l);
    SlabBatch batch;
    batch.level = l;
    for (int x = int(std::floor(q_lo.x() / h)); x <= int(std::floor(q_hi.x() / h)) + 1; ++x)
      for (int y = int(std::floor(q_lo.y() / h)); y <= int(std::floor(q_hi.y() / h)) + 1; ++y)
        for (int z = int(std::floor(q_lo.z() / h)); z <= int(std::floor(q_hi.z() / h)) + 1; ++z) {
          const Int3 g(x, y, z);
          if (map_.InBox(l, g) || (x + y + z) % 5 == 0) continue;
          std::vector<float> f(D);
          for (float& v : f) v = u(rng);
          batch.points.push_back(g);
          batch.features.insert(batch.features.end(), f.begin(), f.end());
          // The store keeps 8-bit rows: reads give the written row rounded (RoundRow8).
          RoundRow8(f.data(), D);
          world[{l, x, y, z}] = f;
          if (l == 0) {
            const uint8_t obs = uint8_t(rng() & 1);
            batch.observed.push_back(obs);
            world_observed[{x, y, z}] = obs;
          }
        }
    ASSERT_FALSE(batch.points.empty());
    store.Write(batch);
  }
  // Mark a few in-box leaf voxels observed: inside the box the map's flags answer.
  const Int3 obs_in(39, 15, 8), unobs_in(38, 15, 8);
  map_.level(0).flags(map_.Slot(0, obs_in)) = LocalMap::kObserved | LocalMap::kHasData;

  auto lookup = [&](int l, const Int3& g) -> std::vector<float> {
    if (map_.InBox(l, g)) {
      const float* f = map_.level(l).features(map_.Slot(l, g));
      return std::vector<float>(f, f + D);
    }
    auto it = world.find({l, g.x(), g.y(), g.z()});
    return it == world.end() ? std::vector<float>(D, 0.f) : it->second;
  };

  FeatureReader reader(map_, store);
  // Get: per lattice point.
  int unknown = 0, stored = 0;
  for (int l = 0; l < L; ++l) {
    const double h = geo_.voxel_m(l);
    for (int x = int(std::floor(q_lo.x() / h)) - 1; x <= int(std::floor(q_hi.x() / h)) + 2; ++x)
      for (int y = int(std::floor(q_lo.y() / h)); y <= int(std::floor(q_hi.y() / h)) + 1; ++y)
        for (int z = int(std::floor(q_lo.z() / h)); z <= int(std::floor(q_hi.z() / h)) + 1; ++z) {
          const Int3 g(x, y, z);
          const std::vector<float> ref = lookup(l, g);
          const float* got = reader.Get(l, g);
          for (int d = 0; d < D; ++d) ASSERT_EQ(got[d], ref[d]) << l << " " << g.transpose();
          if (!map_.InBox(l, g)) (world.count({l, x, y, z}) ? stored : unknown)++;
        }
  }
  EXPECT_GT(stored, 100);
  EXPECT_GT(unknown, 20);

  // Observed: the store's mark outside the box, false where unknown, the map's flag inside.
  int observed_outside = 0;
  for (const auto& [key, obs] : world_observed) {
    const Int3 g(std::get<0>(key), std::get<1>(key), std::get<2>(key));
    EXPECT_EQ(reader.Observed(g), obs != 0) << g.transpose();
    observed_outside += obs;
  }
  EXPECT_GT(observed_outside, 0);
  EXPECT_FALSE(reader.Observed(Int3(45, 15, 5)));  // (45+15+5) % 5 == 0: unknown
  EXPECT_TRUE(reader.Observed(obs_in));
  EXPECT_FALSE(reader.Observed(unobs_in));

  // Encode: points in the query region, some straddling the box face x = 4 m (corners from both
  // the map and the store), compared with the reference interpolation over the lookup.
  std::uniform_real_distribution<double> ux(q_lo.x(), q_hi.x()), uy(q_lo.y(), q_hi.y()),
      uz(q_lo.z(), q_hi.z());
  int straddling = 0;
  std::vector<float> f(F), f_again(F), jac(size_t(F) * 3);
  for (int i = 0; i < 300; ++i) {
    const Vec3d p(ux(rng), uy(rng), uz(rng));
    reader.Encode(p, f.data(), jac.data());
    bool in = false, out = false;
    for (int l = 0; l < L; ++l) {
      std::vector<double> ref(D, 0.0);
      for (const Corner& c : ReferenceCorners(p, geo_.voxel_m(l))) {
        (map_.InBox(l, c.g) ? in : out) = true;
        const std::vector<float> v = lookup(l, c.g);
        for (int d = 0; d < D; ++d) ref[d] += c.w * v[d];
      }
      for (int d = 0; d < D; ++d)
        ASSERT_NEAR(f[size_t(l) * D + d], ref[d], 1e-6) << "point " << i << " level " << l;
    }
    straddling += in && out;
    // Cached store reads give the same answer the second time.
    reader.Encode(p, f_again.data(), nullptr);
    EXPECT_EQ(f, f_again);
  }
  EXPECT_GT(straddling, 10);

  // Far from anything known: all zeros, and a zero jacobian.
  reader.Encode(Vec3d(-50.3, 77.1, 9.9), f.data(), jac.data());
  for (float v : f) EXPECT_EQ(v, 0.f);
  for (float v : jac) EXPECT_EQ(v, 0.f);
}

}  // namespace
}  // namespace rim
