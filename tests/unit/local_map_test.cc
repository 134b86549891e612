// Ring-buffer sliding of the robot-centric local map (DESIGN.md §3.2) against an explicit
// "global array" reference: every world voxel's expected content is kept in a hash map in the
// test, and after every move the live grids must agree with it exactly.
#include "rim/map/local_map.h"

#include <array>
#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "gtest/gtest.h"
#include "rim/base/row8.h"
#include "rim/config/config.h"
#include "rim/map/map_geometry.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"

namespace rim {
namespace {

MapperConfig SmallConfig() {
  MapperConfig c = *MakePreset("maicity");
  // A 4 m × 4 m × 2.4 m box, one coarse voxel more per axis (map_geometry.h): coarse cells
  // (11, 11, 7) of 0.4 m; level 0 has 45×45×29 points.
  absl::Status s = ApplyOverrides(
      {"grid.half_extent_x_m=2", "grid.half_extent_y_m=2", "grid.z_min_m=-1.2", "grid.z_max_m=1.2"},
      &c);
  EXPECT_TRUE(s.ok()) << s;
  return c;
}

// (level, x, y, z) of a world lattice point.
using VoxelKey = std::array<int, 4>;
struct VoxelKeyHash {
  size_t operator()(const VoxelKey& k) const {
    size_t h = 1469598103934665603ull;
    for (int v : k) h = (h ^ static_cast<uint32_t>(v)) * 1099511628211ull;
    return h;
  }
};
VoxelKey KeyOf(int l, const Int3& g) { return {l, g.x(), g.y(), g.z()}; }

struct RefVoxel {
  std::vector<float> features;
  bool observed = false;
};
struct RefAdam {
  std::vector<float> m, v;
  int32_t steps = 0;
};

// Drives a LocalMap through random moves and random writes, mirroring everything in a reference.
class SlidingHarness {
 public:
  // run_loads: entering voxels are loaded a z run at a time through a CachedReader, as the
  // mapper does; otherwise one voxel at a time through SubmapStore::Read.
  SlidingHarness(bool background, uint64_t seed, bool run_loads = false)
      : run_loads_(run_loads),
        config_(SmallConfig()),
        geometry_(config_.grid),
        map_(geometry_),
        store_(geometry_, config_.submap),
        saver_(&store_, background),
        rng_(seed) {}

  const MapGeometry& geometry() const { return geometry_; }
  LocalMap& map() { return map_; }
  SubmapStore& store() { return store_; }
  SlabSaver& saver() { return saver_; }
  const std::unordered_map<VoxelKey, RefVoxel, VoxelKeyHash>& reference() const { return ref_; }

  void MoveTo(const Int3& origin) {
    // As the mapper does: the store must be current before entering slabs are loaded from it.
    saver_.Flush();
    auto save = [this](SlabBatch&& b) { saver_.Submit(std::move(b)); };
    if (run_loads_) {
      SubmapStore::CachedReader reader(store_);
      map_.MoveToLoadingRuns(origin, save,
                             [&reader](int l, const Int3& g, int n, float* f, uint8_t* flags) {
                               reader.ReadRun(l, g, n, f, flags);
                             });
    } else {
      map_.MoveTo(origin, save, [this](int l, const Int3& g, float* f, uint8_t* obs) {
        return store_.Read(l, g, f, obs);
      });
    }
    // Optimiser state is not part of the global map: voxels that left lose it.
    for (auto it = adam_.begin(); it != adam_.end();) {
      const VoxelKey& k = it->first;
      if (!map_.InBox(k[0], Int3(k[1], k[2], k[3]))) {
        it = adam_.erase(it);
      } else {
        ++it;
      }
    }
    // The global map keeps features as 8-bit rows: what left reads back rounded.
    for (auto& [k, voxel] : ref_)
      if (!map_.InBox(k[0], Int3(k[1], k[2], k[3])))
        RoundRow8(voxel.features.data(), int(voxel.features.size()));
  }

