// The metric distance field behind queries (docs/core.md, "Metric distances"): the signed
// Euclidean distance to the nearest mapped surface, up to a bound.
//
// The mapped surface is the neural field's zero level. It is sampled once per observed finest
// voxel that it crosses, as a surfel: a point of the zero level (found by Newton steps from the
// voxel's centre) and the unit normal there (the field's gradient). A surfel stands for a disk of
// radius `surfel_radius_m` in its tangent plane; the disks of neighbouring voxels overlap, so on
// a plane the distance to the nearest disk is the distance to the plane, except in the small gaps
// the disks leave at voxel corners, where a point reads the plane (see Query). The distance of a
// point is the smallest distance to a disk, found exactly with a k-d tree per sub-map (nanoflann);
// its sign is the side of that disk's plane, and its gradient is the unit vector from the disk's
// nearest point. Farther than the bound, a point reads the bound and is flagged saturated.
//
// Surfels are kept per sub-map and replaced region by region as the map trains. Readers and the
// writer may run at once: a query reads immutable per-sub-map snapshots.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <shared_mutex>
#include <vector>

#include "absl/status/status.h"
#include "rim/base/binary_io.h"
#include "rim/base/types.h"
#include "rim/map/map_geometry.h"

namespace rim {

struct Surfel {
  float p[3];      // a point of the zero level, world frame, metres
  float n[3];      // unit normal, toward positive distances (free space)
  uint32_t voxel;  // the finest voxel it samples, as an index within its sub-map
};

struct DistanceFieldStats {
  int64_t surfels = 0;
  int64_t returns = 0;  // deferred returns standing in for surface the network has not learnt
  int64_t bytes = 0;    // surfels and their k-d trees
  int submaps = 0;
};

class DistanceField {
 public:
  DistanceField(const MapGeometry& geometry, float surfel_radius_m);
  ~DistanceField();

  float surfel_radius_m() const { return radius_; }

  // Index of finest voxel g (minimum-corner lattice index) within sub-map `key`, and back.
  uint32_t VoxelIndex(const Int3& key, const Int3& g) const;
  Int3 VoxelOf(const Int3& key, uint32_t index) const;

  // In sub-map `key`, drops the surfels whose voxel lies in one of `regions` (level-0 lattice
  // boxes; empty: all of them) and adds `fresh`, whose voxels must lie there too.
  void Replace(const Int3& key, const std::vector<IntBox>& regions, std::vector<Surfel> fresh);
  void Clear();

  // Surface the network has not learnt: returns seen outside every box so far (the deferred
  // store's rays, deferred_points.h), such as a facade beside the street that no box reached.
  // Each is a point (a disk of radius 0) whose `n` points toward the sensor that saw it; its
  // gradient blends like a disk of `returns_blend_radius_m`. Replaces sub-map `key`'s previous
  // returns (keys as the deferred store files them); `returns` must be sorted by `voxel`.
  void ReplaceReturns(const Int3& key, std::vector<Surfel> returns);
  void SetReturnsBlendRadius(float radius_m) { returns_blend_ = radius_m; }

  // The surfels of sub-map `key` as they stand, sorted by voxel index (null when it has none);
  // immutable, so a caller may read them while the field is replaced.
  std::shared_ptr<const std::vector<Surfel>> Surfels(const Int3& key) const;

  // Signed distance at n points (xyz, world frame), bounded by max_distance_m > 0.
  // - sdf[i]: the distance, positive on the normal's side; ±max_distance_m is never exceeded.
  // - gradient (3 per point, may be null): unit vector from the nearest disk point, with the
  //   sign's orientation; zero when saturated.
  // - saturated[i] (may be null): 1 when no surface lies within max_distance_m; sdf is then
  //   +max_distance_m.
  // - with_returns (may be null: every point): 0 for a point that reads the surfels alone.
  void Query(const float* xyz, size_t n, float max_distance_m, float* sdf, float* gradient,
             uint8_t* saturated, const uint8_t* with_returns = nullptr) const;

  DistanceFieldStats Stats() const;

  // Byte-exact persistence of every sub-map's surfels; a loaded field re-indexes them.
  void Serialize(ByteWriter* w) const;
  // Refuses (DATA_LOSS-worthy message, field unchanged) counts, voxels or values that do not fit.
  absl::Status Deserialize(ByteReader* r);
  // The returns, likewise (a section of their own, which older files lack).
  void SerializeReturns(ByteWriter* w) const;
  absl::Status DeserializeReturns(ByteReader* r);

 private:
  struct Part;
  using PartPtr = std::shared_ptr<const Part>;
  struct KeyLess {
    bool operator()(const Int3& a, const Int3& b) const {
      return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
    }
  };
  static PartPtr MakePart(std::vector<Surfel> surfels, float radius, float blend_radius);
  // Writes a count, then each part's key and surfels (the caller holds mu_).
  static void WriteParts(const std::map<Int3, PartPtr, KeyLess>& parts, ByteWriter* w);
  // Set in a surfel's voxel index until its normal is fitted (indices stay below 2^31).
  static constexpr uint32_t kFresh = 0x80000000u;
  // Refits the normals of the marked surfels of a sorted sub-map, and clears the marks.
  void FitNormals(const Int3& key, std::vector<Surfel>* surfels) const;

  const MapGeometry& geometry_;
  const float radius_;
  float returns_blend_ = 0.f;
  mutable std::shared_mutex mu_;  // guards parts_ and returns_ (the maps, not the parts)
  std::map<Int3, PartPtr, KeyLess> parts_;
  std::map<Int3, PartPtr, KeyLess> returns_;
};

}  // namespace rim
