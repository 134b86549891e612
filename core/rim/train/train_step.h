// The loss and its gradients for one training iteration (§3.1 "Loss"), through libtorch autograd.
// The only core translation unit that includes libtorch.
#pragma once

#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/model/decoder.h"

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

// The reference training iteration, written the way a PyTorch implementation does it: the
// encoding as libtorch ops (gather of the 8 corners per level, trilinear weights) over the dense
// grids of the local map as leaf tensors, the loss and backward through autograd, and a dense
// Adam step over every row of every grid and the decoder with one global step count. It is
// slow on purpose (it touches the whole local map each iteration) and serves as the correctness
// reference for Trainer's fast path: on a batch whose touched rows are the same each iteration,
// lazy Adam with per-row step counts and dense Adam with a global one give the same updates, so
// tests can compare losses and parameters; `Iteration/reference` in rim_bench measures the
// ratio. Without the eikonal term (the fast path's probes are not built here).
class ReferenceTrainer {
 public:
  // The dense moments start at zero in tensors of their own; with `moments_in_map` they are the
  // local map's own moment records instead (as views, starting from what they hold), so that a
  // slot the box recycles starts from zero moments as in the fast path (a whole mapping session,
  // train.step = reference). A map trained that way must not be trained by a Trainer too.
  ReferenceTrainer(const MapperConfig& config, LocalMap* map, Decoder* decoder,
                   bool moments_in_map = false);
  ~ReferenceTrainer();
  // One iteration on n samples (xyz: 3n floats inside the box; labels: n); updates the map's
  // features and, when train_decoder, the decoder's parameters in place. Returns the loss.
  absl::StatusOr<float> Iterate(const float* xyz, const float* labels, int n, bool train_decoder);

 private:
  struct State;
  MapperConfig config_;
  LocalMap* map_;
  Decoder* decoder_;
  std::unique_ptr<State> state_;
};

}  // namespace rim
