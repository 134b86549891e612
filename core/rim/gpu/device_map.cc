#include "rim/gpu/device_map.h"

#include <cuda_runtime_api.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/gpu/kernels.h"

namespace rim::gpu {
namespace {

absl::Status CudaStatus(int code, const char* what) {
  const cudaError_t e = static_cast<cudaError_t>(code);
  if (e == cudaSuccess) return absl::OkStatus();
  return absl::InternalError(
      absl::StrCat("CUDA: ", what, ": ", cudaGetErrorName(e), " (", cudaGetErrorString(e), ")"));
}

// Every CUDA call is checked; the status names the call.
#define RIM_CUDA(call)                                                       \
  do {                                                                       \
    if (absl::Status s_ = CudaStatus(int(call), #call); !s_.ok()) return s_; \
  } while (0)

template <typename T>
class DeviceArray {
 public:
  DeviceArray() = default;
  ~DeviceArray() { Free(); }
  DeviceArray(const DeviceArray&) = delete;
  DeviceArray& operator=(const DeviceArray&) = delete;
  DeviceArray(DeviceArray&& o) noexcept : data_(o.data_), size_(o.size_) {
    o.data_ = nullptr;
    o.size_ = 0;
  }
  absl::Status Allocate(size_t n, int64_t* total) {
    if (n <= size_) return absl::OkStatus();
    Free(total);
    void* p = nullptr;
    RIM_CUDA(cudaMalloc(&p, std::max<size_t>(n, 1) * sizeof(T)));
    data_ = static_cast<T*>(p);
    size_ = n;
    *total += int64_t(n * sizeof(T));
    return absl::OkStatus();
  }
  T* get() const { return data_; }
  size_t size() const { return size_; }

 private:
  void Free(int64_t* total = nullptr) {
    if (data_ != nullptr) cudaFree(data_);
    if (total != nullptr) *total -= int64_t(size_ * sizeof(T));
    data_ = nullptr;
    size_ = 0;
  }
  T* data_ = nullptr;
  size_t size_ = 0;
};

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

}  // namespace

bool BuiltWithCuda() { return true; }

absl::StatusOr<DeviceInfo> OpenDevice(int index) {
  int count = 0;
  const cudaError_t e = cudaGetDeviceCount(&count);
  if (e != cudaSuccess || count == 0) {
    return absl::FailedPreconditionError(absl::StrCat(
        "no CUDA device is visible (", e == cudaSuccess ? "none found" : cudaGetErrorString(e),
        "): run on a machine with an NVIDIA GPU and driver"));
  }
  if (index < 0 || index >= count) {
    return absl::InvalidArgumentError(
        absl::StrCat("device cuda:", index, " does not exist: ", count, " CUDA device(s) visible"));
  }
  RIM_CUDA(cudaSetDevice(index));
  cudaDeviceProp prop;
  RIM_CUDA(cudaGetDeviceProperties(&prop, index));
  DeviceInfo info;
  info.index = index;
  info.name = prop.name;
  info.multiprocessors = prop.multiProcessorCount;
  info.memory_bytes = int64_t(prop.totalGlobalMem);
  info.compute_major = prop.major;
  info.compute_minor = prop.minor;
  return info;
}

struct DeviceMap::Impl {
  DeviceInfo info;
  cudaStream_t stream = nullptr;
  int64_t bytes = 0;
  bool poison = false;
  MapGeometry geometry{GridConfig{}};
  MlpShape shape;
  int params = 0;

  struct Level {
    DeviceArray<float> features, m, v, grad;
    DeviceArray<int32_t> steps, touched;
    DeviceArray<uint32_t> tags, sync_tags;
    DeviceArray<int32_t> dirty;
    int64_t slots = 0;
  };
  // Sync windows (SyncFromHost .. SyncToHost): rows Step updated are listed per level.
  DeviceArray<int32_t> dirty_counts;
  uint32_t sync_stamp = 0;
  bool tracking = false;
  int64_t uploaded = 0, downloaded = 0;
  // Packed rows between the host and the device (grow only).
  DeviceArray<int32_t> pk_slots, pk_steps;
  DeviceArray<float> pk_features, pk_m, pk_v;
  absl::Status GrowPacked(size_t n) {
    RIM_RETURN_IF_ERROR(pk_slots.Allocate(n, &bytes));
    RIM_RETURN_IF_ERROR(pk_steps.Allocate(n, &bytes));
    RIM_RETURN_IF_ERROR(pk_features.Allocate(n * kFeatureDim, &bytes));
    RIM_RETURN_IF_ERROR(pk_m.Allocate(n * kFeatureDim, &bytes));
    RIM_RETURN_IF_ERROR(pk_v.Allocate(n * kFeatureDim, &bytes));
    return absl::OkStatus();
  }
  PackedRows Packed() const {
    PackedRows p;
    p.slots = pk_slots.get();
    p.features = pk_features.get();
    p.adam_m = pk_m.get();
    p.adam_v = pk_v.get();
    p.steps = pk_steps.get();
    return p;
  }
  std::vector<Level> levels;
  DeviceArray<uint8_t> flags0;
  Grids grids;

  DeviceArray<float> dparams, dgrad, dm, dv;
  int decoder_step = 0;

  // The current batch and its scratch.
  DeviceArray<float> xyz, labels, features, y, dy;
  DeviceArray<double> sums;
  DeviceArray<int32_t> counts, error;
  int rows = 0, labelled = 0;
  uint32_t stamp = 0;
  bool have_batch = false, stepped = true;

  DeviceArray<float> query_xyz, query_sdf, query_grad;
  // TimeStages: events recorded between the stages while `marking`.
  cudaEvent_t marks[9] = {};
  bool marking = false;
  void Mark(int i) {
    if (marking) cudaEventRecord(marks[i], stream);
  }

  ~Impl() {
    if (stream != nullptr) cudaStreamDestroy(stream);
  }

  absl::Status Poison(void* p, size_t bytes_) {
    if (!poison || p == nullptr) return absl::OkStatus();
    RIM_CUDA(cudaMemsetAsync(p, 0xff, bytes_, stream));
    return absl::OkStatus();
  }

  TrainArgs Args(const TrainSettings& s, bool train_decoder) const {
    TrainArgs a;
    a.rows = rows;
    a.labelled = labelled;
    a.inv_sigma = 1.f / s.sigma_m;
    a.eikonal_weight = s.eikonal_weight;
    a.inv_2h = 1.f / (2.f * s.eikonal_step_m);
    a.observed_band_m = s.observed_band_m;
    a.stamp = stamp;
    a.train_decoder = train_decoder;
    return a;
  }

  // Enqueues one backward pass on the current batch (no read-back).
  absl::Status EnqueueBackward(const TrainSettings& s, bool train_decoder) {
    Mark(0);
    if (++stamp == 0) {  // the stamps wrapped: clear every tag so no old mark matches
      for (Level& lv : levels)
        RIM_CUDA(cudaMemsetAsync(lv.tags.get(), 0, size_t(lv.slots) * 4, stream));
      stamp = 1;
    }
    RIM_CUDA(cudaMemsetAsync(sums.get(), 0, 2 * sizeof(double), stream));
    RIM_CUDA(cudaMemsetAsync(counts.get(), 0, kMaxGpuLevels * sizeof(int32_t), stream));
    RIM_CUDA(cudaMemsetAsync(error.get(), 0, sizeof(int32_t), stream));
    RIM_CUDA(cudaMemsetAsync(dy.get(), 0, size_t(rows) * sizeof(float), stream));
    if (train_decoder) {
      RIM_CUDA(cudaMemsetAsync(dgrad.get(), 0, size_t(params) * sizeof(float), stream));
    }
    RIM_RETURN_IF_ERROR(Poison(features.get(), size_t(rows) * shape.levels * kFeatureDim * 4));
    RIM_RETURN_IF_ERROR(Poison(y.get(), size_t(rows) * 4));
    TrainBuffers b;
    b.xyz = xyz.get();
    b.labels = labels.get();
    b.features = features.get();
    b.y = y.get();
    b.dy = dy.get();
    b.sums = sums.get();
    b.counts = counts.get();
    b.error = error.get();
    b.params = dparams.get();
    b.grad_params = dgrad.get();
    Mark(1);
    RIM_CUDA(LaunchTrainBackward(grids, shape, Args(s, train_decoder), b, stream,
                                 marking ? reinterpret_cast<void* const*>(&marks[2]) : nullptr));
    stepped = false;
    return absl::OkStatus();
  }

  absl::Status EnqueueStep(const TrainSettings& s, bool train_decoder) {
    const AdamArgs adam{s.adam.lr, s.adam.beta1, s.adam.beta2, s.adam.eps};
    RIM_CUDA(LaunchFeatureAdam(grids, adam, counts.get(), rows * 8, error.get(),
                               tracking ? dirty_counts.get() : nullptr, sync_stamp, stream));
    Mark(7);
    if (train_decoder) {
      // Decoder::Step's bias corrections, in double.
      ++decoder_step;
      const double bc1 = 1.0 - std::pow(double(s.adam.beta1), decoder_step);
      const double bc2 = 1.0 - std::pow(double(s.adam.beta2), decoder_step);
      RIM_CUDA(LaunchDecoderAdam(adam, float(double(s.adam.lr) / bc1), float(1.0 / std::sqrt(bc2)),
                                 params, dparams.get(), dgrad.get(), dm.get(), dv.get(),
                                 error.get(), stream));
    }
    Mark(8);
    stepped = true;
    return absl::OkStatus();
  }
};

DeviceMap::DeviceMap() : impl_(std::make_unique<Impl>()) {}
DeviceMap::~DeviceMap() = default;

absl::StatusOr<std::unique_ptr<DeviceMap>> DeviceMap::Create(const LocalMap& map,
                                                             const Decoder& decoder, int device) {
  const MapGeometry& geo = map.geometry();
  if (geo.feature_dim() != kFeatureDim) {
    return absl::UnimplementedError(absl::StrCat(
        "the GPU path supports grid.feature_dim = ", kFeatureDim, ", not ", geo.feature_dim()));
  }
  const auto& layers = decoder.layers();
  MlpShape shape;
  shape.levels = geo.levels();
  shape.hidden = layers.size() == 2 ? layers[0].out : 0;
  if (layers.size() != 2 || !ShapeSupported(shape)) {
    return absl::UnimplementedError(absl::StrCat(
        "the GPU path supports decoder.hidden_layers = 1 with decoder.hidden_width 16, 32 or 64 "
        "and grid.levels 2 to 4; this map has ",
        int(layers.size()) - 1, " hidden layer(s) of ", layers[0].out, " and ", geo.levels(),
        " levels"));
  }
  if (decoder.input_dim() != geo.encoding_dim()) {
    return absl::InvalidArgumentError("decoder input width differs from the map's encoding");
  }
  absl::StatusOr<DeviceInfo> info = OpenDevice(device);
  if (!info.ok()) return info.status();
  std::unique_ptr<DeviceMap> dm(new DeviceMap());
  Impl& im = *dm->impl_;
  im.info = *info;
  im.geometry = geo;
  im.shape = shape;
  im.params = int(decoder.params().size());
  // A blocking stream: it waits for the legacy default stream's work, which the plain cudaMemcpy
  // and cudaMemset calls here use, and that work waits for it.
  RIM_CUDA(cudaStreamCreate(&im.stream));
  im.levels.resize(size_t(geo.levels()));
  im.grids.levels = geo.levels();
  for (int l = 0; l < geo.levels(); ++l) {
    const LocalMap::Level& src = map.level(l);
    Impl::Level& lv = im.levels[size_t(l)];
    lv.slots = src.slots();
    if (lv.slots >= (int64_t(1) << 31) / kFeatureDim) {
      return absl::UnimplementedError("the GPU path supports up to 2^28 slots per level");
    }
    const size_t n = size_t(lv.slots);
    RIM_RETURN_IF_ERROR(lv.features.Allocate(n * kFeatureDim, &im.bytes));
    RIM_RETURN_IF_ERROR(lv.m.Allocate(n * kFeatureDim, &im.bytes));
    RIM_RETURN_IF_ERROR(lv.v.Allocate(n * kFeatureDim, &im.bytes));
    RIM_RETURN_IF_ERROR(lv.grad.Allocate(n * kFeatureDim, &im.bytes));
    RIM_RETURN_IF_ERROR(lv.steps.Allocate(n, &im.bytes));
    RIM_RETURN_IF_ERROR(lv.tags.Allocate(n, &im.bytes));
    RIM_RETURN_IF_ERROR(lv.sync_tags.Allocate(n, &im.bytes));
    RIM_RETURN_IF_ERROR(lv.dirty.Allocate(n, &im.bytes));
    RIM_CUDA(cudaMemset(lv.grad.get(), 0, n * kFeatureDim * 4));
    RIM_CUDA(cudaMemset(lv.tags.get(), 0, n * 4));
    RIM_CUDA(cudaMemset(lv.sync_tags.get(), 0, n * 4));
  }
  RIM_RETURN_IF_ERROR(im.flags0.Allocate((size_t(im.levels[0].slots) + 3) / 4 * 4, &im.bytes));
  RIM_RETURN_IF_ERROR(im.dparams.Allocate(size_t(im.params), &im.bytes));
  RIM_RETURN_IF_ERROR(im.dgrad.Allocate(size_t(im.params), &im.bytes));
  RIM_RETURN_IF_ERROR(im.dm.Allocate(size_t(im.params), &im.bytes));
  RIM_RETURN_IF_ERROR(im.dv.Allocate(size_t(im.params), &im.bytes));
  RIM_CUDA(cudaMemset(im.dgrad.get(), 0, size_t(im.params) * 4));
  RIM_RETURN_IF_ERROR(im.sums.Allocate(2, &im.bytes));
  RIM_RETURN_IF_ERROR(im.counts.Allocate(kMaxGpuLevels, &im.bytes));
  RIM_RETURN_IF_ERROR(im.error.Allocate(1, &im.bytes));
  RIM_RETURN_IF_ERROR(im.dirty_counts.Allocate(kMaxGpuLevels, &im.bytes));
  RIM_RETURN_IF_ERROR(dm->Upload(map));
  RIM_RETURN_IF_ERROR(dm->UploadDecoder(decoder));
  return dm;
}

absl::Status DeviceMap::Upload(const LocalMap& map) {
  Impl& im = *impl_;
  const MapGeometry& geo = map.geometry();
  if (geo.levels() != im.geometry.levels() || geo.feature_dim() != kFeatureDim) {
    return absl::InvalidArgumentError("Upload: the map's geometry differs from the device copy's");
  }
  std::vector<float> m, v;
  std::vector<int32_t> steps;
  for (int l = 0; l < geo.levels(); ++l) {
    const LocalMap::Level& src = map.level(l);
    Impl::Level& lv = im.levels[size_t(l)];
    if (src.slots() != lv.slots) {
      return absl::InvalidArgumentError("Upload: a level's size differs from the device copy's");
    }
    const size_t n = size_t(lv.slots);
    RIM_CUDA(cudaMemcpy(lv.features.get(), src.features(0), n * kFeatureDim * 4,
                        cudaMemcpyHostToDevice));
    m.resize(n * kFeatureDim);
    v.resize(n * kFeatureDim);
    steps.resize(n);
    for (size_t s = 0; s < n; ++s) {
      std::memcpy(&m[s * kFeatureDim], src.adam_m(int64_t(s)), kFeatureDim * 4);
      std::memcpy(&v[s * kFeatureDim], src.adam_v(int64_t(s)), kFeatureDim * 4);
      steps[s] = src.adam_steps(int64_t(s));
    }
    RIM_CUDA(cudaMemcpy(lv.m.get(), m.data(), n * kFeatureDim * 4, cudaMemcpyHostToDevice));
    RIM_CUDA(cudaMemcpy(lv.v.get(), v.data(), n * kFeatureDim * 4, cudaMemcpyHostToDevice));
    RIM_CUDA(cudaMemcpy(lv.steps.get(), steps.data(), n * 4, cudaMemcpyHostToDevice));
    LevelView& view = im.grids.level[l];
    view.features = lv.features.get();
    view.adam_m = lv.m.get();
    view.adam_v = lv.v.get();
    view.steps = lv.steps.get();
    view.grad = lv.grad.get();
    view.tags = lv.tags.get();
    view.touched = lv.touched.get();
    view.sync_tags = lv.sync_tags.get();
    view.dirty = lv.dirty.get();
    const IntBox box = map.LatticeBox(l);
    for (int a = 0; a < 3; ++a) {
      view.dims[a] = src.dims[a];
      view.lo[a] = box.lo[a];
      // Without a placed box no cell is inside: every point is outside.
      view.cells[a] = map.placed() ? box.hi[a] - box.lo[a] : 0;
    }
    view.inv_h = 1.0 / geo.voxel_m(l);
  }
  const std::vector<uint8_t> flags = map.level(0).FlagCopy();
  RIM_CUDA(cudaMemcpy(im.flags0.get(), flags.data(), flags.size(), cudaMemcpyHostToDevice));
  im.grids.flags0 = im.flags0.get();
  return absl::OkStatus();
}

absl::Status DeviceMap::Download(LocalMap* map) const {
  const Impl& im = *impl_;
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  std::vector<float> m, v;
  std::vector<int32_t> steps;
  for (int l = 0; l < im.geometry.levels(); ++l) {
    LocalMap::Level& dst = map->level(l);
    const Impl::Level& lv = im.levels[size_t(l)];
    if (dst.slots() != lv.slots) {
      return absl::InvalidArgumentError("Download: a level's size differs from the device copy's");
    }
    const size_t n = size_t(lv.slots);
    RIM_CUDA(cudaMemcpy(dst.features(0), lv.features.get(), n * kFeatureDim * 4,
                        cudaMemcpyDeviceToHost));
    m.resize(n * kFeatureDim);
    v.resize(n * kFeatureDim);
    steps.resize(n);
    RIM_CUDA(cudaMemcpy(m.data(), lv.m.get(), n * kFeatureDim * 4, cudaMemcpyDeviceToHost));
    RIM_CUDA(cudaMemcpy(v.data(), lv.v.get(), n * kFeatureDim * 4, cudaMemcpyDeviceToHost));
    RIM_CUDA(cudaMemcpy(steps.data(), lv.steps.get(), n * 4, cudaMemcpyDeviceToHost));
    for (size_t s = 0; s < n; ++s) {
      std::memcpy(dst.adam_m(int64_t(s)), &m[s * kFeatureDim], kFeatureDim * 4);
      std::memcpy(dst.adam_v(int64_t(s)), &v[s * kFeatureDim], kFeatureDim * 4);
      dst.adam_steps(int64_t(s)) = steps[s];
    }
  }
  std::vector<uint8_t> flags(size_t(im.levels[0].slots));
  RIM_CUDA(cudaMemcpy(flags.data(), im.flags0.get(), flags.size(), cudaMemcpyDeviceToHost));
  for (size_t s = 0; s < flags.size(); ++s) map->level(0).flags(int64_t(s)) = flags[s];
  return absl::OkStatus();
}

absl::Status DeviceMap::UploadDecoder(const Decoder& decoder) {
  Impl& im = *impl_;
  if (int(decoder.params().size()) != im.params) {
    return absl::InvalidArgumentError("UploadDecoder: the decoder's shape differs");
  }
  const size_t bytes = size_t(im.params) * 4;
  RIM_CUDA(cudaMemcpy(im.dparams.get(), decoder.params().data(), bytes, cudaMemcpyHostToDevice));
  RIM_CUDA(cudaMemcpy(im.dm.get(), decoder.adam_m().data(), bytes, cudaMemcpyHostToDevice));
  RIM_CUDA(cudaMemcpy(im.dv.get(), decoder.adam_v().data(), bytes, cudaMemcpyHostToDevice));
  im.decoder_step = decoder.adam_step();
  return absl::OkStatus();
}

absl::Status DeviceMap::DownloadDecoder(Decoder* decoder) const {
  const Impl& im = *impl_;
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  const size_t n = size_t(im.params);
  std::vector<float> m(n), v(n);
  RIM_CUDA(cudaMemcpy(decoder->params().data(), im.dparams.get(), n * 4, cudaMemcpyDeviceToHost));
  RIM_CUDA(cudaMemcpy(m.data(), im.dm.get(), n * 4, cudaMemcpyDeviceToHost));
  RIM_CUDA(cudaMemcpy(v.data(), im.dv.get(), n * 4, cudaMemcpyDeviceToHost));
  return decoder->SetAdamState(im.decoder_step, m, v);
}

absl::Status DeviceMap::SyncFromHost(const LocalMap& map) {
  Impl& im = *impl_;
  if (map.geometry().levels() != int(im.levels.size())) {
    return absl::InvalidArgumentError("SyncFromHost: the map's geometry differs");
  }
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  im.uploaded = 0;
  std::vector<int32_t> slots, steps;
  std::vector<float> features, m, v;
  for (int l = 0; l < int(im.levels.size()); ++l) {
    LevelView& view = im.grids.level[l];
    const LocalMap::Level& src = map.level(l);
    const IntBox box = map.LatticeBox(l);  // lattice points lo..hi, both included
    const bool was_placed = view.cells[0] > 0;
    const Int3 old_lo(view.lo[0], view.lo[1], view.lo[2]);
    const Int3 old_hi = old_lo + Int3(view.cells[0], view.cells[1], view.cells[2]);
    auto in_old = [&](int a, int x) { return was_placed && x >= old_lo[a] && x <= old_hi[a]; };
    slots.clear();
    if (map.placed()) {
      // The lattice points of the new box that the old one lacks: whole planes and lines where
      // an axis left the old range, the remainder of z otherwise.
      for (int x = box.lo.x(); x <= box.hi.x(); ++x)
        for (int y = box.lo.y(); y <= box.hi.y(); ++y)
          for (int z = box.lo.z(); z <= box.hi.z(); ++z) {
            if (in_old(0, x) && in_old(1, y) && in_old(2, z)) {
              z = old_hi.z() < box.hi.z() ? std::max(z, old_hi.z()) : box.hi.z();
              continue;
            }
            slots.push_back(int32_t(map.Slot(l, Int3(x, y, z))));
          }
    }
    const size_t n = slots.size();
    if (n > 0) {
      features.resize(n * kFeatureDim);
      m.resize(n * kFeatureDim);
      v.resize(n * kFeatureDim);
      steps.resize(n);
      for (size_t i = 0; i < n; ++i) {
        std::memcpy(&features[i * kFeatureDim], src.features(slots[i]), kFeatureDim * 4);
        std::memcpy(&m[i * kFeatureDim], src.adam_m(slots[i]), kFeatureDim * 4);
        std::memcpy(&v[i * kFeatureDim], src.adam_v(slots[i]), kFeatureDim * 4);
        steps[i] = src.adam_steps(slots[i]);
      }
      RIM_RETURN_IF_ERROR(im.GrowPacked(n));
      const PackedRows p = im.Packed();
      RIM_CUDA(
          cudaMemcpy(const_cast<int32_t*>(p.slots), slots.data(), n * 4, cudaMemcpyHostToDevice));
      RIM_CUDA(cudaMemcpy(p.features, features.data(), n * 32, cudaMemcpyHostToDevice));
      RIM_CUDA(cudaMemcpy(p.adam_m, m.data(), n * 32, cudaMemcpyHostToDevice));
      RIM_CUDA(cudaMemcpy(p.adam_v, v.data(), n * 32, cudaMemcpyHostToDevice));
      RIM_CUDA(cudaMemcpy(p.steps, steps.data(), n * 4, cudaMemcpyHostToDevice));
      RIM_CUDA(LaunchScatterRows(view, p, int(n), im.stream));
      RIM_CUDA(cudaStreamSynchronize(im.stream));  // the packed buffers are reused per level
      im.uploaded += int64_t(n);
    }
    for (int a = 0; a < 3; ++a) {
      view.lo[a] = box.lo[a];
      view.cells[a] = map.placed() ? box.hi[a] - box.lo[a] : 0;
    }
  }
  RIM_CUDA(cudaMemcpy(im.flags0.get(), map.level(0).flag_data(), size_t(im.levels[0].slots),
                      cudaMemcpyHostToDevice));
  if (++im.sync_stamp == 0) {
    for (Impl::Level& lv : im.levels)
      RIM_CUDA(cudaMemset(lv.sync_tags.get(), 0, size_t(lv.slots) * 4));
    im.sync_stamp = 1;
  }
  RIM_CUDA(cudaMemset(im.dirty_counts.get(), 0, kMaxGpuLevels * 4));
  im.tracking = true;
  return absl::OkStatus();
}

absl::Status DeviceMap::SyncToHost(LocalMap* map, Decoder* decoder) {
  Impl& im = *impl_;
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  im.downloaded = 0;
  if (im.tracking) {
    int32_t counts[kMaxGpuLevels];
    RIM_CUDA(cudaMemcpy(counts, im.dirty_counts.get(), sizeof(counts), cudaMemcpyDeviceToHost));
    std::vector<int32_t> slots, steps;
    std::vector<float> features, m, v;
    for (int l = 0; l < int(im.levels.size()); ++l) {
      const size_t n = size_t(counts[l]);
      if (n == 0) continue;
      RIM_RETURN_IF_ERROR(im.GrowPacked(n));
      PackedRows p = im.Packed();
      p.slots = im.levels[size_t(l)].dirty.get();
      RIM_CUDA(LaunchGatherRows(im.grids.level[l], p, int(n), im.stream));
      RIM_CUDA(cudaStreamSynchronize(im.stream));
      slots.resize(n);
      features.resize(n * kFeatureDim);
      m.resize(n * kFeatureDim);
      v.resize(n * kFeatureDim);
      steps.resize(n);
      RIM_CUDA(cudaMemcpy(slots.data(), p.slots, n * 4, cudaMemcpyDeviceToHost));
      RIM_CUDA(cudaMemcpy(features.data(), p.features, n * 32, cudaMemcpyDeviceToHost));
      RIM_CUDA(cudaMemcpy(m.data(), p.adam_m, n * 32, cudaMemcpyDeviceToHost));
      RIM_CUDA(cudaMemcpy(v.data(), p.adam_v, n * 32, cudaMemcpyDeviceToHost));
      RIM_CUDA(cudaMemcpy(steps.data(), p.steps, n * 4, cudaMemcpyDeviceToHost));
      LocalMap::Level& dst = map->level(l);
      for (size_t i = 0; i < n; ++i) {
        std::memcpy(dst.features(slots[i]), &features[i * kFeatureDim], kFeatureDim * 4);
        std::memcpy(dst.adam_m(slots[i]), &m[i * kFeatureDim], kFeatureDim * 4);
        std::memcpy(dst.adam_v(slots[i]), &v[i * kFeatureDim], kFeatureDim * 4);
        dst.adam_steps(slots[i]) = steps[i];
      }
      im.downloaded += int64_t(n);
    }
    im.tracking = false;
  }
  RIM_CUDA(cudaMemcpy(map->level(0).flag_data(), im.flags0.get(), size_t(im.levels[0].slots),
                      cudaMemcpyDeviceToHost));
  if (decoder != nullptr) RIM_RETURN_IF_ERROR(DownloadDecoder(decoder));
  return absl::OkStatus();
}

int64_t DeviceMap::rows_uploaded() const { return impl_->uploaded; }
int64_t DeviceMap::rows_downloaded() const { return impl_->downloaded; }

absl::Status DeviceMap::Encode(const float* xyz, int n, float* features) {
  Impl& im = *impl_;
  if (n < 0) return absl::InvalidArgumentError("Encode: negative point count");
  if (n == 0) return absl::OkStatus();
  const size_t F = size_t(im.shape.levels) * kFeatureDim;
  RIM_RETURN_IF_ERROR(im.query_xyz.Allocate(size_t(n) * 3, &im.bytes));
  RIM_RETURN_IF_ERROR(im.query_sdf.Allocate(size_t(n) * F, &im.bytes));
  RIM_CUDA(
      cudaMemcpyAsync(im.query_xyz.get(), xyz, size_t(n) * 12, cudaMemcpyHostToDevice, im.stream));
  RIM_RETURN_IF_ERROR(im.Poison(im.query_sdf.get(), size_t(n) * F * 4));
  RIM_CUDA(LaunchEncode(im.grids, im.query_xyz.get(), n, im.query_sdf.get(), im.stream));
  RIM_CUDA(cudaMemcpyAsync(features, im.query_sdf.get(), size_t(n) * F * 4, cudaMemcpyDeviceToHost,
                           im.stream));
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  return absl::OkStatus();
}

absl::Status DeviceMap::Query(const float* xyz, int n, float* sdf, float* gradient) {
  Impl& im = *impl_;
  if (n < 0) return absl::InvalidArgumentError("Query: negative point count");
  if (n == 0) return absl::OkStatus();
  RIM_RETURN_IF_ERROR(im.query_xyz.Allocate(size_t(n) * 3, &im.bytes));
  RIM_RETURN_IF_ERROR(im.query_sdf.Allocate(size_t(n), &im.bytes));
  if (gradient != nullptr) RIM_RETURN_IF_ERROR(im.query_grad.Allocate(size_t(n) * 3, &im.bytes));
  RIM_CUDA(
      cudaMemcpyAsync(im.query_xyz.get(), xyz, size_t(n) * 12, cudaMemcpyHostToDevice, im.stream));
  RIM_RETURN_IF_ERROR(im.Poison(im.query_sdf.get(), size_t(n) * 4));
  if (gradient != nullptr) RIM_RETURN_IF_ERROR(im.Poison(im.query_grad.get(), size_t(n) * 12));
  RIM_CUDA(LaunchQuery(im.grids, im.shape, im.dparams.get(), im.query_xyz.get(), n,
                       im.query_sdf.get(), gradient != nullptr ? im.query_grad.get() : nullptr,
                       im.stream));
  RIM_CUDA(
      cudaMemcpyAsync(sdf, im.query_sdf.get(), size_t(n) * 4, cudaMemcpyDeviceToHost, im.stream));
  if (gradient != nullptr) {
    RIM_CUDA(cudaMemcpyAsync(gradient, im.query_grad.get(), size_t(n) * 12, cudaMemcpyDeviceToHost,
                             im.stream));
  }
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  return absl::OkStatus();
}

absl::StatusOr<float> DeviceMap::Backward(const float* xyz, int rows, int labelled,
                                          const float* labels, const TrainSettings& settings,
                                          bool train_decoder) {
  Impl& im = *impl_;
  if (rows < 0 || labelled < 0 || labelled > rows) {
    return absl::InvalidArgumentError(
        absl::StrCat("training batch: bad shape (rows ", rows, ", labelled ", labelled, ")"));
  }
  if (!(settings.sigma_m > 0.f) || !(settings.eikonal_step_m > 0.f)) {
    return absl::InvalidArgumentError("training batch: sigma_m and eikonal_step_m must be > 0");
  }
  if (!im.stepped) {
    return absl::FailedPreconditionError("Backward called twice without Step in between");
  }
  if (rows == 0) {
    im.rows = im.labelled = 0;
    im.have_batch = false;
    return 0.f;
  }
  const size_t F = size_t(im.shape.levels) * kFeatureDim;
  RIM_RETURN_IF_ERROR(im.xyz.Allocate(size_t(rows) * 3, &im.bytes));
  RIM_RETURN_IF_ERROR(im.labels.Allocate(size_t(std::max(labelled, 1)), &im.bytes));
  RIM_RETURN_IF_ERROR(im.features.Allocate(size_t(rows) * F, &im.bytes));
  RIM_RETURN_IF_ERROR(im.y.Allocate(size_t(rows), &im.bytes));
  RIM_RETURN_IF_ERROR(im.dy.Allocate(size_t(rows), &im.bytes));
  for (size_t l = 0; l < im.levels.size(); ++l) {
    Impl::Level& lv = im.levels[l];
    const size_t before = lv.touched.size();
    RIM_RETURN_IF_ERROR(lv.touched.Allocate(size_t(rows) * 8, &im.bytes));
    if (lv.touched.size() != before) im.grids.level[l].touched = lv.touched.get();
  }
  RIM_CUDA(
      cudaMemcpyAsync(im.xyz.get(), xyz, size_t(rows) * 12, cudaMemcpyHostToDevice, im.stream));
  if (labelled > 0) {
    RIM_CUDA(cudaMemcpyAsync(im.labels.get(), labels, size_t(labelled) * 4, cudaMemcpyHostToDevice,
                             im.stream));
  }
  im.rows = rows;
  im.labelled = labelled;
  im.have_batch = true;
  // A point outside the box changes nothing: the check runs first on the device, and every later
  // kernel (the forward pass's flag marking, the Adam passes) does nothing once it failed.
  RIM_RETURN_IF_ERROR(im.EnqueueBackward(settings, train_decoder));
  double sums[2];
  int32_t error = 0;
  RIM_CUDA(cudaMemcpyAsync(sums, im.sums.get(), sizeof(sums), cudaMemcpyDeviceToHost, im.stream));
  RIM_CUDA(cudaMemcpyAsync(&error, im.error.get(), 4, cudaMemcpyDeviceToHost, im.stream));
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  if (error != 0) {
    const int r = error - 1;
    im.stepped = true;
    im.have_batch = false;
    return absl::InvalidArgumentError(absl::StrCat("training batch: point ", r, " (", xyz[3 * r],
                                                   ", ", xyz[3 * r + 1], ", ", xyz[3 * r + 2],
                                                   ") is outside the local box or not a number"));
  }
  const int groups = settings.eikonal_weight > 0.f ? (rows - labelled) / 6 : 0;
  double loss = labelled > 0 ? sums[0] / labelled : 0.0;
  if (groups > 0) loss += double(settings.eikonal_weight) * sums[1] / groups;
  return float(loss);
}

absl::Status DeviceMap::Step(const TrainSettings& settings, bool train_decoder) {
  Impl& im = *impl_;
  if (im.stepped) return absl::OkStatus();  // nothing prepared (or an empty batch)
  // No wait here: the next Backward, a sync or a download waits for the stream, and reports a
  // failed launch.
  RIM_RETURN_IF_ERROR(im.EnqueueStep(settings, train_decoder));
  return absl::OkStatus();
}

absl::StatusOr<float> DeviceMap::Iterate(const float* xyz, int rows, int labelled,
                                         const float* labels, const TrainSettings& settings,
                                         bool train_decoder) {
  absl::StatusOr<float> loss = Backward(xyz, rows, labelled, labels, settings, train_decoder);
  if (!loss.ok()) return loss;
  RIM_RETURN_IF_ERROR(Step(settings, train_decoder));
  return loss;
}

absl::Status DeviceMap::DownloadGradients(int level, std::vector<float>* dense) const {
  const Impl& im = *impl_;
  if (level < 0 || level >= int(im.levels.size())) {
    return absl::InvalidArgumentError(absl::StrCat("no level ", level));
  }
  const Impl::Level& lv = im.levels[size_t(level)];
  dense->resize(size_t(lv.slots) * kFeatureDim);
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  RIM_CUDA(cudaMemcpy(dense->data(), lv.grad.get(), dense->size() * 4, cudaMemcpyDeviceToHost));
  return absl::OkStatus();
}

absl::Status DeviceMap::DownloadDecoderGradient(std::vector<float>* grad) const {
  const Impl& im = *impl_;
  grad->resize(size_t(im.params));
  RIM_CUDA(cudaStreamSynchronize(im.stream));
  RIM_CUDA(cudaMemcpy(grad->data(), im.dgrad.get(), grad->size() * 4, cudaMemcpyDeviceToHost));
  return absl::OkStatus();
}

void DeviceMap::set_poison(bool on) { impl_->poison = on; }

absl::StatusOr<double> DeviceMap::TimeQueries(int n, bool gradient, int reps, uint64_t seed) {
  Impl& im = *impl_;
  if (n <= 0 || reps <= 0) return absl::InvalidArgumentError("TimeQueries: n and reps must be > 0");
  RIM_RETURN_IF_ERROR(im.query_xyz.Allocate(size_t(n) * 3, &im.bytes));
  RIM_RETURN_IF_ERROR(im.query_sdf.Allocate(size_t(n), &im.bytes));
  RIM_RETURN_IF_ERROR(im.query_grad.Allocate(size_t(n) * 3, &im.bytes));
  const LevelView& coarse = im.grids.level[im.shape.levels - 1];
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    const double h = 1.0 / coarse.inv_h;
    lo[a] = coarse.lo[a] * h + 1e-3;
    hi[a] = (coarse.lo[a] + coarse.cells[a]) * h - 1e-3;
  }
  RIM_CUDA(LaunchRandomPoints(lo, hi, n, seed, im.query_xyz.get(), im.stream));
  cudaEvent_t start, stop;
  RIM_CUDA(cudaEventCreate(&start));
  RIM_CUDA(cudaEventCreate(&stop));
  std::vector<double> ms;
  absl::Status status;
  for (int r = 0; r <= reps && status.ok(); ++r) {
    status.Update(CudaStatus(cudaEventRecord(start, im.stream), "cudaEventRecord"));
    status.Update(CudaStatus(
        LaunchQuery(im.grids, im.shape, im.dparams.get(), im.query_xyz.get(), n, im.query_sdf.get(),
                    gradient ? im.query_grad.get() : nullptr, im.stream),
        "LaunchQuery"));
    status.Update(CudaStatus(cudaEventRecord(stop, im.stream), "cudaEventRecord"));
    status.Update(CudaStatus(cudaEventSynchronize(stop), "cudaEventSynchronize"));
    float t = 0;
    status.Update(CudaStatus(cudaEventElapsedTime(&t, start, stop), "cudaEventElapsedTime"));
    if (r > 0) ms.push_back(t);  // the first run warms up
  }
  cudaEventDestroy(start);
  cudaEventDestroy(stop);
  if (!status.ok()) return status;
  return Median(ms);
}

absl::Status DeviceMap::EnqueueIterations(int count, const TrainSettings& settings,
                                          bool train_decoder) {
  Impl& im = *impl_;
  if (!im.have_batch) return absl::FailedPreconditionError("no batch: call Backward first");
  if (!im.stepped) RIM_RETURN_IF_ERROR(im.EnqueueStep(settings, train_decoder));
  for (int i = 0; i < count; ++i) {
    RIM_RETURN_IF_ERROR(im.EnqueueBackward(settings, train_decoder));
    RIM_RETURN_IF_ERROR(im.EnqueueStep(settings, train_decoder));
  }
  return absl::OkStatus();
}

absl::Status DeviceMap::Synchronize() {
  RIM_CUDA(cudaStreamSynchronize(impl_->stream));
  return absl::OkStatus();
}

absl::StatusOr<double> DeviceMap::TimeIterations(int reps, const TrainSettings& settings,
                                                 bool train_decoder) {
  Impl& im = *impl_;
  if (reps <= 0) return absl::InvalidArgumentError("TimeIterations: reps must be > 0");
  cudaEvent_t start, stop;
  RIM_CUDA(cudaEventCreate(&start));
  RIM_CUDA(cudaEventCreate(&stop));
  std::vector<double> ms;
  absl::Status status;
  for (int r = 0; r <= reps && status.ok(); ++r) {
    status.Update(CudaStatus(cudaEventRecord(start, im.stream), "cudaEventRecord"));
    status.Update(EnqueueIterations(1, settings, train_decoder));
    status.Update(CudaStatus(cudaEventRecord(stop, im.stream), "cudaEventRecord"));
    status.Update(CudaStatus(cudaEventSynchronize(stop), "cudaEventSynchronize"));
    float t = 0;
    status.Update(CudaStatus(cudaEventElapsedTime(&t, start, stop), "cudaEventElapsedTime"));
    if (r > 0) ms.push_back(t);
  }
  cudaEventDestroy(start);
  cudaEventDestroy(stop);
  if (!status.ok()) return status;
  return Median(ms);
}

absl::StatusOr<DeviceMap::StageTimes> DeviceMap::TimeStages(int reps, const TrainSettings& settings,
                                                            bool train_decoder) {
  Impl& im = *impl_;
  if (reps <= 0) return absl::InvalidArgumentError("TimeStages: reps must be > 0");
  for (cudaEvent_t& e : im.marks) RIM_CUDA(cudaEventCreate(&e));
  std::vector<std::vector<double>> ms(8);
  absl::Status status;
  for (int r = 0; r <= reps && status.ok(); ++r) {
    im.marking = true;
    status.Update(EnqueueIterations(1, settings, train_decoder));
    im.marking = false;
    status.Update(CudaStatus(cudaEventSynchronize(im.marks[8]), "cudaEventSynchronize"));
    for (int i = 0; i < 8 && status.ok() && r > 0; ++i) {
      float t = 0;
      status.Update(CudaStatus(cudaEventElapsedTime(&t, im.marks[i], im.marks[i + 1]),
                               "cudaEventElapsedTime"));
      ms[size_t(i)].push_back(t);
    }
  }
  for (cudaEvent_t& e : im.marks) {
    cudaEventDestroy(e);
    e = nullptr;
  }
  if (!status.ok()) return status;
  StageTimes st;
  st.memsets = Median(ms[0]);
  st.check = Median(ms[1]);
  st.forward = Median(ms[2]);
  st.loss = Median(ms[3]);
  st.backward = Median(ms[4]);
  st.scatter = Median(ms[5]);
  st.feature_adam = Median(ms[6]);
  st.decoder_adam = Median(ms[7]);
  return st;
}

int64_t DeviceMap::device_bytes() const { return impl_->bytes; }
const DeviceInfo& DeviceMap::device() const { return impl_->info; }

}  // namespace rim::gpu
