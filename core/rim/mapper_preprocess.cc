// Mapper: a frame's preprocessing, before its training iterations: the box slides to the sensor
// (SlideTo), and the scan's rays split at the box into the point buffer and the deferred rays,
// with the reached deferred rays, the moving things (transient.h), free-space marks and outliers
// (Preprocess).
#include <mutex>
#include <vector>

#include "rim/map/deferred_points.h"
#include "rim/map/local_map.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"
#include "rim/mapper.h"
#include "rim/mapper_internal.h"
#include "rim/train/free_space.h"
#include "rim/train/outlier_filter.h"
#include "rim/train/point_buffer.h"
#include "rim/train/trainer.h"
#include "rim/train/transient.h"

namespace rim {

bool Mapper::SlideTo(const Vec3d& position_W) {
  if (local_map_->placed() && !config_.grid.sliding) return false;
  const Int3 origin = geometry_->BoxOriginFor(position_W);
  if (local_map_->placed() && origin == local_map_->coarse_origin()) return false;
  // Leaving slabs go to the saver thread; before reading entering slabs from the store, wait for
  // earlier writes so that a slab that left and comes back is read as it was saved.
  saver_->Flush();
  SubmapStore::CachedReader reader(*store_);  // entering voxels come in runs along z
  local_map_->MoveToLoadingRuns(
      origin, [this](SlabBatch&& b) { saver_->Submit(std::move(b)); },
      [&reader](int l, const Int3& g, int n, float* f, uint8_t* flags) {
        reader.ReadRun(l, g, n, f, flags);
      });
  return true;
}

void Mapper::Preprocess(const PosedScan& scan, bool box_moved) {
  const Eigen::Isometry3f T = scan.T_world_sensor.cast<float>();
  const Vec3f sensor_W = T.translation();
  const Vec3d lo = local_map_->min_m(), hi = local_map_->max_m();
  std::vector<Vec3f> inside_p, inside_o;
  inside_p.reserve(scan.points_S.size());
  inside_o.reserve(scan.points_S.size());
  OutsideRays& outside = outside_->rays;
  outside.points_W.clear();
  outside.origins_W.clear();
  const bool per_point_origins = !scan.origins_S.empty();
  const float min_range = config_.buffer.min_range_m, max_range = config_.buffer.max_range_m;
  for (size_t i = 0; i < scan.points_S.size(); ++i) {
    const Vec3f o_S = per_point_origins ? scan.origins_S[i] : Vec3f::Zero();
    const float range = (scan.points_S[i] - o_S).norm();
    if (range < min_range || range > max_range) continue;
    const Vec3f p_W = T * scan.points_S[i];
    const Vec3f o_W = per_point_origins ? Vec3f(T * o_S) : sensor_W;
    // LocalMap::Contains with the box bounds computed once per scan.
    const Vec3d q = p_W.cast<double>();
    if ((q.array() >= lo.array()).all() && (q.array() < hi.array()).all()) {
      inside_p.push_back(p_W);
      inside_o.push_back(o_W);
    } else {
      outside.points_W.push_back(p_W);
      outside.origins_W.push_back(o_W);
    }
  }
  // Moving things: returns that this scan's rays pass clearly through have gone (transient.h).
  // Judged before the scan joins the buffer, and only for scans from one sensor origin.
  preprocess_transient_s_ = 0;
  if (transient_ && !per_point_origins) {
    const double t0 = mapper_internal::Now();
    transient_->Apply(scan.points_S, T, min_range, max_range, frames_, buffer_.get(),
                      deferred_.get(), local_map_.get(), &aux_mu_, &trainer_->pool());
    const TransientConfig& tr = config_.transient;
    transient_->cleared().Expire(frames_, tr.clear_frames, size_t(tr.max_cleared_points), lo, hi);
    preprocess_transient_s_ = mapper_internal::Now() - t0;
  }
  // Deferred rays that the box has just reached join the buffer as they are, and are marked like
  // the scan's inside rays (their endpoints observed, their part inside the box seen free).
  std::vector<Vec3f> reached_p, reached_o;
  if (box_moved) {
    std::lock_guard<std::mutex> aux(aux_mu_);
    deferred_->TakeInside(lo, hi, &reached_p, &reached_o);
  }
  const std::vector<Vec3f>* mark_p = &inside_p;
  const std::vector<Vec3f>* mark_o = &inside_o;
  std::vector<Vec3f> all_p, all_o;
  if (!reached_p.empty()) {
    all_p = inside_p;
    all_o = inside_o;
    all_p.insert(all_p.end(), reached_p.begin(), reached_p.end());
    all_o.insert(all_o.end(), reached_o.begin(), reached_o.end());
    mark_p = &all_p;
    mark_o = &all_o;
  }
  // On the training threads, idle until the first iteration. Rays ending outside the box crossed
  // it as free space up to the box face. The point buffer and the deferred store are updated as
  // one more task of the same pass: marking touches neither.
  MarkScan(*mark_p, *mark_o, outside.points_W, outside.origins_W, config_.sampler.observed_band_m,
           config_.sampler.free_space_rays, config_.sampler.free_space_rays / 4, local_map_.get(),
           &trainer_->pool(), [&] {
             std::lock_guard<std::mutex> aux(aux_mu_);
             buffer_->AddFrame(inside_p, inside_o);
             buffer_->AddPoints(reached_p, reached_o);
             buffer_->RemoveOutside(lo, hi);
             deferred_->Add(outside.points_W, outside.origins_W, sensor_W);
           });
  // Moving things, on earlier evidence: the newly buffered returns where an earlier scan's rays
  // passed clearly have moved in since, and go before they train.
  if (transient_ && !per_point_origins) {
    const double t0 = mapper_internal::Now();
    transient_->JudgeNewest(frames_, buffer_.get(), local_map_.get(), &aux_mu_, &trainer_->pool());
    preprocess_transient_s_ += mapper_internal::Now() - t0;
  }
  // Outlier removal needs a decoder that already means something: not before it is frozen.
  if (config_.buffer.outlier_removal && frames_ >= config_.decoder.freeze_after_frames &&
      frames_ % config_.buffer.outlier_period_frames == 0) {
    std::lock_guard<std::mutex> aux(aux_mu_);
    RemoveOutliers(*local_map_, *decoder_, config_.buffer.outlier_threshold_m, buffer_.get());
  }
}

}  // namespace rim
