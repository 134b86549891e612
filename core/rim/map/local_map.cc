#include "rim/map/local_map.h"

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

void LocalMap::MoveTo(const Int3& coarse_origin, const SaveFn& save, const LoadFn& load) {
  LoadRunFn load_run;
  if (load) {
    const int D = geometry_.feature_dim();
    load_run = [&load, D](int l, const Int3& g, int n, float* features, uint8_t* flags) {
      for (int i = 0; i < n; ++i) {
        uint8_t observed = 0;
        if (load(l, Int3(g.x(), g.y(), g.z() + i), features + size_t(i) * D, &observed))
          flags[i] = kHasData | (observed & kObservedBits);
      }
    };
  }
  MoveToLoadingRuns(coarse_origin, save, load_run);
}

void LocalMap::MoveToLoadingRuns(const Int3& coarse_origin, const SaveFn& save,
                                 const LoadRunFn& load) {
  if (placed_ && coarse_origin == coarse_origin_) return;
  const int D = geometry_.feature_dim();
  // The leaving slabs go to `save` only after every level has loaded its entering voxels. The
  // mapper's saver writes a batch into the store under the store's lock, and the loads read the
  // store: handed over level by level, level 0's write held up level 0's reads for most of the
  // slide (7.7 of 11.8 ms a frame). Leaving and entering voxels are disjoint, so no load needs a
  // batch of this slide.
  std::vector<SlabBatch> leaving_batches;
  for (int l = 0; l < geometry_.levels(); ++l) {
    Level& lv = levels_[l];
    const int dz = lv.dims.z();
    // Calls fn(slot, z, len) for the pieces of a z run whose slots are consecutive: the run
    // breaks only where the ring wraps along z.
    auto for_each_piece = [&](const Int3& g, int n, auto&& fn) {
      for (int z = g.z(), end = g.z() + n; z < end;) {
        const int len = std::min(end - z, dz - PosMod(z, dz));
        fn(Slot(l, Int3(g.x(), g.y(), z)), z, len);
        z += len;
      }
    };
    const IntBox old_box = LatticeBox(l);
    const IntBox new_box{geometry_.LevelOrigin(coarse_origin, l),
                         geometry_.LevelOrigin(coarse_origin, l) + geometry_.cells(l)};
    if (placed_) {
      SlabBatch batch;
      batch.level = l;
      // Count first: the batch is sized once instead of growing (and copying) as it fills.
      size_t leaving = 0;
      ForEachRunInDifference(old_box, new_box, [&](const Int3& g, int n) {
        for_each_piece(g, n, [&](int64_t slot, int, int len) {
          for (int k = 0; k < len; ++k) leaving += lv.has_data(slot + k);
        });
      });
      batch.points.reserve(leaving);
      batch.features.resize(leaving * D);
      if (l == 0) batch.observed.reserve(leaving);
      float* out = batch.features.data();
      ForEachRunInDifference(old_box, new_box, [&](const Int3& g, int n) {
        for_each_piece(g, n, [&](int64_t slot0, int z0, int len) {
          for (int k = 0; k < len; ++k) {
            const int64_t slot = slot0 + k;
            if (!lv.has_data(slot)) continue;
            batch.points.emplace_back(g.x(), g.y(), z0 + k);
            out = std::copy_n(lv.features(slot), D, out);
            if (l == 0) batch.observed.push_back(lv.flags(slot) & kObservedBits);
            ResetSlot(l, slot);
          }
        });
      });
      if (!batch.points.empty() && save) leaving_batches.push_back(std::move(batch));
    }
    lv.origin = new_box.lo;
    if (!load) continue;
    auto fill = [&](const Int3& g, int n) {
      for_each_piece(g, n, [&](int64_t slot, int z, int len) {
        load(l, Int3(g.x(), g.y(), z), len, lv.features(slot), &lv.flags(slot));
      });
    };
    if (placed_) {
      ForEachRunInDifference(new_box, old_box, fill);
    } else {
      for (int x = new_box.lo.x(); x <= new_box.hi.x(); ++x)
        for (int y = new_box.lo.y(); y <= new_box.hi.y(); ++y)
          fill(Int3(x, y, new_box.lo.z()), new_box.hi.z() - new_box.lo.z() + 1);
    }
  }
  for (SlabBatch& batch : leaving_batches) save(std::move(batch));
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
