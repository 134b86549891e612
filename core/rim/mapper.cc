#include "rim/mapper.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/eval/parallel_for.h"
#include "rim/map/deferred_points.h"
#include "rim/map/distance_field.h"
#include "rim/map/local_map.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"
#include "rim/mesh/mesher.h"
#include "rim/model/decoder.h"
#include "rim/model/encoder.h"
#include "rim/train/free_space.h"
#include "rim/train/outlier_filter.h"
#include "rim/train/point_buffer.h"
#include "rim/train/sampler.h"
#include "rim/train/trainer.h"
#include "rim/train/transient.h"

namespace rim {
namespace {
double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
bool Finite(const Vec3f& v) {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}
}  // namespace

struct Mapper::OutsideRaysHolder {
  OutsideRays rays;
};

Mapper::Mapper(const MapperConfig& config) : config_(config) {
  geometry_ = std::make_unique<MapGeometry>(config.grid);
  local_map_ = std::make_unique<LocalMap>(*geometry_);
  store_ = std::make_unique<SubmapStore>(*geometry_, config.submap);
  saver_ = std::make_unique<SlabSaver>(store_.get(), config.submap.background_save);
  decoder_ = std::make_unique<Decoder>(geometry_->encoding_dim(), config.decoder);
  buffer_ = std::make_unique<PointBuffer>(config.buffer, config.sampler.seed ^ 0x5bd1e995ull);
  deferred_ = std::make_unique<DeferredPoints>(*geometry_, config.grid, config.deferred);
  trainer_ = std::make_unique<Trainer>(config, local_map_.get(), decoder_.get());
  if (config.transient.enabled) {
    transient_ = std::make_unique<TransientFilter>(config.transient);
    trainer_->SetCleared(&transient_->cleared());
  }
  outside_ = std::make_unique<OutsideRaysHolder>();
  distance_ = std::make_unique<DistanceField>(
      *geometry_, float(config.query.surfel_radius_voxels * geometry_->leaf_m()));
  // Returns lie one per deferred voxel: half that spacing spans the gaps between neighbours.
  distance_->SetReturnsBlendRadius(0.5f * config.deferred.voxel_m);
  mesh_changes_ = std::make_unique<MeshChangeLog>();
  mesh_cache_ = std::make_unique<MeshBlockCache>();
}

Mapper::~Mapper() = default;

absl::StatusOr<std::unique_ptr<Mapper>> Mapper::Create(const MapperConfig& config) {
  RIM_RETURN_IF_ERROR(config.Validate());
  return std::unique_ptr<Mapper>(new Mapper(config));
}

uint64_t Mapper::InitialHostBytes(const MapperConfig& config) {
  return uint64_t(LocalMap::MemoryBytesFor(MapGeometry(config.grid)));
}

absl::Status Mapper::ValidateScan(const PosedScan& scan) {
  const Eigen::Matrix3d R = scan.T_world_sensor.linear();
  const Eigen::Vector3d t = scan.T_world_sensor.translation();
  if (!R.allFinite() || !t.allFinite())
    return absl::InvalidArgumentError("scan.pose contains NaN or Inf");
  if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-4 || R.determinant() < 0)
    return absl::InvalidArgumentError(
        "scan.pose rotation is not orthonormal (is the quaternion unit?)");
  if (t.cwiseAbs().maxCoeff() > 1e6)
    return absl::InvalidArgumentError("scan.pose translation is beyond 1e6 m");
  if (scan.points_S.empty()) return absl::InvalidArgumentError("scan.points is empty");
  if (!scan.origins_S.empty() && scan.origins_S.size() != scan.points_S.size())
    return absl::InvalidArgumentError(absl::StrCat("scan.origins has ", scan.origins_S.size(),
                                                   " entries for ", scan.points_S.size(),
                                                   " points"));
  for (size_t i = 0; i < scan.points_S.size(); ++i) {
    if (!Finite(scan.points_S[i]))
      return absl::InvalidArgumentError(absl::StrCat("scan.points[", i, "] is not finite"));
    if (!scan.origins_S.empty() && !Finite(scan.origins_S[i]))
      return absl::InvalidArgumentError(absl::StrCat("scan.origins[", i, "] is not finite"));
  }
  return absl::OkStatus();
}

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
  if (transient_ && !per_point_origins) {
    transient_->Apply(scan.points_S, T, min_range, max_range, frames_, buffer_.get(),
                      deferred_.get(), local_map_.get(), &aux_mu_, &trainer_->pool());
    const TransientConfig& tr = config_.transient;
    transient_->cleared().Expire(frames_, tr.clear_frames, size_t(tr.max_cleared_points), lo, hi);
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
  // Outlier removal needs a decoder that already means something: not before it is frozen.
  if (config_.buffer.outlier_removal && frames_ >= config_.decoder.freeze_after_frames &&
      frames_ % config_.buffer.outlier_period_frames == 0) {
    std::lock_guard<std::mutex> aux(aux_mu_);
    RemoveOutliers(*local_map_, *decoder_, config_.buffer.outlier_threshold_m, buffer_.get());
  }
}

