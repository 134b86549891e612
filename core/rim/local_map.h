// The robot-centric local map (§3.2): L dense feature grids around the robot, stored as ring
// buffers so that moving the box only re-labels storage, plus the per-voxel Adam state and the
// observed mask. The owner thread (the trainer) is the only writer.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "rim/map_geometry.h"

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

  struct Level {
    Int3 dims = Int3::Zero();     // lattice points per axis (storage size)
    Int3 origin = Int3::Zero();   // world lattice index of the box's minimum corner
    std::vector<float> features;  // slot-major, D per slot
    std::vector<float> adam_m;
    std::vector<float> adam_v;
    std::vector<int32_t> adam_steps;  // per-slot step count: Adam bias correction per row
    std::vector<uint8_t> flags;
  };

  // Loads a voxel's data from the global map; returns false when nothing is known there.
  using LoadFn = std::function<bool(int level, const Int3& g, float* features, uint8_t* observed)>;
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

  // Moves the box to a new coarse origin (§3.2 slab exchange): voxels leaving the box are given to
  // `save` and their storage is reset, Adam moments included; voxels entering are filled by
  // `load`, or left zero. The first call places the box and loads all of it.
  void MoveTo(const Int3& coarse_origin, const SaveFn& save, const LoadFn& load);

  // Sets the box position without any slab exchange; used when restoring a saved map whose
  // storage is filled separately.
  void PlaceWithoutLoading(const Int3& coarse_origin);
  // Resets one slot to the never-trained state.
  void ResetSlot(int l, int64_t slot);
  // Bytes held by the dense grids and their optimiser state (constant once constructed).
  int64_t MemoryBytes() const;
  // The same for a local map of `geometry`, without building one.
  static int64_t MemoryBytesFor(const MapGeometry& geometry);

 private:
  double coarse_m() const { return geometry_.voxel_m(geometry_.levels() - 1); }

  MapGeometry geometry_;
  std::vector<Level> levels_;
  Int3 coarse_origin_ = Int3::Zero();
  bool placed_ = false;
};

}  // namespace rim
