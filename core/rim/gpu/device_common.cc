// The parts of the GPU path's interface that every build has, CUDA or not.
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "rim/gpu/device_map.h"

namespace rim::gpu {

absl::StatusOr<int> CudaDeviceIndex(const std::string& device) {
  if (device == "cuda") return 0;
  int index = -1;
  if (device.rfind("cuda:", 0) == 0 && absl::SimpleAtoi(device.substr(5), &index) && index >= 0 &&
      index < 64) {
    return index;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("train.device: '", device, "' is not cpu, cuda or cuda:N"));
}

TrainSettings TrainSettings::From(const MapperConfig& config, const MapGeometry& geometry) {
  TrainSettings s;
  s.sigma_m = config.train.sigma_m;
  s.eikonal_weight = config.train.eikonal_weight;
  s.eikonal_step_m = float(0.5 * geometry.leaf_m());
  s.observed_band_m = config.sampler.observed_band_m;
  s.adam = {config.train.learning_rate, config.train.adam_beta1, config.train.adam_beta2,
            config.train.adam_eps};
  return s;
}

}  // namespace rim::gpu