std::pair<int, int> Mapper::IterationBounds(int rays_per_iteration) const {
  const TrainConfig& t = config_.train;
  const int configured = config_.sampler.rays_per_iteration;
  if (rays_per_iteration <= 0 || rays_per_iteration == configured)
    return {t.min_iterations, t.iterations};
  const double k = double(configured) / double(rays_per_iteration);
  const int most = t.iterations > 0 ? std::max(1, int(std::lround(t.iterations * k))) : 0;
  const int fewest = std::min(most, int(std::lround(t.min_iterations * k)));
  return {fewest, most};
}

absl::Status Mapper::IntegrateScan(const PosedScan& scan, int iterations, StageTimings* timing,
                                   int rays_per_iteration) {
  RIM_RETURN_IF_ERROR(ValidateScan(scan));
  StageTimings t;
  const double start = Now();
  std::optional<IntBox> old_box;  // the box before this frame's slide (its leaving slabs change)
  // The whole frame, from its slide to its versions, against Save: a checkpoint holds whole
  // frames (never a frame's points in the buffer, or some of its iterations, with the frame not
  // counted), so that a restore followed by a replay of the frames after it is the live map.
  std::unique_lock<std::mutex> frame(frame_mu_);
  bool moved = false;
  {
    std::unique_lock lock(mu_);
    const double t0 = Now();
    if (local_map_->placed()) old_box = local_map_->LatticeBox(0);
    moved = SlideTo(scan.T_world_sensor.translation());
    t.slide_s = Now() - t0;
  }
  {
    // Preprocessing writes the map only by setting flag bits, atomically (MarkScan), and the
    // buffers under aux_mu_: readers (queries, meshing) go on beside it. Under load it held the
    // map alone for 20 ms a frame on average, and a planner's batch waited for it.
    std::shared_lock lock(mu_);
    const double t1 = Now();
    Preprocess(scan, moved);
    t.preprocess_s = Now() - t1;
  }
  const auto [fewest, most] = IterationBounds(rays_per_iteration);
  const int rays = rays_per_iteration > 0 ? rays_per_iteration : config_.sampler.rays_per_iteration;
  const int n_iter = iterations >= 0 ? std::clamp(iterations, fewest, most) : most;
  const bool train_decoder = frames_ < config_.decoder.freeze_after_frames;
  IterationTiming it;
  double loss_sum = 0;
  const double train_start = Now();
  RIM_RETURN_IF_ERROR(Iterate(n_iter, rays, train_decoder, nullptr, &it, &loss_sum).status());
  t.train_s = Now() - train_start;
  {
    std::unique_lock lock(mu_);
    ++frames_;
    BumpVersions(train_decoder && n_iter > 0, old_box ? &*old_box : nullptr);
    // What this frame changed, for the mesh block cache: the box's rows and flags, and the slabs
    // that left it (stored in 8-bit rows, which moves their values); everything while the decoder
    // trains.
    std::vector<IntBox> changed{local_map_->LatticeBox(0)};
    if (old_box) changed.push_back(*old_box);
    mesh_changes_->Record(changed, train_decoder && n_iter > 0);
    if (train_decoder && n_iter > 0) distance_all_stale_ = true;
    if (transient_) ClearDepartedLocked();
    RIM_RETURN_IF_ERROR(
        store_->UpdateActivity(geometry_->SubmapOfPoint(scan.T_world_sensor.translation())));
  }
  frame.unlock();  // before the refresh, which takes refresh_mu_ (the order Save keeps)
  if (refresh_in_frame_ && RefreshDueLocked(nullptr)) t.distance_s = RefreshDistanceField();
  t.sample_s = it.sample_s;
  t.encode_s = it.encode_s;
  t.forward_s = it.forward_s;
  t.backward_s = it.backward_s;
  t.step_s = it.step_s;
  t.iterations = n_iter;
  t.rays_per_iteration = rays;
  t.loss = n_iter > 0 ? float(loss_sum / n_iter) : 0.f;
  t.total_s = Now() - start;
  if (timing) *timing = t;
  return absl::OkStatus();
}

