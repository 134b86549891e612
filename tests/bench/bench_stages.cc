// One training iteration at the maicity preset, stage by stage (§3.4 step 3, DESIGN.md §7), after
// a warm-up of Options().warmup_frames frames. Each Stage/* benchmark repeats one stage on the
// real output of the stage before it; Iteration/* runs Trainer::Iterate whole and reports the
// trainer's own per-stage split as counters (ms per iteration).
#include <benchmark/benchmark.h>

#include <memory>

#include "bench/bench_common.h"
#include "bench/training_fixture.h"

namespace rim::bench {
namespace {

TrainingFixture& Fixture() { return SharedTrainingFixture(); }

void SetBatchCounters(benchmark::State& state, TrainingFixture& f) {
  state.counters["samples"] = double(f.batch().size());
  state.counters["touched_rows"] = double(f.TouchedRows());
}

void BM_StageSample(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  for (auto _ : state) f.Sample();
  state.counters["samples"] = double(f.batch().size());
  state.counters["buffer_points"] = double(f.buffer().size());
  f.PrepareBatch();  // leave a consistent batch for the next stages
}

void BM_StageEncode(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  for (auto _ : state) f.Encode();
  SetBatchCounters(state, f);
}

// Arg: 1 while the decoder trains (first frames), 0 once it is frozen (features only).
void BM_StageTrainStep(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  const bool train_decoder = state.range(0) != 0;
  double forward_s = 0, backward_s = 0;
  for (auto _ : state) {
    f.TrainStep(train_decoder);
    forward_s += f.step_output().forward_s;
    backward_s += f.step_output().backward_s;
  }
  state.counters["forward_ms"] =
      benchmark::Counter(1e3 * forward_s, benchmark::Counter::kAvgIterations);
  state.counters["backward_ms"] =
      benchmark::Counter(1e3 * backward_s, benchmark::Counter::kAvgIterations);
  SetBatchCounters(state, f);
  f.TrainStep(true);
}

void BM_PlainForward(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  for (auto _ : state) f.PlainForward();
  state.counters["samples"] = double(f.batch().size());
}

void BM_StageScatter(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  for (auto _ : state) f.Scatter();
  SetBatchCounters(state, f);
}

void BM_StageAdamFeatures(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  f.SaveOptimiserState();
  for (auto _ : state) f.AdamFeatures();
  f.RestoreOptimiserState();
  SetBatchCounters(state, f);
}

void BM_StageAdamDecoder(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  f.SaveOptimiserState();
  for (auto _ : state) f.AdamDecoder();
  f.RestoreOptimiserState();
}

// The optimiser step as the trainer times it, less observed marking: scatter, lazy feature Adam,
// decoder Adam.
void BM_StageOptimiserStep(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  f.SaveOptimiserState();
  for (auto _ : state) {
    f.Scatter();
    f.AdamFeatures();
    f.AdamDecoder();
  }
  f.RestoreOptimiserState();
  SetBatchCounters(state, f);
}

// Arg: 1 while the decoder trains, 0 once it is frozen.
void BM_TrainIteration(benchmark::State& state) {
  TrainingFixture& f = Fixture();
  const bool train_decoder = state.range(0) != 0;
  IterationTiming t;
  for (auto _ : state) {
    auto loss = f.trainer().Iterate(f.buffer(), f.outside(), train_decoder, &t);
    CheckOk(loss.status(), "Trainer::Iterate");
  }
  auto per_iteration = [](double s) {
    return benchmark::Counter(1e3 * s, benchmark::Counter::kAvgIterations);
  };
  state.counters["sample_ms"] = per_iteration(t.sample_s);
  state.counters["encode_ms"] = per_iteration(t.encode_s);
  state.counters["forward_ms"] = per_iteration(t.forward_s);
  state.counters["backward_ms"] = per_iteration(t.backward_s);
  state.counters["step_ms"] = per_iteration(t.step_s);
  state.counters["samples"] = double(f.trainer().last_batch().size());
}

}  // namespace

void RegisterStageBenchmarks() {
  auto ms = [](benchmark::internal::Benchmark* b) {
    b->Unit(benchmark::kMillisecond)->UseRealTime();
  };
  ms(benchmark::RegisterBenchmark("Stage/Sample", BM_StageSample));
  ms(benchmark::RegisterBenchmark("Stage/Encode", BM_StageEncode));
  ms(benchmark::RegisterBenchmark("Stage/TrainStep", BM_StageTrainStep)
         ->ArgName("decoder")
         ->Arg(1)
         ->Arg(0));
  ms(benchmark::RegisterBenchmark("Reference/DecoderForwardWithInputGradient", BM_PlainForward));
  ms(benchmark::RegisterBenchmark("Stage/Scatter", BM_StageScatter));
  ms(benchmark::RegisterBenchmark("Stage/AdamFeatures", BM_StageAdamFeatures));
  ms(benchmark::RegisterBenchmark("Stage/AdamDecoder", BM_StageAdamDecoder));
  ms(benchmark::RegisterBenchmark("Stage/OptimiserStep", BM_StageOptimiserStep));
  ms(benchmark::RegisterBenchmark("Iteration/maicity", BM_TrainIteration)
         ->ArgName("decoder")
         ->Arg(1)
         ->Arg(0));
}

}  // namespace rim::bench
