// What reads a trained map (TrainedMapper(): maicity_online, Options().map_frames frames):
// SDF queries (§3.5), mesh tiles and their Draco encoding (§3.6, §5.1), save and load (§5.3).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "bench/bench_common.h"
#include "proto/codec/mesh_codec.h"
#include "rim/mesh/mesher.h"

namespace rim::bench {
namespace {

constexpr size_t kMaxQueryPoints = 1000000;

// Query points where a robot asks: near the surfaces it scanned (world-frame endpoints of the
// mapped frames, moved uniformly by up to ±0.3 m), fixed seed.
const std::vector<float>& QueryPoints() {
  static const std::vector<float>* points = [] {
    const std::vector<PosedScan>& frames = CitySequence();
    const int n_frames = std::max(1, std::min<int>(Options().map_frames, int(frames.size())));
    std::mt19937_64 rng(1234);
    std::uniform_int_distribution<int> pick_frame(0, n_frames - 1);
    std::uniform_real_distribution<float> jitter(-0.3f, 0.3f);
    auto* out = new std::vector<float>();
    out->reserve(3 * kMaxQueryPoints);
    while (out->size() < 3 * kMaxQueryPoints) {
      const PosedScan& scan = frames[pick_frame(rng)];
      std::uniform_int_distribution<size_t> pick_point(0, scan.points_S.size() - 1);
      const Vec3f p_W = scan.T_world_sensor.cast<float>() * scan.points_S[pick_point(rng)];
      for (int a = 0; a < 3; ++a) out->push_back(p_W[a] + jitter(rng));
    }
    return out;
  }();
  return *points;
}

// Where rim_load's planner asks: within ±10 m (x, y) and ±2 m (z) of a mapped frame's sensor
// position, so mostly in open space and below the ground, fixed seed.
const std::vector<float>& PlannerPoints() {
  static const std::vector<float>* points = [] {
    const std::vector<PosedScan>& frames = CitySequence();
    const int n_frames = std::max(1, std::min<int>(Options().map_frames, int(frames.size())));
    std::mt19937_64 rng(4321);
    std::uniform_int_distribution<int> pick_frame(0, n_frames - 1);
    std::uniform_real_distribution<float> u(-10.f, 10.f);
    auto* out = new std::vector<float>();
    out->reserve(3 * 100000);
    while (out->size() < 3 * 100000) {
      const Vec3d c = frames[pick_frame(rng)].T_world_sensor.translation();
      out->insert(out->end(), {float(c.x()) + u(rng), float(c.y()) + u(rng), 0.2f * u(rng)});
    }
    return out;
  }();
  return *points;
}

// 100k of PlannerPoints(); arg: field (0: QuerySdf, 1: QueryNeural).
void BM_QueryPlanner(benchmark::State& state) {
  const Mapper& mapper = TrainedMapper();
  const std::vector<float>& xyz = PlannerPoints();
  const size_t n = xyz.size() / 3;
  QueryResult result;
  WallClock clock;
  for (auto _ : state) {
    clock.Start();
    CheckOk(state.range(0) ? mapper.QueryNeural(xyz.data(), n, false, &result)
                           : mapper.QuerySdf(xyz.data(), n, false, &result),
            "QuerySdf");
    benchmark::DoNotOptimize(result.sdf.data());
    clock.Stop();
  }
  size_t saturated = 0;
  for (uint8_t s : result.saturated) saturated += s != 0;
  state.counters["points_per_s"] = double(n) * double(state.iterations()) / clock.seconds();
  state.counters["saturated_fraction"] = double(saturated) / double(n);
}

// Args: batch size, gradient (0/1), field (0: the metric distances of QuerySdf, 1: the
// network's own values, QueryNeural).
void BM_Query(benchmark::State& state) {
  const Mapper& mapper = TrainedMapper();
  const size_t n = size_t(state.range(0));
  const bool gradient = state.range(1) != 0;
  const bool neural = state.range(2) != 0;
  const std::vector<float>& xyz = QueryPoints();
  QueryResult result;
  WallClock clock;
  for (auto _ : state) {
    clock.Start();
    CheckOk(neural ? mapper.QueryNeural(xyz.data(), n, gradient, &result)
                   : mapper.QuerySdf(xyz.data(), n, gradient, &result),
            "QuerySdf");
    benchmark::DoNotOptimize(result.sdf.data());
    clock.Stop();
  }
  size_t observed = 0;
  for (uint8_t o : result.observed) observed += o != 0;
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(n));
  // Wall clock, whatever time the library uses for its own rates.
  state.counters["points_per_s"] = double(n) * double(state.iterations()) / clock.seconds();
  state.counters["observed_fraction"] = double(observed) / double(n);
}

// The tile with the most observed voxels: the fullest tile the sequence produced.
TileInfo FullestTile(const Mapper& mapper, size_t* observed_voxels) {
  TileInfo best;
  *observed_voxels = 0;
  for (const TileInfo& tile : mapper.ListTiles(0)) {
    const size_t n = mapper.ObservedVoxels(tile.key).size();
    if (n > *observed_voxels) {
      *observed_voxels = n;
      best = tile;
    }
  }
  return best;
}

void BM_MeshTile(benchmark::State& state) {
  const Mapper& mapper = TrainedMapper();
  size_t voxels = 0;
  const TileInfo tile = FullestTile(mapper, &voxels);
  Mesh mesh;
  WallClock clock;
  for (auto _ : state) {
    clock.Start();
    absl::StatusOr<Mesh> m = mapper.ExtractMeshTile(tile.key);
    clock.Stop();
    CheckOk(m.status(), "ExtractMeshTile");
    mesh = *std::move(m);
  }
  state.counters["observed_voxels"] = double(voxels);
  state.counters["vertices"] = double(mesh.vertices.size());
  state.counters["faces"] = double(mesh.faces.size());
  // Observed share of the tile's 20 × 20 m footprint at the leaf size (a full tile is ~1).
  const double leaf = mapper.config().grid.leaf_size_m;
  const Vec3d size = tile.max_m - tile.min_m;
  state.counters["footprint_fraction"] = double(voxels) * leaf * leaf / (size.x() * size.y());
  state.counters["us_per_observed_voxel"] =
      1e6 * clock.seconds() / double(state.iterations()) / std::max<double>(1, double(voxels));
}

// Meshing as a dashboard sees it: frames are integrated (not timed), and after every
// `frames_per_push` of them the tiles that changed since the last push (ListTiles(since)) are
// meshed again and Draco-encoded, as WatchMeshTiles does with watch.min_interval_s = 1 s at 10 Hz
// (10 frames per push). Args: incremental (0: each tile from scratch, ExtractMeshTile; 1: only its
// changed blocks, MeshTile), frames per push. One iteration is one frame; the counters give
// meshing and encoding per frame and per tile. The mapper is its own (maicity_online, the first
// map_frames frames), so the shared trained map stays as the other benchmarks expect.
void BM_MeshUpdate(benchmark::State& state) {
  const bool incremental = state.range(0) != 0;
  const int frames_per_push = int(state.range(1));
  MapperConfig config = Preset("maicity_online");
  config.mesh.remesh_tolerance_m = float(state.range(2)) * 1e-3f;
  absl::StatusOr<std::unique_ptr<Mapper>> created = Mapper::Create(config);
  CheckOk(created.status(), "Mapper::Create");
  Mapper& mapper = **created;
  // The watcher's level of detail (cm; 0: the finest), quantised as the service does.
  const float level = float(state.range(3)) * 0.01f;
  CheckOk(mapper.MeshLevel(level).status(), "MeshLevel");
  const double max_error_m = std::max(0.001, double(*mapper.MeshLevel(level)) / 50);
  const std::vector<PosedScan>& frames = CitySequence();
  const int start = std::min<int>(Options().map_frames, int(frames.size()) - 1);
  for (int k = 0; k < start; ++k) CheckOk(mapper.IntegrateScan(frames[k]), "IntegrateScan");
  // The first push after the warm-up frames meshes everything once (not timed): a watcher that
  // has been watching since the start has its blocks cached.
  uint64_t since = 0;
  for (const TileInfo& tile : mapper.ListTiles(0)) {
    CheckOk(mapper.MeshTile(tile.key, level, nullptr).status(), "MeshTile");
    since = std::max(since, tile.version);
  }
  int next = start;
  size_t tiles = 0, faces = 0, pushes = 0, bytes = 0, encoded = 0;
  int64_t blocks = 0, remeshed = 0, checked = 0, skipped = 0;
  // A tile whose mesh generation did not move keeps its encoding (server/session/tile_cache.h).
  std::map<std::array<int, 3>, uint64_t> generations;
  WallClock mesh_clock, encode_clock;
  std::vector<double> push_ms;
  for (auto _ : state) {
    state.PauseTiming();
    CheckOk(mapper.IntegrateScan(frames[size_t(next) % frames.size()]), "IntegrateScan");
    ++next;
    const bool push = (next - start) % frames_per_push == 0;
    state.ResumeTiming();
    if (!push) continue;
    ++pushes;
    const double before = mesh_clock.seconds() + encode_clock.seconds();
    uint64_t newest = since;
    for (const TileInfo& tile : mapper.ListTiles(since)) {
      mesh_clock.Start();
      MeshUpdateStats stats;
      absl::StatusOr<Mesh> m = incremental ? mapper.MeshTile(tile.key, level, &stats)
                                           : mapper.ExtractMeshTile(tile.key, level);
      mesh_clock.Stop();
      CheckOk(m.status(), "MeshTile");
      uint64_t& generation = generations[{tile.key.x(), tile.key.y(), tile.key.z()}];
      if (!incremental || stats.generation != generation) {
        encode_clock.Start();
        const std::array<double, 3> lo{tile.min_m.x(), tile.min_m.y(), tile.min_m.z()};
        const std::array<double, 3> hi{tile.max_m.x(), tile.max_m.y(), tile.max_m.z()};
        absl::StatusOr<std::string> draco = codec::EncodeTileDraco(
            *m, lo, hi, max_error_m,
            codec::TileEffort(*mapper.MeshLevel(level), mapper.MeshLevels().front()));
        encode_clock.Stop();
        CheckOk(draco.status(), "EncodeTileDraco");
        bytes += draco->size();
        ++encoded;
      }
      generation = stats.generation;
      newest = std::max(newest, tile.version);
      ++tiles;
      faces += m->faces.size();
      blocks += stats.blocks;
      remeshed += stats.blocks_remeshed;
      checked += stats.blocks_checked;
      skipped += stats.blocks_skipped;
    }
    since = newest;
    push_ms.push_back(1e3 * (mesh_clock.seconds() + encode_clock.seconds() - before));
  }
  const double n_frames = double(state.iterations());
  std::sort(push_ms.begin(), push_ms.end());
  state.counters["pushes"] = double(pushes);
  state.counters["tiles_per_push"] = double(tiles) / std::max<double>(1, double(pushes));
  state.counters["faces_per_tile"] = double(faces) / std::max<double>(1, double(tiles));
  state.counters["mesh_ms_per_frame"] = 1e3 * mesh_clock.seconds() / n_frames;
  state.counters["encode_ms_per_frame"] = 1e3 * encode_clock.seconds() / n_frames;
  state.counters["mesh_ms_per_tile"] = 1e3 * mesh_clock.seconds() / std::max<double>(1, tiles);
  state.counters["encode_ms_per_tile"] = 1e3 * encode_clock.seconds() / std::max<double>(1, tiles);
  state.counters["push_ms_median"] = push_ms.empty() ? 0 : push_ms[push_ms.size() / 2];
  state.counters["bytes_per_tile"] = double(bytes) / std::max<double>(1, double(encoded));
  if (incremental) {
    state.counters["blocks_remeshed_fraction"] =
        double(remeshed) / std::max<double>(1, double(blocks));
    // Of the blocks a change reached, those whose SDF stayed within mesh.remesh_tolerance_m.
    state.counters["blocks_skipped_fraction"] =
        double(skipped) / std::max<double>(1, double(checked));
  }
}

void BM_DracoEncodeTile(benchmark::State& state) {
  const Mapper& mapper = TrainedMapper();
  size_t voxels = 0;
  const TileInfo tile = FullestTile(mapper, &voxels);
  absl::StatusOr<Mesh> mesh = mapper.ExtractMeshTile(tile.key);
  CheckOk(mesh.status(), "ExtractMeshTile");
  const std::array<double, 3> lo{tile.min_m.x(), tile.min_m.y(), tile.min_m.z()};
  const std::array<double, 3> hi{tile.max_m.x(), tile.max_m.y(), tile.max_m.z()};
  size_t bytes = 0;
  for (auto _ : state) {
    absl::StatusOr<std::string> encoded = codec::EncodeTileDraco(*mesh, lo, hi);
    CheckOk(encoded.status(), "EncodeTileDraco");
    bytes = encoded->size();
  }
  state.counters["faces"] = double(mesh->faces.size());
  state.counters["bytes"] = double(bytes);
  state.counters["bytes_per_face"] = double(bytes) / std::max<double>(1, mesh->faces.size());
}

void BM_SaveSession(benchmark::State& state) {
  const Mapper& mapper = TrainedMapper();
  TempDir dir;
  for (auto _ : state) CheckOk(mapper.Save(dir.path()), "Mapper::Save");
  state.counters["bytes"] = double(dir.SizeBytes());
}

void BM_LoadSession(benchmark::State& state) {
  TempDir dir;
  CheckOk(TrainedMapper().Save(dir.path()), "Mapper::Save");
  for (auto _ : state) {
    absl::StatusOr<std::unique_ptr<Mapper>> loaded = Mapper::Load(dir.path());
    CheckOk(loaded.status(), "Mapper::Load");
    benchmark::DoNotOptimize(loaded->get());
  }
  state.counters["bytes"] = double(dir.SizeBytes());
}

}  // namespace

