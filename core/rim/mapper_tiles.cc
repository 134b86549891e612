// Mapper: the tiles (one per sub-map) and their versions: what a frame changed (BumpVersions),
// the moving things the box left behind (ClearDepartedLocked), and the tiles' listing, meshes and
// observed voxels.
#include <cmath>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/map/local_map.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"
#include "rim/mapper.h"
#include "rim/mesh/mesher.h"
#include "rim/model/decoder.h"
#include "rim/train/transient.h"

namespace rim {

void Mapper::ClearDepartedLocked() {
  std::vector<Int3> cells = transient_->TakeOutsideCells();
  if (cells.empty()) return;
  saver_->Flush();  // the slabs that left with them are in the store
  const std::vector<Int3> keys = store_->ClearObserved(cells);
  if (keys.empty()) return;
  // One region per sub-map: the cells' bounds there, widened by one voxel (the cells that have
  // them as corners).
  std::vector<IntBox> regions;
  for (const Int3& key : keys) {
    IntBox b{Int3::Constant(INT32_MAX), Int3::Constant(INT32_MIN)};
    for (const Int3& g : cells) {
      if (geometry_->SubmapOfLattice(0, g) != key) continue;
      b.lo = b.lo.cwiseMin(g - Int3::Ones());
      b.hi = b.hi.cwiseMax(g + Int3::Ones());
    }
    regions.push_back(b);
    store_->SetVersion(key, map_version_.load());
  }
  mesh_changes_->Record(regions, false);
  distance_pending_.insert(distance_pending_.end(), regions.begin(), regions.end());
}

void Mapper::BumpVersions(bool decoder_changed, const IntBox* old_box) {
  const uint64_t v = map_version_.load();
  // The decoder is shared by every tile: while it trains, every tile changes.
  if (decoder_changed) store_->SetAllVersions(v);
  // The tiles of the box, and of the box before the slide: the slabs that left it went to the
  // store in 8-bit rows, which moves their values a little.
  auto bump = [&](const IntBox& box) {
    const Int3 lo = geometry_->SubmapOfLattice(0, box.lo);
    const Int3 hi = geometry_->SubmapOfLattice(0, box.hi - Int3::Ones());
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) store_->SetVersion(Int3(x, y, z), v);
  };
  bump(local_map_->LatticeBox(0));
  if (old_box && (old_box->lo != local_map_->LatticeBox(0).lo)) bump(*old_box);
}

std::vector<TileInfo> Mapper::ListTiles(uint64_t since_version) const {
  std::vector<TileInfo> out;
  for (const auto& [key, version] : store_->Versions()) {
    if (version <= since_version) continue;
    TileInfo t;
    t.key = key;
    t.version = version;
    t.min_m = geometry_->SubmapMin(key);
    t.max_m = t.min_m + geometry_->extent_m();
    out.push_back(t);
  }
  return out;
}

std::vector<float> Mapper::MeshLevels() const {
  std::vector<float> out;
  for (int k = 0; k <= 3; ++k) {
    const float r = config_.mesh.resolution_m * float(1 << k);
    if (MeshGridOf(*geometry_, r).ok()) out.push_back(r);
  }
  return out;
}

namespace {

// The level of `levels` that `resolution_m` names (0: the finest), within a micrometre.
absl::StatusOr<float> PickLevel(const std::vector<float>& levels, float resolution_m) {
  if (resolution_m == 0.f && !levels.empty()) return levels.front();
  for (float l : levels)
    if (std::abs(l - resolution_m) < 1e-6f) return l;
  std::string names;
  for (float l : levels) absl::StrAppend(&names, names.empty() ? "" : ", ", l);
  return absl::InvalidArgumentError(absl::StrCat("resolution_m ", resolution_m,
                                                 " is not a level of this map's tiles (", names,
                                                 " m, or 0 for the finest)"));
}

}  // namespace

absl::StatusOr<float> Mapper::MeshLevel(float resolution_m) const {
  return PickLevel(MeshLevels(), resolution_m);
}

absl::StatusOr<Mesh> Mapper::ExtractMeshTile(const Int3& key, float resolution_m) const {
  auto level = MeshLevel(resolution_m);
  if (!level.ok()) return level.status();
  saver_->Flush();
  MeshTileSource src{*geometry_, *local_map_, *store_, *decoder_, mu_};
  return ExtractTile(src, *level, key);
}

absl::StatusOr<Mesh> Mapper::MeshTile(const Int3& key, MeshUpdateStats* stats) const {
  return MeshTile(key, 0.f, stats);
}

absl::StatusOr<Mesh> Mapper::MeshTile(const Int3& key, float resolution_m,
                                      MeshUpdateStats* stats) const {
  auto level = MeshLevel(resolution_m);
  if (!level.ok()) return level.status();
  MeshBlockCache* cache = mesh_cache_.get();
  if (*level != config_.mesh.resolution_m) {
    std::lock_guard<std::mutex> lock(mesh_levels_mu_);
    cache = nullptr;
    for (auto& [l, c] : mesh_level_caches_)
      if (l == *level) cache = c.get();
    if (!cache) {
      mesh_level_caches_.emplace_back(*level, std::make_unique<MeshBlockCache>());
      cache = mesh_level_caches_.back().second.get();
    }
  }
  const float tolerance = config_.mesh.remesh_tolerance_m;
  saver_->Flush();
  bool keep = false;
  {
    // Blocks are kept for the tiles that the box can still change: within a block and a coarse
    // voxel of it.
    std::shared_lock lock(mu_);
    if (local_map_->placed()) {
      const Int3 cells = geometry_->cells(0);
      const int margin = kMeshBlockVoxels + (1 << (geometry_->levels() - 1)) + 1;
      const IntBox box = local_map_->LatticeBox(0);
      const Int3 lo = key.cwiseProduct(cells) - Int3::Constant(margin);
      const Int3 hi = key.cwiseProduct(cells) + cells + Int3::Constant(margin);
      keep = (lo.array() <= box.hi.array()).all() && (box.lo.array() <= hi.array()).all();
    }
  }
  MeshTileSource src{*geometry_, *local_map_, *store_, *decoder_, mu_};
  return cache->Update(src, *level, tolerance, key, *mesh_changes_, keep, stats);
}

MeshCacheTotals Mapper::MeshTotals() const {
  MeshCacheTotals t = mesh_cache_->Totals();
  std::lock_guard<std::mutex> lock(mesh_levels_mu_);
  for (const auto& [level, cache] : mesh_level_caches_) {
    const MeshCacheTotals c = cache->Totals();
    t.blocks += c.blocks;
    t.blocks_remeshed += c.blocks_remeshed;
    t.blocks_checked += c.blocks_checked;
    t.blocks_skipped += c.blocks_skipped;
  }
  return t;
}

int64_t Mapper::MeshCacheBytes() const {
  int64_t bytes = mesh_cache_->MemoryBytes();
  std::lock_guard<std::mutex> lock(mesh_levels_mu_);
  for (const auto& [level, cache] : mesh_level_caches_) bytes += cache->MemoryBytes();
  return bytes;
}

std::vector<Int3> Mapper::ObservedVoxels(const Int3& key) const {
  std::shared_lock lock(mu_);
  saver_->Flush();  // under the lock, as in QuerySdf
  return rim::ObservedVoxels(MeshTileSource{*geometry_, *local_map_, *store_, *decoder_, mu_}, key);
}

}  // namespace rim
