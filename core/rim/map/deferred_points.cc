#include "rim/map/deferred_points.h"

#include <algorithm>
#include <cmath>
#include <tuple>
#include <utility>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"

namespace rim {

DeferredPoints::DeferredPoints(const MapGeometry& geometry, const GridConfig& grid,
                               const DeferredConfig& config)
    : extent_m_(geometry.extent_m()),
      voxel_m_(config.voxel_m),
      max_per_submap_(config.max_points_per_submap),
      enabled_(config.enabled && grid.sliding) {
  for (int a = 0; a < 3; ++a) dims_[a] = std::max(1, int(std::ceil(extent_m_[a] / voxel_m_)));
  const float height = grid.z_max_m - grid.z_min_m;
  band_lo_m_ = grid.z_min_m - height;
  band_hi_m_ = grid.z_max_m + height;
}

bool DeferredPoints::Locate(const Vec3f& p, Int3* key, uint32_t* voxel) const {
  Int3 v;
  for (int a = 0; a < 3; ++a) {
    const double s = std::floor(double(p[a]) / extent_m_[a]);
    if (!(std::abs(s) < 1e8)) return false;
    (*key)[a] = int(s);
    const double local = double(p[a]) - s * extent_m_[a];
    v[a] = std::clamp(int(local / voxel_m_), 0, dims_[a] - 1);
  }
  *voxel = uint32_t((int64_t(v.x()) * dims_.y() + v.y()) * dims_.z() + v.z());
  return true;
}

void DeferredPoints::Add(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W,
                         const Vec3f& sensor_W) {
  if (!enabled_) return;
  // First every kept point's sub-map and voxel, so that the table probes below can be requested
  // a few points ahead: a scan's rays land all over tables too big for the cache, and one miss
  // after another was most of the cost.
  struct Located {
    uint32_t index;
    uint32_t voxel;
    Int3 key;
  };
  std::vector<Located> kept;
  kept.reserve(points_W.size());
  for (size_t i = 0; i < points_W.size(); ++i) {
    const Vec3f& p = points_W[i];
    const float dz = p.z() - sensor_W.z();
    if (dz < band_lo_m_ || dz > band_hi_m_) continue;
    Located l;
    if (!Locate(p, &l.key, &l.voxel)) continue;
    l.index = uint32_t(i);
    kept.push_back(l);
  }
  constexpr size_t kAhead = 8;
  std::vector<Int3> grown;  // keys: a new sub-map's table may move the others
  // Consecutive points mostly share a sub-map: one table lookup and one change mark per run.
  for (size_t r = 0; r < kept.size();) {
    const Int3 key = kept[r].key;
    size_t end = r + 1;
    while (end < kept.size() && kept[end].key == key) ++end;
    Table& table = submaps_[key];
    bool changed = false;
    for (size_t j = r; j < end; ++j) {
      if (j + kAhead < end) table.prefetch(kept[j + kAhead].voxel);
      const size_t i = kept[j].index;
      const Vec3f& p = points_W[i];
      Ray ray{{p.x(), p.y(), p.z()}, {origins_W[i].x(), origins_W[i].y(), origins_W[i].z()}};
      auto [it, inserted] = table.try_emplace(kept[j].voxel, ray);
      if (inserted) {
        ++size_;
        ++added_;
        changed = true;
        if (table.size() == size_t(max_per_submap_) + 1) grown.push_back(key);
      } else if (ray.range2() < it->second.range2()) {
        it->second = ray;
        ++added_;
        changed = true;
      }
    }
    if (changed) changed_.insert(key);
    r = end;
  }
  for (const Int3& key : grown) {
    Table& t = submaps_.at(key);
    if (t.size() > size_t(max_per_submap_)) Evict(&t);
  }
}

void DeferredPoints::Evict(Table* table) {
  // Down to 7/8 of the bound, so that a full sub-map is not sorted on every scan. Ties on the
  // range are broken by voxel, so that the survivors do not depend on the table's order.
  const size_t keep = size_t(max_per_submap_) - size_t(max_per_submap_) / 8;
  std::vector<std::pair<float, uint32_t>> by_range;
  by_range.reserve(table->size());
  for (const auto& [voxel, ray] : *table) by_range.emplace_back(ray.range2(), voxel);
  std::nth_element(by_range.begin(), by_range.begin() + keep, by_range.end());
  for (size_t i = keep; i < by_range.size(); ++i) table->erase(by_range[i].second);
  const size_t dropped = by_range.size() - keep;
  size_ -= dropped;
  evicted_ += int64_t(dropped);
}

int64_t DeferredPoints::RemoveIf(const Vec3f& center_W, float radius_m, int period, int phase,
                                 const BatchJudge& judge) {
  if (size_ == 0) return 0;
  Int3 lo, hi;
  for (int a = 0; a < 3; ++a) {
    lo[a] = int(std::floor((center_W[a] - radius_m) / extent_m_[a]));
    hi[a] = int(std::floor((center_W[a] + radius_m) / extent_m_[a]));
  }
  const float r2 = radius_m * radius_m;
  // The rays to judge, and where each is filed.
  std::vector<Vec3f> endpoints;
  std::vector<std::pair<Table*, uint32_t>> where;
  std::vector<Int3> keys;
  for (int x = lo.x(); x <= hi.x(); ++x)
    for (int y = lo.y(); y <= hi.y(); ++y)
      for (int z = lo.z(); z <= hi.z(); ++z) {
        if (((x + y + z) % period + period) % period != phase) continue;
        auto sub = submaps_.find(Int3(x, y, z));
        if (sub == submaps_.end()) continue;
        for (auto& [voxel, ray] : sub->second) {
          const Vec3f p(ray.p[0], ray.p[1], ray.p[2]);
          if ((p - center_W).squaredNorm() > r2) continue;
          endpoints.push_back(p);
          where.emplace_back(&sub->second, voxel);
          keys.push_back(sub->first);
        }
      }
  if (endpoints.empty()) return 0;
  std::vector<uint8_t> drop(endpoints.size(), 0);
  judge(endpoints, &drop);
  int64_t removed = 0;
  for (size_t i = 0; i < endpoints.size(); ++i) {
    if (!drop[i]) continue;
    where[i].first->erase(where[i].second);
    ++removed;
    changed_.insert(keys[i]);
  }
  // Tables left empty go, once every erasure through `where` is done.
  for (size_t i = 0; i < endpoints.size(); ++i) {
    if (!drop[i]) continue;
    auto sub = submaps_.find(keys[i]);
    if (sub != submaps_.end() && sub->second.empty()) submaps_.erase(sub);
  }
  size_ -= size_t(removed);
  return removed;
}

void DeferredPoints::TakeInside(const Vec3d& min_m, const Vec3d& max_m,
                                std::vector<Vec3f>* points_W, std::vector<Vec3f>* origins_W) {
  if (size_ == 0) return;
  Int3 lo, hi;
  for (int a = 0; a < 3; ++a) {
    lo[a] = int(std::floor(min_m[a] / extent_m_[a]));
    hi[a] = int(std::floor(max_m[a] / extent_m_[a]));
  }
  // In double, as the mapper's own inside test: a float endpoint equal to the float of a box face
  // can lie beyond the face.
  const Eigen::Array3d box_lo = min_m.array(), box_hi = max_m.array();
  std::vector<std::pair<uint32_t, Ray>> taken;
  for (int x = lo.x(); x <= hi.x(); ++x)
    for (int y = lo.y(); y <= hi.y(); ++y)
      for (int z = lo.z(); z <= hi.z(); ++z) {
        auto sub = submaps_.find(Int3(x, y, z));
        if (sub == submaps_.end()) continue;
        Table& table = sub->second;
        taken.clear();
        for (auto it = table.begin(); it != table.end();) {
          const Eigen::Array3d p(it->second.p[0], it->second.p[1], it->second.p[2]);
          if ((p >= box_lo).all() && (p < box_hi).all()) {
            taken.emplace_back(it->first, it->second);
            table.erase(it++);
          } else {
            ++it;
          }
        }
        std::sort(taken.begin(), taken.end(),
                  [](const auto& a, const auto& b) { return a.first < b.first; });
        for (const auto& [voxel, ray] : taken) {
          points_W->emplace_back(ray.p[0], ray.p[1], ray.p[2]);
          origins_W->emplace_back(ray.o[0], ray.o[1], ray.o[2]);
        }
        size_ -= taken.size();
        taken_ += int64_t(taken.size());
        if (!taken.empty()) changed_.insert(Int3(x, y, z));
        if (table.empty()) submaps_.erase(sub);
      }
}

DeferredStats DeferredPoints::Stats() const {
  DeferredStats s;
  s.points = int64_t(size_);
  s.submaps = int(submaps_.size());
  // A flat hash table holds one slot and one control byte per unit of capacity.
  constexpr int64_t kSlot = sizeof(std::pair<const uint32_t, Ray>) + 1;
  for (const auto& [key, table] : submaps_) s.bytes += int64_t(table.capacity()) * kSlot;
  s.bytes += int64_t(submaps_.capacity()) * int64_t(sizeof(std::pair<const Int3, Table>) + 1);
  s.added = added_;
  s.evicted = evicted_;
  s.taken = taken_;
  return s;
}

void DeferredPoints::Serialize(ByteWriter* w) const {
  std::vector<Int3> keys;
  keys.reserve(submaps_.size());
  for (const auto& [key, table] : submaps_) keys.push_back(key);
  std::sort(keys.begin(), keys.end(), [](const Int3& a, const Int3& b) {
    return std::tie(a.x(), a.y(), a.z()) < std::tie(b.x(), b.y(), b.z());
  });
  w->U64(uint64_t(added_));
  w->U64(uint64_t(evicted_));
  w->U64(uint64_t(taken_));
  w->U32(uint32_t(keys.size()));
  std::vector<uint32_t> voxels;
  std::vector<float> rays;
  for (const Int3& key : keys) {
    Rays(key, &voxels, &rays);
    for (int a = 0; a < 3; ++a) w->I32(key[a]);
    w->PodVector(voxels);
    w->PodVector(rays);
  }
}

void DeferredPoints::Rays(const Int3& key, std::vector<uint32_t>* voxels,
                          std::vector<float>* rays) const {
  voxels->clear();
  rays->clear();
  auto it = submaps_.find(key);
  if (it == submaps_.end()) return;
  const Table& table = it->second;
  voxels->reserve(table.size());
  for (const auto& [voxel, ray] : table) voxels->push_back(voxel);
  std::sort(voxels->begin(), voxels->end());
  rays->reserve(6 * voxels->size());
  for (uint32_t v : *voxels) {
    const Ray& r = table.at(v);
    rays->insert(rays->end(), {r.p[0], r.p[1], r.p[2], r.o[0], r.o[1], r.o[2]});
  }
}

namespace {
std::vector<Int3> Sorted(std::vector<Int3> keys) {
  std::sort(keys.begin(), keys.end(), [](const Int3& a, const Int3& b) {
    return std::tie(a.x(), a.y(), a.z()) < std::tie(b.x(), b.y(), b.z());
  });
  return keys;
}
}  // namespace

std::vector<Int3> DeferredPoints::Changed() const {
  return Sorted(std::vector<Int3>(changed_.begin(), changed_.end()));
}

std::vector<Int3> DeferredPoints::TakeChanged() {
  std::vector<Int3> keys = Changed();
  changed_.clear();
  return keys;
}

void DeferredPoints::SetChanged(const std::vector<Int3>& keys) {
  changed_.clear();
  changed_.insert(keys.begin(), keys.end());
}

absl::Status DeferredPoints::Deserialize(ByteReader* r, float max_range_m) {
  uint64_t added, evicted, taken;
  uint32_t n_submaps;
  RIM_RETURN_IF_ERROR(r->U64(&added));
  RIM_RETURN_IF_ERROR(r->U64(&evicted));
  RIM_RETURN_IF_ERROR(r->U64(&taken));
  RIM_RETURN_IF_ERROR(r->U32(&n_submaps));
  // The same slack as the point buffer's check: the float transform of a ray at max range.
  const float max_range = max_range_m * 1.001f + 0.01f;
  absl::flat_hash_map<Int3, Table, Int3Hash, Int3Equal> submaps;
  size_t size = 0;
  for (uint32_t s = 0; s < n_submaps; ++s) {
    Int3 key;
    for (int a = 0; a < 3; ++a) RIM_RETURN_IF_ERROR(r->I32(&key[a]));
    std::vector<uint32_t> voxels;
    std::vector<float> rays;
    RIM_RETURN_IF_ERROR(r->PodVector(&voxels));
    RIM_RETURN_IF_ERROR(r->PodVector(&rays));
    if (rays.size() != 6 * voxels.size())
      return absl::DataLossError(
          absl::StrCat("deferred points: sub-map ", s, ": ray and voxel counts differ"));
    if (voxels.size() > size_t(max_per_submap_))
      return absl::DataLossError(absl::StrCat("deferred points: sub-map ", s, " holds ",
                                              voxels.size(), " rays, over the bound of ",
                                              max_per_submap_));
    if (submaps.count(key))
      return absl::DataLossError(absl::StrCat("deferred points: sub-map ", s, " is repeated"));
    Table& table = submaps[key];
    table.reserve(voxels.size());
    for (size_t i = 0; i < voxels.size(); ++i) {
      Ray ray;
      std::copy_n(&rays[6 * i], 3, ray.p);
      std::copy_n(&rays[6 * i + 3], 3, ray.o);
      const Vec3f p(ray.p[0], ray.p[1], ray.p[2]), o(ray.o[0], ray.o[1], ray.o[2]);
      Int3 at;
      uint32_t voxel;
      if (!p.allFinite() || !o.allFinite() || !((p - o).norm() <= max_range) ||
          !Locate(p, &at, &voxel) || at != key || voxel != voxels[i] ||
          !table.try_emplace(voxel, ray).second)
        return absl::DataLossError(absl::StrCat("deferred points: sub-map ", s, ", ray ", i,
                                                " is not finite, too long or misfiled"));
    }
    size += voxels.size();
  }
  submaps_ = std::move(submaps);
  changed_.clear();
  for (const auto& [key, table] : submaps_) changed_.insert(key);
  size_ = size;
  added_ = int64_t(added);
  evicted_ = int64_t(evicted);
  taken_ = int64_t(taken);
  return absl::OkStatus();
}

}  // namespace rim
