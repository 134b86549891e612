// The GPU path (-DRIM_CUDA=ON, docs/gpu.md): a copy of the live local map's grids, their Adam
// state and the decoder in device memory, with the training iteration (encode, decoder forward
// and backward, feature gradients by atomics, lazy Adam on the touched rows), encoding and SDF
// and gradient queries run there. The host LocalMap stays the backing store: Upload and Download
// move a whole map. This header compiles without CUDA; a build without it has no DeviceMap and
// OpenDevice names the flag.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/model/decoder.h"

namespace rim::gpu {

struct DeviceInfo {
  int index = 0;
  std::string name;
  int multiprocessors = 0;
  int64_t memory_bytes = 0;
  int compute_major = 0, compute_minor = 0;
};

// Whether this build has the CUDA path.
bool BuiltWithCuda();
// Device `index` (cuda:N): an error that names the reason when the build has no CUDA path, no
// device is visible or the index is out of range.
absl::StatusOr<DeviceInfo> OpenDevice(int index);

// The device index of a `train.device` value: "cuda" (0) or "cuda:N"; "cpu" and anything else
// are an error naming train.device.
absl::StatusOr<int> CudaDeviceIndex(const std::string& device);

// What one training iteration needs besides the samples (Trainer's TrainStepInput and Adam).
struct TrainSettings {
  float sigma_m = 0.05f;
  float eikonal_weight = 0.f;
  float eikonal_step_m = 0.05f;
  float observed_band_m = 0.1f;
  AdamHyper adam{1e-2f, 0.9f, 0.999f, 1e-15f};
  static TrainSettings From(const MapperConfig& config, const MapGeometry& geometry);
};

class DeviceMap {
 public:
  // Allocates the device copy for `map`'s geometry and `decoder`'s shape and uploads both. The
  // kernels support D = 8, 2–4 levels and one hidden layer of 16, 32 or 64 units (every preset);
  // other shapes are an Unimplemented error naming the setting.
  static absl::StatusOr<std::unique_ptr<DeviceMap>> Create(const LocalMap& map,
                                                           const Decoder& decoder, int device);
  ~DeviceMap();
  DeviceMap(const DeviceMap&) = delete;
  DeviceMap& operator=(const DeviceMap&) = delete;

  // The whole local map: features, Adam moments, step counts, level 0's flags and the box.
  absl::Status Upload(const LocalMap& map);
  absl::Status Download(LocalMap* map) const;
  // The decoder's parameters and Adam state.
  absl::Status UploadDecoder(const Decoder& decoder);
  absl::Status DownloadDecoder(Decoder* decoder) const;

  // A Mapper's use, one sync window per frame, the host LocalMap staying the backing store.
  // SyncFromHost, before the frame's iterations: the rows of lattice points that are new to the
  // box since the last sync (the slide's entering slabs) and level 0's flags from the host; opens
  // a sync window. SyncToHost, after them: the rows Step updated in the window, level 0's flags
  // and, with `decoder`, the decoder back into the host copies.
  absl::Status SyncFromHost(const LocalMap& map);
  absl::Status SyncToHost(LocalMap* map, Decoder* decoder);
  // Rows moved by the last SyncFromHost and SyncToHost (for timing and tests).
  int64_t rows_uploaded() const;
  int64_t rows_downloaded() const;

  // Features (n × L·D) of n points; NaN for a point outside the box.
  absl::Status Encode(const float* xyz, int n, float* features);
  // SDF of n points and, when `gradient` is not null, its gradient (3 per point); NaN for a
  // point outside the box (the caller answers those from the sub-map store).
  absl::Status Query(const float* xyz, int n, float* sdf, float* gradient);

  // One training iteration in two parts, like Trainer's Prepare and Apply. Backward: rows
  // [0, labelled) are labelled samples, then groups of 6 eikonal probes; every point must lie in
  // the box (else InvalidArgument and nothing changes). Computes the loss (returned) and the
  // gradients, and marks level 0's observed flags. Step: lazy Adam on the touched rows and, when
  // train_decoder, the decoder.
  absl::StatusOr<float> Backward(const float* xyz, int rows, int labelled, const float* labels,
                                 const TrainSettings& settings, bool train_decoder);
  absl::Status Step(const TrainSettings& settings, bool train_decoder);
  absl::StatusOr<float> Iterate(const float* xyz, int rows, int labelled, const float* labels,
                                const TrainSettings& settings, bool train_decoder);

  // For tests: level l's gradient rows as Backward left them (slots × D, dense), and the
  // decoder's gradient.
  absl::Status DownloadGradients(int level, std::vector<float>* dense) const;
  absl::Status DownloadDecoderGradient(std::vector<float>* grad) const;
  // For tests: fill every output buffer with NaN bit patterns before each kernel writes it, so
  // that an element a kernel failed to write shows.
  void set_poison(bool on);

  // Benchmarks, on device-resident inputs, after one untimed run; median milliseconds of `reps`.
  // Queries of n points drawn uniformly in the box.
  absl::StatusOr<double> TimeQueries(int n, bool gradient, int reps, uint64_t seed);
  // Training iterations (Backward and Step without reading the loss back) on the batch of the
  // last Backward. Enqueue only starts them on this map's stream; Synchronize waits.
  absl::StatusOr<double> TimeIterations(int reps, const TrainSettings& settings,
                                        bool train_decoder);
  absl::Status EnqueueIterations(int count, const TrainSettings& settings, bool train_decoder);
  // Where an iteration's device time goes: median milliseconds of each stage over `reps`.
  struct StageTimes {
    double memsets = 0, check = 0, forward = 0, loss = 0, backward = 0, scatter = 0,
           feature_adam = 0, decoder_adam = 0;
  };
  absl::StatusOr<StageTimes> TimeStages(int reps, const TrainSettings& settings,
                                        bool train_decoder);
  absl::Status Synchronize();

  int64_t device_bytes() const;
  const DeviceInfo& device() const;

 private:
  DeviceMap();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace rim::gpu
