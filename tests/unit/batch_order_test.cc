// The training batch's cell order (OrderBatchByCell, rim/train/trainer.h): a stable permutation
// of the samples by the box cell that holds them, with labels and endpoint indices following.
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/map/map_geometry.h"
#include "rim/train/sampler.h"
#include "rim/train/trainer.h"

namespace rim {
namespace {

class BatchOrderTest : public ::testing::Test {
 protected:
  BatchOrderTest() : config_(Config()), geometry_(config_.grid), map_(geometry_) {
    // Away from the origin, so that the box's own numbering is what orders the cells.
    map_.MoveTo(Int3(-3, 2, -1), nullptr, nullptr);
    cell_m_ = BatchOrderScratch::kCellScale * geometry_.voxel_m(geometry_.levels() - 1);
    cells_ = (geometry_.cells(geometry_.levels() - 1) +
              Int3::Constant(BatchOrderScratch::kCellScale - 1)) /
             BatchOrderScratch::kCellScale;
  }
  static MapperConfig Config() {
    MapperConfig c = *MakePreset("maicity");
    EXPECT_TRUE(ApplyOverrides({"grid.half_extent_x_m=3.2", "grid.half_extent_y_m=2.4",
                                "grid.z_min_m=-1.6", "grid.z_max_m=1.6"},
                               &c)
                    .ok());
    return c;
  }
  // The cell of a point of the test (never near a cell face), numbered x slowest, z fastest;
  // points outside the box count in the nearest cell.
  int64_t CellOf(const float* p) const {
    const Vec3d lo = map_.min_m();
    int64_t key = 0;
    for (int a = 0; a < 3; ++a) {
      const int c = std::clamp(int(std::floor((p[a] - lo[a]) / cell_m_)), 0, cells_[a] - 1);
      key = key * cells_[a] + c;
    }
    return key;
  }

  MapperConfig config_;
  MapGeometry geometry_;
  LocalMap map_;
  double cell_m_ = 0;
  Int3 cells_;
};

TEST_F(BatchOrderTest, StablePermutationByCellWithLabelsAndEndpointsFollowing) {
  std::mt19937 rng(7);
  const Vec3d lo = map_.min_m();
  std::uniform_int_distribution<int> cx(0, cells_.x() - 1), cy(0, cells_.y() - 1),
      cz(0, cells_.z() - 1);
  std::uniform_real_distribution<double> jitter(0.1, 0.9);  // never near a cell face
  SampleBatch batch;
  const int n = 5000;
  for (int i = 0; i < n; ++i) {
    const int c[3] = {cx(rng), cy(rng), cz(rng)};
    for (int a = 0; a < 3; ++a) batch.xyz.push_back(float(lo[a] + (c[a] + jitter(rng)) * cell_m_));
    batch.labels.push_back(float(i));  // the label names the sample: exact below 2^24
  }
  // Beyond every face of the box: the nearest cell, without reading or writing out of bounds.
  const Vec3d hi = map_.max_m();
  for (const Vec3d& p :
       {Vec3d(lo.x() - 5, lo.y() - 5, lo.z() - 5), Vec3d(hi.x() + 5, hi.y() + 5, hi.z() + 5),
        Vec3d(hi.x() + 1, lo.y() - 1, 0.5 * (lo.z() + hi.z()))}) {
    for (int a = 0; a < 3; ++a) batch.xyz.push_back(float(p[a]));
    batch.labels.push_back(float(batch.labels.size()));
  }
  for (int i = 0; i < int(batch.labels.size()); i += 7) batch.endpoints.push_back(i);
  const SampleBatch before = batch;

  BatchOrderScratch scratch;
  OrderBatchByCell(map_, &batch, &scratch);

  ASSERT_EQ(batch.labels.size(), before.labels.size());
  ASSERT_EQ(batch.xyz.size(), before.xyz.size());
  ASSERT_EQ(batch.endpoints.size(), before.endpoints.size());
  std::vector<bool> seen(before.labels.size(), false);
  int64_t last_cell = -1;
  int last_index = -1;
  for (size_t k = 0; k < batch.labels.size(); ++k) {
    const int i = int(batch.labels[k]);
    ASSERT_GE(i, 0);
    ASSERT_LT(i, int(before.labels.size()));
    EXPECT_FALSE(seen[size_t(i)]) << "sample " << i << " twice";
    seen[size_t(i)] = true;
    for (int a = 0; a < 3; ++a)
      ASSERT_EQ(batch.xyz[3 * k + a], before.xyz[3 * size_t(i) + a]) << "sample " << i;
    const int64_t cell = CellOf(&batch.xyz[3 * k]);
    EXPECT_GE(cell, last_cell) << "position " << k << ": cells out of order";
    // Stable: within a cell, the batch's own order.
    if (cell == last_cell) EXPECT_GT(i, last_index) << "position " << k;
    last_cell = cell;
    last_index = i;
  }
  for (size_t e = 0; e < batch.endpoints.size(); ++e)
    EXPECT_EQ(int(batch.labels[size_t(batch.endpoints[e])]), before.endpoints[e])
        << "endpoint " << e << " no longer names its sample";

  // The same again on the ordered batch changes nothing (the scratch's buffers are reused).
  const SampleBatch ordered = batch;
  OrderBatchByCell(map_, &batch, &scratch);
  EXPECT_EQ(batch.xyz, ordered.xyz);
  EXPECT_EQ(batch.labels, ordered.labels);
  EXPECT_EQ(batch.endpoints, ordered.endpoints);
}

TEST_F(BatchOrderTest, EmptyAndUnplacedBatchesStayAsTheyAre) {
  BatchOrderScratch scratch;
  SampleBatch empty;
  OrderBatchByCell(map_, &empty, &scratch);
  EXPECT_EQ(empty.size(), 0u);

  LocalMap unplaced(geometry_);
  SampleBatch batch;
  batch.xyz = {3.f, 2.f, 1.f, -1.f, -2.f, -3.f};
  batch.labels = {0.5f, -0.5f};
  batch.endpoints = {1};
  const SampleBatch before = batch;
  OrderBatchByCell(unplaced, &batch, &scratch);
  EXPECT_EQ(batch.xyz, before.xyz);
  EXPECT_EQ(batch.labels, before.labels);
  EXPECT_EQ(batch.endpoints, before.endpoints);
}

}  // namespace
}  // namespace rim
