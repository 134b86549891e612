// The deferred ray store (map/deferred_points.h): one ray per voxel with the shortest range
// kept, the vertical band, the per-sub-map bound dropping the longest ranges first, hand-over of
// the rays the box reaches, and persistence that refuses corrupt bytes and keeps its state.
#include "rim/map/deferred_points.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "rim/base/binary_io.h"
#include "rim/config/config.h"
#include "rim/map/map_geometry.h"

namespace rim {
namespace {

// The maicity box: 20 x 20 x 6 m sub-maps, the sensor's band from 9 m below to 9 m above it.
struct Fixture {
  // 10 cm voxels, so that the cases below can be written in round numbers.
  explicit Fixture(int max_per_submap = 100000) {
    deferred.voxel_m = 0.1f;
    deferred.max_points_per_submap = max_per_submap;
  }
  GridConfig grid;
  DeferredConfig deferred;
  MapGeometry geometry{grid};
  DeferredPoints Make() const { return DeferredPoints(geometry, grid, deferred); }
};

struct Rays {
  std::vector<Vec3f> p, o;
  void Add(const Vec3f& point, const Vec3f& origin) {
    p.push_back(point);
    o.push_back(origin);
  }
};

TEST(DeferredPointsTest, OneRayPerVoxelAndTheClosestLookWins) {
  Fixture f;
  DeferredPoints store = f.Make();
  Rays a;
  a.Add(Vec3f(30.02f, 5.01f, 1.01f), Vec3f(0, 0, 1.7f));   // range ~30.4
  a.Add(Vec3f(30.07f, 5.08f, 1.08f), Vec3f(10, 0, 1.7f));  // same 10 cm voxel, range ~20.7
  a.Add(Vec3f(30.12f, 5.01f, 1.01f), Vec3f(0, 0, 1.7f));   // the next voxel along x
  store.Add(a.p, a.o, Vec3f(0, 0, 1.7f));
  EXPECT_EQ(store.size(), 2u);
  // A farther look at the first voxel does not replace the closer one.
  Rays b;
  b.Add(Vec3f(30.05f, 5.05f, 1.05f), Vec3f(-20, 0, 1.7f));
  store.Add(b.p, b.o, Vec3f(-20, 0, 1.7f));
  EXPECT_EQ(store.size(), 2u);

  std::vector<Vec3f> p, o;
  store.TakeInside(Vec3d(20, -5, -2), Vec3d(40, 15, 4), &p, &o);
  ASSERT_EQ(p.size(), 2u);
  EXPECT_EQ(store.size(), 0u);
  EXPECT_EQ(p[0], a.p[1]);
  EXPECT_EQ(o[0], a.o[1]);
  EXPECT_EQ(p[1], a.p[2]);
  EXPECT_EQ(store.Stats().taken, 2);
}

TEST(DeferredPointsTest, ChangedSubmapsAreReportedOnceAndRestoredStoresCountAsChanged) {
  Fixture f;
  DeferredPoints store = f.Make();
  EXPECT_TRUE(store.TakeChanged().empty());
  Rays a;
  a.Add(Vec3f(30.02f, 5.01f, 1.01f), Vec3f(0, 0, 1.7f));  // sub-map (1, 0, 0)
  a.Add(Vec3f(-5.f, 3.f, 1.f), Vec3f(0, 0, 1.7f));        // sub-map (-1, 0, 0)
  store.Add(a.p, a.o, Vec3f(0, 0, 1.7f));
  EXPECT_EQ(store.Changed(), (std::vector<Int3>{Int3(-1, 0, 0), Int3(1, 0, 0)}));
  EXPECT_EQ(store.TakeChanged(), (std::vector<Int3>{Int3(-1, 0, 0), Int3(1, 0, 0)}));
  EXPECT_TRUE(store.TakeChanged().empty());

  std::vector<uint32_t> voxels;
  std::vector<float> rays;
  store.Rays(Int3(1, 0, 0), &voxels, &rays);
  ASSERT_EQ(voxels.size(), 1u);
  EXPECT_EQ(std::vector<float>(rays.begin(), rays.begin() + 3),
            (std::vector<float>{30.02f, 5.01f, 1.01f}));
  store.Rays(Int3(5, 5, 0), &voxels, &rays);
  EXPECT_TRUE(voxels.empty() && rays.empty());

  // A farther look at a kept voxel changes nothing; a closer one replaces the ray.
  Rays b;
  b.Add(Vec3f(30.03f, 5.02f, 1.02f), Vec3f(-20, 0, 1.7f));
  store.Add(b.p, b.o, Vec3f(-20, 0, 1.7f));
  EXPECT_TRUE(store.TakeChanged().empty());
  b.p[0] = Vec3f(30.04f, 5.02f, 1.02f);
  b.o[0] = Vec3f(25, 0, 1.7f);
  store.Add(b.p, b.o, Vec3f(25, 0, 1.7f));
  EXPECT_EQ(store.TakeChanged(), std::vector<Int3>{Int3(1, 0, 0)});

  // Taking rays out changes their sub-map; a box that takes none changes nothing.
  std::vector<Vec3f> p, o;
  store.TakeInside(Vec3d(100, 100, -2), Vec3d(120, 120, 4), &p, &o);
  EXPECT_TRUE(store.TakeChanged().empty());
  store.TakeInside(Vec3d(-10, -10, -2), Vec3d(0, 10, 4), &p, &o);
  EXPECT_EQ(store.TakeChanged(), std::vector<Int3>{Int3(-1, 0, 0)});

  store.SetChanged({Int3(7, 7, 0)});
  EXPECT_EQ(store.Changed(), std::vector<Int3>{Int3(7, 7, 0)});
  ByteWriter w;
  store.Serialize(&w);
  DeferredPoints loaded = f.Make();
  ByteReader r(w.data(), "deferred");
  ASSERT_TRUE(loaded.Deserialize(&r, 100.f).ok());
  EXPECT_EQ(loaded.Changed(), std::vector<Int3>{Int3(1, 0, 0)});
}

TEST(DeferredPointsTest, EndpointsFarAboveOrBelowTheBoxBandAreNotKept) {
  Fixture f;
  DeferredPoints store = f.Make();
  Rays r;
  const Vec3f sensor(0, 0, 2);
  r.Add(Vec3f(25, 0, 2 + 8.9f), sensor);  // 8.9 m above: within z_max + 6 m
  r.Add(Vec3f(25, 1, 2 + 9.2f), sensor);  // beyond it
  r.Add(Vec3f(25, 2, 2 - 8.9f), sensor);  // within z_min - 6 m
  r.Add(Vec3f(25, 3, 2 - 9.2f), sensor);  // beyond it
  store.Add(r.p, r.o, sensor);
  EXPECT_EQ(store.size(), 2u);
}

TEST(DeferredPointsTest, TakeInsideMovesOnlyTheBoxAndIsHalfOpen) {
  Fixture f;
  DeferredPoints store = f.Make();
  Rays r;
  const Vec3f s(0, 0, 1.7f);
  r.Add(Vec3f(10.f, 0.5f, 0.5f), s);   // on the box's min face: inside
  r.Add(Vec3f(30.f, 0.5f, 0.5f), s);   // on its max face: outside
  r.Add(Vec3f(29.9f, 0.5f, 0.5f), s);  // inside
  r.Add(Vec3f(15.f, 12.f, 0.5f), s);   // beside it
  r.Add(Vec3f(15.f, 0.5f, -3.5f), s);  // below it
  store.Add(r.p, r.o, s);
  ASSERT_EQ(store.size(), 5u);
  std::vector<Vec3f> p, o;
  store.TakeInside(Vec3d(10, -10, -3), Vec3d(30, 10, 3), &p, &o);
  ASSERT_EQ(p.size(), 2u);
  EXPECT_EQ(store.size(), 3u);
  std::sort(p.begin(), p.end(), [](const Vec3f& a, const Vec3f& b) { return a.x() < b.x(); });
  EXPECT_EQ(p[0], r.p[0]);
  EXPECT_EQ(p[1], r.p[2]);
  // Taken once: a second call finds nothing more there.
  p.clear();
  store.TakeInside(Vec3d(10, -10, -3), Vec3d(30, 10, 3), &p, &o);
  EXPECT_TRUE(p.empty());
}

TEST(DeferredPointsTest, TheBoundDropsTheLongestRangesFirst) {
  Fixture f(/*max_per_submap=*/800);
  DeferredPoints store = f.Make();
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  Rays r;
  const Vec3f sensor(0, 0, 1.7f);
  // 2000 distinct voxels of one sub-map (x in [20.4, 40.8)), seen from origins at random
  // distances.
  for (int i = 0; i < 2000; ++i) {
    const Vec3f p(21.05f + 0.1f * float(i % 100), 0.05f + 0.1f * float(i / 100), 1.05f);
    r.Add(p, p - Vec3f(5.f + 40.f * u(rng), 0, 0));
  }
  store.Add(r.p, r.o, sensor);
  EXPECT_LE(store.size(), 800u);
  EXPECT_GE(store.size(), 700u);
  EXPECT_EQ(store.Stats().evicted, 2000 - int64_t(store.size()));
  std::vector<Vec3f> p, o;
  store.TakeInside(Vec3d(20, 0, 0), Vec3d(40, 20, 6), &p, &o);
  ASSERT_EQ(p.size(), 700u);
  float longest_kept = 0.f;
  for (size_t i = 0; i < p.size(); ++i) longest_kept = std::max(longest_kept, (p[i] - o[i]).norm());
  int longer = 0;
  for (size_t i = 0; i < r.p.size(); ++i) longer += (r.p[i] - r.o[i]).norm() > longest_kept;
  EXPECT_EQ(longer, 2000 - 700) << "a shorter ray was dropped before a longer one";
}

TEST(DeferredPointsTest, SerializeRoundTripAndCorruptBytesChangeNothing) {
  Fixture f;
  DeferredPoints store = f.Make();
  Rays r;
  const Vec3f s(0, 0, 1.7f);
  for (int i = 0; i < 300; ++i) r.Add(Vec3f(-35.f + 0.2f * float(i), 11.3f, 0.2f), s);
  store.Add(r.p, r.o, s);
  ByteWriter w;
  store.Serialize(&w);

  DeferredPoints copy = f.Make();
  ByteReader reader(w.data(), "deferred");
  ASSERT_TRUE(copy.Deserialize(&reader, 60.f).ok());
  EXPECT_EQ(copy.size(), store.size());
  ByteWriter again;
  copy.Serialize(&again);
  EXPECT_EQ(again.data(), w.data()) << "not byte-exact";

  // Every single-byte change past the counters is refused or leaves a valid store; a refused
  // one leaves the target as it was.
  const std::string good(w.data());
  int refused = 0;
  for (size_t at = 24; at < good.size(); at += 7) {
    std::string bad = good;
    bad[at] = char(bad[at] ^ 0x40);
    DeferredPoints target = f.Make();
    Rays one;
    one.Add(Vec3f(55, 55, 1), s);
    target.Add(one.p, one.o, s);
    ByteReader br(bad, "deferred");
    const absl::Status st = target.Deserialize(&br, 60.f);
    if (!st.ok()) {
      ++refused;
      EXPECT_EQ(target.size(), 1u) << "a refused load changed the store";
    }
  }
  EXPECT_GT(refused, 0);
  // Truncation is refused.
  DeferredPoints target = f.Make();
  ByteReader cut(std::string_view(good).substr(0, good.size() - 5), "deferred");
  EXPECT_FALSE(target.Deserialize(&cut, 60.f).ok());
  // A ray longer than the range limit is refused.
  ByteReader shortrange(good, "deferred");
  EXPECT_FALSE(target.Deserialize(&shortrange, 5.f).ok());
}

TEST(DeferredPointsTest, DisabledOrFixedBoxKeepsNothing) {
  Fixture f;
  f.deferred.enabled = false;
  DeferredPoints off = f.Make();
  Rays r;
  r.Add(Vec3f(30, 0, 1), Vec3f(0, 0, 1.7f));
  off.Add(r.p, r.o, Vec3f(0, 0, 1.7f));
  EXPECT_EQ(off.size(), 0u);
  Fixture g;
  g.grid.sliding = false;
  DeferredPoints fixed = g.Make();
  fixed.Add(r.p, r.o, Vec3f(0, 0, 1.7f));
  EXPECT_EQ(fixed.size(), 0u);
}

}  // namespace
}  // namespace rim
