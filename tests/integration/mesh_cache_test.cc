// Block-incremental meshing (Mapper::MeshTile, mesh/mesher.h) on the sim city: a watched map that
// re-meshes only its changed blocks after every frame must give, at any time, the mesh that
// meshing the same map from scratch gives, while re-meshing a fraction of the blocks.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>

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

class MeshCacheTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto config = MakePreset("maicity_online");
    ASSERT_TRUE(config.ok());
    // Few iterations, and a decoder that freezes early, keep the test short; the block logic does
    // not depend on either.
    ASSERT_TRUE(ApplyOverrides({"train.iterations=4", "train.min_iterations=1",
                                "decoder.freeze_after_frames=3"},
                               &*config)
                    .ok());
    auto mapper = Mapper::Create(*config);
    ASSERT_TRUE(mapper.ok()) << mapper.status();
    mapper_ = mapper->release();
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

}  // namespace
}  // namespace rim
