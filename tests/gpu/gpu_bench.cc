// rim_gpu_bench: the GPU path's throughput on the maicity geometry (a 20 × 20 × 6 m box, 3
// levels, D = 8, one hidden layer of 32), with random features and a random decoder:
//  - SDF and SDF+gradient queries of points drawn uniformly in the box, device-resident, and a
//    host round trip;
//  - one training iteration (a maicity-sized batch: 2048 rays × 6 samples and 1024 eikonal
//    probe groups) on the device, against the CPU path's iteration on this host's cores;
//  - device memory over 500 iterations;
//  - robots per GPU: N maps, each running 30 iterations a frame, all N frames within 100 ms.
// Prints a table and writes JSON (--out). Run by tests/gpu/run.sh; results in BENCHMARK.md.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "gpu/gpu_common.h"
#include "nlohmann/json.hpp"
#include "rim/base/flags.h"
#include "rim/base/worker_pool.h"
#include "rim/gpu/device_map.h"
#include "rim/model/encoder.h"
#include "rim/train/mlp_step.h"
#include "rim/train/trainer.h"

namespace rim {
namespace {

double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

int Fail(const absl::Status& s) {
  std::fprintf(stderr, "rim_gpu_bench: %s\n", s.ToString().c_str());
  return 1;
}

int Main(int argc, char** argv) {
  CLI::App app("rim_gpu_bench: the GPU path's throughput (BENCHMARK.md, \"GPU path\")");
  std::string out_path;
  int max_robots = 64;
  int query_reps = 20;
  app.add_option("--out", out_path, "write the results as JSON here");
  app.add_option("--max-robots", max_robots, "largest N tried for robots per GPU");
  app.add_option("--query-reps", query_reps, "timed runs per query size");
  CLI11_PARSE(app, argc, argv);

  absl::StatusOr<gpu::DeviceInfo> info = gpu::OpenDevice(0);
  if (!info.ok()) return Fail(info.status());
  nlohmann::json out;
  out["device"] = info->name;
  out["multiprocessors"] = info->multiprocessors;
  out["device_memory_gib"] = double(info->memory_bytes) / (1 << 30);
  std::printf("device: %s, %d SMs, %.1f GiB\n", info->name.c_str(), info->multiprocessors,
              double(info->memory_bytes) / (1 << 30));

  absl::StatusOr<MapperConfig> config = MakePreset("maicity");
  if (!config.ok()) return Fail(config.status());
  const MapGeometry geo(config->grid);
  LocalMap map(geo);
  gpu_testing::PlaceAndFill(&map, 1);
  Decoder decoder(geo.encoding_dim(), config->decoder);
  gpu_testing::PerturbDecoder(&decoder, 2);
  const gpu::TrainSettings settings = gpu::TrainSettings::From(*config, geo);
  double t0 = Now();
  absl::StatusOr<std::unique_ptr<gpu::DeviceMap>> dm = gpu::DeviceMap::Create(map, decoder, 0);
  if (!dm.ok()) return Fail(dm.status());
  std::printf("map: %lld slots at level 0, %.0f MB on the device, created in %.2f s\n",
              (long long)map.level(0).slots(), (*dm)->device_bytes() / 1e6, Now() - t0);

  // Queries.
  nlohmann::json queries = nlohmann::json::array();
  std::printf("\n%-28s %12s %14s\n", "queries (device-resident)", "ms", "M points/s");
  for (int n : {1 << 20, 1 << 24}) {
    for (bool gradient : {false, true}) {
      absl::StatusOr<double> ms = (*dm)->TimeQueries(n, gradient, query_reps, 99);
      if (!ms.ok()) return Fail(ms.status());
      const double rate = n / (*ms * 1e-3) / 1e6;
      std::printf("%-28s %12.3f %14.0f\n",
                  (std::to_string(n) + (gradient ? " sdf+gradient" : " sdf")).c_str(), *ms, rate);
      queries.push_back({{"points", n}, {"gradient", gradient}, {"ms", *ms}, {"mpoints_s", rate}});
      if (n == 1 << 24) out[gradient ? "query_gradient_mpoints_s" : "query_sdf_mpoints_s"] = rate;
    }
  }
  out["queries"] = queries;
  {
    const int n = 1 << 20;
    const std::vector<float> xyz = gpu_testing::RandomPointsInBox(map, n, 1e-3, 5);
    std::vector<float> sdf(n), grad(3 * size_t(n));
    std::vector<double> walls;
    for (int r = 0; r < 6; ++r) {
      const double s = Now();
      if (absl::Status st = (*dm)->Query(xyz.data(), n, sdf.data(), grad.data()); !st.ok())
        return Fail(st);
      if (r > 0) walls.push_back((Now() - s) * 1e3);
    }
    const double ms = Median(walls);
    std::printf("%-28s %12.3f %14.0f\n", "1048576 sdf+gradient, host", ms, n / (ms * 1e-3) / 1e6);
    out["query_host_roundtrip"] = {{"points", n}, {"ms", ms}, {"mpoints_s", n / (ms * 1e-3) / 1e6}};
  }

  // One training iteration.
  const int rays = config->sampler.rays_per_iteration;
  const int labelled = rays * (config->sampler.surface_samples + config->sampler.free_samples);
  gpu_testing::Batch batch =
      gpu_testing::SurfaceBatch(map, labelled, 1024, settings.eikonal_step_m, 3);
  nlohmann::json train;
  train["rows"] = batch.rows;
  train["labelled"] = batch.labelled;
  std::printf("\ntraining batch: %d rows (%d labelled, %d eikonal probes)\n", batch.rows,
              batch.labelled, batch.rows - batch.labelled);
  for (bool train_decoder : {true, false}) {
    absl::StatusOr<float> loss = (*dm)->Iterate(batch.xyz.data(), batch.rows, batch.labelled,
                                                batch.labels.data(), settings, train_decoder);
    if (!loss.ok()) return Fail(loss.status());
    absl::StatusOr<double> ms = (*dm)->TimeIterations(50, settings, train_decoder);
    if (!ms.ok()) return Fail(ms.status());
    std::printf("GPU iteration (%s decoder): %.3f ms (median of 50)\n",
                train_decoder ? "training the" : "frozen", *ms);
    train[train_decoder ? "gpu_ms_decoder_training" : "gpu_ms_decoder_frozen"] = *ms;
    if (train_decoder) train["gpu_ms_30_iterations"] = 30 * *ms;
    absl::StatusOr<gpu::DeviceMap::StageTimes> st = (*dm)->TimeStages(50, settings, train_decoder);
    if (!st.ok()) return Fail(st.status());
    std::printf(
        "  stages, ms: memsets %.4f, check %.4f, forward %.4f, loss %.4f, backward %.4f, "
        "scatter %.4f, feature Adam %.4f, decoder Adam %.4f\n",
        st->memsets, st->check, st->forward, st->loss, st->backward, st->scatter, st->feature_adam,
        st->decoder_adam);
    train[train_decoder ? "stages_ms_decoder_training" : "stages_ms_decoder_frozen"] = {
        {"memsets", st->memsets},           {"check", st->check},
        {"forward", st->forward},           {"loss", st->loss},
        {"backward", st->backward},         {"scatter", st->scatter},
        {"feature_adam", st->feature_adam}, {"decoder_adam", st->decoder_adam}};
  }
  {  // One iteration with its host transfers and the loss read back.
    std::vector<double> walls;
    for (int r = 0; r < 11; ++r) {
      const double s = Now();
      absl::StatusOr<float> loss = (*dm)->Iterate(batch.xyz.data(), batch.rows, batch.labelled,
                                                  batch.labels.data(), settings, false);
      if (!loss.ok()) return Fail(loss.status());
      if (r > 0) walls.push_back((Now() - s) * 1e3);
    }
    train["gpu_ms_with_transfers"] = Median(walls);
    std::printf("GPU iteration with upload and loss read back: %.3f ms\n", Median(walls));
  }
  // The CPU path's iteration (encode, decoder step, scatter, lazy Adam) on this host.
  for (int threads : {2, 16}) {
    WorkerPool pool(threads);
    LocalEncoding enc;
    std::vector<float> features(size_t(batch.rows) * geo.encoding_dim());
    MlpTrainStep mlp;
    TrainStepOutput step;
    SparseGradient sg;
    sg.Reset(map);
    const AdamBiasTable bias(settings.adam);
    std::vector<double> walls;
    for (int r = 0; r < 11; ++r) {
      const double s = Now();
      EncodeLocal(map, batch.xyz.data(), batch.rows, &enc, features.data(), &pool);
      TrainStepInput in;
      in.features = features.data();
      in.rows = batch.rows;
      in.labelled = batch.labelled;
      in.labels = batch.labels.data();
      in.sigma_m = settings.sigma_m;
      in.eikonal_weight = settings.eikonal_weight;
      in.eikonal_step_m = settings.eikonal_step_m;
      in.train_decoder = false;
      if (absl::Status st = mlp.Run(decoder, in, &step, &pool); !st.ok()) return Fail(st);
      sg.BeginIteration(&map);
      sg.Scatter(&map, enc, step.grad_features.data(), &pool);
      pool.Run(geo.levels(), [&](int l) {
        SparseGradient::Level& g = sg.level(l);
        UpdateTouchedRows(settings.adam, bias, g, 0, g.touched.size(), &map.level(l));
      });
      if (r > 0) walls.push_back((Now() - s) * 1e3);
    }
    std::printf("CPU iteration, %2d threads on this host: %.3f ms\n", threads, Median(walls));
    train["cpu_ms_threads_" + std::to_string(threads)] = Median(walls);
  }
  out["training"] = train;

  // A Mapper's frame on the device: the host box slides one coarse cell, SyncFromHost sends the
  // entering rows and the flags, 30 iterations with the loss read back after each, SyncToHost
  // brings back the rows they changed.
  {
    map.MoveTo(map.coarse_origin() + Int3(1, 0, 0), LocalMap::SaveFn(), gpu_testing::LoadNothing);
    const gpu_testing::Batch moved =
        gpu_testing::SurfaceBatch(map, labelled, 1024, settings.eikonal_step_m, 4);
    double s = Now();
    if (absl::Status st = (*dm)->SyncFromHost(map); !st.ok()) return Fail(st);
    const double from_ms = (Now() - s) * 1e3;
    s = Now();
    for (int i = 0; i < 30; ++i) {
      absl::StatusOr<float> loss = (*dm)->Iterate(moved.xyz.data(), moved.rows, moved.labelled,
                                                  moved.labels.data(), settings, false);
      if (!loss.ok()) return Fail(loss.status());
    }
    const double iterations_ms = (Now() - s) * 1e3;
    s = Now();
    if (absl::Status st = (*dm)->SyncToHost(&map, nullptr); !st.ok()) return Fail(st);
    const double to_ms = (Now() - s) * 1e3;
    std::printf(
        "\na frame as rim_map runs it (%d rows a batch): SyncFromHost %.2f ms "
        "(%lld rows), 30 iterations %.2f ms, SyncToHost %.2f ms (%lld rows)\n",
        moved.rows, from_ms, (long long)(*dm)->rows_uploaded(), iterations_ms, to_ms,
        (long long)(*dm)->rows_downloaded());
    out["frame_sync"] = {{"sync_from_host_ms", from_ms},
                         {"rows_uploaded", (*dm)->rows_uploaded()},
                         {"iterations_30_ms", iterations_ms},
                         {"sync_to_host_ms", to_ms},
                         {"rows_downloaded", (*dm)->rows_downloaded()}};
    batch = moved;  // the first batch's points near the old box's edge are outside the new one
  }

  // Device memory over 500 iterations.
  {
    const int64_t before = (*dm)->device_bytes();
    if (absl::Status st = (*dm)->EnqueueIterations(500, settings, false); !st.ok()) return Fail(st);
    if (absl::Status st = (*dm)->Synchronize(); !st.ok()) return Fail(st);
    std::printf("\ndevice memory: %lld bytes before 500 iterations, %lld after\n",
                (long long)before, (long long)(*dm)->device_bytes());
    out["memory_before_500"] = before;
    out["memory_after_500"] = (*dm)->device_bytes();
  }

  // Robots per GPU: N maps, 30 iterations each per frame.
  std::vector<std::unique_ptr<gpu::DeviceMap>> robots;
  robots.push_back(std::move(*dm));
  nlohmann::json fleet = nlohmann::json::array();
  int largest = 0;
  std::printf("\n%-8s %16s %10s\n", "robots", "frame ms (30 it)", "real time");
  for (int n : {1, 2, 4, 8, 16, 20, 24, 32, 48, 64, 96, 128}) {
    if (n > max_robots) break;
    while (int(robots.size()) < n) {
      auto r = gpu::DeviceMap::Create(map, decoder, 0);
      if (!r.ok()) return Fail(r.status());
      absl::StatusOr<float> loss = (*r)->Iterate(batch.xyz.data(), batch.rows, batch.labelled,
                                                 batch.labels.data(), settings, false);
      if (!loss.ok()) return Fail(loss.status());
      robots.push_back(std::move(*r));
    }
    std::vector<double> frames, enqueues;
    for (int rep = 0; rep < 3; ++rep) {
      const double s = Now();
      for (auto& r : robots)
        if (absl::Status st = r->EnqueueIterations(30, settings, false); !st.ok()) return Fail(st);
      enqueues.push_back((Now() - s) * 1e3);
      for (auto& r : robots)
        if (absl::Status st = r->Synchronize(); !st.ok()) return Fail(st);
      frames.push_back((Now() - s) * 1e3);
    }
    const double ms = Median(frames);
    const bool real_time = ms <= 100.0;
    if (real_time) largest = n;
    std::printf("%-8d %16.2f %10s   (host enqueue %.2f ms)\n", n, ms, real_time ? "yes" : "no",
                Median(enqueues));
    fleet.push_back({{"robots", n},
                     {"frame_ms", ms},
                     {"host_enqueue_ms", Median(enqueues)},
                     {"real_time", real_time}});
    if (!real_time) break;
  }
  out["robots"] = fleet;
  out["robots_real_time"] = largest;
  std::printf("largest N in real time (10 Hz, 30 iterations a frame, training only): %d\n",
              largest);
  if (!out_path.empty()) std::ofstream(out_path) << out.dump(2) << "\n";
  return 0;
}

}  // namespace
}  // namespace rim

int main(int argc, char** argv) { return rim::Main(argc, argv); }
