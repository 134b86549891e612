// The RIM mapper: one robot's map. IntegrateScan follows Alg. 1 of the paper; queries, mesh tiles
// and persistence read the same state. One owner thread calls IntegrateScan; any thread may query,
// mesh or save concurrently. A reader never sees a half-applied update and waits at most one
// training iteration (§3.5).
#pragma once

#include <Eigen/Geometry>
#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/base/mesh.h"
#include "rim/base/scan.h"
#include "rim/base/shared_mutex.h"
#include "rim/base/types.h"
#include "rim/config/config.h"

namespace rim {
namespace gpu {
class DeviceMap;
}

class Decoder;
class DeferredPoints;
class DistanceField;
struct IntBox;
struct Surfel;
struct IterationTiming;
class LocalMap;
class PointBuffer;
class SlabSaver;
class SubmapStore;
class Trainer;
class TransientFilter;
class MapGeometry;
class MeshBlockCache;
class MeshChangeLog;
struct MeshUpdateStats;
struct MeshCacheTotals;

// Per-frame stage times (§3.4 step 4), seconds; training stages are summed over iterations.
struct StageTimings {
  double slide_s = 0, preprocess_s = 0, sample_s = 0, encode_s = 0, forward_s = 0, backward_s = 0,
         step_s = 0, total_s = 0;
  double distance_s = 0;   // distance field refresh (every query.refresh_frames frames)
  double transient_s = 0;  // of preprocess_s: the moving-things filter (train/transient.h)
  double sync_s = 0;       // of step_s, train.device = cuda: the syncs with the host map
  // Wall time of the iterations: the stages above from sample to step, and what they waited for
  // (the map's lock, the training threads) between them.
  double train_s = 0;
  int iterations = 0;
  int rays_per_iteration = 0;  // the frame's batch (not summed)
  float loss = 0;              // mean over the frame's iterations

  // Adds another frame's times (loss is not summed).
  StageTimings& operator+=(const StageTimings& o) {
    slide_s += o.slide_s;
    preprocess_s += o.preprocess_s;
    sample_s += o.sample_s;
    encode_s += o.encode_s;
    forward_s += o.forward_s;
    backward_s += o.backward_s;
    step_s += o.step_s;
    total_s += o.total_s;
    distance_s += o.distance_s;
    transient_s += o.transient_s;
    sync_s += o.sync_s;
    train_s += o.train_s;
    iterations += o.iterations;
    return *this;
  }
};

struct QueryResult {
  // Metres. QuerySdf: the signed Euclidean distance to the nearest mapped surface (positive in
  // free space), bounded by query.max_distance_m; QueryNeural: the network's value.
  std::vector<float> sdf;
  // 3 per point, when asked. QuerySdf: unit length, away from the nearest surface (zero when
  // saturated); QueryNeural: the network's analytic gradient.
  std::vector<float> gradient;
  // QuerySdf only, per point: 1 when no mapped surface lies within query.max_distance_m (sdf is
  // then +max_distance_m: "at least this far").
  std::vector<uint8_t> saturated;
  // Per point, how the finest voxel at the point was observed: 0 never (the sdf is the network's
  // extrapolation), else kObservedSurface (training samples near a surface fell in it, what the
  // mesh covers) and/or kObservedFree (a ray crossed it in front of its endpoint). The service
  // reports observed = (value != 0).
  std::vector<uint8_t> observed;
  static constexpr uint8_t kObservedSurface = 1, kObservedFree = 2;
  uint64_t map_version = 0;
};

struct TileInfo {
  Int3 key = Int3::Zero();
  uint64_t version = 0;
  Vec3d min_m = Vec3d::Zero(), max_m = Vec3d::Zero();
};

struct MapperStats {
  int64_t frames = 0;
  uint64_t map_version = 0;
  int64_t buffer_points = 0;
  int64_t deferred_points = 0;  // rays seen outside the box, waiting for it (deferred_points.h)
  int64_t deferred_bytes = 0;
  int64_t local_map_bytes = 0;
  int64_t distance_surfels = 0;  // the metric distance field (map/distance_field.h)
  int64_t distance_returns = 0;  // its deferred returns (surface the network has not learnt)
  int64_t distance_bytes = 0;
  // Moving things (train/transient.h), since creation or load: returns dropped from the point
  // buffer and from the deferred rays because later rays passed clearly through them.
  int64_t transient_buffer_removed = 0;
  int64_t transient_deferred_removed = 0;
  int64_t transient_departed_removed = 0;  // points the box had left, seen through after
  int64_t transient_past_removed = 0;  // of the buffer's, new returns an earlier scan saw through
  int64_t transient_busy_removed =
      0;                         // of the buffer's, returns in busy places whose passes added up
  int64_t mesh_cache_bytes = 0;  // cached mesh blocks (MeshTile)
  int64_t submap_bytes = 0;
  int submaps_active = 0, submaps_frozen = 0, submaps_on_disk = 0;
  bool decoder_frozen = false;
  // Where the training iterations run (train.device): "cpu", or the GPU's name once the first
  // iteration made its device copy; that copy's bytes of device memory.
  std::string device = "cpu";
  int64_t device_bytes = 0;
};

class Mapper {
 public:
  static absl::StatusOr<std::unique_ptr<Mapper>> Create(const MapperConfig& config);
  // Restores a mapper saved by Save(); a missing or corrupt file is an error naming it. With
  // `max_host_bytes` > 0, a checkpoint whose config needs more host memory at start
  // (InitialHostBytes) is RESOURCE_EXHAUSTED before anything is allocated.
  static absl::StatusOr<std::unique_ptr<Mapper>> Load(const std::string& dir,
                                                      uint64_t max_host_bytes = 0);
  ~Mapper();

