// Mapper configuration: one plain struct per module, composed into MapperConfig, with the named
// presets of DESIGN.md §3.7. Parsing of overrides (`key=value`) and validation happen here only.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace rim {

// The robot-centric local map and its multi-resolution feature grids (§3.1, §3.2).
struct GridConfig {
  float leaf_size_m = 0.1f;  // s: finest voxel size; level l has voxel size s * 2^l.
  int levels = 3;            // L
  int feature_dim = 8;       // D
  // Half extents of the local box around the robot, metres. z is asymmetric (ground below).
  float half_extent_x_m = 10.f;
  float half_extent_y_m = 10.f;
  float z_min_m = -3.f;  // relative to the robot
  float z_max_m = 3.f;
  bool sliding = true;  // false: the box stays where the first frame put it (indoor depth scenes)
};

// The shallow MLP decoder (§3.1).
struct DecoderConfig {
  int hidden_layers = 1;  // the paper uses 1, the official code 2
  int hidden_width = 32;
  int freeze_after_frames = 20;  // decoder frozen once this many frames were integrated
  uint64_t seed = 42;            // decoder initialisation
};

// Training per frame (§3.4 step 3).
struct TrainConfig {
  int iterations = 30;
  int min_iterations = 3;  // lower bound when a caller asks for fewer iterations under load
  float learning_rate = 1e-2f;
  float sigma_m = 0.05f;       // σ of S(d) = 1/(1+exp(d/σ)) and of the surface-sample noise
  float eikonal_weight = 0.f;  // 0 disables the eikonal term
  float adam_beta1 = 0.9f;
  float adam_beta2 = 0.999f;
  float adam_eps = 1e-15f;
  // The decoder part of a training step: "fast" (hand-written Eigen products, mlp_step.h) or
  // "libtorch" (autograd, train_step.h): the reference the fast one is tested against. Both
  // update the features by lazy Adam on the touched rows. "reference" runs the whole iteration
  // as ReferenceTrainer (train_step.h): libtorch ops over the dense grids and dense Adam over
  // every row, ~25x slower; for measuring the fast path's reconstruction against it.
  std::string step = "fast";
  // Threads of one session's training iterations (encode, gradient scatter, Adam). The server
  // runs --train-slots sessions at once, each with this many threads.
  int threads = 2;
  // Where the training iterations run: "cpu", or "cuda" / "cuda:N" (the GPU path, docs/gpu.md:
  // a build with -DRIM_CUDA=ON; the samples are still drawn on the CPU). Nothing else moves.
  std::string device = "cpu";
};

// Ray sampling (§3.4 step 3, "Sample").
struct SamplerConfig {
  int rays_per_iteration = 2048;  // N
  // Rays per iteration of a frame that a robot streams in real time (the server's paced frames),
  // whose training is bounded by the robot's rate rather than by train.iterations: within the
  // same time, more iterations of smaller batches learn more (docs/core.md, "Batches of a paced
  // frame"). The iteration bounds scale to keep the rays per frame: train.iterations ×
  // rays_per_iteration / paced_rays_per_iteration at most, likewise the minimum; outside rays
  // scale by the same ratio. 0: rays_per_iteration, as for any other frame.
  int paced_rays_per_iteration = 512;
  int surface_samples = 3;  // Ns ~ N(d, σ²)
  int free_samples = 3;     // Nf, stratified in [free_min_ratio·d, free_max_ratio·d]
  float free_min_ratio = 0.3f;
  float free_max_ratio = 0.9f;
  bool outside_rays = false;  // sample free space of out-of-box rays up to the box exit
  int outside_rays_per_iteration = 512;
  // Share of the rays_per_iteration rays drawn from the points the newest frame added to the
  // buffer (uniformly among them); the rest are drawn uniformly from the whole buffer, as the
  // paper does. Training replays the history and also learns the scan it just got: a frame that
  // trains few iterations (a robot at its sensor's rate on a small machine) otherwise leaves its
  // new surface barely trained (docs/core.md, "Training samples"). 0: uniform, as the paper.
  float newest_share = 0.5f;
  // A training sample with |label| below this marks its finest voxel as observed (and meshed);
  // one with a larger positive label marks it as seen free (observed for queries only).
  float observed_band_m = 0.15f;
  // Rays per frame walked voxel by voxel to mark the space in front of their endpoints as seen
  // free (queries report it observed); 0 turns it off.
  int free_space_rays = 4096;
  uint64_t seed = 7;
};

// Historical point buffer (bundle supervision, §3.4 step 2).
struct BufferConfig {
  int max_points = 1000000;
  int max_points_per_frame = 10000;
  float min_range_m = 0.3f;  // closer returns hit the robot itself
  float max_range_m = 60.f;
  bool outlier_removal = false;
  int outlier_period_frames = 10;
  float outlier_threshold_m = 0.05f;  // ε
};

