// rim::Mapper: construction, the checks on a scan, and IntegrateScan's orchestration of a frame
// (Alg. 1): slide, preprocess (mapper_preprocess.cc), training iterations, versions and tiles
// (mapper_tiles.cc), the distance refresh (mapper_distance_refresh.cc). Queries are in
// mapper_query.cc, save and load in mapper_persistence.cc.
#include "rim/mapper.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <mutex>
#include <optional>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/gpu/device_map.h"
#include "rim/map/deferred_points.h"
#include "rim/map/distance_field.h"
#include "rim/map/local_map.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"
#include "rim/mapper_internal.h"
#include "rim/mesh/mesher.h"
#include "rim/model/decoder.h"
#include "rim/train/point_buffer.h"
#include "rim/train/trainer.h"
#include "rim/train/transient.h"

namespace rim {
using mapper_internal::Now;
namespace {
bool Finite(const Vec3f& v) {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}
}  // namespace

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
  device_name_ = config.train.device;  // the GPU's name once its device copy exists
}

Mapper::~Mapper() = default;

absl::StatusOr<std::unique_ptr<Mapper>> Mapper::Create(const MapperConfig& config) {
  RIM_RETURN_IF_ERROR(config.Validate());
  if (config.train.device != "cpu") {
    // A missing CUDA build or device is an error now, not at the first frame.
    RIM_ASSIGN_OR_RETURN(const int index, gpu::CudaDeviceIndex(config.train.device));
    absl::StatusOr<gpu::DeviceInfo> device = gpu::OpenDevice(index);
    if (!device.ok()) {
      return absl::Status(
          device.status().code(),
          absl::StrCat("train.device = ", config.train.device, ": ", device.status().message()));
    }
  }
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
    t.transient_s = preprocess_transient_s_;
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
  t.sync_s = it.sync_s;
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
  if (config_.train.device != "cpu") {
    return IterateOnDevice(iterations, rays, train_decoder, keep_going, it, loss_sum);
  }
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

absl::StatusOr<int> Mapper::IterateOnDevice(int iterations, int rays, bool train_decoder,
                                            const std::function<bool()>* keep_going,
                                            IterationTiming* it, double* loss_sum) {
  if (!device_) {
    RIM_ASSIGN_OR_RETURN(const int index, gpu::CudaDeviceIndex(config_.train.device));
    std::unique_lock lock(mu_);  // Stats reads device_ beside the frame
    RIM_ASSIGN_OR_RETURN(device_, gpu::DeviceMap::Create(*local_map_, *decoder_, index));
    device_name_ = device_->device().name;
  }
  double t0 = Now();
  {
    // The host map is the backing store: the slide's new rows and this frame's flags go over.
    std::shared_lock lock(mu_);
    RIM_RETURN_IF_ERROR(device_->SyncFromHost(*local_map_));
  }
  if (it) {
    it->step_s += Now() - t0;
    it->sync_s += Now() - t0;
  }
  const gpu::TrainSettings settings = gpu::TrainSettings::From(config_, *geometry_);
  int done = 0;
  absl::Status status;
  while (status.ok() && done < iterations && (keep_going == nullptr || (*keep_going)())) {
    {
      std::shared_lock lock(mu_);
      status = trainer_->SampleRows(*buffer_, outside_->rays, it, rays);
    }
    if (!status.ok()) break;
    const std::vector<float>& xyz = trainer_->rows_xyz();
    const SampleBatch& batch = trainer_->last_batch();
    t0 = Now();
    absl::StatusOr<float> loss =
        device_->Iterate(xyz.data(), int(xyz.size() / 3), int(batch.size()), batch.labels.data(),
                         settings, train_decoder);
    if (it) it->step_s += Now() - t0;
    if (!loss.ok()) {
      status = loss.status();
      break;
    }
    *loss_sum += *loss;
    ++done;
  }
  // Readers see the frame's training at once, when the rows it changed are back in the host map.
  t0 = Now();
  std::unique_lock lock(mu_);
  const absl::Status back =
      device_->SyncToHost(local_map_.get(), train_decoder ? decoder_.get() : nullptr);
  map_version_.fetch_add(uint64_t(done));
  device_bytes_ = device_->device_bytes();
  if (it) {
    it->step_s += Now() - t0;
    it->sync_s += Now() - t0;
  }
  RIM_RETURN_IF_ERROR(status);
  RIM_RETURN_IF_ERROR(back);
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
    timing->sync_s += it.sync_s;
    timing->train_s += Now() - start;
    timing->total_s += Now() - start;
    timing->iterations += done;
    timing->rays_per_iteration = rays;
  }
  return done;
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
      s.transient_past_removed = tr.past_removed;
      s.transient_busy_removed = tr.busy_removed;
    }
  }
  s.deferred_points = deferred.points;
  s.deferred_bytes = deferred.bytes;
  s.local_map_bytes = local_map_->MemoryBytes();
  const DistanceFieldStats distance = distance_->Stats();
  s.distance_surfels = distance.surfels;
  s.distance_returns = distance.returns;
  s.distance_bytes = distance.bytes;
  s.mesh_cache_bytes = MeshCacheBytes();
  const SubmapStoreStats st = store_->Stats();
  s.submap_bytes = st.host_bytes;
  s.submaps_active = st.active;
  s.submaps_frozen = st.frozen;
  s.submaps_on_disk = st.on_disk;
  s.decoder_frozen = frames_ >= config_.decoder.freeze_after_frames;
  s.device = device_name_;
  s.device_bytes = device_bytes_;
  return s;
}

}  // namespace rim
