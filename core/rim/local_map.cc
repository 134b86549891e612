#include "rim/local_map.h"

#include <sys/mman.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <new>

namespace rim {

namespace {
constexpr size_t kHugePage = size_t{2} << 20;
}  // namespace

void LocalMap::Level::FreeAllocated(void* p) { std::free(p); }

void* LocalMap::Level::AllocateZeroed(size_t bytes) {
  // Arrays of at least a huge page start on a huge-page boundary; smaller ones (coarse levels,
  // test maps) on a cache line, so that they do not pin a 2 MiB page each.
  const size_t align = bytes >= kHugePage ? kHugePage : 64;
  const size_t rounded = (std::max<size_t>(bytes, 1) + align - 1) / align * align;
  void* p = std::aligned_alloc(align, rounded);
  if (p == nullptr) throw std::bad_alloc();
  // Advice only: with transparent huge pages off this is a no-op and the memory is the same.
  if (align == kHugePage) (void)::madvise(p, rounded, MADV_HUGEPAGE);
  std::memset(p, 0, bytes);
  return p;
}

int LocalMap::Level::MomentFloats(int feature_dim) {
  const int payload = 2 * feature_dim;
  if (payload <= 8) return 8;
  return (payload + 15) / 16 * 16;
}

void LocalMap::Level::Allocate(const Int3& lattice_dims, int feature_dim) {
  dims = lattice_dims;
  feature_dim_ = feature_dim;
  slots_ = int64_t(dims.x()) * dims.y() * dims.z();
  moment_floats_ = MomentFloats(feature_dim);
  // Features start at zero (§3.1: random feature initialisation hurts); so do the moments,
  // step counts, flags and scatter tags.
  features_.Allocate(slots_ * feature_dim);
  moments_.Allocate(slots_ * moment_floats_);
  steps_.Allocate(slots_);
  flags_.Allocate(slots_);
  tags_.Allocate(slots_);
}

std::vector<float> LocalMap::Level::FeatureCopy() const {
  return std::vector<float>(features_.data(), features_.data() + slots_ * feature_dim_);
}

std::vector<uint8_t> LocalMap::Level::FlagCopy() const {
  return std::vector<uint8_t>(flags_.data(), flags_.data() + slots_);
}

int64_t LocalMap::Level::MemoryBytesFor(const Int3& lattice_dims, int feature_dim) {
  const int64_t n = int64_t(lattice_dims.x()) * lattice_dims.y() * lattice_dims.z();
  return n * ((int64_t(feature_dim) + MomentFloats(feature_dim)) * int64_t(sizeof(float)) +
              int64_t(sizeof(int32_t) + sizeof(uint8_t) + sizeof(ScatterTag)));
}

int64_t LocalMap::Level::MemoryBytes() const { return MemoryBytesFor(dims, feature_dim_); }

LocalMap::LocalMap(const MapGeometry& geometry) : geometry_(geometry) {
  levels_.resize(geometry_.levels());
  for (int l = 0; l < geometry_.levels(); ++l)
    levels_[l].Allocate(geometry_.lattice_points(l), geometry_.feature_dim());
}

void LocalMap::ResetSlot(int l, int64_t slot) {
  Level& lv = levels_[l];
  const int D = geometry_.feature_dim();
  std::fill_n(lv.features(slot), D, 0.f);
  // The official code keeps Adam's moments of recycled storage; a new voxel must not inherit the
  // momentum of the one that used the slot before (§3.2).
  std::fill_n(lv.adam_m(slot), 2 * D, 0.f);
  lv.adam_steps(slot) = 0;
  lv.flags(slot) = 0;
}

uint32_t LocalMap::NextScatterStamp() {
  if (++scatter_stamp_ == 0) {
    for (Level& lv : levels_)
      for (int64_t s = 0; s < lv.slots(); ++s) lv.tags_[s] = ScatterTag{0, 0};
    scatter_stamp_ = 1;
  }
  return scatter_stamp_;
}

namespace {
// Slot() for a walk over lattice points that mostly steps +1 in z (how slabs are visited): the
// next slot from the last one, without the three integer divisions of the modulo map, which
// made up most of a move's time.
class SlotWalker {
 public:
  SlotWalker(const LocalMap& map, int l) : map_(map), l_(l), dz_(map.level(l).dims.z()) {}
  int64_t operator()(const Int3& g) {
    if (slot_ >= 0 && g.z() == last_.z() + 1 && g.x() == last_.x() && g.y() == last_.y()) {
      ++slot_;
      if (++zmod_ == dz_) {
        zmod_ = 0;
        slot_ -= dz_;
      }
    } else {
      slot_ = map_.Slot(l_, g);
      zmod_ = PosMod(g.z(), dz_);
    }
    last_ = g;
    return slot_;
  }

 private:
  const LocalMap& map_;
  const int l_, dz_;
  Int3 last_ = Int3::Zero();
  int64_t slot_ = -1;
  int zmod_ = 0;
};
}  // namespace

void LocalMap::MoveTo(const Int3& coarse_origin, const SaveFn& save, const LoadFn& load) {
  if (placed_ && coarse_origin == coarse_origin_) return;
  const int D = geometry_.feature_dim();
  for (int l = 0; l < geometry_.levels(); ++l) {
    Level& lv = levels_[l];
    SlotWalker slot_of(*this, l);
    const IntBox old_box = LatticeBox(l);
    const IntBox new_box{geometry_.LevelOrigin(coarse_origin, l),
                         geometry_.LevelOrigin(coarse_origin, l) + geometry_.cells(l)};
    if (placed_) {
      SlabBatch batch;
      batch.level = l;
      ForEachInDifference(old_box, new_box, [&](const Int3& g) {
        const int64_t slot = slot_of(g);
        if (!lv.has_data(slot)) return;
        batch.points.push_back(g);
        batch.features.insert(batch.features.end(), lv.features(slot), lv.features(slot) + D);
        if (l == 0) batch.observed.push_back(lv.flags(slot) & kObservedBits);
        ResetSlot(l, slot);
      });
      if (!batch.points.empty() && save) save(std::move(batch));
    }
    lv.origin = new_box.lo;
    auto fill = [&](const Int3& g) {
      const int64_t slot = slot_of(g);
      uint8_t observed = 0;
      if (load && load(l, g, lv.features(slot), &observed)) {
        lv.flags(slot) = kHasData | (observed & kObservedBits);
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
  for (int l = 0; l < geometry.levels(); ++l)
    bytes += Level::MemoryBytesFor(geometry.lattice_points(l), geometry.feature_dim());
  return bytes;
}

int64_t LocalMap::MemoryBytes() const {
  int64_t bytes = 0;
  for (const Level& lv : levels_) bytes += lv.MemoryBytes();
  return bytes;
}

}  // namespace rim
