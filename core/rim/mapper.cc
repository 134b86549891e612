#include "rim/mapper.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/map/deferred_points.h"
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
  outside_ = std::make_unique<OutsideRaysHolder>();
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
  // Deferred rays that the box has just reached join the buffer as they are, and are marked like
  // the scan's inside rays (their endpoints observed, their part inside the box seen free).
  std::vector<Vec3f> reached_p, reached_o;
  if (box_moved) deferred_->TakeInside(lo, hi, &reached_p, &reached_o);
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
             buffer_->AddFrame(inside_p, inside_o);
             buffer_->AddPoints(reached_p, reached_o);
             buffer_->RemoveOutside(lo, hi);
             deferred_->Add(outside.points_W, outside.origins_W, sensor_W);
           });
  // Outlier removal needs a decoder that already means something: not before it is frozen.
  if (config_.buffer.outlier_removal && frames_ >= config_.decoder.freeze_after_frames &&
      frames_ % config_.buffer.outlier_period_frames == 0) {
    RemoveOutliers(*local_map_, *decoder_, config_.buffer.outlier_threshold_m, buffer_.get());
  }
}

absl::Status Mapper::IntegrateScan(const PosedScan& scan, int iterations, StageTimings* timing) {
  RIM_RETURN_IF_ERROR(ValidateScan(scan));
  StageTimings t;
  const double start = Now();
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    const double t0 = Now();
    const bool moved = SlideTo(scan.T_world_sensor.translation());
    const double t1 = Now();
    Preprocess(scan, moved);
    t.slide_s = t1 - t0;
    t.preprocess_s = Now() - t1;
  }
  int n_iter = config_.train.iterations;
  if (iterations >= 0) n_iter = std::clamp(iterations, config_.train.min_iterations, n_iter);
  const bool train_decoder = frames_ < config_.decoder.freeze_after_frames;
  IterationTiming it;
  double loss_sum = 0;
  for (int i = 0; i < n_iter; ++i) {
    // One exclusive section per iteration: readers wait at most one iteration (§3.5).
    std::unique_lock<std::shared_mutex> lock(mu_);
    auto loss = trainer_->Iterate(*buffer_, outside_->rays, train_decoder, &it);
    if (!loss.ok()) return loss.status();
    loss_sum += *loss;
    map_version_.fetch_add(1);
  }
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    ++frames_;
    BumpVersions(train_decoder && n_iter > 0);
    RIM_RETURN_IF_ERROR(
        store_->UpdateActivity(geometry_->SubmapOfPoint(scan.T_world_sensor.translation())));
  }
  t.sample_s = it.sample_s;
  t.encode_s = it.encode_s;
  t.forward_s = it.forward_s;
  t.backward_s = it.backward_s;
  t.step_s = it.step_s;
  t.iterations = n_iter;
  t.loss = n_iter > 0 ? float(loss_sum / n_iter) : 0.f;
  t.total_s = Now() - start;
  if (timing) *timing = t;
  return absl::OkStatus();
}

void Mapper::BumpVersions(bool decoder_changed) {
  const uint64_t v = map_version_.load();
  // The decoder is shared by every tile: while it trains, every tile changes.
  if (decoder_changed) store_->SetAllVersions(v);
  const IntBox box = local_map_->LatticeBox(0);
  const Int3 lo = geometry_->SubmapOfLattice(0, box.lo);
  const Int3 hi = geometry_->SubmapOfLattice(0, box.hi - Int3::Ones());
  for (int x = lo.x(); x <= hi.x(); ++x)
    for (int y = lo.y(); y <= hi.y(); ++y)
      for (int z = lo.z(); z <= hi.z(); ++z) store_->SetVersion(Int3(x, y, z), v);
}

