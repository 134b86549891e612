// Block-incremental meshing (Mapper::MeshTile, mesh/mesher.h) on the sim city: a watched map that
// re-meshes only its changed blocks after every frame must give, at any time, the mesh that
// meshing the same map from scratch gives, while re-meshing a fraction of the blocks.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <set>
#include <string>

#include "rim/mapper.h"
#include "rim/mesh/mesher.h"
#include "sim/city_frames.h"

namespace rim {
namespace {

// Faces as their three vertex positions, sorted: two meshes with equal face lists are the same
// surface whatever their vertex order.
std::vector<std::array<float, 9>> FaceList(const Mesh& m) {
  std::vector<std::array<float, 9>> out;
  out.reserve(m.faces.size());
  for (const auto& f : m.faces) {
    std::array<float, 9> t;
    for (int k = 0; k < 3; ++k)
      for (int i = 0; i < 3; ++i) t[3 * k + i] = m.vertices[f[k]][i];
    out.push_back(t);
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Largest coordinate difference between matching faces; +inf when the face counts differ.
double MaxFaceDifference(const Mesh& a, const Mesh& b) {
  const auto fa = FaceList(a), fb = FaceList(b);
  if (fa.size() != fb.size()) return INFINITY;
  double worst = 0;
  for (size_t i = 0; i < fa.size(); ++i)
    for (int k = 0; k < 9; ++k) worst = std::max(worst, double(std::abs(fa[i][k] - fb[i][k])));
  return worst;
}

// A maicity_online mapper with few iterations and a decoder that freezes early, which keep the
// test short (the block logic does not depend on either), re-meshing blocks whose SDF moved by
// more than `tolerance_m`.
std::unique_ptr<Mapper> MakeMapper(float tolerance_m) {
  auto config = MakePreset("maicity_online");
  EXPECT_TRUE(config.ok());
  EXPECT_TRUE(ApplyOverrides(
                  {"train.iterations=4", "train.min_iterations=1", "decoder.freeze_after_frames=3",
                   "mesh.remesh_tolerance_m=" + std::to_string(tolerance_m)},
                  &*config)
                  .ok());
  auto mapper = Mapper::Create(*config);
  EXPECT_TRUE(mapper.ok()) << mapper.status();
  return mapper.ok() ? std::move(*mapper) : nullptr;
}

// The mesh grid points of a tile's observed voxels (the corners of their cells), grouped by mesh
// block, as world positions: what a block's mesh is made from.
struct BlockPoints {
  std::vector<Int3> blocks;                     // block keys, in the order of `first`
  std::vector<size_t> first;                    // index of each block's first point in `xyz` / 3
  std::vector<float> xyz;                       // points
  std::map<std::array<int, 3>, size_t> voxels;  // observed voxels per block
};

BlockPoints TilePoints(const Mapper& mapper, const Int3& key) {
  const float res = mapper.config().mesh.resolution_m;
  const int r = int(std::lround(mapper.config().grid.leaf_size_m / res));
  std::map<std::array<int, 3>, std::vector<Int3>> by_block;
  for (const Int3& g : mapper.ObservedVoxels(key))
    by_block[{FloorDiv(g.x(), kMeshBlockVoxels), FloorDiv(g.y(), kMeshBlockVoxels),
              FloorDiv(g.z(), kMeshBlockVoxels)}]
        .push_back(g);
  BlockPoints out;
  for (const auto& [b, voxels] : by_block) {
    out.blocks.emplace_back(b[0], b[1], b[2]);
    out.first.push_back(out.xyz.size() / 3);
    out.voxels[b] = voxels.size();
    for (const Int3& g : voxels)
      for (int i = 0; i <= r; ++i)
        for (int j = 0; j <= r; ++j)
          for (int k = 0; k <= r; ++k) {
            const Int3 m = g * r + Int3(i, j, k);
            for (int a = 0; a < 3; ++a) out.xyz.push_back(float(m[a] * double(res)));
          }
  }
  out.first.push_back(out.xyz.size() / 3);
  return out;
}

std::vector<float> Values(const Mapper& mapper, const BlockPoints& p) {
  QueryResult q;
  EXPECT_TRUE(mapper.QueryNeural(p.xyz.data(), p.xyz.size() / 3, false, &q).ok());
  return q.sdf;
}

// For each vertex of `a`, the distance to the nearest vertex of `b`.
std::vector<double> NearestVertexDistances(const Mesh& a, const Mesh& b, double cell) {
  std::map<std::array<int, 3>, std::vector<uint32_t>> grid;
  auto cell_of = [cell](const std::array<float, 3>& v) {
    return std::array<int, 3>{int(std::floor(v[0] / cell)), int(std::floor(v[1] / cell)),
                              int(std::floor(v[2] / cell))};
  };
  for (uint32_t i = 0; i < b.vertices.size(); ++i) grid[cell_of(b.vertices[i])].push_back(i);
  std::vector<double> out;
  out.reserve(a.vertices.size());
  for (const auto& v : a.vertices) {
    const auto c = cell_of(v);
    double best = INFINITY;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          auto it = grid.find({c[0] + dx, c[1] + dy, c[2] + dz});
          if (it == grid.end()) continue;
          for (uint32_t i : it->second) {
            const auto& w = b.vertices[i];
            best = std::min(
                best, std::hypot(double(v[0] - w[0]), double(v[1] - w[1]), double(v[2] - w[2])));
          }
        }
    out.push_back(best);
  }
  return out;
}

class MeshCacheTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    // Tolerance 0: a block is re-meshed whenever a change reaches it, and the tiles are the
    // from-scratch ones.
    mapper_ = MakeMapper(0.f).release();
    ASSERT_NE(mapper_, nullptr);
    sim::CityFrameOptions options;
    options.frames = 24;
    options.columns = 360;
    options.noise = 0.02;
    options.seed = 31;
    options.threads = 2;
    frames_ = new sim::CityFrames(options);
  }
  static void TearDownTestSuite() {
    delete mapper_;
    delete frames_;
  }

