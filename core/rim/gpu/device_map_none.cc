// A build without the CUDA path (RIM_CUDA=OFF, the CPU build and CI): OpenDevice and
// DeviceMap::Create name the missing build option, so `train.device = cuda` fails with that error;
// no DeviceMap can exist, and its other members are never reached.
#include "rim/gpu/device_map.h"

namespace rim::gpu {
namespace {
absl::Status NoCuda() {
  return absl::FailedPreconditionError(
      "this build has no CUDA path: configure with -DRIM_CUDA=ON on a machine with the CUDA "
      "toolkit (docs/gpu.md)");
}
const DeviceInfo kNoDevice;
}  // namespace

struct DeviceMap::Impl {};

bool BuiltWithCuda() { return false; }
absl::StatusOr<DeviceInfo> OpenDevice(int) { return NoCuda(); }

DeviceMap::DeviceMap() = default;
DeviceMap::~DeviceMap() = default;
absl::StatusOr<std::unique_ptr<DeviceMap>> DeviceMap::Create(const LocalMap&, const Decoder&, int) {
  return NoCuda();
}
absl::Status DeviceMap::Upload(const LocalMap&) { return NoCuda(); }
absl::Status DeviceMap::Download(LocalMap*) const { return NoCuda(); }
absl::Status DeviceMap::UploadDecoder(const Decoder&) { return NoCuda(); }
absl::Status DeviceMap::DownloadDecoder(Decoder*) const { return NoCuda(); }
absl::Status DeviceMap::SyncFromHost(const LocalMap&) { return NoCuda(); }
absl::Status DeviceMap::SyncToHost(LocalMap*, Decoder*) { return NoCuda(); }
int64_t DeviceMap::rows_uploaded() const { return 0; }
int64_t DeviceMap::rows_downloaded() const { return 0; }
absl::Status DeviceMap::Encode(const float*, int, float*) { return NoCuda(); }
absl::Status DeviceMap::Query(const float*, int, float*, float*) { return NoCuda(); }
absl::StatusOr<float> DeviceMap::Backward(const float*, int, int, const float*,
                                          const TrainSettings&, bool) {
  return NoCuda();
}
absl::Status DeviceMap::Step(const TrainSettings&, bool) { return NoCuda(); }
absl::StatusOr<float> DeviceMap::Iterate(const float*, int, int, const float*, const TrainSettings&,
                                         bool) {
  return NoCuda();
}
absl::Status DeviceMap::DownloadGradients(int, std::vector<float>*) const { return NoCuda(); }
absl::Status DeviceMap::DownloadDecoderGradient(std::vector<float>*) const { return NoCuda(); }
void DeviceMap::set_poison(bool) {}
absl::StatusOr<double> DeviceMap::TimeQueries(int, bool, int, uint64_t) { return NoCuda(); }
absl::StatusOr<double> DeviceMap::TimeIterations(int, const TrainSettings&, bool) {
  return NoCuda();
}
absl::Status DeviceMap::EnqueueIterations(int, const TrainSettings&, bool) { return NoCuda(); }
absl::StatusOr<DeviceMap::StageTimes> DeviceMap::TimeStages(int, const TrainSettings&, bool) {
  return NoCuda();
}
absl::Status DeviceMap::Synchronize() { return NoCuda(); }
int64_t DeviceMap::device_bytes() const { return 0; }
const DeviceInfo& DeviceMap::device() const { return kNoDevice; }

}  // namespace rim::gpu