absl::StatusOr<int> Mapper::Iterate(int iterations, int rays, bool train_decoder,
                                    const std::function<bool()>* keep_going, IterationTiming* it,
                                    double* loss_sum) {
  int done = 0;
  while (done < iterations && (keep_going == nullptr || (*keep_going)())) {
    // Readers wait at most one iteration's writes (§3.5): the iteration reads the map beside them
    // and takes it alone only to write. Nothing else writes the map, so the writes find it as the
    // reads left it.
    {
      std::shared_lock lock(mu_);
      RIM_RETURN_IF_ERROR(trainer_->Prepare(*buffer_, outside_->rays, train_decoder, it, rays));
    }
    std::unique_lock lock(mu_);
    auto loss = trainer_->Apply(train_decoder, it);
    if (!loss.ok()) return loss.status();
    *loss_sum += *loss;
    map_version_.fetch_add(1);
    ++done;
  }
  return done;
}

absl::StatusOr<int> Mapper::TrainBetweenFrames(int iterations, int rays_per_iteration,
                                               const std::function<bool()>& keep_going,
                                               StageTimings* timing) {
  // Whole units against Save, as a frame is: a checkpoint holds these iterations or none of them.
  std::unique_lock<std::mutex> frame(frame_mu_);
  if (frames_ == 0 || iterations <= 0) return 0;
  const int rays = rays_per_iteration > 0 ? rays_per_iteration : config_.sampler.rays_per_iteration;
  const bool train_decoder = frames_ < config_.decoder.freeze_after_frames;
  IterationTiming it;
  const double start = Now();
  double loss_sum = 0;
  absl::StatusOr<int> trained =
      Iterate(iterations, rays, train_decoder, &keep_going, &it, &loss_sum);
  if (!trained.ok()) return trained.status();
  const int done = *trained;
  if (done > 0) {
    std::unique_lock lock(mu_);
    BumpVersions(train_decoder, nullptr);
    mesh_changes_->Record({local_map_->LatticeBox(0)}, train_decoder);
    if (train_decoder) distance_all_stale_ = true;
  }
  if (timing) {
    timing->sample_s += it.sample_s;
    timing->encode_s += it.encode_s;
    timing->forward_s += it.forward_s;
    timing->backward_s += it.backward_s;
    timing->step_s += it.step_s;
    timing->train_s += Now() - start;
    timing->total_s += Now() - start;
    timing->iterations += done;
    timing->rays_per_iteration = rays;
  }
  return done;
}

void Mapper::ClearDepartedLocked() {
  std::vector<Int3> cells = transient_->TakeOutsideCells();
  if (cells.empty()) return;
  saver_->Flush();  // the slabs that left with them are in the store
  const std::vector<Int3> keys = store_->ClearObserved(cells);
  if (keys.empty()) return;
  // One region per sub-map: the cells' bounds there, widened by one voxel (the cells that have
  // them as corners).
  std::vector<IntBox> regions;
  for (const Int3& key : keys) {
    IntBox b{Int3::Constant(INT32_MAX), Int3::Constant(INT32_MIN)};
    for (const Int3& g : cells) {
      if (geometry_->SubmapOfLattice(0, g) != key) continue;
      b.lo = b.lo.cwiseMin(g - Int3::Ones());
      b.hi = b.hi.cwiseMax(g + Int3::Ones());
    }
    regions.push_back(b);
    store_->SetVersion(key, map_version_.load());
  }
  mesh_changes_->Record(regions, false);
  distance_pending_.insert(distance_pending_.end(), regions.begin(), regions.end());
}

void Mapper::BumpVersions(bool decoder_changed, const IntBox* old_box) {
  const uint64_t v = map_version_.load();
  // The decoder is shared by every tile: while it trains, every tile changes.
  if (decoder_changed) store_->SetAllVersions(v);
  // The tiles of the box, and of the box before the slide: the slabs that left it went to the
  // store in 8-bit rows, which moves their values a little.
  auto bump = [&](const IntBox& box) {
    const Int3 lo = geometry_->SubmapOfLattice(0, box.lo);
    const Int3 hi = geometry_->SubmapOfLattice(0, box.hi - Int3::Ones());
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) store_->SetVersion(Int3(x, y, z), v);
  };
  bump(local_map_->LatticeBox(0));
  if (old_box && (old_box->lo != local_map_->LatticeBox(0).lo)) bump(*old_box);
}

