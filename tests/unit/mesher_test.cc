// MeshChangeLog: which mesh blocks a recorded change makes stale; the meshing config keys.
#include "rim/mesh/mesher.h"

#include <gtest/gtest.h>

#include "rim/config/config.h"

namespace rim {
namespace {

IntBox Box(int lo, int hi) { return {Int3::Constant(lo), Int3::Constant(hi)}; }

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