  // Host memory a new mapper of a valid `config` allocates at once: the dense grids of the local
  // map with their optimiser state. What it holds later (sub-maps, point buffer) grows with use.
  static uint64_t InitialHostBytes(const MapperConfig& config);

  // The checks IntegrateScan makes on a scan before changing anything: a finite rigid pose within
  // 1e6 m of the origin, at least one point, finite points and origins, one origin per point or
  // none. INVALID_ARGUMENT naming the problem. The service runs them before it accepts a scan, so
  // that an accepted (logged) scan is never refused by training or by a replay of the log.
  static absl::Status ValidateScan(const PosedScan& scan);

  // Validates and integrates one posed scan (Alg. 1). iterations < 0: the configured number;
  // otherwise clamped to [train.min_iterations, train.iterations]. Invalid input changes nothing.
  // `rays_per_iteration` > 0 trains on batches of that many rays (a paced frame's,
  // sampler.paced_rays_per_iteration), with both iteration bounds scaled by
  // sampler.rays_per_iteration / rays_per_iteration (IterationBounds).
  absl::Status IntegrateScan(const PosedScan& scan, int iterations = -1,
                             StageTimings* timing = nullptr, int rays_per_iteration = 0);
  // The [fewest, most] iterations of a frame trained on batches of `rays_per_iteration` rays
  // (0: sampler.rays_per_iteration): train.min_iterations and train.iterations scaled so that a
  // frame trains as many rays as with the configured batch, rounded, the most at least 1 when
  // train.iterations is.
  std::pair<int, int> IterationBounds(int rays_per_iteration) const;

  // More training on what the map has seen, between frames: up to `iterations` iterations of
  // `rays_per_iteration` rays (as IntegrateScan's) on the point buffer and the last scan's
  // outside rays, each run only while `keep_going()` says so (checked before each). For an owner
  // with idle time before the next scan comes (a robot streaming in real time); the frame count
  // does not change. The decoder trains as the next frame's iterations would. Returns the
  // iterations run; 0 before the first frame. `timing` (optional) accumulates their stages.
  absl::StatusOr<int> TrainBetweenFrames(int iterations, int rays_per_iteration,
                                         const std::function<bool()>& keep_going,
                                         StageTimings* timing = nullptr);

  // Signed Euclidean distance to the nearest mapped surface (and its gradient) at n points xyz
  // (world frame), anywhere in the mapped world: the metric distance field (distance_field.h),
  // as of its last refresh.
  absl::Status QuerySdf(const float* xyz, size_t n, bool want_gradient, QueryResult* out) const;
  // The network's own value and analytic gradient at the points (what meshing and training see;
  // along-ray, not Euclidean, away from the surface).
  absl::Status QueryNeural(const float* xyz, size_t n, bool want_gradient, QueryResult* out) const;

  // Brings the distance field up to the map: re-extracts the surfels of the box (widened by the
  // coarse voxel whose rows it shares) and of what the box left since the last refresh, or of
  // the whole map while the decoder trains. IntegrateScan calls it after frames 1, 2, 4, 8, ...
  // and then every query.refresh_frames frames (unless set_refresh_in_frame(false) hands that
  // schedule to the caller); a caller with idle time may call it in between.
  // Returns seconds spent.
  double RefreshDistanceField();
  // Whether frames were integrated since the last refresh.
  bool DistanceFieldBehind() const;
  // Who keeps the schedule above. On (the default), IntegrateScan refreshes when it is due. Off,
  // it never refreshes, and the caller asks DistanceRefreshDue after each frame and decides (the
  // server holds refreshes to a share of the session's time). Set before frames are integrated.
  void set_refresh_in_frame(bool on) { refresh_in_frame_ = on; }
  // Whether the schedule has a refresh due; `overdue` (may be null): due since at least
  // query.refresh_frames further frames.
  bool DistanceRefreshDue(bool* overdue = nullptr) const;

