// The training step's decoder part (loss, its gradient with respect to the encoded features and
// to the decoder's parameters) written out by hand: dense Eigen products over the batch, or for
// the presets' one-hidden-layer decoder, AVX2/FMA kernels where the CPU has them.
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
#include "rim/base/worker_pool.h"
#include "rim/model/decoder.h"
#include "rim/train/train_step.h"

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

  // The decoder of every preset (one hidden layer, input and hidden widths multiples of 8, up
  // to 64) goes through hand-written AVX2/FMA kernels for the forward pass and the feature
  // gradient when the CPU has those instructions (checked at run time; the build stays
  // baseline x86-64). Off, or on other CPUs and shapes: the Eigen products. The two agree to
  // float rounding; each is the same for any thread count.
  static bool VectorKernelsAvailable();
  void set_vector_kernels(bool on) { vector_kernels_ = on; }

 private:
  using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  struct Work {
    RowMatrix grad, grad_prev;  // d loss / d (pre-activation) of the layer being back-propagated
  };
  std::vector<RowMatrix> act_;  // per layer: its output, after ReLU for the hidden layers
  RowMatrix grad_;              // d loss / d output, n × 1
  std::vector<Work> work_;      // per chunk
  std::vector<std::vector<float>> chunk_grad_params_;
  std::vector<float> w0_transposed_;  // first layer's weights, in × out, for the kernels
  std::vector<double> chunk_loss_;    // per chunk: its labelled rows' loss terms
  bool vector_kernels_ = true;
};

}  // namespace rim