  // Writes random features and optimiser state into `count` random in-box voxels, as training
  // would, and mirrors them in the reference.
  void WriteRandom(int count) {
    const int D = geometry_.feature_dim();
    std::uniform_real_distribution<float> value(-1.f, 1.f);
    std::uniform_real_distribution<float> positive(1e-6f, 1.f);
    std::uniform_int_distribution<int> level_pick(0, geometry_.levels() - 1);
    std::uniform_int_distribution<int> steps(1, 1000);
    std::bernoulli_distribution coin(0.5);
    for (int i = 0; i < count; ++i) {
      const int l = level_pick(rng_);
      const IntBox box = map_.LatticeBox(l);
      Int3 g;
      for (int a = 0; a < 3; ++a)
        g[a] = std::uniform_int_distribution<int>(box.lo[a], box.hi[a])(rng_);
      LocalMap::Level& lv = map_.level(l);
      const int64_t slot = map_.Slot(l, g);
      RefVoxel& ref = ref_[KeyOf(l, g)];
      ref.features.resize(D);
      RefAdam& adam = adam_[KeyOf(l, g)];
      adam.m.resize(D);
      adam.v.resize(D);
      for (int d = 0; d < D; ++d) {
        ref.features[d] = lv.features(slot)[d] = value(rng_);
        adam.m[d] = lv.adam_m(slot)[d] = value(rng_);
        adam.v[d] = lv.adam_v(slot)[d] = positive(rng_);
      }
      adam.steps = lv.adam_steps(slot) = steps(rng_);
      lv.flags(slot) |= LocalMap::kHasData;
      if (l == 0 && coin(rng_)) {
        lv.flags(slot) |= LocalMap::kObserved;
        ref.observed = true;
      }
    }
  }

  // Compares every in-box voxel of every level with the reference. Returns the number of
  // mismatching voxels and describes the first few in `report`.
  int64_t CheckAgainstReference(std::string* report) const {
    const int D = geometry_.feature_dim();
    const std::vector<float> zeros(D, 0.f);
    int64_t bad = 0;
    auto fail = [&](const std::string& what, int l, const Int3& g) {
      if (++bad <= 5) {
        *report += what + " at level " + std::to_string(l) + " g=(" + std::to_string(g.x()) + "," +
                   std::to_string(g.y()) + "," + std::to_string(g.z()) + ")\n";
      }
    };
    for (int l = 0; l < geometry_.levels(); ++l) {
      const LocalMap::Level& lv = map_.level(l);
      const IntBox box = map_.LatticeBox(l);
      for (int x = box.lo.x(); x <= box.hi.x(); ++x)
        for (int y = box.lo.y(); y <= box.hi.y(); ++y)
          for (int z = box.lo.z(); z <= box.hi.z(); ++z) {
            const Int3 g(x, y, z);
            const int64_t slot = map_.Slot(l, g);
            const float* f = lv.features(slot);
            auto it = ref_.find(KeyOf(l, g));
            const float* want = it == ref_.end() ? zeros.data() : it->second.features.data();
            const bool want_observed = it != ref_.end() && it->second.observed;
            if (std::memcmp(f, want, sizeof(float) * D) != 0) fail("features differ", l, g);
            if (bool(lv.flags(slot) & LocalMap::kObserved) != want_observed)
              fail("observed flag differs", l, g);
            if (it != ref_.end() && !lv.has_data(slot))
              fail("has_data false on a voxel with data", l, g);
            auto at = adam_.find(KeyOf(l, g));
            const float* want_m = at == adam_.end() ? zeros.data() : at->second.m.data();
            const float* want_v = at == adam_.end() ? zeros.data() : at->second.v.data();
            const int32_t want_steps = at == adam_.end() ? 0 : at->second.steps;
            if (std::memcmp(lv.adam_m(slot), want_m, sizeof(float) * D) != 0 ||
                std::memcmp(lv.adam_v(slot), want_v, sizeof(float) * D) != 0 ||
                lv.adam_steps(slot) != want_steps) {
              fail("Adam state differs (stale optimiser state in a recycled slot?)", l, g);
            }
          }
    }
    return bad;
  }

  std::mt19937_64& rng() { return rng_; }