  // Tiles (one per sub-map) whose version is newer than `since_version`.
  std::vector<TileInfo> ListTiles(uint64_t since_version) const;
  // Marching cubes over one sub-map's observed voxels; neighbouring tiles share border vertices.
  // `resolution_m`: 0 for mesh.resolution_m, or one of MeshLevels().
  absl::StatusOr<Mesh> ExtractMeshTile(const Int3& key, float resolution_m = 0) const;
  // The tile, re-meshing only the blocks that changed visibly since this tile was last meshed
  // here: blocks are cached for the tiles near the box (mesh/mesher.h, MeshBlockCache), and a
  // block whose SDF at the mesh grid moved by no more than mesh.remesh_tolerance_m keeps its mesh.
  // Every value the tile is meshed from is within that tolerance of the map's; with 0 it is
  // ExtractMeshTile's mesh (same vertices and faces, possibly in another order).
  absl::StatusOr<Mesh> MeshTile(const Int3& key, MeshUpdateStats* stats = nullptr) const;
  // The same at a level of detail, one of MeshLevels() (0: mesh.resolution_m); each level has its
  // own block cache, with the tolerance mesh.remesh_tolerance_m. Any other resolution is
  // InvalidArgument naming resolution_m.
  absl::StatusOr<Mesh> MeshTile(const Int3& key, float resolution_m, MeshUpdateStats* stats) const;
  // The levels of detail tiles are meshed at: mesh.resolution_m, then twice as coarse each, up to
  // eight times, as far as the mesh grid allows (mesh/mesher.h, MeshGridOf). Finest first.
  std::vector<float> MeshLevels() const;
  // The level that `resolution_m` names: itself when it is one of MeshLevels() (within a
  // micrometre), the finest for 0; otherwise InvalidArgument naming resolution_m and the levels.
  absl::StatusOr<float> MeshLevel(float resolution_m) const;
  // Blocks meshed, checked and skipped by MeshTile since creation, all levels together.
  MeshCacheTotals MeshTotals() const;
  // Host memory of the cached mesh blocks, all levels together.
  int64_t MeshCacheBytes() const;

  // Observed finest voxels of one sub-map (minimum-corner lattice indices): what its tile meshes.
  std::vector<Int3> ObservedVoxels(const Int3& key) const;

  // Writes the whole state under `dir` as a new checkpoint, switched to atomically. With
  // `frames_saved`, also says how many frames the checkpoint holds (for log truncation).
  absl::Status Save(const std::string& dir, int64_t* frames_saved = nullptr) const;

  const MapperConfig& config() const { return config_; }
  MapperStats Stats() const;
  uint64_t map_version() const { return map_version_.load(); }
  int64_t frames() const { return frames_; }

  // For tests and tools.
  const LocalMap& local_map() const { return *local_map_; }
  const SubmapStore& store() const { return *store_; }
  const Decoder& decoder() const { return *decoder_; }
  const DeferredPoints& deferred() const { return *deferred_; }
  const DistanceField& distance_field() const { return *distance_; }

 private:
  explicit Mapper(const MapperConfig& config);
  // Returns true when the box was placed or moved.
  bool SlideTo(const Vec3d& position_W);
  // Sets preprocess_transient_s_.
  void Preprocess(const PosedScan& scan, bool box_moved);
  void BumpVersions(bool decoder_changed, const IntBox* old_box);
  // Moving things seen through after the box left them (TransientFilter::TakeOutsideCells): their
  // voxels in the store read seen free, their tiles' versions move, and their meshes and distance
  // surfels are made again. Caller holds mu_ alone.
  void ClearDepartedLocked();
  // Up to `iterations` training iterations of `rays` rays, each while *keep_going (when given)
  // says so; adds their losses to *loss_sum. Returns the iterations run. The caller holds
  // frame_mu_; mu_ is taken per iteration (shared to read, alone to write).
  absl::StatusOr<int> Iterate(int iterations, int rays, bool train_decoder,
                              const std::function<bool()>* keep_going, IterationTiming* it,
                              double* loss_sum);
  // Iterate with train.device = cuda: the samples drawn here, the iterations on the device copy
  // of the local map (gpu/device_map.h), synced with the host map before and after.
  absl::StatusOr<int> IterateOnDevice(int iterations, int rays, bool train_decoder,
                                      const std::function<bool()>* keep_going, IterationTiming* it,
                                      double* loss_sum);
  absl::Status SaveState(const std::string& path) const;
  absl::Status LoadState(const std::string& path, uint32_t* version);
  absl::Status SaveDeferred(const std::string& path) const;
  absl::Status SaveDistance(const std::string& path) const;
  absl::Status LoadDistance(const std::string& path);
  // Network values (and gradients, 3 per point, when `grad`) at n points; caller holds mu_.
  void EvalNeural(const float* xyz, size_t n, float* sdf, float* grad, uint8_t* observed) const;
  // The observed voxels of sub-map `key` in `regions` (all of it when empty), whose surfels a
  // refresh extracts; caller holds mu_ shared.
  std::vector<Int3> RefreshVoxels(const Int3& key, const std::vector<IntBox>& regions) const;
  // Appends to `out` the surfels of voxels[begin, begin + m) of sub-map `key`, starting from
  // `before` (the sub-map's surfels at the last refresh, or null); caller holds mu_ shared.
  void ExtractSurfels(const Int3& key, const std::vector<Int3>& voxels, size_t begin, size_t m,
                      const std::vector<Surfel>* before, std::vector<Surfel>* out) const;
  // Rebuilds the distance field's returns (DistanceField::ReplaceReturns) in the deferred
  // sub-maps that changed since the last rebuild: every kept ray whose endpoint voxel the map
  // has not observed as surface. Under refresh_mu_ and a shared mu_.
  void RefreshReturns();
  absl::Status LoadDeferred(const std::string& path);

