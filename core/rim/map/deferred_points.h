// Deferred supervision: returns seen outside the local box, kept until the box covers them.
//
// A LiDAR sees the upper facades along a street from tens of metres back, at grazing angles, while
// they are still outside the local box; by the time the box reaches them the sensor no longer
// sees them. Dropping such returns leaves those surfaces out of the map for good. The store keeps
// them instead, with the sensor origin each was seen from, voxel-downsampled and bounded per
// sub-map, and gives them back when the box slides over them; the mapper then adds them to the
// historical point buffer like the current scan's inside points.
//
// Rules (docs/core.md, "Deferred supervision"):
//  - one ray per deferred voxel (`deferred.voxel_m`) of the sub-map that owns its endpoint; a
//    later ray into the same voxel replaces the kept one if its range is shorter (a closer look
//    is more accurate and less grazing);
//  - endpoints more than one box height above or below the box's vertical band (about the sensor
//    when seen) are not kept: a ground robot's box does not get there;
//  - at most `deferred.max_points_per_submap` rays per sub-map: past it, the rays seen from the
//    longest ranges are dropped first, down to 7/8 of the bound;
//  - the store never holds a ray whose endpoint is inside the current box: Add skips them (they
//    are the scan's inside points) and TakeInside moves them out after every slide.
// Deterministic: what TakeInside returns and what Serialize writes are sorted, whatever the
// hash tables' iteration order.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "rim/base/binary_io.h"
#include "rim/base/types.h"
#include "rim/config/config.h"
#include "rim/map/map_geometry.h"

namespace rim {

struct DeferredStats {
  int64_t points = 0;   // rays held
  int64_t bytes = 0;    // host memory of the tables, estimated from their capacity
  int submaps = 0;      // sub-maps holding at least one
  int64_t added = 0;    // rays kept since creation (new voxels and replacements)
  int64_t evicted = 0;  // rays dropped by the per-sub-map bound since creation
  int64_t taken = 0;    // rays given back to training since creation
};

class DeferredPoints {
 public:
  DeferredPoints(const MapGeometry& geometry, const GridConfig& grid, const DeferredConfig& config);

  // Keeps the rays origins_W[i] -> points_W[i] (world frame; endpoints outside the box) of a
  // scan taken from sensor_W, by the rules above.
  void Add(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W,
           const Vec3f& sensor_W);

  // Moves every kept ray whose endpoint lies in [min_m, max_m) out of the store, appending them
  // to points/origins in (sub-map, voxel) order.
  void TakeInside(const Vec3d& min_m, const Vec3d& max_m, std::vector<Vec3f>* points_W,
                  std::vector<Vec3f>* origins_W);

  // Drops the rays whose endpoint lies within radius_m of center_W and that `judge` marks,
  // looking only at the sub-maps (x, y, z) with (x + y + z) mod period == phase (period >= 1; a
  // walk through a table costs more than judging its rays, so a frame walks only some). `judge`
  // gets those rays' endpoints at once (it may judge them in parallel) and sets drop[i] for each
  // to go. Returns how many were dropped; their sub-maps count as changed. Moving things,
  // train/transient.h.
  using BatchJudge =
      std::function<void(const std::vector<Vec3f>& endpoints, std::vector<uint8_t>* drop)>;
  int64_t RemoveIf(const Vec3f& center_W, float radius_m, int period, int phase,
                   const BatchJudge& judge);

  size_t size() const { return size_; }
  DeferredStats Stats() const;

  // The rays of sub-map `key` (keys as Locate files them: floor(endpoint / sub-map extent)),
  // sorted by voxel: voxels[i] and rays[6i..6i+5] = endpoint xyz, origin xyz.
  void Rays(const Int3& key, std::vector<uint32_t>* voxels, std::vector<float>* rays) const;
  // Sub-maps whose rays changed (added, replaced, evicted or taken) since the last TakeChanged,
  // sorted; the distance field rebuilds its returns there (docs/core.md, "Metric distances").
  std::vector<Int3> TakeChanged();
  std::vector<Int3> Changed() const;
  // Sets which sub-maps count as changed (a restored distance field's pending ones). A store
  // that Deserialize fills counts every sub-map it holds as changed.
  void SetChanged(const std::vector<Int3>& keys);

  // The rays and the counters. Deserialize checks every ray (finite, no longer than
  // `max_range_m`, in the sub-map and voxel it is filed under) and replaces the contents only
  // when all of it is valid.
  void Serialize(ByteWriter* w) const;
  absl::Status Deserialize(ByteReader* r, float max_range_m);

 private:
  struct Ray {
    float p[3];
    float o[3];
    float range2() const {
      const float dx = p[0] - o[0], dy = p[1] - o[1], dz = p[2] - o[2];
      return dx * dx + dy * dy + dz * dz;
    }
  };
  using Table = absl::flat_hash_map<uint32_t, Ray>;

  // Sub-map of a point and the voxel's index inside it; false if the point is out of range.
  bool Locate(const Vec3f& p, Int3* key, uint32_t* voxel) const;
  void Evict(Table* table);

  Vec3d extent_m_;
  Int3 dims_;  // deferred voxels per sub-map and axis
  double voxel_m_;
  float band_lo_m_, band_hi_m_;  // kept heights relative to the sensor
  int max_per_submap_;
  bool enabled_;
  absl::flat_hash_map<Int3, Table, Int3Hash, Int3Equal> submaps_;
  absl::flat_hash_set<Int3, Int3Hash, Int3Equal> changed_;
  size_t size_ = 0;
  int64_t added_ = 0, evicted_ = 0, taken_ = 0;
};

}  // namespace rim
