// The loss and its gradients for one training iteration (§3.1 "Loss"), through libtorch autograd.
// The only core translation unit that includes libtorch.
#pragma once

#include <vector>

#include "absl/status/statusor.h"
#include "rim/decoder.h"

namespace rim {

struct TrainStepInput {
  // Encoded features, rows × decoder input_dim. Rows [0, labelled) are labelled samples; the
  // rows after them come in groups of 6 eikonal probes (+x, −x, +y, −y, +z, −z around a point).
  float* features = nullptr;
  int rows = 0;
  int labelled = 0;
  const float* labels = nullptr;  // labelled entries, metres
  float sigma_m = 0.05f;
  float eikonal_weight = 0.f;
  float eikonal_step_m = 0.05f;  // probe offset h: gradient by central differences over 2h
  bool train_decoder = true;
};

struct TrainStepOutput {
  float loss = 0.f;
  std::vector<float> grad_features;  // rows × input_dim: d loss / d features
  std::vector<float> grad_params;    // like Decoder::params(); empty when the decoder is frozen
  double forward_s = 0, backward_s = 0;
};

// Loss = BCE(S(label), S(prediction)) with S(d) = 1/(1+exp(d/σ)), computed from logits −pred/σ
// so that it stays finite for any SDF, plus the optional eikonal term w·mean((|∇f|−1)²).
// Converts libtorch exceptions to a status.
absl::StatusOr<TrainStepOutput> RunTrainStep(const Decoder& decoder, const TrainStepInput& in);

}  // namespace rim
