// A build without libtorch (RIM_TORCH=OFF: the GPU path's carried build, docs/gpu.md). The
// hand-written training step is unaffected; the two libtorch references report that they are
// missing, and train.step = libtorch | reference fails with that error at the first iteration.
#include "rim/base/version.h"
#include "rim/train/train_step.h"

namespace rim {
namespace {
absl::Status NoTorch(const char* what) {
  return absl::FailedPreconditionError(
      std::string(what) +
      " needs libtorch, and this build has none (RIM_TORCH=OFF); use "
      "train.step = fast, or a build with libtorch");
}
}  // namespace

std::string TorchVersion() { return "none"; }

absl::StatusOr<TrainStepOutput> RunTrainStep(const Decoder&, const TrainStepInput&) {
  return NoTorch("train.step = libtorch");
}

struct ReferenceTrainer::State {};

ReferenceTrainer::ReferenceTrainer(const MapperConfig& config, LocalMap* map, Decoder* decoder,
                                   bool)
    : config_(config), map_(map), decoder_(decoder), state_(std::make_unique<State>()) {}

ReferenceTrainer::~ReferenceTrainer() = default;

absl::StatusOr<float> ReferenceTrainer::Iterate(const float*, const float*, int, bool) {
  return NoTorch("train.step = reference");
}

}  // namespace rim
