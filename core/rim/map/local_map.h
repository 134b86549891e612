// The robot-centric local map (§3.2): L dense feature grids around the robot, stored as ring
// buffers so that moving the box only re-labels storage, plus the per-voxel Adam state and the
// observed mask. The owner thread (the trainer) is the only writer.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <type_traits>
#include <vector>

#include "rim/map/map_geometry.h"

namespace rim {

// Voxels that leave the box, handed to the global map; only voxels that hold data are included.
struct SlabBatch {
  int level = 0;
  std::vector<Int3> points;       // world lattice indices
  std::vector<float> features;    // D per point
  std::vector<uint8_t> observed;  // per point, kObserved | kSeenFree bits (level 0 only)
};

class LocalMap {
 public:
  // kObserved: a training sample near the surface fell in the voxel (what meshing visits).
  // kSeenFree: a free-space sample fell in it; queries there report observed, meshing skips it.
  enum Flags : uint8_t { kObserved = 1, kHasData = 2, kSeenFree = 4 };
  static constexpr uint8_t kObservedBits = kObserved | kSeenFree;

  // The gradient scatter's per-slot mark (SparseGradient): the slot has gradient row `row` in the
  // iteration whose stamp equals `stamp`. Stamp and row share one 8-byte record so that a touch
  // costs one cache miss; the array is small enough (8 bytes per slot) to stay mostly in cache.
  struct ScatterTag {
    uint32_t stamp;
    int32_t row;
  };

  // One level's dense grid. The training step touches ~100k random slots per iteration, so the
  // layout is chosen by cache lines touched per slot:
  //  - features: D floats per slot, dense (for D = 8 the two z-neighbours of a trilinear corner
  //    pair share one line, which the encode, the queries and the mesher all exploit);
  //  - Adam moments m and v of a slot side by side in one record (one line for D = 8, where two
  //    separate arrays cost two misses per updated row);
  //  - the small per-slot arrays (scatter tags, step counts, flags) apart, so that they stay
  //    mostly cache-resident and the passes that only need flags (free-space marking, meshing)
  //    read 1 byte per slot.
  class Level {
   public:
    Int3 dims = Int3::Zero();    // lattice points per axis (storage size)
    Int3 origin = Int3::Zero();  // world lattice index of the box's minimum corner

    void Allocate(const Int3& lattice_dims, int feature_dim);
    int64_t slots() const { return slots_; }
    int feature_dim() const { return feature_dim_; }
    float* features(int64_t slot) { return features_.data() + slot * feature_dim_; }
    const float* features(int64_t slot) const { return features_.data() + slot * feature_dim_; }
    float* adam_m(int64_t slot) { return moments_.data() + slot * moment_floats_; }
    const float* adam_m(int64_t slot) const { return moments_.data() + slot * moment_floats_; }
    float* adam_v(int64_t slot) { return adam_m(slot) + feature_dim_; }
    const float* adam_v(int64_t slot) const { return adam_m(slot) + feature_dim_; }
    // Per-slot Adam step count: bias correction per row.
    int32_t& adam_steps(int64_t slot) { return steps_[slot]; }
    int32_t adam_steps(int64_t slot) const { return steps_[slot]; }
    uint8_t& flags(int64_t slot) { return flags_[slot]; }
    uint8_t flags(int64_t slot) const { return flags_[slot]; }
    // The flags as a reader holding the map's lock shared reads them: a frame's marking sets bits
    // under the shared lock too (MarkScan, with atomic ORs), so such a reader loads them
    // atomically. Relaxed: a bit set a moment earlier or later changes no answer's meaning.
    uint8_t flags_shared(int64_t slot) const {
      return __atomic_load_n(&flags_[slot], __ATOMIC_RELAXED);
    }
    // Whether the slot holds anything worth keeping: loaded or marked data (kHasData), or an
    // optimiser update (a step count). The training step sets no flag, so that its pass over
    // the touched rows does not write one more random line per row.
    bool has_data(int64_t slot) const { return (flags_[slot] & kHasData) || steps_[slot] != 0; }
    ScatterTag& scatter_tag(int64_t slot) { return tags_[slot]; }
    const ScatterTag& scatter_tag(int64_t slot) const { return tags_[slot]; }
    // Copies for tests and tools: every slot's features (slots × D) or flags, dense.
    std::vector<float> FeatureCopy() const;
    std::vector<uint8_t> FlagCopy() const;
    // The flags of every slot, contiguous (for a bulk copy: the GPU path's sync).
    const uint8_t* flag_data() const { return flags_.data(); }
    uint8_t* flag_data() { return flags_.data(); }
    int64_t MemoryBytes() const;
    static int64_t MemoryBytesFor(const Int3& lattice_dims, int feature_dim);

   private:
    friend class LocalMap;
    // Zeroed storage on 2 MiB boundaries, with the kernel asked for transparent huge pages: the
    // training step's random accesses over hundreds of MB would otherwise miss the TLB on
    // almost every row (4 KiB pages), and a page walk per row costs as much as the row.
    static void* AllocateZeroed(size_t bytes);
    static void FreeAllocated(void* p);
    template <typename T>
    class Array {
     public:
      void Allocate(int64_t n) {
        static_assert(std::is_trivially_copyable_v<T>);
        data_.reset(static_cast<T*>(AllocateZeroed(size_t(n) * sizeof(T))));
      }
      T* data() { return data_.get(); }
      const T* data() const { return data_.get(); }
      T& operator[](int64_t i) { return data_.get()[i]; }
      const T& operator[](int64_t i) const { return data_.get()[i]; }

