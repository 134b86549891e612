// Multi-resolution trilinear feature encoding (§3.1 "Decoding a point"): for every level, the
// features of the 8 lattice corners around a point, weighted trilinearly, concatenated over
// levels into L·D features.
#pragma once

#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

#include "rim/local_map.h"
#include "rim/submap_store.h"
#include "rim/worker_pool.h"

namespace rim {

// Training-side encoding against the live local map. Keeps the corner slots and weights of
// every point so that the backward pass can scatter feature gradients without recomputing.
struct LocalEncoding {
  int points = 0;
  std::vector<int64_t> slots;  // points × L × 8
  std::vector<float> weights;  // points × L × 8
};

// Encodes n points (xyz, inside the box) into features (n × L·D); spread over `pool`'s threads
// when one is given (same result either way).
void EncodeLocal(const LocalMap& map, const float* xyz, int n, LocalEncoding* enc, float* features,
                 WorkerPool* pool = nullptr);

// Accumulates feature gradients of the voxels a batch touched, per level, without touching
// anything else: per-slot stamps say whether a slot already has a row this iteration.
class SparseGradient {
 public:
  void Reset(const LocalMap& map);  // sizes the stamp arrays once; cheap afterwards
  void BeginIteration();
  // grad_features: points × L·D, as produced by the loss backward.
  // With a pool, one level per task.
  void Scatter(const LocalMap& map, const LocalEncoding& enc, const float* grad_features,
               WorkerPool* pool = nullptr);
  struct Level {
    // Per slot, together so that a touch costs one cache miss, not two: whether the slot has a
    // gradient row this iteration (stamp == iteration) and which row.
    struct Tag {
      uint32_t stamp;
      int32_t row;
    };
    std::vector<Tag> tag;
    std::vector<int64_t> touched;  // slots with a gradient row
    std::vector<float> grad;       // touched.size() × D
  };
  Level& level(int l) { return levels_[l]; }

 private:
  void ScatterLevel(const LocalMap& map, const LocalEncoding& enc, const float* grad_features,
                    int l);

  std::vector<Level> levels_;
  uint32_t iteration_ = 0;
};

// Reads features anywhere in the mapped world: from the live local map inside the box, from the
// sub-map store elsewhere, zero where nothing is known. Keeps the store blocks it read (up to
// kMaxCachedBlocks per level, then starts over), so use one reader per batch and per thread.
class FeatureReader {
 public:
  FeatureReader(const LocalMap& map, const SubmapStore& store);
  // Blocks pinned per level before the cache starts over (they stay alive while pinned even if
  // the store replaces them).
  static constexpr size_t kMaxCachedBlocks = 4096;
  // Features of lattice point g at a level (D floats, valid until the next call to Get).
  const float* Get(int level, const Int3& g);
  // Whether the finest voxel with minimum corner g was observed, near a surface or as free space.
  bool Observed(const Int3& g0) { return ObservedBits(g0) != 0; }
  // The LocalMap::kObservedBits of that voxel (meshing wants kObserved only).
  uint8_t ObservedBits(const Int3& g0);

  // Encodes one point; with `jacobian` (L·D × 3, row-major) also d features / d position.
  void Encode(const Vec3d& p_W, float* features, float* jacobian);

 private:
  // One store block (null: the store has none there), shared with the store without a copy.
  // Points near each other share blocks, so a batch pays one store lookup per block instead of
  // one per lattice point, and nothing is allocated or copied per point.
  using CachedBlock = std::shared_ptr<const SubmapStore::Block>;
  struct Slot {
    const SubmapStore::Block* block;  // null: no data
    int index;
  };
  Slot Fetch(int level, const Int3& g);

  const LocalMap& map_;
  const SubmapStore& store_;
  std::unordered_map<Int3, CachedBlock, Int3Hash, Int3Equal> blocks_[kMaxLevels];
  // The last block used per level: consecutive lookups mostly stay in it.
  Int3 last_origin_[kMaxLevels];
  const SubmapStore::Block* last_block_[kMaxLevels] = {};
  bool last_valid_[kMaxLevels] = {};
  std::vector<float> zeros_;
};

}  // namespace rim