  static Mapper* mapper_;
  static sim::CityFrames* frames_;
};
Mapper* MeshCacheTest::mapper_ = nullptr;
sim::CityFrames* MeshCacheTest::frames_ = nullptr;

TEST_F(MeshCacheTest, WatchedTilesEqualFromScratchTilesAndReuseUnchangedBlocks) {
  uint64_t since = 0;
  int blocks_total = 0, remeshed_total = 0, compared = 0;
  for (size_t k = 0; k < frames_->size(); ++k) {
    ASSERT_TRUE(mapper_->IntegrateScan(frames_->Frame(k)).ok());
    const bool decoder_trained = k < 3;
    // A watcher: every tile whose version moved, through the block cache.
    std::map<std::array<int, 3>, Mesh> watched;
    for (const TileInfo& tile : mapper_->ListTiles(since)) {
      MeshUpdateStats stats;
      auto mesh = mapper_->MeshTile(tile.key, &stats);
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      since = std::max(since, tile.version);
      if (decoder_trained) {
        // The decoder moved every value: nothing can be reused.
        EXPECT_EQ(stats.blocks_remeshed, stats.blocks) << "frame " << k;
      } else if (k >= 5) {
        blocks_total += stats.blocks;
        remeshed_total += stats.blocks_remeshed;
      }
      watched[{tile.key.x(), tile.key.y(), tile.key.z()}] = std::move(*mesh);
    }
    if (k % 4 != 3) continue;
    // Every tile meshed from scratch now equals what the cache gave.
    for (const TileInfo& tile : mapper_->ListTiles(0)) {
      auto scratch = mapper_->ExtractMeshTile(tile.key);
      ASSERT_TRUE(scratch.ok());
      auto it = watched.find({tile.key.x(), tile.key.y(), tile.key.z()});
      Mesh cached;
      if (it != watched.end()) {
        cached = it->second;
      } else {
        // Not changed by this frame: the cache gives it again (the same as its last push).
        auto again = mapper_->MeshTile(tile.key);
        ASSERT_TRUE(again.ok());
        cached = std::move(*again);
      }
      ASSERT_EQ(cached.faces.size(), scratch->faces.size()) << "frame " << k;
      EXPECT_LE(MaxFaceDifference(cached, *scratch), 1e-5) << "frame " << k;
      // Welded like one marching-cubes call: a vertex per crossed grid edge, none twice.
      EXPECT_EQ(cached.vertices.size(), scratch->vertices.size()) << "frame " << k;
      if (!scratch->faces.empty()) ++compared;
    }
  }
  EXPECT_GT(compared, 6);
  // The box covers part of each tile it overlaps: blocks beyond its reach come from the cache.
  ASSERT_GT(blocks_total, 0);
  const double share = double(remeshed_total) / blocks_total;
  std::printf("blocks re-meshed after the decoder froze: %d of %d (%.0f %%)\n", remeshed_total,
              blocks_total, 100 * share);
  EXPECT_LT(share, 0.9);
  EXPECT_GT(mapper_->Stats().mesh_cache_bytes, 0);
}

// Levels of detail (Mapper::MeshLevels): a coarser level meshes the same surface within its
// resolution, with a fraction of the fine tile's faces; its cached tiles equal its from-scratch
// ones; and a resolution that is not a level is refused by name.
TEST_F(MeshCacheTest, LevelsOfDetailMeshTheSameSurfaceWithinTheirResolution) {
  for (size_t k = size_t(mapper_->frames()); k < frames_->size(); ++k)
    ASSERT_TRUE(mapper_->IntegrateScan(frames_->Frame(k)).ok());
  const std::vector<float> levels = mapper_->MeshLevels();
  ASSERT_GE(levels.size(), 3u);
  EXPECT_FLOAT_EQ(levels[0], mapper_->config().mesh.resolution_m);
  for (size_t i = 1; i < levels.size(); ++i) EXPECT_FLOAT_EQ(levels[i], 2 * levels[i - 1]);

  for (size_t i = 1; i < levels.size() && i <= 2; ++i) {
    const float res = levels[i];
    size_t fine_faces = 0, coarse_faces = 0;
    std::vector<double> to_fine, to_coarse;
    for (const TileInfo& tile : mapper_->ListTiles(0)) {
      auto fine = mapper_->ExtractMeshTile(tile.key);
      ASSERT_TRUE(fine.ok()) << fine.status();
      MeshUpdateStats stats;
      auto coarse = mapper_->MeshTile(tile.key, res, &stats);
      ASSERT_TRUE(coarse.ok()) << coarse.status();
      auto scratch = mapper_->ExtractMeshTile(tile.key, res);
      ASSERT_TRUE(scratch.ok()) << scratch.status();
      ASSERT_EQ(coarse->faces.size(), scratch->faces.size()) << res << " m";
      EXPECT_LE(MaxFaceDifference(*coarse, *scratch), 1e-5) << res << " m";
      fine_faces += fine->faces.size();
      coarse_faces += coarse->faces.size();
      if (fine->vertices.empty() || coarse->vertices.empty()) continue;
      for (double d : NearestVertexDistances(*coarse, *fine, 2 * res)) to_fine.push_back(d);
      for (double d : NearestVertexDistances(*fine, *coarse, 2 * res)) to_coarse.push_back(d);
    }
    ASSERT_GT(fine_faces, 1000u);
    ASSERT_FALSE(to_fine.empty());
    auto quantile = [](std::vector<double> v, double q) {
      std::sort(v.begin(), v.end());
      return v[size_t(q * double(v.size() - 1))];
    };
    const double acc50 = quantile(to_fine, 0.5), acc95 = quantile(to_fine, 0.95);
    const double comp50 = quantile(to_coarse, 0.5), comp95 = quantile(to_coarse, 0.95);
    std::printf(
        "level %.2f m: faces %zu of the fine %zu (%.2f); coarse to fine vertex median %.3f, "
        "p95 %.3f m; fine to coarse median %.3f, p95 %.3f m\n",
        res, coarse_faces, fine_faces, double(coarse_faces) / double(fine_faces), acc50, acc95,
        comp50, comp95);
    // Nearest vertices, not surfaces: the fine level's vertices lie up to a fine cell apart.
    EXPECT_LE(acc50, 0.5 * res);
    EXPECT_LE(acc95, 1.0 * res);
    EXPECT_LE(comp50, 0.5 * res);
    EXPECT_LE(comp95, 1.0 * res);
    // Twice as coarse: about a quarter of the faces.
    EXPECT_LE(double(coarse_faces), 0.4 * double(fine_faces)) << res << " m";
  }

  const Int3 key = mapper_->ListTiles(0).front().key;
  for (float bad : {0.07f, -0.1f, 3.2f, float(NAN)}) {
    auto mesh = mapper_->MeshTile(key, bad, nullptr);
    ASSERT_FALSE(mesh.ok()) << bad;
    EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(mesh.status().message().find("resolution_m"), std::string::npos)
        << mesh.status().message();
  }
  EXPECT_TRUE(mapper_->MeshTile(key, 0.f, nullptr).ok());  // 0: the finest level
}

// With a tolerance, a watched tile is meshed from values within the tolerance of the map's, so
// its surface stays within about that distance of the from-scratch tile's.
// The same at a coarse level of detail (0.2 m), whose tolerance scales with its resolution.
TEST_F(MeshCacheTest, WatchedTilesStayWithinTheToleranceOfFromScratchTiles) {
  for (const float level : {0.f, 0.2f}) {
    std::unique_ptr<Mapper> mapper = MakeMapper(0.005f);
    ASSERT_NE(mapper, nullptr);
    const double res = level > 0 ? level : mapper->config().mesh.resolution_m;
    const float kTolerance = 0.005f;
    uint64_t since = 0;
    int64_t checked = 0, skipped = 0;
    std::vector<double> distances;
    size_t strays = 0, missing = 0;
    double stray_sdf = 0;
    std::map<std::array<int, 3>, Mesh> watched;
    for (size_t k = 0; k < frames_->size(); ++k) {
      ASSERT_TRUE(mapper->IntegrateScan(frames_->Frame(k)).ok());
      for (const TileInfo& tile : mapper->ListTiles(since)) {
        MeshUpdateStats stats;
        auto mesh = mapper->MeshTile(tile.key, level, &stats);
        ASSERT_TRUE(mesh.ok()) << mesh.status();
        since = std::max(since, tile.version);
        checked += stats.blocks_checked;
        skipped += stats.blocks_skipped;
        watched[{tile.key.x(), tile.key.y(), tile.key.z()}] = std::move(*mesh);
      }
      if (k < 5 || k % 4 != 3) continue;
      for (const TileInfo& tile : mapper->ListTiles(0)) {
        auto scratch = mapper->ExtractMeshTile(tile.key, level);
        ASSERT_TRUE(scratch.ok());
        const Mesh& cached = watched.at({tile.key.x(), tile.key.y(), tile.key.z()});
        // Both ways: no vertex strays, and no part of the surface is missing. A vertex with no
        // counterpart within the mesh voxel belongs to a speck of surface that one mesh has and
        // the other lacks: where the map's SDF is within the tolerance of zero, so that a value
        // within the tolerance gives it or takes it away. The map's value there says so.
        const std::vector<double> there = NearestVertexDistances(cached, *scratch, res);
        std::vector<float> stray;
        for (size_t i = 0; i < there.size(); ++i) {
          distances.push_back(there[i]);
          if (!(there[i] <= res))
            stray.insert(stray.end(), cached.vertices[i].begin(), cached.vertices[i].end());
        }
        for (double d : NearestVertexDistances(*scratch, cached, res)) {
          distances.push_back(d);
          missing += !(d <= res);
        }
        if (stray.empty()) continue;
        QueryResult q;
        ASSERT_TRUE(mapper->QueryNeural(stray.data(), stray.size() / 3, false, &q).ok());
        for (float v : q.sdf) stray_sdf = std::max(stray_sdf, double(std::abs(v)));
        strays += q.sdf.size();
      }
    }
    ASSERT_GT(checked, 0);
    EXPECT_GT(skipped, 0);
    ASSERT_FALSE(distances.empty());
    std::sort(distances.begin(), distances.end());
    const double p99 = distances[distances.size() * 99 / 100];
    const double p999 = distances[distances.size() * 999 / 1000];
    std::printf(
        "level %.2f m: blocks skipped: %lld of %lld checked; vertex to the other mesh's nearest: "
        "p99 %.4f, "
        "p99.9 %.4f m over %zu vertices; farther than the mesh voxel: %zu watched (|SDF| <= %.4f "
        "m there), %zu from scratch\n",
        res, (long long)skipped, (long long)checked, p99, p999, distances.size(), strays, stray_sdf,
        missing);
    EXPECT_LE(p99, kTolerance);
    EXPECT_LE(p999, 2 * kTolerance);
    EXPECT_LE(strays + missing, distances.size() / 10000);
    EXPECT_LE(stray_sdf, 2 * kTolerance);
  }
}

// A training step re-meshes exactly the blocks whose SDF at the mesh grid moved by more than the
// tolerance (or whose observed voxels changed): a tile that it moved less re-meshes nothing and
// keeps its mesh generation (its encoding is reused).
TEST_F(MeshCacheTest, ATrainingStepReMeshesExactlyTheBlocksThatMovedBeyondTheTolerance) {
  constexpr float kTolerance = 0.005f;
  std::unique_ptr<Mapper> mapper = MakeMapper(kTolerance);
  ASSERT_NE(mapper, nullptr);
  for (size_t k = 0; k < 10; ++k) ASSERT_TRUE(mapper->IntegrateScan(frames_->Frame(k)).ok());
  std::map<std::array<int, 3>, uint64_t> generation;
  for (const TileInfo& tile : mapper->ListTiles(0)) {
    MeshUpdateStats stats;
    ASSERT_TRUE(mapper->MeshTile(tile.key, &stats).ok());
    generation[{tile.key.x(), tile.key.y(), tile.key.z()}] = stats.generation;
  }
  int kept = 0, remeshed = 0, ambiguous = 0, quiet_tiles = 0;
  // A small step (one iteration of few rays) and a larger one.
  for (const auto& [iterations, rays] : {std::pair{1, 64}, std::pair{8, 0}}) {
    std::map<std::array<int, 3>, BlockPoints> points;
    std::map<std::array<int, 3>, std::vector<float>> before;
    for (const TileInfo& tile : mapper->ListTiles(0)) {
      const std::array<int, 3> key{tile.key.x(), tile.key.y(), tile.key.z()};
      points[key] = TilePoints(*mapper, tile.key);
      before[key] = Values(*mapper, points[key]);
    }
    auto trained = mapper->TrainBetweenFrames(iterations, rays, [] { return true; });
    ASSERT_TRUE(trained.ok()) << trained.status();
    ASSERT_EQ(*trained, iterations);
    for (const TileInfo& tile : mapper->ListTiles(0)) {
      const std::array<int, 3> key{tile.key.x(), tile.key.y(), tile.key.z()};
      const BlockPoints now = TilePoints(*mapper, tile.key);
      const std::vector<float> after = Values(*mapper, now);
      MeshUpdateStats stats;
      ASSERT_TRUE(mapper->MeshTile(tile.key, &stats).ok());
      // A tile far from the box is not kept, and is meshed whole.
      if (stats.blocks_checked == 0 && stats.blocks_remeshed == stats.blocks) continue;
      std::set<std::array<int, 3>> got;
      for (const Int3& b : stats.remeshed) got.insert({b.x(), b.y(), b.z()});
      const BlockPoints& old = points.at(key);
      bool quiet = true;
      for (size_t i = 0; i < now.blocks.size(); ++i) {
        const std::array<int, 3> b{now.blocks[i].x(), now.blocks[i].y(), now.blocks[i].z()};
        bool expect = true;  // a block that is new, or whose voxels changed
        double moved = 0;
        const auto it = std::find(old.blocks.begin(), old.blocks.end(), now.blocks[i]);
        if (it != old.blocks.end() && old.voxels.at(b) == now.voxels.at(b)) {
          const size_t j = size_t(it - old.blocks.begin());
          ASSERT_EQ(old.first[j + 1] - old.first[j], now.first[i + 1] - now.first[i]);
          for (size_t p = 0; p < now.first[i + 1] - now.first[i]; ++p)
            moved = std::max(moved, double(std::abs(after[now.first[i] + p] -
                                                    before.at(key)[old.first[j] + p])));
          // The query path's encoding may differ from the mesher's in the last bits.
          if (std::abs(moved - kTolerance) < 1e-4) {
            ++ambiguous;
            quiet = false;
            continue;
          }
          expect = moved > kTolerance;
        }
        if (expect) quiet = false;
        EXPECT_EQ(got.count(b) == 1, expect)
            << "block (" << b[0] << "," << b[1] << "," << b[2] << ") moved " << moved;
        (expect ? remeshed : kept) += 1;
      }
      if (quiet) {
        ++quiet_tiles;
        EXPECT_EQ(stats.blocks_remeshed, 0);
        EXPECT_EQ(stats.generation, generation.at(key));
      }
      generation[key] = stats.generation;
    }
  }
  // Nothing changed since: every tile comes from the cache, with the same generation.
  for (const TileInfo& tile : mapper->ListTiles(0)) {
    MeshUpdateStats stats;
    ASSERT_TRUE(mapper->MeshTile(tile.key, &stats).ok());
    if (stats.blocks_checked == 0 && stats.blocks_remeshed == stats.blocks) continue;  // not kept
    EXPECT_EQ(stats.blocks_remeshed, 0);
    EXPECT_EQ(stats.blocks_checked, 0);
    EXPECT_EQ(stats.generation, generation.at({tile.key.x(), tile.key.y(), tile.key.z()}));
  }
  std::printf("blocks kept %d, re-meshed %d, at the tolerance %d; tiles unchanged %d\n", kept,
              remeshed, ambiguous, quiet_tiles);
  EXPECT_GT(kept, 0);
  EXPECT_GT(remeshed, 0);
  EXPECT_LE(ambiguous, (kept + remeshed) / 100);
}

}  // namespace
}  // namespace rim