void RegisterMapBenchmarks() {
  for (int neural : {0, 1}) {
    for (int gradient : {0, 1}) {
      for (int64_t n : {1000, 100000, 1000000}) {
        benchmark::RegisterBenchmark(neural ? "QueryNeural" : "Query", BM_Query)
            ->ArgNames({"points", "gradient", "neural"})
            ->Args({n, gradient, neural})
            ->Unit(benchmark::kMillisecond)
            ->UseRealTime();
      }
    }
  }
  benchmark::RegisterBenchmark("QueryPlanner", BM_QueryPlanner)
      ->ArgNames({"neural"})
      ->DenseRange(0, 1)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
  for (auto [name, fn] :
       {std::pair{"MeshTile", BM_MeshTile}, std::pair{"DracoEncodeTile", BM_DracoEncodeTile},
        std::pair{"Session/Save", BM_SaveSession}, std::pair{"Session/Load", BM_LoadSession}}) {
    benchmark::RegisterBenchmark(name, fn)->Unit(benchmark::kMillisecond)->UseRealTime();
  }
  // Thirty frames: pushes after every frame, from scratch and incremental, and every tenth frame
  // (a watcher at watch.min_interval_s = 1 s of a robot at 10 Hz), incremental.
  benchmark::RegisterBenchmark("MeshUpdate", BM_MeshUpdate)
      ->ArgNames({"incremental", "frames_per_push", "remesh_tolerance_mm", "level_cm"})
      ->Args({0, 1, 0, 0})
      ->Args({1, 1, 0, 0})
      ->Args({1, 10, 0, 0})
      ->Args({1, 10, 5, 0})
      ->Args({1, 10, 5, 10})
      ->Args({1, 10, 5, 20})
      ->Iterations(30)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
}

}  // namespace rim::bench
