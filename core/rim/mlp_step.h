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
#include "rim/worker_pool.h"

namespace rim {

class MlpTrainStep {
 public:
  // Fills `out` (loss, grad_features, grad_params when in.train_decoder, forward_s, backward_s).
  // Reuses its buffers across calls: after the first iteration nothing is allocated. Rows go in
  // fixed chunks of kChunkRows, spread over `pool` when one is given; the result is the same
  // for any thread count.
  absl::Status Run(const Decoder& decoder, const TrainStepInput& in, TrainStepOutput* out,
                   WorkerPool* pool = nullptr);

  static constexpr int kChunkRows = 2048;

 private:
  using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  struct Work {
    RowMatrix grad, grad_prev;  // d loss / d (pre-activation) of the layer being back-propagated
  };
  std::vector<RowMatrix> act_;  // per layer: its output, after ReLU for the hidden layers
  RowMatrix grad_;              // d loss / d output, n × 1
  std::vector<Work> work_;      // per chunk
  std::vector<std::vector<float>> chunk_grad_params_;
};

}  // namespace rim
