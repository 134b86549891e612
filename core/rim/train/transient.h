// Moving things leave no trace (docs/core.md, "Moving things"): a return that a later scan's rays
// clearly pass is evidence that what stood there (a person, a passing car) has gone. Such returns
// are dropped from the point buffer and from the deferred rays, and for a few frames free-space
// samples where they stood clear the network, so the mesh, the distance field and the observed
// surface forget them.
//
// The rule, judged per point p against the later scan's range image (nearest return per bin of
// direction, in the sensor frame), over a window of bins around p's direction:
//  - the window holds returns on both sides of p in azimuth and in elevation (p is surrounded by
//    rays, not at the edge of what the sensor sees), and
//  - every return in the window ends at least margin_m + margin_per_m · range beyond p.
// A static surface that the scan sees is never eroded: along a continuous surface the range
// changes monotonically, so of two rays on opposite sides of p one ends nearer than p (a wall or
// the ground at a grazing angle, whose far side lies beyond p, has its near side in front of it).
// A surface hidden behind something nearer keeps its points (the nearer returns are in front). A
// thin pole keeps its points as long as the beams that hit it fall in the window: any return
// near p's range vetoes. A surface seen once from afar and never again in the window's reach
// (above the sensor's field of view, or no returns around it) is not judged. Empty bins (no
// return: sky, absorbing or specular surfaces) are no evidence of free space.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <mutex>
#include <vector>

#include "rim/base/types.h"
#include "rim/base/worker_pool.h"
#include "rim/config/config.h"
#include "rim/map/deferred_points.h"
#include "rim/train/point_buffer.h"
#include "rim/train/sampler.h"

namespace rim {

// The nearest return per bin of direction (azimuth, elevation) of one scan, in the sensor frame.
class RangeImage {
 public:
  explicit RangeImage(float bin_deg);

  // Bins the points (sensor frame) whose range lies in [min_range_m, max_range_m].
  void Fill(const std::vector<Vec3f>& points_S, float min_range_m, float max_range_m);

  int azimuth_bins() const { return na_; }
  int elevation_bins() const { return ne_; }
  // The bin of a direction (need not be unit; not zero).
  void BinOf(const Vec3f& d_S, int* azimuth, int* elevation) const;
  // The nearest range in bin (azimuth, elevation), +inf when it holds no return. Azimuth wraps;
  // elevation must be in [0, elevation_bins()).
  float At(int azimuth, int elevation) const {
    azimuth %= na_;
    if (azimuth < 0) azimuth += na_;
    return range_[size_t(elevation) * na_ + azimuth];
  }

 private:
  float inv_bin_rad_;
  int na_, ne_;
  std::vector<float> range_;
};

// The rule above for a point p_S (sensor frame) at range r = |p_S| in [min_range_m, max_range_m]
// (false outside it).
bool SeenThrough(const RangeImage& image, const TransientConfig& config, const Vec3f& p_S);

// Where dropped returns stood, for a few frames: free-space samples there clear the network.
class ClearedPoints {
 public:
  // p_W, seen along dir_W (unit, from the sensor that saw it), dropped at `frame`.
  void Add(const Vec3f& p_W, const Vec3f& dir_W, int64_t frame);
  // Forgets points dropped before frame − lifetime_frames, or outside the box [lo, hi), and the
  // oldest beyond max_points.
  void Expire(int64_t frame, int lifetime_frames, size_t max_points, const Vec3d& lo,
              const Vec3d& hi);
  size_t size() const { return points_.size(); }
  // Appends n samples at p + u·dir (u uniform in [−band_m, band_m], p a uniformly drawn point)
  // with label `label_m` (free space), dropping those outside the box [lo, hi).
  void Sample(int n, float band_m, float label_m, const Vec3f& lo, const Vec3f& hi, FastRng* rng,
              SampleBatch* out) const;
  void Clear();

 private:
  std::vector<Vec3f> points_, dirs_;
  std::vector<int64_t> frames_;  // non-decreasing
};

struct TransientStats {
  int64_t buffer_removed = 0;    // buffered returns dropped since creation
  int64_t deferred_removed = 0;  // deferred rays dropped since creation
  int64_t judged = 0;            // points judged since creation
};

class TransientFilter {
 public:
  explicit TransientFilter(const TransientConfig& config);

  // Judges against the scan (points in the sensor frame, the sensor's pose) one in period_frames
  // of the buffer's points and of the deferred rays within max_range_m of the sensor (which ones
  // turns with `frame`), and drops those seen through. Dropped buffer points join the cleared
  // points. `aux_mu` is held while the buffer and the deferred store change (readers of their
  // sizes take it); judging the buffer reads it without the lock, so nothing else may write it
  // meanwhile. With a pool, the buffer's points are judged on its threads.
  void Apply(const std::vector<Vec3f>& points_S, const Eigen::Isometry3f& T_world_sensor,
             float scan_min_range_m, float scan_max_range_m, int64_t frame, PointBuffer* buffer,
             DeferredPoints* deferred, std::mutex* aux_mu, WorkerPool* pool);

  const ClearedPoints& cleared() const { return cleared_; }
  ClearedPoints& cleared() { return cleared_; }
  // Read under the `aux_mu` that Apply takes.
  TransientStats Stats() const { return stats_; }
  const RangeImage& image() const { return image_; }

 private:
  TransientConfig config_;
  RangeImage image_;
  ClearedPoints cleared_;
  TransientStats stats_;
  std::vector<uint8_t> drop_;
};

}  // namespace rim
