// Free-space marking (rim/train/free_space.h): the finest voxels a ray crosses in front of its
// endpoint are marked seen free, exactly those, and the surface band and the space behind stay
// unmarked.
#include "rim/train/free_space.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <tuple>
#include <vector>

#include "gtest/gtest.h"
#include "rim/config/config.h"
#include "rim/map/map_geometry.h"

namespace rim {
namespace {

class FreeSpaceTest : public ::testing::Test {
 protected:
  FreeSpaceTest() : config_(Config()), geometry_(config_.grid), map_(geometry_) {
    map_.MoveTo(Int3::Zero(), nullptr, nullptr);  // box [0,4) x [0,4) x [0,2.4) m
  }
  static MapperConfig Config() {
    MapperConfig c = *MakePreset("maicity");
    EXPECT_TRUE(ApplyOverrides({"grid.half_extent_x_m=2", "grid.half_extent_y_m=2",
                                "grid.z_min_m=-1.2", "grid.z_max_m=1.2"},
                               &c)
                    .ok());
    return c;
  }
  bool SeenFree(const Vec3f& p) {
    const double s = geometry_.leaf_m();
    const Int3 g(int(std::floor(p.x() / s)), int(std::floor(p.y() / s)),
                 int(std::floor(p.z() / s)));
    return map_.level(0).flags(map_.Slot(0, g)) & LocalMap::kSeenFree;
  }
  int CountSeenFree() {
    int n = 0;
    for (uint8_t f : map_.level(0).FlagCopy()) n += (f & LocalMap::kSeenFree) != 0;
    return n;
  }