  MapperConfig config_;
  std::unique_ptr<MapGeometry> geometry_;
  std::unique_ptr<LocalMap> local_map_;
  std::unique_ptr<SubmapStore> store_;
  std::unique_ptr<SlabSaver> saver_;
  std::unique_ptr<Decoder> decoder_;
  std::unique_ptr<PointBuffer> buffer_;
  std::unique_ptr<DeferredPoints> deferred_;
  std::unique_ptr<Trainer> trainer_;
  std::unique_ptr<gpu::DeviceMap> device_;  // train.device = cuda: made at the first iteration
  std::string device_name_ = "cpu";         // for Stats, under mu_
  int64_t device_bytes_ = 0;
  std::unique_ptr<TransientFilter> transient_;  // null when transient.enabled is false
  double preprocess_transient_s_ = 0;  // the last Preprocess's time in transient_ (frame_mu_)
  std::unique_ptr<DistanceField> distance_;
  // What each frame changed, and the mesh blocks of the tiles near the box (MeshTile).
  std::unique_ptr<MeshChangeLog> mesh_changes_;
  std::unique_ptr<MeshBlockCache> mesh_cache_;  // mesh.resolution_m
  // Coarser levels' caches (MeshLevels() after the first), made when first asked for.
  mutable std::mutex mesh_levels_mu_;
  mutable std::vector<std::pair<float, std::unique_ptr<MeshBlockCache>>> mesh_level_caches_;
  // Refresh state (training thread only): the widened box of the last refresh, the frame count
  // then, and whether the decoder changed since (which moves every surfel).
  // Regions whose voxels the moving-things filter marked seen free in the global map since the
  // last refresh: the next refresh re-extracts them (under mu_).
  std::vector<IntBox> distance_pending_;
  std::unique_ptr<IntBox> distance_box_;
  mutable std::mutex refresh_mu_;  // one refresh (or save) at a time
  int64_t distance_frames_ = -1;
  bool distance_all_stale_ = true;
  bool refresh_in_frame_ = true;
  // DistanceRefreshDue without the locks (the training thread, or a caller holding them).
  bool RefreshDueLocked(bool* overdue) const;
  struct OutsideRaysHolder;
  std::unique_ptr<OutsideRaysHolder> outside_;

  // Writers (the training thread) hold it exclusively per step; readers share it. A waiting writer
  // goes before new readers (base/shared_mutex.h): no method takes it shared twice. A training
  // iteration holds it shared while it samples, encodes and runs the network (Trainer::Prepare,
  // which reads the map) and exclusively only for its writes (Trainer::Apply), so readers wait for
  // the writes alone.
  mutable WriterFirstSharedMutex mu_;
  // Held by IntegrateScan over a frame's changes (slide, preprocessing, every iteration, the
  // versions; not its distance refresh) and by Save: a checkpoint holds whole frames, never a
  // frame's points or iterations without the frame counted, nor an iteration half done (its
  // sampler drawn, its step not taken). Order: save_mu_, refresh_mu_, frame_mu_, mu_.
  mutable std::mutex frame_mu_;
  // The point buffer and the deferred rays, which a frame's preprocessing changes under the shared
  // mu_ (beside readers): held over those changes, by Stats() to read their sizes, and by a
  // distance refresh over the deferred rays. After frame_mu_ and mu_ in the lock order.
  mutable std::mutex aux_mu_;
  // One Save() at a time, whatever the directory: overlapping saves picked the same checkpoint
  // folder, or pruned each other's (mapper_persistence.cc).
  mutable std::mutex save_mu_;
  std::atomic<uint64_t> map_version_{0};
  int64_t frames_ = 0;
};

}  // namespace rim