 private:
  const bool run_loads_;
  MapperConfig config_;
  MapGeometry geometry_;
  LocalMap map_;
  SubmapStore store_;
  SlabSaver saver_;
  std::mt19937_64 rng_;
  std::unordered_map<VoxelKey, RefVoxel, VoxelKeyHash> ref_;
  std::unordered_map<VoxelKey, RefAdam, VoxelKeyHash> adam_;
};

struct StoragePointers {
  std::vector<const void*> ptrs;
  std::vector<size_t> sizes;
};
StoragePointers Capture(const LocalMap& map) {
  StoragePointers s;
  for (int l = 0; l < map.geometry().levels(); ++l) {
    const LocalMap::Level& lv = map.level(l);
    s.ptrs.insert(s.ptrs.end(), {lv.features(0), lv.adam_m(0)});
    s.sizes.push_back(size_t(lv.slots()));
  }
  return s;
}

// Parameters: whether slabs are saved on the background thread, and whether entering voxels are
// loaded by z runs (the mapper's path) or one at a time.
class LocalMapSlidingTest : public ::testing::TestWithParam<std::tuple<bool, bool>> {};

TEST_P(LocalMapSlidingTest, RandomMovesMatchGlobalReference) {
  SlidingHarness h(/*background=*/std::get<0>(GetParam()), /*seed=*/1234,
                   /*run_loads=*/std::get<1>(GetParam()));
  const MapGeometry& geo = h.geometry();
  ASSERT_EQ(geo.cells(0), Int3(44, 44, 28));
  const Int3 coarse = geo.cells(geo.levels() - 1);

  Int3 origin(0, 0, 0);
  h.MoveTo(origin);
  ASSERT_TRUE(h.map().placed());
  const StoragePointers before = Capture(h.map());
  const int64_t bytes_before = h.map().MemoryBytes();

  std::vector<Int3> visited = {origin};
  std::uniform_int_distribution<int> kind(0, 9);
  std::uniform_int_distribution<int> small(-3, 3);
  std::uniform_int_distribution<int> big(-40, 40);
  int jumps = 0, returns = 0, small_moves = 0;
  for (int step = 0; step < 60; ++step) {
    h.WriteRandom(300);
    const int k = kind(h.rng());
    Int3 next;
    if (k < 6) {
      next = origin + Int3(small(h.rng()), small(h.rng()), small(h.rng()) / 2);
      ++small_moves;
    } else if (k < 8) {
      // A jump larger than the box along at least one axis: every slot is recycled.
      next = origin + Int3(big(h.rng()), big(h.rng()), small(h.rng()));
      if (std::abs(next.x() - origin.x()) <= coarse.x()) next.x() = origin.x() + 2 * coarse.x();
      ++jumps;
    } else {
      // Back to a place visited before: its data must come back from the global map.
      next = visited[std::uniform_int_distribution<size_t>(0, visited.size() - 1)(h.rng())];
      ++returns;
    }
    h.MoveTo(next);
    origin = next;
    visited.push_back(origin);
    ASSERT_EQ(h.map().coarse_origin(), origin);
    for (int l = 0; l < geo.levels(); ++l)
      ASSERT_EQ(h.map().level(l).origin, geo.LevelOrigin(origin, l));
    std::string report;
    const int64_t bad = h.CheckAgainstReference(&report);
    ASSERT_EQ(bad, 0) << "after move " << step << " to (" << origin.transpose() << ")\n" << report;
  }
  EXPECT_GT(jumps, 3);
  EXPECT_GT(returns, 3);
  EXPECT_GT(small_moves, 10);

  // Moving never reallocates: the same buffers, the same sizes.
  const StoragePointers after = Capture(h.map());
  EXPECT_EQ(before.ptrs, after.ptrs);
  EXPECT_EQ(before.sizes, after.sizes);
  EXPECT_EQ(bytes_before, h.map().MemoryBytes());

  // Finally leave everything behind: the global map then holds every voxel ever written.
  h.MoveTo(origin + Int3(1000, 1000, 0));
  h.saver().Flush();
  const int D = geo.feature_dim();
  std::vector<float> f(D);
  int64_t missing = 0, wrong = 0;
  for (const auto& [key, ref] : h.reference()) {
    uint8_t obs = 0;
    if (!h.store().Read(key[0], Int3(key[1], key[2], key[3]), f.data(), &obs)) {
      ++missing;
      continue;
    }
    if (std::memcmp(f.data(), ref.features.data(), sizeof(float) * D) != 0 ||
        bool(obs) != ref.observed)
      ++wrong;
  }
  EXPECT_EQ(missing, 0);
  EXPECT_EQ(wrong, 0);
  EXPECT_GT(h.reference().size(), 5000u);
}

INSTANTIATE_TEST_SUITE_P(SaveModes, LocalMapSlidingTest,
                         ::testing::Combine(::testing::Bool(), ::testing::Bool()),
                         [](const ::testing::TestParamInfo<std::tuple<bool, bool>>& info) {
                           return std::string(std::get<0>(info.param) ? "BackgroundSaver"
                                                                      : "Synchronous") +
                                  (std::get<1>(info.param) ? "RunLoads" : "VoxelLoads");
                         });

TEST(LocalMapTest, RunsInDifferenceCoverItExactlyOnce) {
  // Random pairs of boxes, overlapping, nested, disjoint, or empty in z: the runs cover every
  // point of a that is not in b once, and nothing else.
  std::mt19937_64 rng(11);
  std::uniform_int_distribution<int> lo(-6, 6), size(-1, 8);
  for (int trial = 0; trial < 300; ++trial) {
    IntBox a, b;
    for (IntBox* box : {&a, &b})
      for (int axis = 0; axis < 3; ++axis) {
        box->lo[axis] = lo(rng);
        box->hi[axis] = box->lo[axis] + size(rng);
      }
    std::map<std::tuple<int, int, int>, int> seen;
    ForEachRunInDifference(a, b, [&](const Int3& start, int n) {
      ASSERT_GE(n, 1);
      for (int i = 0; i < n; ++i) ++seen[{start.x(), start.y(), start.z() + i}];
    });
    int64_t expected = 0;
    for (int x = a.lo.x(); x <= a.hi.x(); ++x)
      for (int y = a.lo.y(); y <= a.hi.y(); ++y)
        for (int z = a.lo.z(); z <= a.hi.z(); ++z) {
          const bool in_b = b.Contains(Int3(x, y, z));
          const auto it = seen.find({x, y, z});
          const int count = it == seen.end() ? 0 : it->second;
          ASSERT_EQ(count, in_b ? 0 : 1)
              << "trial " << trial << " at " << x << "," << y << "," << z;
          expected += !in_b;
        }
    ASSERT_EQ(int64_t(seen.size()), expected) << "trial " << trial << ": points outside a";
  }
}

TEST(LocalMapTest, MoveToSameOriginIsNoOp) {
  SlidingHarness h(/*background=*/false, /*seed=*/7);
  h.MoveTo(Int3(3, -2, 1));
  h.WriteRandom(500);
  LocalMap& map = h.map();
  std::vector<std::vector<float>> features;
  std::vector<std::vector<uint8_t>> flags;
  for (int l = 0; l < h.geometry().levels(); ++l) {
    features.push_back(map.level(l).FeatureCopy());
    flags.push_back(map.level(l).FlagCopy());
  }
  int saves = 0, loads = 0;
  map.MoveTo(
      Int3(3, -2, 1), [&](SlabBatch&&) { ++saves; },
      [&](int, const Int3&, float*, uint8_t*) {
        ++loads;
        return false;
      });
  EXPECT_EQ(saves, 0);
  EXPECT_EQ(loads, 0);
  EXPECT_EQ(map.coarse_origin(), Int3(3, -2, 1));
  for (int l = 0; l < h.geometry().levels(); ++l) {
    EXPECT_EQ(map.level(l).FeatureCopy(), features[l]) << "level " << l;
    EXPECT_EQ(map.level(l).FlagCopy(), flags[l]) << "level " << l;
  }
  std::string report;
  EXPECT_EQ(h.CheckAgainstReference(&report), 0) << report;
}

TEST(LocalMapTest, FirstPlacementLoadsTheWholeBox) {
  MapperConfig c = SmallConfig();
  MapGeometry geo(c.grid);
  LocalMap map(geo);
  EXPECT_FALSE(map.placed());
  int64_t loads = 0;
  const int D = geo.feature_dim();
  map.MoveTo(
      Int3(-5, 7, 2), [](SlabBatch&&) { FAIL() << "nothing to save on first placement"; },
      [&](int l, const Int3& g, float* f, uint8_t* obs) {
        ++loads;
        // A recognisable value per voxel, and "known" only on even x.
        for (int d = 0; d < D; ++d) f[d] = float(l * 1000 + g.x() + 0.5 * d);
        *obs = 1;
        return PosMod(g.x(), 2) == 0;
      });
  int64_t expected = 0;
  for (int l = 0; l < geo.levels(); ++l) expected += map.LatticeBox(l).Count();
  EXPECT_EQ(loads, expected);
  for (int l = 0; l < geo.levels(); ++l) {
    const IntBox box = map.LatticeBox(l);
    for (const Int3& g : {box.lo, box.hi, Int3(box.lo.x() + 1, box.hi.y(), box.lo.z())}) {
      const int64_t slot = map.Slot(l, g);
      const bool known = PosMod(g.x(), 2) == 0;
      EXPECT_EQ(bool(map.level(l).flags(slot) & LocalMap::kHasData), known);
      EXPECT_EQ(bool(map.level(l).flags(slot) & LocalMap::kObserved), known);
    }
  }
}

TEST(LocalMapTest, SaveBatchHoldsOnlyLeavingVoxelsWithData) {
  MapperConfig c = SmallConfig();
  MapGeometry geo(c.grid);
  LocalMap map(geo);
  map.MoveTo(Int3(0, 0, 0), nullptr, nullptr);
  const int D = geo.feature_dim();
  // One voxel with data in the x = lo slab of level 0 and one with data that stays.
  const IntBox box = map.LatticeBox(0);
  const Int3 leaving = box.lo + Int3(0, 3, 4);
  const Int3 staying = box.lo + Int3(4, 3, 4);
  for (const Int3& g : {leaving, staying}) {
    const int64_t slot = map.Slot(0, g);
    map.level(0).features(slot)[0] = 2.5f;
    map.level(0).flags(slot) = LocalMap::kHasData | LocalMap::kObserved;
  }
  std::vector<SlabBatch> batches;
  // One coarse voxel along +x: 4 level-0 slabs leave.
  map.MoveTo(
      Int3(1, 0, 0), [&](SlabBatch&& b) { batches.push_back(std::move(b)); }, nullptr);
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].level, 0);
  ASSERT_EQ(batches[0].points.size(), 1u);
  EXPECT_EQ(batches[0].points[0], leaving);
  ASSERT_EQ(batches[0].features.size(), size_t(D));
  EXPECT_EQ(batches[0].features[0], 2.5f);
  ASSERT_EQ(batches[0].observed.size(), 1u);
  EXPECT_EQ(batches[0].observed[0], 1);
  EXPECT_EQ(map.level(0).features(map.Slot(0, staying))[0], 2.5f);
}

