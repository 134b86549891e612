// Mesh tiles (§3.6): marching cubes over one sub-map's observed voxels on a world-aligned grid,
// meshed block by block, so that a tile whose map changed in a few places re-meshes only those
// blocks (MeshBlockCache) and still equals a tile meshed from scratch.
#pragma once

#include <memory>
#include <mutex>
#include <shared_mutex>
#include <utility>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/status/statusor.h"
#include "rim/base/mesh.h"
#include "rim/base/shared_mutex.h"
#include "rim/map/local_map.h"
#include "rim/map/submap_store.h"
#include "rim/mesh/marching_cubes.h"
#include "rim/model/decoder.h"

namespace rim {

struct MeshTileSource {
  const MapGeometry& geometry;
  const LocalMap& local_map;
  const SubmapStore& store;
  const Decoder& decoder;
  WriterFirstSharedMutex& mutex;  // shared while reading the map, released between blocks
};

// Finest voxels per edge of a mesh block, the unit of re-meshing (1.6 m at a 0.1 m leaf). Larger
// blocks evaluate fewer grid points twice (a block face is evaluated by both blocks); the box
// changes nearly every block it covers in a frame, so finer blocks would not re-mesh less.
inline constexpr int kMeshBlockVoxels = 16;

// Finest-level voxels (minimum-corner lattice index) owned by sub-map `key` that were observed:
// from the live local map inside the box, from the store elsewhere. Caller holds the shared lock.
std::vector<Int3> ObservedVoxels(const MeshTileSource& src, const Int3& key);

// The mesh grid of `resolution_m`: (r, 1) for r cells per finest voxel edge (a resolution that
// divides the leaf), (1, s) for one cell per s finest voxels (a coarser level of detail: the leaf
// times s, s a power of two that divides a mesh block and the sub-map). Anything else is
// InvalidArgument naming resolution_m.
absl::StatusOr<std::pair<int, int>> MeshGridOf(const MapGeometry& geo, float resolution_m);

// Meshes the tile of sub-map `key` at `resolution_m` (MeshGridOf).
// - Only observed finest voxels are visited (sparse). A fine cell is meshed when it lies in an
//   observed voxel; a coarse cell (resolution above the leaf) when at least a quarter of its
//   finest voxels are observed.
// - The tile owns the mesh cells whose minimum corner lies in its sub-map; cells on its upper
//   border read features across the border, so neighbouring tiles compute bit-identical vertices
//   on their shared faces (no seams, no gaps).
// - Blocks are meshed one at a time under the shared lock, so that meshing a large tile never
//   holds training up for more than one block.
absl::StatusOr<Mesh> ExtractTile(const MeshTileSource& src, float resolution_m, const Int3& key);

// What changed in the map, for MeshBlockCache: regions of finest lattice points (widened by the
// reach of a feature row and of an observed flag) stamped with a change counter, or "everything"
// (the decoder trained). The mapper records one change per frame, after the frame's last update.
class MeshChangeLog {
 public:
  // The stamp a reader takes before it reads the map: a change recorded later has a larger one.
  uint64_t Stamp() const;
  // Records that `regions` (finest lattice points, inclusive) changed; `all` = everything did.
  void Record(const std::vector<IntBox>& regions, bool all);
  // Whether anything recorded after `stamp` touches `region`.
  bool ChangedSince(uint64_t stamp, const IntBox& region) const;

 private:
  struct Entry {
    uint64_t stamp;
    IntBox region;
    bool all;
  };
  static constexpr size_t kMaxEntries = 4096;
  mutable std::mutex mu_;
  uint64_t stamp_ = 0;
  uint64_t floor_ = 0;  // entries up to this stamp were dropped: older pieces count as changed
  std::vector<Entry> entries_;
};

struct MeshUpdateStats {
  int blocks = 0;           // observed blocks of the tile
  int blocks_remeshed = 0;  // of them, meshed now (the others came from the cache)
  // Blocks that a change reached since their last meshing, whose SDF was evaluated again and
  // compared with the values they were meshed from; of them, those kept because no value moved
  // by more than the tolerance (skipped: not re-meshed).
  int blocks_checked = 0;
  int blocks_skipped = 0;
  std::vector<Int3> remeshed;  // keys (FloorDiv(voxel, kMeshBlockVoxels)) of the blocks meshed now
  // Names the tile's mesh: two updates of a tile that return the same generation returned the
  // same mesh (no block was re-meshed or dropped in between), so its encoding can be reused.
  uint64_t generation = 0;
};

// Totals over a cache's updates (MeshBlockCache::Totals), for the service's metrics.
struct MeshCacheTotals {
  int64_t blocks = 0, blocks_remeshed = 0, blocks_checked = 0, blocks_skipped = 0;
};

// Per-block meshes of the tiles that can still change. Update() re-meshes the blocks that changed
// visibly since their last meshing, reuses the others and welds them into the tile. A block that a
// change recorded since its last meshing reaches has its SDF evaluated again at its grid points;
// it is re-meshed only when a value moved by more than `tolerance_m` from the values it was meshed
// from (or its observed voxels changed). With a tolerance of 0 the tile is the same mesh as
// ExtractTile's (same vertices and faces, possibly in another order); otherwise every value it
// was meshed from is within the tolerance of the map's value now. Thread safe; two updates of
// one tile run one after the other.
class MeshBlockCache {
 public:
  // `keep` says whether the tile's blocks are worth keeping afterwards (they can still change);
  // a tile far from the box is meshed the same way and then dropped from the cache.
  absl::StatusOr<Mesh> Update(const MeshTileSource& src, float resolution_m, float tolerance_m,
                              const Int3& key, const MeshChangeLog& log, bool keep,
                              MeshUpdateStats* stats);
  // Host memory held by the cached blocks.
  int64_t MemoryBytes() const;
  MeshCacheTotals Totals() const;

  struct Piece;  // one block's mesh (mesher.cc)
 private:
  struct Tile {
    std::mutex mu;  // held through an update of this tile
    absl::flat_hash_map<Int3, std::shared_ptr<Piece>, Int3Hash, Int3Equal> pieces;
    int64_t bytes = 0;
    uint64_t generation = 0;
  };
  mutable std::mutex mu_;
  absl::flat_hash_map<Int3, std::shared_ptr<Tile>, Int3Hash, Int3Equal> tiles_;
  uint64_t generations_ = 0;  // the last generation given out
  MeshCacheTotals totals_;
};

}  // namespace rim
