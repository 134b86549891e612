#include "server/session/tile_cache.h"

#include <algorithm>
#include <array>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "proto/codec/mesh_codec.h"
#include "rim/mesh/mesher.h"

namespace rim::server {

absl::StatusOr<std::shared_ptr<const EncodedTile>> TileCache::Get(const Mapper& mapper,
                                                                  const TileInfo& tile,
                                                                  float resolution_m) {
  auto level = mapper.MeshLevel(resolution_m);
  if (!level.ok()) return level.status();
  const Key key{tile.key.x(), tile.key.y(), tile.key.z(), *level};
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = tiles_.find(key);
    if (it != tiles_.end() && it->second->version >= tile.version) {
      ++hits_;
      return it->second;
    }
    ++misses_;
  }
  // Meshing runs outside the cache lock: other tiles (and other callers) are not held up.
  const auto start = std::chrono::steady_clock::now();
  MeshUpdateStats stats;
  auto mesh = mapper.MeshTile(tile.key, *level, &stats);
  if (!mesh.ok()) return mesh.status();
  std::shared_ptr<const EncodedTile> same;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = tiles_.find(key);
    if (it != tiles_.end() && it->second->generation == stats.generation) same = it->second;
  }
  auto encoded = std::make_shared<EncodedTile>();
  if (same) {
    // The same mesh as the cached encoding's: no block changed visibly.
    *encoded = *same;
  } else {
    const std::array<double, 3> lo{tile.min_m.x(), tile.min_m.y(), tile.min_m.z()};
    const std::array<double, 3> hi{tile.max_m.x(), tile.max_m.y(), tile.max_m.z()};
    auto draco = codec::EncodeTileDraco(*mesh, lo, hi, std::max(0.001, double(*level) / 50),
                                        codec::TileEffort(*level, mapper.MeshLevels().front()));
    if (!draco.ok())
      return absl::InternalError(absl::StrCat("encoding tile (", tile.key.x(), ",", tile.key.y(),
                                              ",", tile.key.z(), "): ", draco.status().message()));
    encoded->draco = std::move(*draco);
    encoded->vertex_count = uint32_t(mesh->vertices.size());
    // The faces a decoder gets back: the encoder leaves out those with a repeated vertex.
    encoded->face_count = 0;
    for (const auto& f : mesh->faces)
      encoded->face_count += f[0] != f[1] && f[1] != f[2] && f[0] != f[2];
    encoded->generation = stats.generation;
    encoded->resolution_m = *level;
  }
  encoded->version = tile.version;
  if (on_encoded_)
    on_encoded_(encoded->draco.size(),
                std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
                stats.blocks_remeshed);
  std::lock_guard<std::mutex> lock(mu_);
  auto& slot = tiles_[key];
  if (!slot || slot->version <= encoded->version) slot = encoded;
  return std::shared_ptr<const EncodedTile>(slot);
}

uint64_t TileCache::hits() const {
  std::lock_guard<std::mutex> lock(mu_);
  return hits_;
}

uint64_t TileCache::misses() const {
  std::lock_guard<std::mutex> lock(mu_);
  return misses_;
}

}  // namespace rim::server
