// Reference/*: not rim's code paths, but measured floors for the optimisations BENCHMARK.md
// proposes, on the same batch as the Stage/* benchmarks (SharedTrainingFixture()).
//
// - AdamFeaturesSlotOrder: the lazy Adam loop of Stage/AdamFeatures, visiting the touched rows in
//   storage order instead of first-touch order. The gap between the two is what the random
//   access pattern costs; the one-off sort is reported as a counter.
// - AdamFeaturesContiguous: the same updates on the rows copied out into contiguous arrays: the
//   arithmetic alone.
// - BatchedMlp/decoder:0,1: forward, BCE-with-logits gradient and backward of the 1-hidden-layer
//   decoder as three dense Eigen products over the batch, what a hand-written replacement of
//   RunTrainStep would cost. Checked against libtorch's feature gradient (max_rel_diff).
// - Iteration/OnBatch/fast,reference: a whole iteration on the same batch, Trainer's path against
//   the dense libtorch reference (ReferenceTrainer), side by side.
#include <benchmark/benchmark.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <memory>
#include <numeric>
#include <vector>

#include "bench/bench_common.h"
#include "bench/training_fixture.h"
#include "rim/train/train_step.h"

namespace rim::bench {
namespace {

using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

void BM_AdamFeaturesSlotOrder(benchmark::State& state) {
  TrainingFixture& f = SharedTrainingFixture();
  const MapGeometry& geo = f.map().geometry();
  const int D = geo.feature_dim();
  const TrainConfig& t = f.config().train;
  const AdamHyper hyper{t.learning_rate, t.adam_beta1, t.adam_beta2, t.adam_eps};
  std::vector<std::vector<int32_t>> order(geo.levels());
  WallClock sort_clock;
  sort_clock.Start();
  for (int l = 0; l < geo.levels(); ++l) {
    const std::vector<int64_t>& touched = f.gradient().level(l).touched;
    order[l].resize(touched.size());
    std::iota(order[l].begin(), order[l].end(), 0);
    std::sort(order[l].begin(), order[l].end(),
              [&](int32_t a, int32_t b) { return touched[a] < touched[b]; });
  }
  sort_clock.Stop();
  f.SaveOptimiserState();
  for (auto _ : state) {
    for (int l = 0; l < geo.levels(); ++l) {
      LocalMap::Level& lv = f.map().level(l);
      SparseGradient::Level& g = f.gradient().level(l);
      for (int32_t r : order[l]) {
        const int64_t slot = g.touched[r];
        float step_size, inv_sqrt_bc2;
        f.bias().Get(++lv.adam_steps(slot), &step_size, &inv_sqrt_bc2);
        AdamUpdateRow(hyper, step_size, inv_sqrt_bc2, D, &g.grad[size_t(r) * D], lv.features(slot),
                      lv.adam_m(slot), lv.adam_v(slot));
      }
    }
  }
  f.RestoreOptimiserState();
  state.counters["touched_rows"] = double(f.TouchedRows());
  state.counters["sort_ms"] = 1e3 * sort_clock.seconds();
}

// The same row updates on the touched rows copied into contiguous arrays: the compute alone,
// without the random access into the dense grids.
void BM_AdamFeaturesContiguous(benchmark::State& state) {
  TrainingFixture& f = SharedTrainingFixture();
  const MapGeometry& geo = f.map().geometry();
  const int D = geo.feature_dim();
  const TrainConfig& t = f.config().train;
  const AdamHyper hyper{t.learning_rate, t.adam_beta1, t.adam_beta2, t.adam_eps};
  struct Rows {
    std::vector<float> features, m, v;
    std::vector<int32_t> steps;
  };
  std::vector<Rows> rows(geo.levels());
  for (int l = 0; l < geo.levels(); ++l) {
    const LocalMap::Level& lv = f.map().level(l);
    for (int64_t slot : f.gradient().level(l).touched) {
      rows[l].features.insert(rows[l].features.end(), lv.features(slot), lv.features(slot) + D);
      rows[l].m.insert(rows[l].m.end(), lv.adam_m(slot), lv.adam_m(slot) + D);
      rows[l].v.insert(rows[l].v.end(), lv.adam_v(slot), lv.adam_v(slot) + D);
      rows[l].steps.push_back(lv.adam_steps(slot));
    }
  }
  for (auto _ : state) {
    for (int l = 0; l < geo.levels(); ++l) {
      Rows& r = rows[l];
      const std::vector<float>& grad = f.gradient().level(l).grad;
      for (size_t i = 0; i < r.steps.size(); ++i) {
        float step_size, inv_sqrt_bc2;
        f.bias().Get(++r.steps[i], &step_size, &inv_sqrt_bc2);
        AdamUpdateRow(hyper, step_size, inv_sqrt_bc2, D, &grad[i * D], &r.features[i * D],
                      &r.m[i * D], &r.v[i * D]);
      }
    }
    benchmark::ClobberMemory();
  }
  state.counters["touched_rows"] = double(f.TouchedRows());
}

// Arg: 1 also computes the decoder's parameter gradient (while it trains).
void BM_BatchedMlp(benchmark::State& state) {
  TrainingFixture& f = SharedTrainingFixture();
  const Decoder& decoder = f.decoder();
  if (decoder.layers().size() != 2) {
    state.SkipWithError("written for decoder.hidden_layers = 1");
    return;
  }
  const bool train_decoder = state.range(0) != 0;
  const Decoder::Layer& L1 = decoder.layers()[0];
  const Decoder::Layer& L2 = decoder.layers()[1];
  const float* p = decoder.params().data();
  const Eigen::Map<const RowMatrix> W1(p + L1.weight_offset, L1.out, L1.in);
  const Eigen::Map<const Eigen::RowVectorXf> b1(p + L1.bias_offset, L1.out);
  const Eigen::Map<const Eigen::VectorXf> w2(p + L2.weight_offset, L2.in);
  const float b2 = p[L2.bias_offset];
  const int n = int(f.batch().size());
  const Eigen::Map<const RowMatrix> X(f.features().data(), n, L1.in);
  const Eigen::Map<const Eigen::VectorXf> labels(f.batch().labels.data(), n);
  const float inv_sigma = 1.f / f.config().train.sigma_m;
  const Eigen::VectorXf target =
      labels.unaryExpr([&](float d) { return 1.f / (1.f + std::exp(d * inv_sigma)); });

  RowMatrix H(n, L1.out), dH(n, L1.out), dX(n, L1.in), dW1(L1.out, L1.in);
  Eigen::VectorXf y(n), dy(n), dw2(L2.in);
  Eigen::RowVectorXf db1(L1.out);
  for (auto _ : state) {
    H.noalias() = X * W1.transpose();
    H.rowwise() += b1;
    H = H.cwiseMax(0.f);
    y.noalias() = H * w2;
    // d mean BCE(sigmoid(s), target) / d y with s = −(y + b2)/σ: (sigmoid(s) − target)·(−1/σ)/n.
    for (int i = 0; i < n; ++i) {
      const float s = -(y[i] + b2) * inv_sigma;
      dy[i] = (1.f / (1.f + std::exp(-s)) - target[i]) * (-inv_sigma / float(n));
    }
    dH.noalias() = dy * w2.transpose();
    dH = (H.array() > 0.f).select(dH, 0.f);
    dX.noalias() = dH * W1;
    if (train_decoder) {
      dW1.noalias() = dH.transpose() * X;
      db1 = dH.colwise().sum();
      dw2.noalias() = H.transpose() * dy;
    }
    benchmark::DoNotOptimize(dX.data());
  }
  // Same gradient as libtorch's (RunTrainStep on this batch, decoder frozen)?
  f.TrainStep(false);
  const Eigen::Map<const RowMatrix> torch_dX(f.step_output().grad_features.data(), n, L1.in);
  const float scale = std::max(torch_dX.cwiseAbs().maxCoeff(), 1e-30f);
  state.counters["max_rel_diff"] = (dX - torch_dX).cwiseAbs().maxCoeff() / scale;
  state.counters["samples"] = double(n);
  f.TrainStep(true);
}

// One whole training iteration on the fixture's batch (decoder frozen): Trainer's fast path
// against ReferenceTrainer (libtorch ops over the dense grids, dense Adam over every row). Both
// leave the touched rows as they found them afterwards.
void BM_IterationOnBatch(benchmark::State& state, bool reference) {
  TrainingFixture& f = SharedTrainingFixture();
  f.SaveOptimiserState();
  std::unique_ptr<ReferenceTrainer> ref;
  if (reference)
    ref = std::make_unique<ReferenceTrainer>(f.config(), &f.map(), &f.mutable_decoder());
  const SampleBatch& batch = f.batch();
  for (auto _ : state) {
    absl::StatusOr<float> loss =
        reference ? ref->Iterate(batch.xyz.data(), batch.labels.data(), int(batch.size()), false)
                  : f.trainer().IterateOn(batch, false, nullptr);
    CheckOk(loss.status(), "iteration");
    benchmark::DoNotOptimize(*loss);
  }
  f.RestoreOptimiserState();
  state.counters["samples"] = double(batch.size());
}

}  // namespace

void RegisterReferenceBenchmarks() {
  benchmark::RegisterBenchmark("Iteration/OnBatch/fast", BM_IterationOnBatch, false)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
  benchmark::RegisterBenchmark("Iteration/OnBatch/reference", BM_IterationOnBatch, true)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
  benchmark::RegisterBenchmark("Reference/AdamFeaturesSlotOrder", BM_AdamFeaturesSlotOrder)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
  benchmark::RegisterBenchmark("Reference/AdamFeaturesContiguous", BM_AdamFeaturesContiguous)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
  benchmark::RegisterBenchmark("Reference/BatchedMlp", BM_BatchedMlp)
      ->ArgName("decoder")
      ->Arg(1)
      ->Arg(0)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
}

}  // namespace rim::bench
