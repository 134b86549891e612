// Multi-resolution trilinear feature encoding (§3.1 "Decoding a point"): for every level, the
// features of the 8 lattice corners around a point, weighted trilinearly, concatenated over
// levels into L·D features.
#pragma once

#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

#include "rim/base/worker_pool.h"
#include "rim/map/local_map.h"
#include "rim/map/submap_store.h"

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
// anything else. Whether a slot already has a row this iteration, and which, is marked in the
// level's scatter tags (LocalMap::ScatterTag).
class SparseGradient {
 public:
  void Reset(const LocalMap& map);  // sizes the per-level row tables
  void BeginIteration(LocalMap* map);
  // grad_features: points × L·D, as produced by the loss backward. Writes the scatter marks of
  // the touched slots. With a pool, one level per task.
  void Scatter(LocalMap* map, const LocalEncoding& enc, const float* grad_features,
               WorkerPool* pool = nullptr);
  // One level of Scatter: levels are independent, so a caller may run them as its own tasks.
  void ScatterLevel(LocalMap* map, const LocalEncoding& enc, const float* grad_features, int l);
  // One cache line or more each: levels are scattered on different threads at once, and the
  // scatter writes its level's vector ends for every new row; levels sharing a line made every
  // such write contend with the other thread (BENCHMARK.md, "False sharing in the training step").
  struct alignas(64) Level {
    std::vector<int64_t> touched;  // slots with a gradient row, in first-touch order
    std::vector<float> grad;       // row r at [r·D, (r+1)·D) for r < touched.size()
  };
  Level& level(int l) { return levels_[l]; }
  // Row of `slot` this iteration, or -1 when the batch did not touch it.
  int32_t RowOf(const LocalMap& map, int l, int64_t slot) const {
    const LocalMap::ScatterTag& tag = map.level(l).scatter_tag(slot);
    return tag.stamp == stamp_ ? tag.row : -1;
  }

 private:
  std::vector<Level> levels_;
  uint32_t stamp_ = 0;
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
  // Starts loading the live-map rows that Encode(p_W) will read, without waiting for them: call
  // it a few points ahead so that the cache misses of several points overlap.
  void Prefetch(const Vec3d& p_W) const;

 private:
  // One store block (null: the store has none there), shared with the store without a copy.
  // Points near each other share blocks, so a batch pays one store lookup per block instead of
  // one per lattice point, and nothing is allocated or copied per point.
  using CachedBlock = std::shared_ptr<const SubmapStore::Block>;
  struct Slot {
    const SubmapStore::Block* block;  // null: no data
    int index;
  };
  Slot Fetch(int level, const Int3& g) { return Fetch(level, g, store_.Address(level, g)); }
  Slot Fetch(int level, const Int3& g, const SubmapStore::BlockAddress& a);
  // One level's cell of Encode for D = 8: `f` the point's fractions in the cell, `corner` the 8
  // rows when the cell is in the live box (else null: read through Get).
  void EncodeCell8(const float f[3], float inv_h, const float* const* corner, int l,
                   const Int3& base, float* out, float* jac);
  // The 8 corner rows of a level-l cell that lies wholly outside the live box, decoded into
  // `rows` (8 × 8 floats) with `corner` pointing at them: one address computation for the cell
  // and one block lookup per block its corners fall in, instead of one of each per corner.
  // False (nothing written) when a corner is in the box; Get reads those.
  bool StoreCorners8(int l, const Int3& base, const float** corner, float* rows);

  const LocalMap& map_;
  const SubmapStore& store_;
  std::unordered_map<Int3, CachedBlock, Int3Hash, Int3Equal> blocks_[kMaxLevels];
  // The last block used per level: consecutive lookups mostly stay in it.
  Int3 last_origin_[kMaxLevels];
  const SubmapStore::Block* last_block_[kMaxLevels] = {};
  bool last_valid_[kMaxLevels] = {};
  std::vector<float> zeros_;
  std::vector<float> widened_;  // a store row (half floats) as floats, for Get
};

}  // namespace rim
