// The hand-written training step (MlpTrainStep) against the libtorch reference (RunTrainStep):
// same loss, same feature gradient, same parameter gradient, for decoders of 0–2 hidden layers,
// with and without the eikonal term, frozen or training, on one thread or several.
#include "rim/train/mlp_step.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "gtest/gtest.h"
#include "rim/base/worker_pool.h"
#include "rim/config/config.h"
#include "rim/model/decoder.h"
#include "rim/train/train_step.h"

namespace rim {
namespace {

constexpr int kInput = 24;  // L·D of the maicity preset

struct Case {
  int hidden_layers;
  float eikonal_weight;
  bool train_decoder;
};

class MlpStepTest : public ::testing::TestWithParam<Case> {};

// Max |a − b| relative to the largest |b|: the two sum in different orders, so they agree to
// float rounding, not bit for bit.
float MaxRelDiff(const std::vector<float>& a, const std::vector<float>& b) {
  EXPECT_EQ(a.size(), b.size());
  float scale = 1e-30f, diff = 0.f;
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    scale = std::max(scale, std::abs(b[i]));
    diff = std::max(diff, std::abs(a[i] - b[i]));
  }
  return diff / scale;
}

// A batch of random features in [−range, range] and labels in [−0.4, 0.4] m; rows after the
// labelled ones are eikonal probes. `in` points into the vectors, so a batch is never copied.
struct Batch {
  std::vector<float> features, labels;
  TrainStepInput in;
};
std::unique_ptr<Batch> RandomBatch(int rows, int labelled, int inputs, float range, uint32_t seed,
                                   float eikonal_weight, bool train_decoder) {
  auto b = std::make_unique<Batch>();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> feature(-range, range), label(-0.4f, 0.4f);
  b->features.resize(size_t(rows) * inputs);
  b->labels.resize(size_t(labelled));
  for (float& f : b->features) f = feature(rng);
  for (float& l : b->labels) l = label(rng);
  b->in.features = b->features.data();
  b->in.rows = rows;
  b->in.labelled = labelled;
  b->in.labels = b->labels.data();
  b->in.sigma_m = 0.05f;
  b->in.eikonal_weight = eikonal_weight;
  b->in.eikonal_step_m = 0.05f;
  b->in.train_decoder = train_decoder;
  return b;
}

TEST_P(MlpStepTest, MatchesLibtorchAutograd) {
  const Case c = GetParam();
  DecoderConfig dc;
  dc.hidden_layers = c.hidden_layers;
  dc.hidden_width = 32;
  dc.seed = 11;
  Decoder decoder(kInput, dc);
  const int labelled = 5000, groups = 400;     // several chunks of MlpTrainStep::kChunkRows
  const int rows = labelled + 6 * groups + 5;  // 5 rows that form no full probe group
  const auto batch =
      RandomBatch(rows, labelled, kInput, 0.5f, 3, c.eikonal_weight, c.train_decoder);
  const TrainStepInput& in = batch->in;
  auto ref = RunTrainStep(decoder, in);
  ASSERT_TRUE(ref.ok()) << ref.status();
  // Both forms of the fast step: the AVX2/FMA kernels (where this CPU has them; the one-hidden-
  // layer cases use them) and the Eigen products.
  for (const bool vector_kernels : {true, false}) {
    SCOPED_TRACE(vector_kernels ? "vector kernels" : "Eigen products");
    MlpTrainStep fast;
    fast.set_vector_kernels(vector_kernels);
    TrainStepOutput out;
    // Twice: the second call reuses the first one's buffers and must give the same result.
    for (int run = 0; run < 2; ++run) {
      ASSERT_TRUE(fast.Run(decoder, in, &out).ok());
      EXPECT_NEAR(out.loss, ref->loss, 1e-5f * std::abs(ref->loss)) << "run " << run;
      EXPECT_LT(MaxRelDiff(out.grad_features, ref->grad_features), 1e-4f) << "run " << run;
      if (c.train_decoder) {
        EXPECT_LT(MaxRelDiff(out.grad_params, ref->grad_params), 1e-4f) << "run " << run;
      } else {
        EXPECT_TRUE(out.grad_params.empty());
      }
    }
    // Spread over threads: bit for bit the same (rows go in fixed chunks whatever the threads).
    WorkerPool pool(3);
    TrainStepOutput threaded;
    ASSERT_TRUE(fast.Run(decoder, in, &threaded, &pool).ok());
    EXPECT_EQ(threaded.loss, out.loss);
    EXPECT_EQ(threaded.grad_features, out.grad_features);
    EXPECT_EQ(threaded.grad_params, out.grad_params);
    // The gradient is not trivially zero.
    float norm = 0.f;
    for (float g : out.grad_features) norm += g * g;
    EXPECT_GT(norm, 0.f);
  }
}

// The kernels against the Eigen products on the preset's shape and on the other widths they
// take (8–64 hidden units, 8–64 inputs), with dead ReLUs and a zero upstream gradient in the
// batch. Skipped on CPUs without AVX2 and FMA, where only the Eigen form runs.
TEST(MlpStepKernelTest, VectorKernelsMatchTheEigenProducts) {
  if (!MlpTrainStep::VectorKernelsAvailable())
    GTEST_SKIP() << "this CPU has no AVX2/FMA: the vector kernels never run here";
  for (const auto [inputs, width] :
       {std::pair{24, 32}, std::pair{8, 8}, std::pair{64, 64}, std::pair{16, 40}}) {
    for (const bool train : {false, true}) {
      SCOPED_TRACE("inputs " + std::to_string(inputs) + " width " + std::to_string(width) +
                   (train ? " training" : " frozen"));
      DecoderConfig dc;
      dc.hidden_layers = 1;
      dc.hidden_width = width;
      dc.seed = 5;
      Decoder decoder(inputs, dc);
      const auto batch = RandomBatch(3000, 2400, inputs, 1.f, 8, 0.1f, train);
      const TrainStepInput& in = batch->in;
      MlpTrainStep kernels, eigen;
      eigen.set_vector_kernels(false);
      TrainStepOutput a, b;
      ASSERT_TRUE(kernels.Run(decoder, in, &a).ok());
      ASSERT_TRUE(eigen.Run(decoder, in, &b).ok());
      EXPECT_NEAR(a.loss, b.loss, 1e-6f * std::abs(b.loss));
      EXPECT_LT(MaxRelDiff(a.grad_features, b.grad_features), 1e-5f);
      if (train) EXPECT_LT(MaxRelDiff(a.grad_params, b.grad_params), 1e-5f);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Decoders, MlpStepTest,
                         ::testing::Values(Case{0, 0.f, true}, Case{1, 0.f, true},
                                           Case{1, 0.f, false}, Case{1, 0.1f, true},
                                           Case{1, 0.1f, false}, Case{2, 0.1f, true}));

TEST(MlpStepShapeTest, RejectsBadShapes) {
  DecoderConfig dc;
  Decoder decoder(kInput, dc);
  std::vector<float> features(10 * kInput, 0.f), labels(10, 0.f);
  TrainStepInput in;
  in.features = features.data();
  in.rows = 10;
  in.labelled = 11;  // more labelled rows than rows
  in.labels = labels.data();
  MlpTrainStep fast;
  TrainStepOutput out;
  const absl::Status s = fast.Run(decoder, in, &out);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("labelled"), std::string::npos) << s;
}

TEST(MlpStepShapeTest, NoLabelledRowsGivesZeroLoss) {
  DecoderConfig dc;
  Decoder decoder(kInput, dc);
  std::vector<float> features(6 * kInput, 0.1f);
  TrainStepInput in;
  in.features = features.data();
  in.rows = 6;
  in.labelled = 0;
  MlpTrainStep fast;
  TrainStepOutput out;
  ASSERT_TRUE(fast.Run(decoder, in, &out).ok());
  EXPECT_EQ(out.loss, 0.f);
  for (float g : out.grad_features) EXPECT_EQ(g, 0.f);
}

}  // namespace
}  // namespace rim