namespace {
absl::Status CheckQueryPoints(const float* xyz, size_t n) {
  for (size_t i = 0; i < 3 * n; ++i)
    if (!std::isfinite(xyz[i]) || std::abs(xyz[i]) > 1e6f)
      return absl::InvalidArgumentError(
          absl::StrCat("points[", i / 3, "] is not finite or beyond 1e6 m"));
  return absl::OkStatus();
}

uint8_t ObservedCode(uint8_t bits) {
  return ((bits & LocalMap::kObserved) ? QueryResult::kObservedSurface : 0) |
         ((bits & LocalMap::kSeenFree) ? QueryResult::kObservedFree : 0);
}

// Chunks of points, so that scratch buffers stay small whatever the batch, spread over up to
// `threads` threads for large batches. Every point's answer depends on that point alone, so the
// split does not change any value. A batch over one chunk is cut into equal chunks of at most
// twice kQueryChunk, as many per thread: a planner's 10k points go as two chunks of 5k, one per
// thread, where chunks of 4096 left one thread two of them (5.9k points against 4.1k) and two
// waits for the map's lock in a row.
constexpr size_t kQueryChunk = 4096;
void ForChunks(size_t n, int threads, const std::function<void(size_t, size_t)>& fn) {
  threads = std::max(threads, 1);
  size_t block = kQueryChunk;
  if (n > kQueryChunk && threads > 1) {
    const size_t per_round = size_t(threads) * 2 * kQueryChunk;
    const size_t chunks = size_t(threads) * ((n + per_round - 1) / per_round);
    block = (n + chunks - 1) / chunks;
  }
  eval::ParallelFor(int64_t(n), int64_t(block), threads,
                    [&](int64_t b, int64_t e) { fn(size_t(b), size_t(e - b)); });
}
}  // namespace

void Mapper::EvalNeural(const float* xyz, size_t n, float* sdf, float* grad,
                        uint8_t* observed) const {
  const int F = geometry_->encoding_dim();
  const double inv_s = 1.0 / geometry_->leaf_m();
  FeatureReader reader(*local_map_, *store_);
  const size_t chunk = std::min(n, kQueryChunk);
  std::vector<float> features(chunk * F), jac(grad ? chunk * F * 3 : 0), dsdf(grad ? chunk * F : 0);
  for (size_t begin = 0; begin < n; begin += kQueryChunk) {
    const size_t m = std::min(kQueryChunk, n - begin);
    constexpr size_t kAhead = 4;  // points whose rows are on their way while one is blended
    for (size_t i = 0; i < m; ++i) {
      if (i + kAhead < m) {
        const float* ahead = xyz + 3 * (begin + i + kAhead);
        reader.Prefetch(Vec3d(ahead[0], ahead[1], ahead[2]));
      }
      const float* q = xyz + 3 * (begin + i);
      const Vec3d p(q[0], q[1], q[2]);
      reader.Encode(p, &features[i * F], grad ? &jac[i * F * 3] : nullptr);
      if (observed) {
        const Int3 g0(int(std::floor(p.x() * inv_s)), int(std::floor(p.y() * inv_s)),
                      int(std::floor(p.z() * inv_s)));
        observed[begin + i] = ObservedCode(reader.ObservedBits(g0));
      }
    }
    decoder_->Forward(features.data(), int(m), sdf + begin, grad ? dsdf.data() : nullptr);
    if (!grad) continue;
    // Chain rule: d sdf / d p = (d sdf / d features) · (d features / d p).
    for (size_t i = 0; i < m; ++i) {
      float* g = grad + 3 * (begin + i);
      g[0] = g[1] = g[2] = 0.f;
      for (int f = 0; f < F; ++f)
        for (int a = 0; a < 3; ++a) g[a] += dsdf[i * F + f] * jac[(i * F + f) * 3 + a];
    }
  }
}

absl::Status Mapper::QueryNeural(const float* xyz, size_t n, bool want_gradient,
                                 QueryResult* out) const {
  RIM_RETURN_IF_ERROR(CheckQueryPoints(xyz, n));
  std::shared_lock lock(mu_);
  // Under the lock, or a slide in between could leave slabs on their way to the store, in
  // neither the local map nor the store, and read as unobserved zeros.
  saver_->Flush();
  out->sdf.resize(n);
  out->observed.resize(n);
  out->gradient.assign(want_gradient ? 3 * n : 0, 0.f);
  out->saturated.clear();
  ForChunks(n, config_.train.threads, [&](size_t begin, size_t m) {
    EvalNeural(xyz + 3 * begin, m, &out->sdf[begin],
               want_gradient ? &out->gradient[3 * begin] : nullptr, &out->observed[begin]);
  });
  out->map_version = map_version_.load();
  return absl::OkStatus();
}

