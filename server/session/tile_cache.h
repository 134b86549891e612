// Draco-encoded mesh tiles cached per sub-map version (DESIGN.md §3.6, §5.1): a tile is
// re-meshed and re-encoded only when its version moved since it was last encoded.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>

#include "absl/status/statusor.h"
#include "rim/base/types.h"
#include "rim/mapper.h"

namespace rim::server {

struct EncodedTile {
  uint64_t version = 0;
  float resolution_m = 0;  // the level of detail (Mapper::MeshLevels)
  std::string draco;
  uint32_t vertex_count = 0;
  uint32_t face_count = 0;  // faces in the payload (degenerate ones are not encoded)
  // The mesh's generation (MeshUpdateStats): a newer version of the tile with the same generation
  // has the same mesh, and takes these bytes instead of being encoded again.
  uint64_t generation = 0;
};

class TileCache {
 public:
  // `on_encoded(bytes, seconds, blocks_remeshed)` runs after each tile meshed and encoded (not for
  // cache hits).
  using EncodedFn = std::function<void(size_t, double, int)>;
  explicit TileCache(EncodedFn on_encoded = nullptr) : on_encoded_(std::move(on_encoded)) {}

  // The tile at `tile.version` or newer, meshed at `resolution_m` (one of the mapper's
  // MeshLevels(), or 0 for the finest; anything else is InvalidArgument naming resolution_m) and
  // encoded with positions within the larger of 1 mm and resolution_m / 50. From the cache when
  // its encoding is that recent, otherwise meshed (Mapper::MeshTile: only its visibly changed
  // blocks) and encoded now, unless no block changed visibly (the cached encoding is then tagged
  // with the new version). A tile that changes while being meshed is tagged with the version read
  // before, so it is simply re-encoded next time. Each level is cached apart.
  absl::StatusOr<std::shared_ptr<const EncodedTile>> Get(const Mapper& mapper, const TileInfo& tile,
                                                         float resolution_m = 0);

  uint64_t hits() const;
  uint64_t misses() const;

 private:
  const EncodedFn on_encoded_;
  mutable std::mutex mu_;
  // Per sub-map key and level.
  using Key = std::tuple<int, int, int, float>;
  std::map<Key, std::shared_ptr<const EncodedTile>> tiles_;
  uint64_t hits_ = 0, misses_ = 0;
};

}  // namespace rim::server