     private:
      struct Free {
        void operator()(T* p) const { FreeAllocated(p); }
      };
      std::unique_ptr<T[], Free> data_;
    };
    // Moment record size in floats: 2·D rounded up to 32 or a multiple of 64 bytes, so that no
    // record straddles two cache lines.
    static int MomentFloats(int feature_dim);

    int feature_dim_ = 0;
    int64_t slots_ = 0;
    int moment_floats_ = 0;
    Array<float> features_, moments_;
    Array<int32_t> steps_;
    Array<uint8_t> flags_;
    Array<ScatterTag> tags_;
  };

  // Loads a voxel's data from the global map; returns false when nothing is known there.
  using LoadFn = std::function<bool(int level, const Int3& g, float* features, uint8_t* observed)>;
  // Loads a run of n voxels g, g + ẑ, ..., g + (n − 1)·ẑ of a level, whose storage is contiguous:
  // for voxel i that the global map knows, writes its D features to features + i·D and sets
  // flags[i] = kHasData | its observed bits; leaves the others as they are.
  using LoadRunFn =
      std::function<void(int level, const Int3& g, int n, float* features, uint8_t* flags)>;
  using SaveFn = std::function<void(SlabBatch&&)>;

  explicit LocalMap(const MapGeometry& geometry);

  const MapGeometry& geometry() const { return geometry_; }
  bool placed() const { return placed_; }
  const Int3& coarse_origin() const { return coarse_origin_; }
  Level& level(int l) { return levels_[l]; }
  const Level& level(int l) const { return levels_[l]; }

  // Box bounds in metres, half-open: [min, max).
  Vec3d min_m() const { return coarse_origin_.cast<double>() * coarse_m(); }
  Vec3d max_m() const { return min_m() + geometry_.extent_m(); }
  bool Contains(const Vec3d& p_W) const {
    return placed_ && (p_W.array() >= min_m().array()).all() &&
           (p_W.array() < max_m().array()).all();
  }
  // Lattice points of a level covered by the box.
  IntBox LatticeBox(int l) const {
    return {levels_[l].origin, levels_[l].origin + geometry_.cells(l)};
  }
  bool InBox(int l, const Int3& g) const { return placed_ && LatticeBox(l).Contains(g); }

  // Storage slot of lattice point g; g must be in the box. A pure modulo map: moving the box
  // never moves data in memory (§3.2 "moving without copying").
  int64_t Slot(int l, const Int3& g) const {
    const Int3& d = levels_[l].dims;
    return (int64_t(PosMod(g.x(), d.x())) * d.y() + PosMod(g.y(), d.y())) * d.z() +
           PosMod(g.z(), d.z());
  }

  // Storage slots of the 8 corners of the cell whose lower corner is lattice point g (g and
  // g + (1, 1, 1) in the box), corner c at offset (c >> 2 & 1, c >> 1 & 1, c & 1): the lower
  // corner's slot per axis and a wrap, 3 modulo operations for the cell instead of 24.
  void CellSlots(int l, const Int3& g, int64_t slots[8]) const {
    const Int3& d = levels_[l].dims;
    int64_t s0[3], s1[3];
    for (int a = 0; a < 3; ++a) {
      s0[a] = PosMod(g[a], d[a]);
      s1[a] = s0[a] + 1 == d[a] ? 0 : s0[a] + 1;
    }
    for (int c = 0; c < 8; ++c)
      slots[c] = ((c & 4 ? s1[0] : s0[0]) * d.y() + (c & 2 ? s1[1] : s0[1])) * d.z() +
                 (c & 1 ? s1[2] : s0[2]);
  }

  // Moves the box to a new coarse origin (§3.2 slab exchange): voxels leaving the box are given to
  // `save` and their storage is reset, Adam moments included; voxels entering are filled by
  // `load`, or left zero. The first call places the box and loads all of it.
  void MoveTo(const Int3& coarse_origin, const SaveFn& save, const LoadFn& load);
  // The same, loading entering voxels a z run at a time: a loader that handles a run costs one
  // call per run instead of one per voxel (the mapper's slide).
  void MoveToLoadingRuns(const Int3& coarse_origin, const SaveFn& save, const LoadRunFn& load);

  // Sets the box position without any slab exchange; used when restoring a saved map whose
  // storage is filled separately.
  void PlaceWithoutLoading(const Int3& coarse_origin);
  // Resets one slot to the never-trained state.
  void ResetSlot(int l, int64_t slot);
  // Bytes held by the dense grids and their optimiser state (constant once constructed).
  int64_t MemoryBytes() const;
  // The same for a local map of `geometry`, without building one.
  static int64_t MemoryBytesFor(const MapGeometry& geometry);

  // A new stamp for one gradient scatter (ScatterTag::stamp). When the counter wraps,
  // every slot's stamp is cleared first, so an old mark never equals a new stamp.
  uint32_t NextScatterStamp();

 private:
  double coarse_m() const { return geometry_.voxel_m(geometry_.levels() - 1); }

  MapGeometry geometry_;
  std::vector<Level> levels_;
  Int3 coarse_origin_ = Int3::Zero();
  bool placed_ = false;
  uint32_t scatter_stamp_ = 0;
};

}  // namespace rim
