// The fast training path (Trainer: fused-free Eigen MLP step, sparse gradient scatter, lazy Adam
// with per-row step counts, several threads) against the reference (ReferenceTrainer: libtorch
// ops and autograd over the dense grids, dense Adam with one global step count). On a batch that
// touches the same rows every iteration both must give the same losses and the same updated
// features and decoder parameters, up to float rounding.
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/map/map_geometry.h"
#include "rim/model/decoder.h"
#include "rim/train/sampler.h"
#include "rim/train/train_step.h"
#include "rim/train/trainer.h"

namespace rim {
namespace {

MapperConfig SmallConfig(const std::string& step) {
  auto config = MakePreset("maicity");
  EXPECT_TRUE(ApplyOverrides({"grid.half_extent_x_m=2", "grid.half_extent_y_m=2",
                              "grid.z_min_m=-1.2", "grid.z_max_m=1.2", "train.step=" + step},
                             &*config)
                  .ok());
  return *config;
}

SampleBatch RandomBatch(const LocalMap& map, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  SampleBatch batch;
  const Vec3d lo = map.min_m(), hi = map.max_m();
  for (int i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) {
      std::uniform_real_distribution<double> u(lo[a] + 0.05, hi[a] - 0.15);
      batch.xyz.push_back(float(u(rng)));
    }
    batch.labels.push_back(std::uniform_real_distribution<float>(-0.3f, 0.3f)(rng));
  }
  return batch;
}

float MaxAbs(const std::vector<float>& v) {
  float m = 0.f;
  for (float x : v) m = std::max(m, std::abs(x));
  return m;
}

class ReferenceTrainerTest : public ::testing::TestWithParam<std::string> {};

TEST_P(ReferenceTrainerTest, FastPathMatchesTheDenseLibtorchReference) {
  const MapperConfig config = SmallConfig(GetParam());
  const MapGeometry geometry(config.grid);
  LocalMap fast_map(geometry), ref_map(geometry);
  fast_map.PlaceWithoutLoading(Int3::Zero());
  ref_map.PlaceWithoutLoading(Int3::Zero());
  Decoder fast_decoder(geometry.encoding_dim(), config.decoder);
  Decoder ref_decoder(geometry.encoding_dim(), config.decoder);
  ASSERT_EQ(fast_decoder.params(), ref_decoder.params());
  Trainer fast(config, &fast_map, &fast_decoder);
  ReferenceTrainer reference(config, &ref_map, &ref_decoder);

  const SampleBatch batch = RandomBatch(fast_map, 3000, 5);
  for (int it = 0; it < 4; ++it) {
    const bool train_decoder = it < 3;  // then with the decoder frozen
    auto fast_loss = fast.IterateOn(batch, train_decoder, nullptr);
    auto ref_loss =
        reference.Iterate(batch.xyz.data(), batch.labels.data(), int(batch.size()), train_decoder);
    ASSERT_TRUE(fast_loss.ok()) << fast_loss.status();
    ASSERT_TRUE(ref_loss.ok()) << ref_loss.status();
    EXPECT_NEAR(*fast_loss, *ref_loss, 1e-5f * std::abs(*ref_loss)) << "iteration " << it;
  }
  // Every row of every grid (untouched rows must still be zero in both), and the decoder.
  for (int l = 0; l < geometry.levels(); ++l) {
    const std::vector<float> a = fast_map.level(l).FeatureCopy();
    const std::vector<float> b = ref_map.level(l).FeatureCopy();
    ASSERT_EQ(a.size(), b.size());
    const float scale = MaxAbs(b);
    EXPECT_GT(scale, 0.f) << "level " << l << " did not train";
    float diff = 0.f;
    for (size_t i = 0; i < a.size(); ++i) diff = std::max(diff, std::abs(a[i] - b[i]));
    EXPECT_LT(diff, 1e-3f * scale) << "level " << l;
  }
  float diff = 0.f;
  for (size_t i = 0; i < fast_decoder.params().size(); ++i)
    diff = std::max(diff, std::abs(fast_decoder.params()[i] - ref_decoder.params()[i]));
  EXPECT_LT(diff, 1e-3f * MaxAbs(ref_decoder.params()));
  EXPECT_NE(fast_decoder.params(), Decoder(geometry.encoding_dim(), config.decoder).params());
}

// Both decoder-step implementations of the fast path.
INSTANTIATE_TEST_SUITE_P(Steps, ReferenceTrainerTest, ::testing::Values("fast", "libtorch"));

}  // namespace
}  // namespace rim