absl::Status Mapper::QuerySdf(const float* xyz, size_t n, bool want_gradient,
                              QueryResult* out) const {
  RIM_RETURN_IF_ERROR(CheckQueryPoints(xyz, n));
  out->sdf.resize(n);
  out->observed.resize(n);
  out->saturated.resize(n);
  out->gradient.assign(want_gradient ? 3 * n : 0, 0.f);
  // The version the answer starts from; a large batch may read newer ones in later chunks.
  out->map_version = map_version_.load();
  const double inv_s = 1.0 / geometry_->leaf_m();
  ForChunks(n, config_.train.threads, [&](size_t begin, size_t m) {
    // The map itself (observed flags, the network's side inside surface bands) is read under
    // the shared lock one chunk at a time, so that training waits for at most one chunk of a
    // large batch, not the whole of it; the distances then come from the field's own snapshots,
    // outside the lock.
    // The sign. The side of the nearest disk's plane is wrong past a convex edge (the disk's
    // plane runs on beyond it) and before a stray surfel. A voxel that rays crossed, away from
    // any surface band, is free space; inside a surface band the network, trained there, knows
    // the side; elsewhere (never observed) the disk decides.
    std::vector<size_t> band;
    std::vector<float> band_xyz, band_sdf;
    {
      std::shared_lock lock(mu_);
      saver_->Flush();  // under the lock, as in QueryNeural
      FeatureReader reader(*local_map_, *store_);
      for (size_t i = begin; i < begin + m; ++i) {
        const float* q = xyz + 3 * i;
        const Int3 g0(int(std::floor(q[0] * inv_s)), int(std::floor(q[1] * inv_s)),
                      int(std::floor(q[2] * inv_s)));
        out->observed[i] = ObservedCode(reader.ObservedBits(g0));
        if (out->observed[i] & QueryResult::kObservedSurface) {
          band.push_back(i);
          band_xyz.insert(band_xyz.end(), q, q + 3);
        }
      }
      band_sdf.resize(band.size());
      if (!band.empty())
        EvalNeural(band_xyz.data(), band.size(), band_sdf.data(), nullptr, nullptr);
    }
    // Returns count at observed points only: elsewhere a planner must treat the place as
    // unknown whatever it reads, and the surfels' distance there costs no more than before
    // returns were kept (half the points of a batch spread over the map lie out there).
    distance_->Query(xyz + 3 * begin, m, config_.query.max_distance_m, &out->sdf[begin],
                     want_gradient ? &out->gradient[3 * begin] : nullptr, &out->saturated[begin],
                     &out->observed[begin]);
    // The gradient turns too, except within a couple of centimetres of the surface: there the
    // two disagree because the network's zero level and the disks' planes lie millimetres apart,
    // and the gradient of a signed distance at its surface is the normal on either side.
    auto flip = [&](size_t i) {
      out->sdf[i] = -out->sdf[i];
      if (want_gradient && std::abs(out->sdf[i]) > 0.02f)
        for (int a = 0; a < 3; ++a) out->gradient[3 * i + a] = -out->gradient[3 * i + a];
    };
    for (size_t k = 0; k < band.size(); ++k)
      if ((band_sdf[k] < 0) != (out->sdf[band[k]] < 0)) flip(band[k]);
    for (size_t i = begin; i < begin + m; ++i)
      if (out->observed[i] == QueryResult::kObservedFree && out->sdf[i] < 0) flip(i);
  });
  return absl::OkStatus();
}

std::vector<Int3> Mapper::RefreshVoxels(const Int3& key, const std::vector<IntBox>& regions) const {
  const MeshTileSource src{*geometry_, *local_map_, *store_, *decoder_, mu_};
  std::vector<Int3> voxels = rim::ObservedVoxels(src, key);
  if (!regions.empty()) {
    voxels.erase(std::remove_if(voxels.begin(), voxels.end(),
                                [&](const Int3& g) {
                                  for (const IntBox& b : regions)
                                    if (b.Contains(g)) return false;
                                  return true;
                                }),
                 voxels.end());
  }
  return voxels;
}