  MapperConfig config_;
  MapGeometry geometry_;
  LocalMap map_;
};

TEST_F(FreeSpaceTest, MarksTheVoxelsInFrontOfTheEndpointOnly) {
  const Vec3f o(0.55f, 1.05f, 1.05f), p(3.55f, 1.05f, 1.05f);  // along +x, 3 m, leaf 0.1 m
  MarkFreeSpace({p}, {o}, 0.15f, 100, &map_);
  for (float x = 0.56f; x < 3.35f; x += 0.05f) EXPECT_TRUE(SeenFree(Vec3f(x, 1.05f, 1.05f))) << x;
  // The surface band (last 0.15 m) and the space behind the endpoint are not free.
  EXPECT_FALSE(SeenFree(Vec3f(3.45f, 1.05f, 1.05f)));
  EXPECT_FALSE(SeenFree(Vec3f(3.75f, 1.05f, 1.05f)));
  // Voxels beside the ray are untouched: one voxel per crossing, 28 or 29 of them.
  EXPECT_FALSE(SeenFree(Vec3f(2.f, 1.15f, 1.05f)));
  EXPECT_GE(CountSeenFree(), 28);
  EXPECT_LE(CountSeenFree(), 30);
}

TEST_F(FreeSpaceTest, DiagonalRayMarksAConnectedChainOfVoxels) {
  const Vec3f o(0.31f, 0.22f, 0.13f), p(3.7f, 3.1f, 2.2f);
  MarkFreeSpace({p}, {o}, 0.15f, 100, &map_);
  const Vec3f d = (p - o).normalized();
  const float len = (p - o).norm() - 0.15f;
  for (float t = 0.f; t < len; t += 0.01f) EXPECT_TRUE(SeenFree(o + t * d)) << t;
  // A voxel walk crosses at most one voxel per boundary: no more voxels than boundaries crossed.
  const Vec3f span = ((o + len * d) / 0.1f).array().floor() - (o / 0.1f).array().floor();
  EXPECT_LE(CountSeenFree(), int(span.cwiseAbs().sum()) + 1);
}

TEST_F(FreeSpaceTest, ClipsRaysToTheBox) {
  // Starts outside the box (x < 0) and ends outside it (x > 4.4, the 4 m asked and one coarse
  // voxel): only the part inside is walked.
  const Vec3f o(-5.f, 2.05f, 1.05f), p(9.f, 2.05f, 1.05f);
  MarkFreeSpace({p}, {o}, 0.15f, 100, &map_);
  EXPECT_TRUE(SeenFree(Vec3f(0.05f, 2.05f, 1.05f)));
  EXPECT_TRUE(SeenFree(Vec3f(4.35f, 2.05f, 1.05f)));
  EXPECT_EQ(CountSeenFree(), 44);
}

TEST_F(FreeSpaceTest, RayBudgetBoundsTheWork) {
  std::vector<Vec3f> points, origins;
  for (int i = 0; i < 100; ++i) {
    origins.push_back(Vec3f(0.05f, 0.05f + 0.04f * i, 1.05f));
    points.push_back(Vec3f(3.95f, 0.05f + 0.04f * i, 1.05f));
  }
  MarkFreeSpace(points, origins, 0.15f, 0, &map_);
  EXPECT_EQ(CountSeenFree(), 0);
  MarkFreeSpace(points, origins, 0.15f, 10, &map_);
  const int ten = CountSeenFree();
  EXPECT_GT(ten, 0);
  EXPECT_LE(ten, 10 * 38);
}

TEST_F(FreeSpaceTest, MarksTheSameWithAPool) {
  // Many rays in every direction, crossing each other: the threads of a pool share voxels.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> in(0.05f, 3.95f), in_z(0.05f, 2.35f), out(-3.f, 7.f);
  std::vector<Vec3f> points, origins;
  for (int i = 0; i < 3000; ++i) {
    origins.push_back(Vec3f(in(rng), in(rng), in_z(rng)));
    points.push_back(i % 3 ? Vec3f(in(rng), in(rng), in_z(rng)) : Vec3f(out(rng), out(rng), 1.f));
  }
  MarkSurfaceVoxels(points, &map_);
  MarkFreeSpace(points, origins, 0.15f, 2000, &map_);
  const std::vector<uint8_t> alone = map_.level(0).FlagCopy();
  for (const int threads : {2, 3}) {
    LocalMap pooled(geometry_);
    pooled.MoveTo(Int3::Zero(), nullptr, nullptr);
    WorkerPool pool(threads);
    MarkSurfaceVoxels(points, &pooled, &pool);
    MarkFreeSpace(points, origins, 0.15f, 2000, &pooled, &pool);
    EXPECT_EQ(pooled.level(0).FlagCopy(), alone) << threads << " threads";
  }
  EXPECT_GT(CountSeenFree(), 2000);
}

TEST_F(FreeSpaceTest, MarkScanMarksWhatTheThreeCallsMarkAndRunsItsTaskOnce) {
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<float> in(0.05f, 3.95f), in_z(0.05f, 2.35f), out(-3.f, 7.f);
  std::vector<Vec3f> inside_p, inside_o, outside_p, outside_o;
  for (int i = 0; i < 3000; ++i) {
    inside_o.push_back(Vec3f(in(rng), in(rng), in_z(rng)));
    inside_p.push_back(Vec3f(in(rng), in(rng), in_z(rng)));
    outside_o.push_back(Vec3f(in(rng), in(rng), in_z(rng)));
    outside_p.push_back(Vec3f(out(rng), out(rng), 1.f));
  }
  MarkSurfaceVoxels(inside_p, &map_);
  MarkFreeSpace(inside_p, inside_o, 0.15f, 1000, &map_);
  MarkFreeSpace(outside_p, outside_o, 0.15f, 250, &map_);
  const std::vector<uint8_t> three = map_.level(0).FlagCopy();
  for (const int threads : {1, 2, 3}) {
    LocalMap scanned(geometry_);
    scanned.MoveTo(Int3::Zero(), nullptr, nullptr);
    WorkerPool pool(threads);
    std::atomic<int> also{0};
    MarkScan(inside_p, inside_o, outside_p, outside_o, 0.15f, 1000, 250, &scanned, &pool,
             [&] { also.fetch_add(1); });
    EXPECT_EQ(scanned.level(0).FlagCopy(), three) << threads << " threads";
    EXPECT_EQ(also.load(), 1) << threads << " threads";
  }
  LocalMap serial(geometry_);
  serial.MoveTo(Int3::Zero(), nullptr, nullptr);
  MarkScan(inside_p, inside_o, outside_p, outside_o, 0.15f, 1000, 250, &serial, nullptr);
  EXPECT_EQ(serial.level(0).FlagCopy(), three) << "no pool, no task";
}

// The plain walk: the same voxel sequence, each voxel's slot from LocalMap::Slot (a modulo per
// axis). The marking follows the slot along the ring instead (and surface marking steps from the
// box corner's ring position); they must agree wherever the ring wraps inside the box.
void ReferenceMarkFreeSpace(const std::vector<Vec3f>& points, const std::vector<Vec3f>& origins,
                            float band_m, LocalMap* map) {
  const double s = map->geometry().leaf_m();
  const Vec3d lo = map->min_m(), hi = map->max_m();
  for (size_t i = 0; i < points.size(); ++i) {
    const Vec3d o = origins[i].cast<double>();
    Vec3d d = points[i].cast<double>() - o;
    const double range = d.norm();
    if (range <= band_m) continue;
    d /= range;
    double t0 = 0, t1 = range - band_m;
    bool empty = false;
    for (int a = 0; a < 3 && !empty; ++a) {
      if (std::abs(d[a]) < 1e-12) {
        empty = o[a] < lo[a] || o[a] >= hi[a];
        continue;
      }
      double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (empty || !(t0 < t1)) continue;
    const Vec3d p = o + t0 * d;
    Int3 g(int(std::floor(p.x() / s)), int(std::floor(p.y() / s)), int(std::floor(p.z() / s)));
    Int3 step;
    Vec3d t_max, t_delta;
    for (int a = 0; a < 3; ++a) {
      step[a] = d[a] > 0 ? 1 : d[a] < 0 ? -1 : 0;
      t_max[a] = d[a] > 0   ? t0 + ((g[a] + 1) * s - p[a]) / d[a]
                 : d[a] < 0 ? t0 + (g[a] * s - p[a]) / d[a]
                            : std::numeric_limits<double>::infinity();
      t_delta[a] = d[a] != 0 ? std::abs(s / d[a]) : std::numeric_limits<double>::infinity();
    }
    for (double t = t0; t < t1;) {
      if (map->InBox(0, g))
        map->level(0).flags(map->Slot(0, g)) |= LocalMap::kSeenFree | LocalMap::kHasData;
      int a = 0;
      if (t_max[1] < t_max[a]) a = 1;
      if (t_max[2] < t_max[a]) a = 2;
      t = t_max[a];
      t_max[a] += t_delta[a];
      g[a] += step[a];
    }
  }
}

TEST_F(FreeSpaceTest, MarksWhatPerVoxelSlotLookupsMarkWhereTheRingWraps) {
  // A box whose ring wraps on every axis inside it, as after the robot drove a while.
  for (const Int3& origin : {Int3(3, -7, 2), Int3(-5, 11, -3)}) {
    LocalMap walked(geometry_), reference(geometry_);
    walked.MoveTo(origin, nullptr, nullptr);
    reference.MoveTo(origin, nullptr, nullptr);
    const Vec3d lo = walked.min_m(), ext = walked.max_m() - walked.min_m();
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(0.0, 1.0), wide(-1.0, 2.0);
    std::vector<Vec3f> points, origins;
    for (int i = 0; i < 2000; ++i) {
      Vec3d o, p;
      for (int a = 0; a < 3; ++a) {
        o[a] = lo[a] + ext[a] * (i % 4 ? u(rng) : wide(rng));  // some origins outside the box
        p[a] = lo[a] + ext[a] * (i % 2 ? u(rng) : wide(rng));  // some endpoints beyond it
      }
      if (i % 50 == 0) p.z() = o.z();  // flat rays: no step along z
      origins.push_back(o.cast<float>());
      points.push_back(p.cast<float>());
    }
    MarkFreeSpace(points, origins, 0.15f, int(points.size()), &walked);
    ReferenceMarkFreeSpace(points, origins, 0.15f, &reference);
    // Surface marking finds each endpoint's slot without a modulo too.
    MarkSurfaceVoxels(points, &walked);
    const double inv_s = 1.0 / geometry_.leaf_m();  // as the marking rounds
    int surface = 0;
    for (const Vec3f& p : points) {
      const Int3 g(int(std::floor(p.x() * inv_s)), int(std::floor(p.y() * inv_s)),
                   int(std::floor(p.z() * inv_s)));
      if (!reference.InBox(0, g)) continue;
      reference.level(0).flags(reference.Slot(0, g)) |= LocalMap::kObserved | LocalMap::kHasData;
      ++surface;
    }
    EXPECT_GT(surface, 300) << origin.transpose();
    EXPECT_EQ(walked.level(0).FlagCopy(), reference.level(0).FlagCopy()) << origin.transpose();
    int marked = 0;
    for (uint8_t f : walked.level(0).FlagCopy()) marked += (f & LocalMap::kSeenFree) != 0;
    EXPECT_GT(marked, 3000) << origin.transpose();
  }
}

}  // namespace
}  // namespace rim
