// Draco-encoded mesh tiles cached per sub-map version (DESIGN.md §3.6, §5.1): a tile is
// re-meshed and re-encoded only when its version moved since it was last encoded.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

#include "absl/status/statusor.h"
#include "rim/base/types.h"
#include "rim/mapper.h"

namespace rim::server {

struct EncodedTile {
  uint64_t version = 0;
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

  // The tile at `tile.version` or newer: from the cache when its encoding is that recent,
  // otherwise meshed (Mapper::MeshTile: only its visibly changed blocks) and encoded now, unless
  // no block changed visibly (the cached encoding is then tagged with the new version). A tile that
  // changes while being meshed is tagged with the version read before, so it is simply
  // re-encoded next time.
  absl::StatusOr<std::shared_ptr<const EncodedTile>> Get(const Mapper& mapper,
                                                         const TileInfo& tile);

  uint64_t hits() const;
  uint64_t misses() const;

 private:
  const EncodedFn on_encoded_;
  mutable std::mutex mu_;
  std::unordered_map<Int3, std::shared_ptr<const EncodedTile>, Int3Hash, Int3Equal> tiles_;
  uint64_t hits_ = 0, misses_ = 0;
};

}  // namespace rim::server