void Mapper::ExtractSurfels(const Int3& key, const std::vector<Int3>& voxels, size_t begin,
                            size_t m, const std::vector<Surfel>* before,
                            std::vector<Surfel>* out) const {
  const double s = geometry_->leaf_m();
  // Newton steps onto the zero level, p ← p − f ∇f / |∇f|². A voxel that held a surfel starts
  // from it: the level moves millimetres between refreshes, so one step lands on it, and the
  // voxel keeps the point when that step was short. Any other voxel, and one whose step from its
  // old surfel was long, starts from its centre and takes two steps, the second from where the
  // first landed. Either way the voxel keeps the point when it lies in it (with a hair of slack)
  // and the last step was short.
  enum Stage : uint8_t { kFromSurfel, kFirst, kSecond, kDone, kDropped };
  std::vector<float> p(3 * m), f(m), g(3 * m);
  std::vector<uint8_t> stage(m, kFirst);
  std::vector<float> old_n(3 * m);
  auto centre = [&](size_t i) {
    for (int a = 0; a < 3; ++a) p[3 * i + a] = float((voxels[begin + i][a] + 0.5) * s);
  };
  for (size_t i = 0; i < m; ++i) {
    centre(i);
    if (!before) continue;
    const uint32_t index = distance_->VoxelIndex(key, voxels[begin + i]);
    auto it = std::lower_bound(before->begin(), before->end(), index,
                               [](const Surfel& x, uint32_t v) { return x.voxel < v; });
    if (it == before->end() || it->voxel != index) continue;
    for (int a = 0; a < 3; ++a) p[3 * i + a] = it->p[a];
    for (int a = 0; a < 3; ++a) old_n[3 * i + a] = it->n[a];
    stage[i] = kFromSurfel;
  }
  std::vector<size_t> live;
  std::vector<float> q, fv, gv;
  while (true) {
    live.clear();
    for (size_t i = 0; i < m; ++i)
      if (stage[i] < kDone) live.push_back(i);
    if (live.empty()) break;
    q.resize(3 * live.size());
    fv.resize(live.size());
    gv.resize(3 * live.size());
    for (size_t k = 0; k < live.size(); ++k)
      for (int a = 0; a < 3; ++a) q[3 * k + a] = p[3 * live[k] + a];
    EvalNeural(q.data(), live.size(), fv.data(), gv.data(), nullptr);
    for (size_t k = 0; k < live.size(); ++k) {
      const size_t i = live[k];
      const float* gk = &gv[3 * k];
      const float g2 = gk[0] * gk[0] + gk[1] * gk[1] + gk[2] * gk[2];
      // The Newton step's length |f| / |∇f| (the field's slope is not 1: along-ray labels
      // steepen it where rays graze a surface): a surface farther than the voxel's half
      // diagonal from its centre does not cross it.
      const float len = std::sqrt(std::max(g2, 1e-12f));
      const float step_m = std::abs(fv[k]) / len;
      bool ok = g2 > 0.01f && step_m <= (stage[i] == kFirst ? 0.9 : 0.5) * s;
      if (stage[i] == kFromSurfel) {
        // Only where the level barely moved (a quarter voxel) and did not turn (26°): a voxel
        // whose field changes more goes back to the centre's two steps, which decide again
        // whether the level crosses it. Without these bounds gradients at 0.1–2 m came out
        // worse on the dev city (BENCHMARK.md, "A cheaper distance refresh").
        const float* n = &old_n[3 * i];
        ok = ok && step_m <= 0.25 * s && (gk[0] * n[0] + gk[1] * n[1] + gk[2] * n[2]) >= 0.9f * len;
      }
      if (!ok) {
        if (stage[i] == kFromSurfel) {
          stage[i] = kFirst;
          centre(i);
        } else {
          stage[i] = kDropped;
        }
        continue;
      }
      f[i] = fv[k];
      for (int a = 0; a < 3; ++a) {
        g[3 * i + a] = gk[a];
        p[3 * i + a] -= fv[k] * gk[a] / g2;
      }
      stage[i] = stage[i] == kFirst ? kSecond : kDone;
    }
  }
  for (size_t i = 0; i < m; ++i)
    if (stage[i] == kDone) live.push_back(i);
  for (size_t i : live) {
    const Int3& v = voxels[begin + i];
    bool inside = true;
    for (int a = 0; a < 3; ++a)
      inside = inside && p[3 * i + a] >= (v[a] - 0.05) * s && p[3 * i + a] <= (v[a] + 1.05) * s;
    if (!inside) continue;
    Surfel sf;
    const float* gi = &g[3 * i];
    const float norm = std::sqrt(gi[0] * gi[0] + gi[1] * gi[1] + gi[2] * gi[2]);
    for (int a = 0; a < 3; ++a) {
      sf.p[a] = p[3 * i + a];
      sf.n[a] = gi[a] / norm;
    }
    sf.voxel = distance_->VoxelIndex(key, v);
    out->push_back(sf);
  }
}

bool Mapper::RefreshDueLocked(bool* overdue) const {
  // Every query.refresh_frames frames, and more often while the map is young and small (after
  // frames 1, 2, 4, 8, ...), so that a short session's first queries see its surfaces.
  const int64_t every = config_.query.refresh_frames;
  if (overdue) *overdue = distance_frames_ < 0 || frames_ - distance_frames_ >= 2 * every;
  return distance_frames_ < 0 ||
         frames_ - distance_frames_ >=
             std::min<int64_t>(every, std::max<int64_t>(1, distance_frames_));
}

bool Mapper::DistanceRefreshDue(bool* overdue) const {
  std::lock_guard<std::mutex> refresh(refresh_mu_);
  std::shared_lock lock(mu_);
  return RefreshDueLocked(overdue);
}

bool Mapper::DistanceFieldBehind() const {
  std::lock_guard<std::mutex> refresh(refresh_mu_);
  std::shared_lock lock(mu_);
  return distance_frames_ != frames_;
}