// Deferred supervision (map/deferred_points.h): returns seen outside the local box are kept per
// sub-map and join the point buffer when the box covers them.
struct DeferredConfig {
  bool enabled = true;   // ignored (nothing kept) when grid.sliding is false
  float voxel_m = 0.2f;  // one ray kept per voxel of this size, the shortest-range one
  int max_points_per_submap = 100000;  // past it the longest-range rays are dropped first
};

// Moving things leave no trace (train/transient.h): a return that a later scan's rays clearly pass
// is dropped from the point buffer and the deferred rays, and free-space samples clear the network
// where it stood. docs/core.md, "Moving things", gives the rule and why it spares static surfaces.
struct TransientConfig {
  bool enabled = true;
  // The later scan's range image: bins of this angle, in azimuth and elevation, in the sensor
  // frame.
  float bin_deg = 0.4f;
  // A point is judged on the bins within this many bins of its direction, each side: azimuth,
  // elevation. Rays must surround it (returns on both sides in both directions).
  int window_azimuth_bins = 1;
  int window_elevation_bins = 2;
  // ... and at least this far each side of the point, in metres at its range: a return's place is
  // known to a few centimetres (range noise, the beam's footprint, the pose), so near the sensor,
  // where a bin spans millimetres, a noisy return beside a pole or in front of a car's side must
  // still see the rays that hit them.
  float window_min_m = 0.15f;
  // Every return in the window must end at least margin_m + margin_per_m · range beyond it.
  float margin_m = 0.3f;
  float margin_per_m = 0.01f;
  // Where some returns in the window end before that, the scan's surface around the point's
  // direction decides: a plane fitted to the window's returns (1/range is linear in the direction
  // for any plane), when they fit it within fit_rms_m + fit_rms_per_m · range (one surface, no
  // depth edge), must pass the point by the same margin. Off (false): those points are kept.
  bool surface_fit = true;
  float fit_rms_m = 0.06f;
  float fit_rms_per_m = 0.002f;
  // ... and passes it by at least this along the plane's normal.
  float fit_normal_margin_m = 0.1f;
  // Either way, a return of the later scan within near_m + near_bins · (the bin's width at the
  // point's range) of the point says something is still there (a thin pole's hits), and the point
  // is kept.
  float near_m = 0.08f;
  float near_bins = 0.6f;
  // A direction the sensor fired in that brought nothing back within the scan's range counts as a
  // return at that range: the sky behind a person seen along the street. A row of the range image
  // counts as fired when it holds returns at this share of its azimuths or more: a spinning
  // sensor's ring lined up with the image. A sensor whose rings do not line up with it (a tilted
  // or deskewed frame, a non-repeating pattern) leaves most rows partly filled, with gaps between
  // its beams, and its empty bins are no evidence. Off (empty_is_free=false): empty bins never
  // are (a sensor whose beams often bring nothing back from dark or glass surfaces).
  bool empty_is_free = true;
  float fired_row_share = 0.5f;
  // Points nearer or farther than this from the sensor are not judged.
  float min_range_m = 1.f;
  float max_range_m = 40.f;
  // Each frame judges one in this many of the buffered and deferred points (in turn).
  int period_frames = 4;
  // Where things move: a buffered point is judged every active_period_frames frames (0: every
  // period_frames) while a buffered return within about a column of it (columns of active_cell_m,
  // across x and y) was dropped in the last active_frames frames, and one turn in quiet_turns
  // elsewhere (every period_frames · quiet_turns frames). 99 % of the turn's drops lay within a
  // column of a drop of the ten frames before, in a fifth of the buffer. A place beside the road
  // is often in view for a few frames only, as the robot passes: active_period_frames 1 judges it
  // in each of them, for a fifth fewer floaters on the hardest city and a fifth more time in the
  // filter (docs/core.md, "Moving things"). active_frames 0 or quiet_turns 1: every point takes
  // its turn every period_frames frames, wherever it is.
  int active_frames = 10;
  float active_cell_m = 1.f;
  int quiet_turns = 4;
  int active_period_frames = 0;
  // Busy places: a column (with the eight around it) where busy_drops or more buffered returns
  // were dropped in the last active_frames frames. A person walking away from the road between
  // parked cars is seen for a few frames as the robot passes, each frame's returns just in front
  // of the next frame's body, and then hidden by the cars: no one scan sees clearly through the
  // places they left, so the rule above keeps them. In busy places the buffer is judged every
  // frame, and evidence also adds up over frames: a return is dropped once, in busy_passes judged
  // frames since the last that found something within the near distance of it, a ray passed
  // within busy_radius_m of it and ended beyond it by the margin (at most busy_max_range_m from
  // the sensor, where rings are dense enough that such a ray grazing a static surface ends within
  // the margin). 0 (the default): off; 6 is the measured setting (docs/core.md, "Moving things").
  int busy_drops = 0;
  int busy_passes = 2;
  float busy_radius_m = 0.05f;
  float busy_max_range_m = 10.f;
  // Free-space samples where dropped returns stood: how many per iteration, their label, for how
  // many frames a dropped return is cleared, and at most how many are held.
  int clear_samples_per_iteration = 128;
  float clear_label_m = 0.15f;
  int clear_frames = 10;
  int max_cleared_points = 50000;
  // Points the box has left are still judged for this many frames (one per finest voxel, at most
  // max_departed_points): a car that passed the robot, or a person behind it, is often seen
  // through only after the box has moved on. Their voxels in the global map then read seen free.
  int departed_frames = 30;
  int max_departed_points = 200000;
  // Earlier evidence: each frame's newly buffered points are judged by the same rule against the
  // scans past_frames, 2 · past_frames, ... past_scans · past_frames frames before. A return where
  // an earlier scan's rays passed clearly is something that has moved in since (a person who
  // walked into space the robot saw free); it is dropped before it trains. Several lags: the
  // scan just before may have been too near the place (within min_range_m) or blocked. The scans
  // are asked nearest first, and one with a return at the point settles it (kept): something that
  // stops is mapped past_frames frames later (0.5 s at 10 Hz). 0 of either: off.
  int past_frames = 5;
  int past_scans = 4;
};

