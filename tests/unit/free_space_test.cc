// Free-space marking (rim/free_space.h): the finest voxels a ray crosses in front of its endpoint
// are marked seen free, exactly those, and the surface band and the space behind stay unmarked.
#include "rim/free_space.h"

#include <cmath>
#include <random>
#include <set>
#include <tuple>
#include <vector>

#include "gtest/gtest.h"
#include "rim/config.h"
#include "rim/map_geometry.h"

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
  // Starts outside the box (x < 0) and ends outside it (x > 4): only the part inside is walked.
  const Vec3f o(-5.f, 2.05f, 1.05f), p(9.f, 2.05f, 1.05f);
  MarkFreeSpace({p}, {o}, 0.15f, 100, &map_);
  EXPECT_TRUE(SeenFree(Vec3f(0.05f, 2.05f, 1.05f)));
  EXPECT_TRUE(SeenFree(Vec3f(3.95f, 2.05f, 1.05f)));
  EXPECT_EQ(CountSeenFree(), 40);
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

}  // namespace
}  // namespace rim
