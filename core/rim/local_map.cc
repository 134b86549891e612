#include "rim/local_map.h"

#include <algorithm>
#include <cstring>

namespace rim {

LocalMap::LocalMap(const MapGeometry& geometry) : geometry_(geometry) {
  const int D = geometry_.feature_dim();
  levels_.resize(geometry_.levels());
  for (int l = 0; l < geometry_.levels(); ++l) {
    Level& lv = levels_[l];
    lv.dims = geometry_.lattice_points(l);
    const size_t n = size_t(lv.dims.x()) * lv.dims.y() * lv.dims.z();
    // Features start at zero (§3.1: random feature initialisation hurts).
    lv.features.assign(n * D, 0.f);
    lv.adam_m.assign(n * D, 0.f);
    lv.adam_v.assign(n * D, 0.f);
    lv.adam_steps.assign(n, 0);
    lv.flags.assign(n, 0);
  }
}

void LocalMap::ResetSlot(int l, int64_t slot) {
  Level& lv = levels_[l];
  const int D = geometry_.feature_dim();
  std::fill_n(&lv.features[slot * D], D, 0.f);
  // The official code keeps Adam's moments of recycled storage; a new voxel must not inherit the
  // momentum of the one that used the slot before (§3.2).
  std::fill_n(&lv.adam_m[slot * D], D, 0.f);
  std::fill_n(&lv.adam_v[slot * D], D, 0.f);
  lv.adam_steps[slot] = 0;
  lv.flags[slot] = 0;
}

void LocalMap::MoveTo(const Int3& coarse_origin, const SaveFn& save, const LoadFn& load) {
  if (placed_ && coarse_origin == coarse_origin_) return;
  const int D = geometry_.feature_dim();
  for (int l = 0; l < geometry_.levels(); ++l) {
    Level& lv = levels_[l];
    const IntBox old_box = LatticeBox(l);
    const IntBox new_box{geometry_.LevelOrigin(coarse_origin, l),
                         geometry_.LevelOrigin(coarse_origin, l) + geometry_.cells(l)};
    if (placed_) {
      SlabBatch batch;
      batch.level = l;
      ForEachInDifference(old_box, new_box, [&](const Int3& g) {
        const int64_t slot = Slot(l, g);
        if (!(lv.flags[slot] & kHasData)) return;
        batch.points.push_back(g);
        batch.features.insert(batch.features.end(), &lv.features[slot * D],
                              &lv.features[slot * D] + D);
        if (l == 0) batch.observed.push_back(lv.flags[slot] & kObservedBits);
        ResetSlot(l, slot);
      });
      if (!batch.points.empty() && save) save(std::move(batch));
    }
    lv.origin = new_box.lo;
    auto fill = [&](const Int3& g) {
      const int64_t slot = Slot(l, g);
      uint8_t observed = 0;
      if (load && load(l, g, &lv.features[slot * D], &observed)) {
        lv.flags[slot] = kHasData | (observed & kObservedBits);
      }
    };
    if (placed_) {
      ForEachInDifference(new_box, old_box, fill);
    } else {
      for (int x = new_box.lo.x(); x <= new_box.hi.x(); ++x)
        for (int y = new_box.lo.y(); y <= new_box.hi.y(); ++y)
          for (int z = new_box.lo.z(); z <= new_box.hi.z(); ++z) fill(Int3(x, y, z));
    }
  }
  coarse_origin_ = coarse_origin;
  placed_ = true;
}

void LocalMap::PlaceWithoutLoading(const Int3& coarse_origin) {
  for (int l = 0; l < geometry_.levels(); ++l)
    levels_[l].origin = geometry_.LevelOrigin(coarse_origin, l);
  coarse_origin_ = coarse_origin;
  placed_ = true;
}

int64_t LocalMap::MemoryBytesFor(const MapGeometry& geometry) {
  int64_t bytes = 0;
  for (int l = 0; l < geometry.levels(); ++l) {
    const Int3 dims = geometry.lattice_points(l);
    const int64_t n = int64_t(dims.x()) * dims.y() * dims.z();
    // features, adam_m, adam_v (D floats each), adam_steps and flags, as the constructor sizes
    // them.
    bytes += n * (3 * int64_t(geometry.feature_dim()) * int64_t(sizeof(float)) +
                  int64_t(sizeof(int32_t)) + 1);
  }
  return bytes;
}

int64_t LocalMap::MemoryBytes() const {
  int64_t bytes = 0;
  for (const Level& lv : levels_) {
    bytes += int64_t(lv.features.size() + lv.adam_m.size() + lv.adam_v.size()) * sizeof(float);
    bytes += int64_t(lv.adam_steps.size()) * sizeof(int32_t) + int64_t(lv.flags.size());
  }
  return bytes;
}

}  // namespace rim