absl::Status Mapper::QuerySdf(const float* xyz, size_t n, bool want_gradient,
                              QueryResult* out) const {
  for (size_t i = 0; i < 3 * n; ++i)
    if (!std::isfinite(xyz[i]) || std::abs(xyz[i]) > 1e6f)
      return absl::InvalidArgumentError(
          absl::StrCat("points[", i / 3, "] is not finite or beyond 1e6 m"));
  std::shared_lock<std::shared_mutex> lock(mu_);
  // Under the lock, or a slide in between could leave slabs on their way to the store, in
  // neither the local map nor the store, and read as unobserved zeros.
  saver_->Flush();
  const int F = geometry_->encoding_dim();
  out->sdf.resize(n);
  out->observed.resize(n);
  out->gradient.assign(want_gradient ? 3 * n : 0, 0.f);
  // Chunks of points, so that the scratch buffers stay small whatever the batch, spread over up
  // to train.threads threads for large batches. Every point's answer depends on that point
  // alone (the plain decoder is batch-independent), so the split does not change any value.
  constexpr size_t kChunk = 4096;
  const size_t chunks = (n + kChunk - 1) / kChunk;
  const double inv_s = 1.0 / geometry_->leaf_m();
  auto run = [&](size_t first, size_t stride) {
    FeatureReader reader(*local_map_, *store_);
    std::vector<float> features(kChunk * F), jac(want_gradient ? kChunk * F * 3 : 0),
        dsdf(want_gradient ? kChunk * F : 0);
    for (size_t c = first; c < chunks; c += stride) {
      const size_t begin = c * kChunk, m = std::min(kChunk, n - begin);
      constexpr size_t kAhead = 4;  // points whose rows are on their way while one is blended
      for (size_t i = 0; i < m; ++i) {
        if (i + kAhead < m) {
          const float* ahead = xyz + 3 * (begin + i + kAhead);
          reader.Prefetch(Vec3d(ahead[0], ahead[1], ahead[2]));
        }
        const float* q = xyz + 3 * (begin + i);
        const Vec3d p(q[0], q[1], q[2]);
        reader.Encode(p, &features[i * F], want_gradient ? &jac[i * F * 3] : nullptr);
        const Int3 g0(int(std::floor(p.x() * inv_s)), int(std::floor(p.y() * inv_s)),
                      int(std::floor(p.z() * inv_s)));
        const uint8_t bits = reader.ObservedBits(g0);
        out->observed[begin + i] =
            ((bits & LocalMap::kObserved) ? QueryResult::kObservedSurface : 0) |
            ((bits & LocalMap::kSeenFree) ? QueryResult::kObservedFree : 0);
      }
      decoder_->Forward(features.data(), int(m), &out->sdf[begin],
                        want_gradient ? dsdf.data() : nullptr);
      if (!want_gradient) continue;
      // Chain rule: d sdf / d p = (d sdf / d features) · (d features / d p).
      for (size_t i = 0; i < m; ++i) {
        float* grad = &out->gradient[3 * (begin + i)];
        for (int f = 0; f < F; ++f)
          for (int a = 0; a < 3; ++a) grad[a] += dsdf[i * F + f] * jac[(i * F + f) * 3 + a];
      }
    }
  };
  const size_t threads = std::min<size_t>(size_t(config_.train.threads), chunks);
  std::vector<std::thread> helpers;
  for (size_t t = 1; t < threads; ++t) helpers.emplace_back(run, t, threads);
  run(0, std::max<size_t>(threads, 1));
  for (std::thread& t : helpers) t.join();
  out->map_version = map_version_.load();
  return absl::OkStatus();
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

std::vector<Int3> Mapper::ObservedVoxels(const Int3& key) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  saver_->Flush();  // under the lock, as in QuerySdf
  return rim::ObservedVoxels(MeshTileSource{*geometry_, *local_map_, *store_, *decoder_, mu_}, key);
}

MapperStats Mapper::Stats() const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  MapperStats s;
  s.frames = frames_;
  s.map_version = map_version_.load();
  s.buffer_points = int64_t(buffer_->size());
  const DeferredStats deferred = deferred_->Stats();
  s.deferred_points = deferred.points;
  s.deferred_bytes = deferred.bytes;
  s.local_map_bytes = local_map_->MemoryBytes();
  const SubmapStoreStats st = store_->Stats();
  s.submap_bytes = st.host_bytes;
  s.submaps_active = st.active;
  s.submaps_frozen = st.frozen;
  s.submaps_on_disk = st.on_disk;
  s.decoder_frozen = frames_ >= config_.decoder.freeze_after_frames;
  return s;
}

}  // namespace rim