// Global map of sub-maps (§3.3).
struct SubmapConfig {
  int block_size = 8;  // sparse storage unit, voxels per edge
  // Sub-maps whose centre is within this many sub-map sizes of the robot stay active; farther
  // ones are frozen (host memory, and the first to spill).
  float active_radius_submaps = 1.5f;
  // Frozen sub-maps spill to `spill_dir` when host memory of the store exceeds this (0: never).
  int64_t host_budget_bytes = 0;
  std::string spill_dir;  // empty: spilling disabled
  bool background_save = true;
};

// Metric distances for queries (map/distance_field.h): the signed Euclidean distance to the
// nearest mapped surface, from surfels on the field's zero level.
struct QueryConfig {
  float max_distance_m = 2.f;         // farther points read this and are flagged saturated
  int refresh_frames = 10;            // surfels of the box re-extracted every this many frames
  float surfel_radius_voxels = 0.6f;  // disk radius of a surfel, in finest voxels
};

struct MeshConfig {
  float resolution_m = 0.05f;  // must divide the leaf size
  // A cached mesh block is re-meshed only when its SDF at the mesh grid moved by more than this
  // since it was meshed (metres, in [0, resolution_m]; 0: whenever the map under it changed).
  float remesh_tolerance_m = 0.005f;
};

// Mesh tile pushes to dashboards (the service's WatchMeshTiles): each tile is pushed at most once
// per interval, its latest version; 0 pushes after every frame that changed it.
struct WatchConfig {
  float min_interval_s = 1.f;
};

struct MapperConfig {
  std::string preset = "maicity";
  GridConfig grid;
  DecoderConfig decoder;
  TrainConfig train;
  SamplerConfig sampler;
  BufferConfig buffer;
  DeferredConfig deferred;
  TransientConfig transient;
  SubmapConfig submap;
  MeshConfig mesh;
  QueryConfig query;
  WatchConfig watch;

  // Checks every value; the error names the bad field (e.g. "grid.leaf_size_m must be > 0").
  absl::Status Validate() const;
  // Every field as `key = value` lines, in the form ApplyOverride accepts.
  std::string ToString() const;
};

// Names of the built-in presets: maicity, maicity_online, kitti, replica, campus.
std::vector<std::string> PresetNames();
absl::StatusOr<MapperConfig> MakePreset(const std::string& name);

// Sets one field by its dotted name ("train.iterations", "grid.leaf_size_m"). Unknown keys and
// unparsable values are INVALID_ARGUMENT naming the key. Does not validate the whole config.
absl::Status ApplyOverride(const std::string& key, const std::string& value, MapperConfig* config);
// Applies `key=value` strings in order, then validates.
absl::Status ApplyOverrides(const std::vector<std::string>& key_values, MapperConfig* config);
// Builds a config from a preset, a config file (`key = value` lines, '#' comments; a `preset = X`
// line selects the base), and overrides, in that order of precedence (last wins). Validated.
absl::StatusOr<MapperConfig> LoadConfigFile(const std::string& path,
                                            const std::vector<std::string>& overrides = {});
absl::StatusOr<MapperConfig> ParseConfigText(const std::string& text,
                                             const std::string& source_name);

}  // namespace rim
