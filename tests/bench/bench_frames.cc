// Whole frames through Mapper::IntegrateScan (Alg. 1) on the city sequence.
//
// Frame/PRESET: a fresh mapper integrates Options().warmup_frames frames untimed, then each
// benchmark iteration is the next frame, Options().measured_frames of them. Wall time is ms per
// frame; the counters are the mapper's own StageTimings, ms per frame.
//
// Stage/Slide, Stage/Preprocess, Stage/Transient: the same frames at maicity_online, each
// benchmark's time the one stage's (manual time), so that its median and spread are reported on
// their own. Stage/RangeImage: the moving-things filter's range image of each frame's scan alone
// (RangeImage::Fill over two threads), with no mapper.
//
// Sequence/PRESET (long mode only): the whole sequence from an empty map, with resident memory
// and sub-map bytes recorded every frame (counters every 10 frames, all frames in the CSV).
#include <benchmark/benchmark.h>

#include <chrono>
#include <cstdio>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "bench/bench_common.h"
#include "rim/base/worker_pool.h"
#include "rim/train/transient.h"

namespace rim::bench {
namespace {

std::unique_ptr<Mapper> NewMapper(const std::string& preset,
                                  const std::vector<std::string>& overrides = {}) {
  MapperConfig config = Preset(preset);
  CheckOk(ApplyOverrides(overrides, &config), "ApplyOverrides");
  absl::StatusOr<std::unique_ptr<Mapper>> mapper = Mapper::Create(config);
  CheckOk(mapper.status(), "Mapper::Create");
  return *std::move(mapper);
}

void SetStageCounters(benchmark::State& state, const StageTimings& t) {
  auto per_frame = [](double s) {
    return benchmark::Counter(1e3 * s, benchmark::Counter::kAvgIterations);
  };
  state.counters["slide_ms"] = per_frame(t.slide_s);
  state.counters["preprocess_ms"] = per_frame(t.preprocess_s);
  state.counters["sample_ms"] = per_frame(t.sample_s);
  state.counters["encode_ms"] = per_frame(t.encode_s);
  state.counters["forward_ms"] = per_frame(t.forward_s);
  state.counters["backward_ms"] = per_frame(t.backward_s);
  state.counters["step_ms"] = per_frame(t.step_s);
  state.counters["distance_ms"] = per_frame(t.distance_s);
  state.counters["total_ms"] = per_frame(t.total_s);
  state.counters["iterations"] =
      benchmark::Counter(t.iterations, benchmark::Counter::kAvgIterations);
}

// A fresh mapper integrates the warm-up frames untimed, then one frame per benchmark iteration;
// `after_frame` sees each measured frame's StageTimings. The stage counters are set at the end.
template <typename Fn>
void RunFrames(benchmark::State& state, const std::string& preset,
               const std::vector<std::string>& overrides, Fn&& after_frame,
               CityKind city = CityKind::kDefault) {
  const std::vector<PosedScan>& frames = CitySequence(city);
  std::unique_ptr<Mapper> mapper = NewMapper(preset, overrides);
  size_t k = 0;
  for (; k < size_t(Options().warmup_frames) && k < frames.size(); ++k)
    CheckOk(mapper->IntegrateScan(frames[k]), "IntegrateScan (warm-up)");
  StageTimings sum;
  for (auto _ : state) {
    if (k >= frames.size()) {
      state.SkipWithError("the sequence is shorter than warm-up plus measured frames");
      break;
    }
    StageTimings t;
    CheckOk(mapper->IntegrateScan(frames[k++], -1, &t), "IntegrateScan");
    after_frame(t);
    sum += t;
  }
  SetStageCounters(state, sum);
}

void BM_Frame(benchmark::State& state, const std::string& preset,
              const std::vector<std::string>& overrides, CityKind city) {
  RunFrames(
      state, preset, overrides, [](const StageTimings&) {}, city);
  state.counters["rss_mb"] = double(ResidentBytes()) / (1 << 20);
}

// Stage/Slide, Stage/Preprocess and Stage/Refresh: per-frame stages of IntegrateScan outside the
// training iterations, each timed on its own (manual time) while the mapper runs whole frames as
// Frame/ does. The distance field is refreshed every query.refresh_frames frames, so Refresh's
// time is the refresh's cost per frame on average (zero on the frames between refreshes).
enum class FrameStage { kSlide, kPreprocess, kTransient, kRefresh };

void BM_FrameStage(benchmark::State& state, const std::string& preset,
                   const std::vector<std::string>& overrides, FrameStage stage, CityKind city) {
  RunFrames(
      state, preset, overrides,
      [&](const StageTimings& t) {
        state.SetIterationTime(stage == FrameStage::kSlide        ? t.slide_s
                               : stage == FrameStage::kPreprocess ? t.preprocess_s
                               : stage == FrameStage::kTransient  ? t.transient_s
                                                                  : t.distance_s);
      },
      city);
}

// The range image that the moving-things filter judges against, filled from each frame's scan in
// turn with the preset's settings, on a pool of two threads as a mapper's trainer pool.
void BM_RangeImage(benchmark::State& state) {
  const std::vector<PosedScan>& frames = CitySequence();
  const MapperConfig config = Preset("maicity_online");
  const TransientConfig& c = config.transient;
  RangeImage image(c.bin_deg);
  RangeImage::Scratch scratch;
  WorkerPool pool(2);
  size_t k = 0, points = 0;
  for (auto _ : state) {
    const PosedScan& scan = frames[k++ % frames.size()];
    image.Fill(scan.points_S, config.buffer.min_range_m, config.buffer.max_range_m, &pool,
               c.fired_row_share, &scratch);
    points += scan.points_S.size();
    benchmark::DoNotOptimize(image.rows());
  }
  state.counters["points"] = benchmark::Counter(double(points), benchmark::Counter::kAvgIterations);
  state.counters["rows"] = double(image.rows());
}

void BM_Sequence(benchmark::State& state, const std::string& preset) {
  const std::vector<PosedScan>& frames = CitySequence();
  std::FILE* csv = nullptr;
  if (!Options().rss_csv.empty()) {
    const std::string path = Options().rss_csv + "." + preset + ".csv";
    csv = std::fopen(path.c_str(), "w");
    if (csv) std::fprintf(csv, "frame,ms,rss_bytes,submap_bytes,local_map_bytes\n");
  }
  for (auto _ : state) {
    std::unique_ptr<Mapper> mapper = NewMapper(preset);
    StageTimings sum;
    for (size_t k = 0; k < frames.size(); ++k) {
      StageTimings t;
      CheckOk(mapper->IntegrateScan(frames[k], -1, &t), "IntegrateScan");
      sum += t;
      const int64_t rss = ResidentBytes();
      const MapperStats stats = mapper->Stats();
      if (csv)
        std::fprintf(csv, "%zu,%.3f,%lld,%lld,%lld\n", k, 1e3 * t.total_s, (long long)rss,
                     (long long)stats.submap_bytes, (long long)stats.local_map_bytes);
      if (k % 10 == 0 || k + 1 == frames.size()) {
        char name[32];
        std::snprintf(name, sizeof(name), "rss_mb_f%03zu", k);
        state.counters[name] = double(rss) / (1 << 20);
        std::snprintf(name, sizeof(name), "submap_mb_f%03zu", k);
        state.counters[name] = double(stats.submap_bytes) / (1 << 20);
      }
    }
    state.counters["frames"] = double(frames.size());
    state.counters["ms_per_frame"] = 1e3 * sum.total_s / double(frames.size());
    state.counters["step_ms_per_frame"] = 1e3 * sum.step_s / double(frames.size());
  }
  if (csv) std::fclose(csv);
}

}  // namespace

void RegisterFrameBenchmarks() {
  // The default path (fast step, train.threads = 2) and, in the same run, one thread and the
  // libtorch reference step on one thread (the path before the fast step), so that BENCHMARK.md
  // can quote ratios measured side by side.
  const std::vector<std::pair<std::string, std::vector<std::string>>> variants = {
      {"", {}},
      {"/threads:1", {"train.threads=1"}},
      {"/libtorch,threads:1", {"train.step=libtorch", "train.threads=1"}}};
  for (const char* preset : {"maicity", "maicity_online"}) {
    for (const auto& [suffix, overrides] : variants) {
      benchmark::RegisterBenchmark((std::string("Frame/") + preset + suffix).c_str(), BM_Frame,
                                   std::string(preset), overrides, CityKind::kDefault)
          ->Iterations(Options().measured_frames)
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime();
    }
  }
  // The same presets on a city whose facades stand beyond the local box: most returns off
  // buildings end outside it, which is what the outside rays and the deferred store cost.
  for (const char* preset : {"maicity", "maicity_online"}) {
    benchmark::RegisterBenchmark((std::string("Frame/far/") + preset).c_str(), BM_Frame,
                                 std::string(preset), std::vector<std::string>{},
                                 CityKind::kFarReturns)
        ->Iterations(Options().measured_frames)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
  }
}

void RegisterFrameStageBenchmarks() {
  // The box moves with the robot at every preset's speed the same way: one preset is enough.
  for (const auto& [name, stage] : {std::pair{"Stage/Slide", FrameStage::kSlide},
                                    std::pair{"Stage/Preprocess", FrameStage::kPreprocess},
                                    std::pair{"Stage/Transient", FrameStage::kTransient}}) {
    benchmark::RegisterBenchmark(name, BM_FrameStage, std::string("maicity_online"),
                                 std::vector<std::string>{}, stage, CityKind::kDefault)
        ->Iterations(Options().measured_frames)
        ->Unit(benchmark::kMillisecond)
        ->UseManualTime();
  }
  benchmark::RegisterBenchmark("Stage/RangeImage", BM_RangeImage)
      ->Iterations(20 * Options().measured_frames)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
  // The refresh on the far-return city at the floor a loaded server trains at (3 iterations a
  // frame), where it is the largest stage of a frame; twice measured_frames after the warm-up (by
  // default 40 frames and 4 refreshes with query.refresh_frames = 10; measured_frames holds 2).
  benchmark::RegisterBenchmark(
      "Stage/Refresh/far", BM_FrameStage, std::string("maicity"),
      std::vector<std::string>{"train.iterations=3", "train.min_iterations=3"},
      FrameStage::kRefresh, CityKind::kFarReturns)
      ->Iterations(2 * Options().measured_frames)
      ->Unit(benchmark::kMillisecond)
      ->UseManualTime();
}

void RegisterSequenceBenchmarks() {
  for (const char* preset : {"maicity", "maicity_online"}) {
    benchmark::RegisterBenchmark((std::string("Sequence/") + preset).c_str(), BM_Sequence,
                                 std::string(preset))
        ->Iterations(1)
        ->Repetitions(1)
        ->Unit(benchmark::kSecond)
        ->UseRealTime();
  }
}

}  // namespace rim::bench
