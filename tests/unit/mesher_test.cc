// MeshChangeLog: which mesh blocks a recorded change makes stale; the meshing config keys.
#include "rim/mesh/mesher.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <tuple>
#include <vector>

#include "rim/config/config.h"
#include "rim/mesh/grid_encoder.h"

namespace rim {
namespace {

IntBox Box(int lo, int hi) { return {Int3::Constant(lo), Int3::Constant(hi)}; }

// Coarse cells counted densely per block (what a coarse tile meshes) are the cells a hash map of
// counts gives, block by block, both in key order: random voxels, in random order, over blocks on
// both sides of zero, at every coarse step a block allows.
TEST(CoarseCellsTest, DenseCountsPerBlockGiveTheCellsOfCountingInAMap) {
  std::mt19937 rng(7);
  using Key = std::tuple<int, int, int>;
  auto key = [](const Int3& g) { return Key(g.x(), g.y(), g.z()); };
  for (int s : {2, 4, 8, 16}) {
    std::set<Key> unique;
    std::vector<Int3> voxels;
    // Half-filled boxes wide enough to hold whole cells (cells over the share) and scattered
    // voxels (cells under it).
    std::uniform_int_distribution<int> corner(-40, 40), any(-60, 60);
    std::bernoulli_distribution half(0.5);
    const int w = 2 * s + 2;
    for (int cluster = 0; cluster < 12; ++cluster) {
      const Int3 c(corner(rng), corner(rng), corner(rng));
      for (int x = 0; x < w; ++x)
        for (int y = 0; y < w; ++y)
          for (int z = 0; z < w; ++z) {
            const Int3 g = c + Int3(x, y, z);
            if (half(rng) && unique.insert(key(g)).second) voxels.push_back(g);
          }
    }
    for (int k = 0; k < 3000; ++k) {
      const Int3 g(any(rng), any(rng), any(rng));
      if (unique.insert(key(g)).second) voxels.push_back(g);
    }
    std::shuffle(voxels.begin(), voxels.end(), rng);
    const auto dense = mesh_internal::CountCoarseCells(s, 0.25, [&](const auto& fn) {
      for (const Int3& g : voxels) fn(g);
    });
    // The reference: counts per cell in an ordered map, cells grouped by their block.
    const int need = int(std::ceil(0.25 * s * s * s));
    std::map<Key, int> counts;
    std::map<Key, std::vector<Int3>> blocks;
    for (const Int3& g : voxels) {
      ++counts[key(FloorDiv(g, Int3::Constant(s)))];
      blocks[key(FloorDiv(g, Int3::Constant(kMeshBlockVoxels)))];
    }
    for (const auto& [c, n] : counts) {
      if (n < need) continue;
      const Int3 cell(std::get<0>(c), std::get<1>(c), std::get<2>(c));
      blocks[key(FloorDiv(cell * s, Int3::Constant(kMeshBlockVoxels)))].push_back(cell);
    }
    ASSERT_EQ(dense.size(), blocks.size()) << "s = " << s;
    size_t i = 0, kept = 0, empty = 0;
    for (const auto& [b, cells] : blocks) {
      EXPECT_EQ(key(dense[i].first), b) << "s = " << s << ", block " << i;
      EXPECT_EQ(dense[i].second, cells) << "s = " << s << ", block " << i;
      kept += cells.size();
      empty += cells.empty();
      ++i;
    }
    // Both kinds of cell and of block occur, so the comparison means something.
    EXPECT_GE(kept, 12u) << "s = " << s;
    EXPECT_LT(kept, counts.size()) << "s = " << s;
    if (s <= 4) EXPECT_GT(empty, 0u) << "s = " << s;
  }
}

TEST(MeshChangeLogTest, ARegionIsStaleOnlyForChangesAfterItsStampThatTouchIt) {
  MeshChangeLog log;
  const uint64_t s0 = log.Stamp();
  EXPECT_FALSE(log.ChangedSince(s0, Box(0, 10)));
  log.Record({Box(0, 10)}, false);
  const uint64_t s1 = log.Stamp();
  EXPECT_GT(s1, s0);
  EXPECT_TRUE(log.ChangedSince(s0, Box(10, 20)));   // shares the corner point
  EXPECT_FALSE(log.ChangedSince(s0, Box(11, 20)));  // beside it
  EXPECT_FALSE(log.ChangedSince(s1, Box(0, 10)));   // read after the change
  log.Record({Box(100, 110), Box(-50, -40)}, false);
  EXPECT_TRUE(log.ChangedSince(s1, Box(-45, -44)));
  EXPECT_FALSE(log.ChangedSince(s1, Box(0, 10)));
}

TEST(MeshChangeLogTest, EverythingChangedMakesEveryOlderStampStale) {
  MeshChangeLog log;
  log.Record({Box(0, 1)}, false);
  const uint64_t s = log.Stamp();
  log.Record({}, /*all=*/true);
  EXPECT_TRUE(log.ChangedSince(s, Box(1000, 1001)));
  EXPECT_FALSE(log.ChangedSince(log.Stamp(), Box(1000, 1001)));
}

TEST(MeshChangeLogTest, DroppedEntriesCountAsChanges) {
  MeshChangeLog log;
  const uint64_t s = log.Stamp();
  // Far more changes than the log keeps, none near the probe region.
  for (int i = 0; i < 10000; ++i) log.Record({Box(1000 + i, 1000 + i)}, false);
  EXPECT_TRUE(log.ChangedSince(s, Box(0, 1)));  // cannot tell any more: stale, to be safe
  EXPECT_FALSE(log.ChangedSince(log.Stamp() - 1, Box(0, 1)));
}

TEST(WatchConfigTest, BadMinIntervalIsRefusedByName) {
  for (const char* bad :
       {"watch.min_interval_s=-1", "watch.min_interval_s=nan", "watch.min_interval_s=inf",
        "watch.min_interval_s=-0.001", "watch.min_interval_s=1e9"}) {
    MapperConfig c;
    const absl::Status s = ApplyOverrides({bad}, &c);
    ASSERT_FALSE(s.ok()) << bad;
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(std::string(s.message()).find("watch.min_interval_s"), std::string::npos) << s;
    EXPECT_EQ(c.watch.min_interval_s, 1.f) << "a refused override changed the config";
  }
  MapperConfig c;
  ASSERT_TRUE(ApplyOverrides({"watch.min_interval_s=0"}, &c).ok());
  EXPECT_EQ(c.watch.min_interval_s, 0.f);
}

TEST(MeshConfigTest, BadRemeshToleranceIsRefusedByName) {
  for (const char* bad : {"mesh.remesh_tolerance_m=-0.001", "mesh.remesh_tolerance_m=nan",
                          "mesh.remesh_tolerance_m=inf", "mesh.remesh_tolerance_m=0.06"}) {
    MapperConfig c;
    const absl::Status s = ApplyOverrides({bad}, &c);
    ASSERT_FALSE(s.ok()) << bad;
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(std::string(s.message()).find("mesh.remesh_tolerance_m"), std::string::npos) << s;
    EXPECT_EQ(c.mesh.remesh_tolerance_m, 0.005f) << "a refused override changed the config";
  }
  // At most the mesh voxel, and 0 (re-mesh whenever the map under a block changed).
  for (const char* good : {"mesh.remesh_tolerance_m=0", "mesh.remesh_tolerance_m=0.05"}) {
    MapperConfig c;
    EXPECT_TRUE(ApplyOverrides({good}, &c).ok()) << good;
  }
}

}  // namespace
}  // namespace rim
