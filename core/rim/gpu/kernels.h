// The CUDA kernels of the GPU path, behind plain C++ declarations: device_map.cc (host C++, no
// CUDA compiler) calls these launchers; kernels.cu is the one file nvcc compiles. Only plain
// types cross this line, so nvcc never parses abseil or Eigen.
#pragma once

#include <cstdint>

namespace rim::gpu {

inline constexpr int kFeatureDim = 8;  // D of every preset; the GPU path supports this one
inline constexpr int kMaxGpuLevels = 6;

// One level's dense grid in device memory, with the box it covers. Slots as LocalMap::Slot.
struct LevelView {
  float* features = nullptr;      // slots × D
  float* adam_m = nullptr;        // slots × D
  float* adam_v = nullptr;        // slots × D
  int32_t* steps = nullptr;       // slots: per-row Adam step count
  float* grad = nullptr;          // slots × D: the iteration's feature gradient (zero between)
  uint32_t* tags = nullptr;       // slots: the stamp of the last iteration that touched the row
  int32_t* touched = nullptr;     // rows touched this iteration (capacity: rows × 8)
  uint32_t* sync_tags = nullptr;  // slots: the last sync window whose Adam pass updated the row
  int32_t* dirty = nullptr;       // rows updated in this sync window (capacity: slots)
  int dims[3] = {0, 0, 0};        // storage size per axis
  int lo[3] = {0, 0, 0};          // lattice box: lower corner (world lattice index)
  int cells[3] = {0, 0, 0};       // cells per axis: a cell's lower corner lies in [lo, lo + cells)
  double inv_h = 0;               // 1 / voxel size
};

struct Grids {
  LevelView level[kMaxGpuLevels];
  int levels = 0;
  uint8_t* flags0 = nullptr;  // level 0's LocalMap flags, slots bytes rounded up to 4
};

// The decoder's shape: one hidden layer of `hidden` units on levels·D inputs.
struct MlpShape {
  int levels = 0, hidden = 0;
};
// Whether the kernels were built for this shape (levels 2–4, hidden 16, 32 or 64).
bool ShapeSupported(const MlpShape& shape);

struct TrainArgs {
  int rows = 0, labelled = 0;
  float inv_sigma = 0, eikonal_weight = 0, inv_2h = 0;
  float observed_band_m = 0;
  uint32_t stamp = 0;
  bool train_decoder = true;
};

// Scratch of one training iteration, device pointers.
struct TrainBuffers {
  const float* xyz = nullptr;     // rows × 3
  const float* labels = nullptr;  // labelled
  float* features = nullptr;      // rows × levels·D
  float* y = nullptr;             // rows
  float* dy = nullptr;            // rows
  double* sums = nullptr;         // [0] BCE terms, [1] eikonal terms
  int32_t* counts = nullptr;      // touched rows per level
  int32_t* error = nullptr;       // set to 1 + index of a point outside the box, or NaN
  const float* params = nullptr;  // decoder parameters
  float* grad_params = nullptr;   // their gradient
};

// One training iteration's forward, loss and backward (feature gradients scattered into the
// levels' grad rows with atomics, decoder gradient summed per block), on `stream`. The
// backward pass overwrites `features` with their gradient.
// The caller has zeroed counts, sums, error, dy and (when training the decoder) grad_params.
// With `marks` (5 cudaEvent_t), records one after each stage: check, forward, loss, backward,
// scatter.
int LaunchTrainBackward(const Grids& grids, const MlpShape& shape, const TrainArgs& args,
                        const TrainBuffers& buf, void* stream, void* const* marks = nullptr);

// Lazy Adam on the touched rows of every level (each with its own step count), then clears
// their gradient rows. `max_rows`: an upper bound of any level's touched count.
struct AdamArgs {
  float lr, beta1, beta2, eps;
};
// With `dirty_counts` (per level), also appends each updated row to its level's dirty list the
// first time in the sync window `sync_stamp`.
int LaunchFeatureAdam(const Grids& grids, const AdamArgs& adam, const int32_t* counts, int max_rows,
                      const int32_t* error, int32_t* dirty_counts, uint32_t sync_stamp,
                      void* stream);

// Rows of one level, packed (features, Adam moments, step counts of n slots): written into the
// slots (ScatterRows: host rows into the device copy) or read from them (GatherRows).
struct PackedRows {
  const int32_t* slots = nullptr;
  float* features = nullptr;  // n × D
  float* adam_m = nullptr;    // n × D
  float* adam_v = nullptr;    // n × D
  int32_t* steps = nullptr;   // n
};
int LaunchScatterRows(const LevelView& level, const PackedRows& rows, int n, void* stream);
int LaunchGatherRows(const LevelView& level, const PackedRows& rows, int n, void* stream);

// Adam on the decoder's n parameters with the bias corrections given (Decoder::Step's), then
// clears the gradient.
int LaunchDecoderAdam(const AdamArgs& adam, float step_size, float inv_sqrt_bc2, int n,
                      float* params, float* grad, float* m, float* v, const int32_t* error,
                      void* stream);

// Encodes n points (levels·D features each); points outside the box get NaN.
int LaunchEncode(const Grids& grids, const float* xyz, int n, float* features, void* stream);

// SDF (and, with `gradient`, its gradient, 3 per point) of n points inside the box; a point
// outside the box (or NaN) gets NaN.
int LaunchQuery(const Grids& grids, const MlpShape& shape, const float* params, const float* xyz,
                int n, float* sdf, float* gradient, void* stream);

// n points uniformly inside the box [lo, hi) (metres), from a counter-based hash of `seed`: the
// benchmark's device-resident inputs.
int LaunchRandomPoints(const double lo[3], const double hi[3], int n, uint64_t seed, float* xyz,
                       void* stream);

}  // namespace rim::gpu