// The box moves in whole coarse voxels, yet always holds the configured box about the robot: a
// robot driving along a street maps the facade 9.9 m to its side (half extent 10 m) wherever it
// stands on the coarse lattice.
TEST(MapGeometryTest, BoxHoldsTheConfiguredExtentAboutTheRobot) {
  for (const char* preset : {"maicity", "kitti", "campus", "replica"}) {
    const MapperConfig c = *MakePreset(preset);
    const MapGeometry geo(c.grid);
    const Vec3d lo_rel(-c.grid.half_extent_x_m, -c.grid.half_extent_y_m, c.grid.z_min_m);
    const Vec3d hi_rel(c.grid.half_extent_x_m, c.grid.half_extent_y_m, c.grid.z_max_m);
    const double coarse = geo.voxel_m(geo.levels() - 1);
    // At most one coarse voxel more than asked, per axis.
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(geo.extent_m()[a], hi_rel[a] - lo_rel[a] - 1e-9) << preset;
      EXPECT_LE(geo.extent_m()[a], hi_rel[a] - lo_rel[a] + coarse + 1e-6) << preset;
    }
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(-500.0, 500.0);
    std::vector<Vec3d> positions = {{161.8, 31.5, 1.73}, {0, 0, 0}, {-0.2, 0.2, -0.4}};
    for (int i = 0; i < 2000; ++i) positions.emplace_back(u(rng), u(rng), 0.01 * u(rng));
    // Robots standing exactly on lattice planes and half-way between them.
    for (int k = -5; k <= 5; ++k) positions.emplace_back(k * coarse, (k + 0.5) * coarse, 1.73);
    for (const Vec3d& p : positions) {
      const Vec3d box_lo = geo.BoxOriginFor(p).cast<double>() * coarse;
      const Vec3d box_hi = box_lo + geo.extent_m();
      for (int a = 0; a < 3; ++a) {
        EXPECT_LE(box_lo[a], p[a] + lo_rel[a] + 1e-6) << preset << " axis " << a;
        EXPECT_GE(box_hi[a], p[a] + hi_rel[a] - 1e-6) << preset << " axis " << a;
      }
    }
  }
}

}  // namespace
}  // namespace rim
