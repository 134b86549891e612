// The historical point buffer (§3.4 step 2, "bundle supervision"): endpoints of past rays that
// lie in the local box, with the sensor origin each was seen from. Training samples rays from it.
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "rim/base/binary_io.h"
#include "rim/base/types.h"
#include "rim/config/config.h"

namespace rim {

class PointBuffer {
 public:
  PointBuffer(const BufferConfig& config, uint64_t seed);

  // Adds a frame's inside points (world frame), keeping at most max_points_per_frame of them
  // (uniform random subset), then drops random older points while over max_points. The points
  // kept start the newest frame's (newest()).
  void AddFrame(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W);
  // Adds rays as they are (no per-frame subset) to the newest frame's, then drops random older
  // points while over max_points: deferred rays that the box has just reached
  // (map/deferred_points.h).
  void AddPoints(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W);
  // Drops points whose endpoint left the box [min, max).
  void RemoveOutside(const Vec3d& min_m, const Vec3d& max_m);
  // Drops points where keep[i] is false.
  void Filter(const std::vector<bool>& keep);
  // Drops the points at these indices (increasing, each once, all below size()).
  void Remove(const std::vector<uint32_t>& drop);

  size_t size() const { return points_.size(); }
  // The points the newest frame added are the last newest() of points(): every removal keeps the
  // order, and dropping for the bound never picks them. Not saved: the next frame sets it.
  size_t newest() const { return newest_; }
  const std::vector<Vec3f>& points() const { return points_; }
  const std::vector<Vec3f>& origins() const { return origins_; }
  // Per point, a count the moving-things filter keeps (TransientFilter's busy places: frames in
  // which later rays passed it since one last found something there). It moves with its point;
  // new points start at 0. Not saved: a loaded buffer starts every count at 0, as the filter's
  // other state starts over.
  std::vector<uint8_t>& passes() { return passes_; }
  const std::vector<uint8_t>& passes() const { return passes_; }

  void Serialize(ByteWriter* w) const;
  absl::Status Deserialize(ByteReader* r);

 private:
  void TrimToBound();

  BufferConfig config_;
  std::mt19937_64 rng_;
  std::vector<Vec3f> points_;
  std::vector<Vec3f> origins_;
  std::vector<uint8_t> passes_;
  size_t newest_ = 0;
};

}  // namespace rim