double Mapper::RefreshDistanceField() {
  const double start = Now();
  std::lock_guard<std::mutex> refresh(refresh_mu_);
  std::shared_lock lock(mu_);
  saver_->Flush();
  distance_frames_ = frames_;
  std::vector<Int3> keys;
  std::vector<IntBox> regions;
  std::unique_ptr<IntBox> box;
  if (local_map_->placed()) {
    // Voxels just outside the box read coarse rows on its faces, which still train.
    const IntBox b = local_map_->LatticeBox(0);
    const Int3 widen = Int3::Constant(geometry_->scale_to_coarse(0));
    box = std::make_unique<IntBox>(IntBox{b.lo - widen, b.hi + widen});
  }
  if (distance_all_stale_) {
    // Every sub-map the store knows, and those the box covers.
    for (const auto& [key, version] : store_->Versions()) keys.push_back(key);
    distance_all_stale_ = false;
  } else if (box) {
    regions.push_back(*box);
    if (distance_box_ && !(distance_box_->lo == box->lo && distance_box_->hi == box->hi))
      regions.push_back(*distance_box_);
    regions.insert(regions.end(), distance_pending_.begin(), distance_pending_.end());
  }
  distance_pending_.clear();
  for (const IntBox& r : box ? std::vector<IntBox>{*box} : std::vector<IntBox>{}) {
    const Int3 lo = geometry_->SubmapOfLattice(0, r.lo), hi = geometry_->SubmapOfLattice(0, r.hi);
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) keys.push_back(Int3(x, y, z));
  }
  for (const IntBox& r : regions) {
    const Int3 lo = geometry_->SubmapOfLattice(0, r.lo), hi = geometry_->SubmapOfLattice(0, r.hi);
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) keys.push_back(Int3(x, y, z));
  }
  std::sort(keys.begin(), keys.end(), [](const Int3& a, const Int3& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  });
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  // Extraction runs in pieces of at most kRefreshPiece voxels of one sub-map, all sub-maps' pieces
  // over the threads at once: most sub-maps of a refresh hold fewer voxels than two threads'
  // worth of pieces, and extracting them one after another left a core idle. A voxel's surfel
  // depends on that voxel alone, and Replace sorts each sub-map's surfels, so the split changes
  // nothing. The normal fits and tree builds of Replace are one thread's work per sub-map, so
  // those run side by side too (sub-maps share nothing there).
  const int threads = std::max(config_.train.threads, 1);
  std::vector<std::vector<Int3>> voxels(keys.size());
  // Where the last refresh found the zero level, by voxel: the next refresh starts there.
  std::vector<std::shared_ptr<const std::vector<Surfel>>> before(keys.size());
  eval::ParallelFor(int64_t(keys.size()), 1, threads, [&](int64_t begin, int64_t end) {
    for (int64_t k = begin; k < end; ++k) {
      voxels[size_t(k)] = RefreshVoxels(keys[size_t(k)], regions);
      before[size_t(k)] = distance_->Surfels(keys[size_t(k)]);
    }
  });
  struct Piece {
    size_t key, begin, count;
  };
  constexpr size_t kRefreshPiece = 1024;
  std::vector<Piece> pieces;
  for (size_t k = 0; k < keys.size(); ++k)
    for (size_t b = 0; b < voxels[k].size(); b += kRefreshPiece)
      pieces.push_back({k, b, std::min(kRefreshPiece, voxels[k].size() - b)});
  std::vector<std::vector<Surfel>> found(pieces.size());
  eval::ParallelFor(int64_t(pieces.size()), 1, threads, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const Piece& piece = pieces[size_t(i)];
      ExtractSurfels(keys[piece.key], voxels[piece.key], piece.begin, piece.count,
                     before[piece.key].get(), &found[size_t(i)]);
    }
  });
  std::vector<std::vector<Surfel>> fresh(keys.size());
  std::vector<size_t> counts(keys.size(), 0);
  for (size_t i = 0; i < pieces.size(); ++i) counts[pieces[i].key] += found[i].size();
  for (size_t k = 0; k < keys.size(); ++k) fresh[k].reserve(counts[k]);
  for (size_t i = 0; i < pieces.size(); ++i) {
    std::vector<Surfel>& to = fresh[pieces[i].key];
    to.insert(to.end(), found[i].begin(), found[i].end());
  }
  eval::ParallelFor(int64_t(keys.size()), 1, std::max(config_.train.threads, 1),
                    [&](int64_t begin, int64_t end) {
                      for (int64_t k = begin; k < end; ++k)
                        distance_->Replace(keys[size_t(k)], regions, std::move(fresh[size_t(k)]));
                    });
  if (box) distance_box_ = std::move(box);
  RefreshReturns();
  return Now() - start;
}

