// The training step's decoder part (loss, its gradient with respect to the encoded features and
// to the decoder's parameters) written out by hand as dense Eigen products over the batch.
//
// It computes what RunTrainStep (train_step.h, libtorch autograd) computes, without libtorch's
// per-operation overhead and without a BLAS library: the decoder is a few narrow layers, so a
// batch of 20k samples is three or four small matrix products that Eigen's own kernels run
// in about 2–3 ms on one core. libtorch stays the reference the tests compare against
// (train.step = "libtorch" selects it at run time).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "absl/status/status.h"
#include "rim/decoder.h"
#include "rim/train_step.h"

namespace rim {

class MlpTrainStep {
 public:
  // Fills `out` (loss, grad_features, grad_params when in.train_decoder, forward_s, backward_s).
  // Reuses its buffers across calls: after the first iteration nothing is allocated.
  absl::Status Run(const Decoder& decoder, const TrainStepInput& in, TrainStepOutput* out);

 private:
  using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  std::vector<RowMatrix> act_;  // per layer: its output, after ReLU for the hidden layers
  RowMatrix grad_, grad_prev_;  // d loss / d (pre-activation) of the layer being back-propagated
};

}  // namespace rim