void Mapper::RefreshReturns() {
  std::lock_guard<std::mutex> aux(aux_mu_);
  const std::vector<Int3> keys = deferred_->TakeChanged();
  if (keys.empty()) return;
  const double inv_s = 1.0 / geometry_->leaf_m();
  std::vector<std::vector<Surfel>> built(keys.size());
  eval::ParallelFor(
      int64_t(keys.size()), 1, std::max(config_.train.threads, 1), [&](int64_t begin, int64_t end) {
        FeatureReader reader(*local_map_, *store_);
        std::vector<uint32_t> voxels;
        std::vector<float> rays;
        for (int64_t k = begin; k < end; ++k) {
          deferred_->Rays(keys[size_t(k)], &voxels, &rays);
          std::vector<Surfel>& out = built[size_t(k)];
          out.reserve(voxels.size());
          for (size_t i = 0; i < voxels.size(); ++i) {
            const float* p = &rays[6 * i];
            const Int3 g0(int(std::floor(p[0] * inv_s)), int(std::floor(p[1] * inv_s)),
                          int(std::floor(p[2] * inv_s)));
            // Where training put surface samples, the network's zero level holds the surface.
            if (reader.ObservedBits(g0) & LocalMap::kObserved) continue;
            Surfel s;
            float n2 = 0;
            for (int a = 0; a < 3; ++a) {
              s.p[a] = p[a];
              s.n[a] = p[3 + a] - p[a];
              n2 += s.n[a] * s.n[a];
            }
            if (!(n2 > 1e-12f)) continue;
            const float inv = 1.f / std::sqrt(n2);
            for (float& c : s.n) c *= inv;
            s.voxel = voxels[i];
            out.push_back(s);
          }
        }
      });
  for (size_t k = 0; k < keys.size(); ++k) distance_->ReplaceReturns(keys[k], std::move(built[k]));
}

std::vector<TileInfo> Mapper::ListTiles(uint64_t since_version) const {
  std::vector<TileInfo> out;
  for (const auto& [key, version] : store_->Versions()) {
    if (version <= since_version) continue;
    TileInfo t;
    t.key = key;
    t.version = version;
    t.min_m = geometry_->SubmapMin(key);
    t.max_m = t.min_m + geometry_->extent_m();
    out.push_back(t);
  }
  return out;
}

absl::StatusOr<Mesh> Mapper::ExtractMeshTile(const Int3& key) const {
  saver_->Flush();
  MeshTileSource src{*geometry_, *local_map_, *store_, *decoder_, mu_};
  return ExtractTile(src, config_.mesh.resolution_m, key);
}

absl::StatusOr<Mesh> Mapper::MeshTile(const Int3& key, MeshUpdateStats* stats) const {
  saver_->Flush();
  bool keep = false;
  {
    // Blocks are kept for the tiles that the box can still change: within a block and a coarse
    // voxel of it.
    std::shared_lock lock(mu_);
    if (local_map_->placed()) {
      const Int3 cells = geometry_->cells(0);
      const int margin = kMeshBlockVoxels + (1 << (geometry_->levels() - 1)) + 1;
      const IntBox box = local_map_->LatticeBox(0);
      const Int3 lo = key.cwiseProduct(cells) - Int3::Constant(margin);
      const Int3 hi = key.cwiseProduct(cells) + cells + Int3::Constant(margin);
      keep = (lo.array() <= box.hi.array()).all() && (box.lo.array() <= hi.array()).all();
    }
  }
  MeshTileSource src{*geometry_, *local_map_, *store_, *decoder_, mu_};
  return mesh_cache_->Update(src, config_.mesh.resolution_m, key, *mesh_changes_, keep, stats);
}

std::vector<Int3> Mapper::ObservedVoxels(const Int3& key) const {
  std::shared_lock lock(mu_);
  saver_->Flush();  // under the lock, as in QuerySdf
  return rim::ObservedVoxels(MeshTileSource{*geometry_, *local_map_, *store_, *decoder_, mu_}, key);
}

MapperStats Mapper::Stats() const {
  std::shared_lock lock(mu_);
  MapperStats s;
  s.frames = frames_;
  s.map_version = map_version_.load();
  DeferredStats deferred;
  {
    std::lock_guard<std::mutex> aux(aux_mu_);
    s.buffer_points = int64_t(buffer_->size());
    deferred = deferred_->Stats();
    if (transient_) {
      const TransientStats tr = transient_->Stats();
      s.transient_buffer_removed = tr.buffer_removed;
      s.transient_deferred_removed = tr.deferred_removed;
      s.transient_departed_removed = tr.departed_removed;
    }
  }
  s.deferred_points = deferred.points;
  s.deferred_bytes = deferred.bytes;
  s.local_map_bytes = local_map_->MemoryBytes();
  const DistanceFieldStats distance = distance_->Stats();
  s.distance_surfels = distance.surfels;
  s.distance_returns = distance.returns;
  s.distance_bytes = distance.bytes;
  s.mesh_cache_bytes = mesh_cache_->MemoryBytes();
  const SubmapStoreStats st = store_->Stats();
  s.submap_bytes = st.host_bytes;
  s.submaps_active = st.active;
  s.submaps_frozen = st.frozen;
  s.submaps_on_disk = st.on_disk;
  s.decoder_frozen = frames_ >= config_.decoder.freeze_after_frames;
  return s;
}

}  // namespace rim
