// The shallow MLP decoder (§3.1): L·D features → hidden ReLU layers → SDF. Parameters live in one
// contiguous buffer (weights then bias, per layer) with their Adam state, so that training
// (train_step.cc, through libtorch autograd), queries (plain C++ here) and persistence all share
// one copy. The plain forward is deterministic: the same input gives bit-identical output
// whatever the batch, which seamless meshing across tiles relies on.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "absl/status/status.h"
#include "rim/base/binary_io.h"
#include "rim/config/config.h"

namespace rim {

struct AdamHyper {
  float lr, beta1, beta2, eps;
};

// One Adam update of n parameters with their own step count (already incremented, ≥ 1).
void AdamUpdate(const AdamHyper& h, int step, int n, const float* grad, float* param, float* m,
                float* v);

// Adam's bias corrections per step count, computed once: the sparse feature update runs one
// small Adam row per touched voxel, and two pow() calls per row would dominate it. Filled in the
// constructor and read-only afterwards, so threads may share it. Past the table's end (the
// first step where β₁ᵗ and β₂ᵗ are both below 1e-9, at most 2²¹ steps) the corrections are the
// last entry's: they equal 1 to float precision there.
class AdamBiasTable {
 public:
  explicit AdamBiasTable(const AdamHyper& h);
  // lr / (1 − β1^t) and 1 / sqrt(1 − β2^t).
  void Get(int step, float* step_size, float* inv_sqrt_bc2) const {
    const size_t t = std::min(size_t(step < 0 ? 0 : step), step_size_.size() - 1);
    *step_size = step_size_[t];
    *inv_sqrt_bc2 = inv_sqrt_bc2_[t];
  }

 private:
  std::vector<float> step_size_, inv_sqrt_bc2_;
};

// Adam update with the bias corrections given.
inline void AdamUpdateRow(const AdamHyper& h, float step_size, float inv_sqrt_bc2, int n,
                          const float* grad, float* param, float* m, float* v);

inline void AdamUpdateRow(const AdamHyper& h, float step_size, float inv_sqrt_bc2, int n,
                          const float* grad, float* param, float* m, float* v) {
  for (int i = 0; i < n; ++i) {
    m[i] = h.beta1 * m[i] + (1.f - h.beta1) * grad[i];
    v[i] = h.beta2 * v[i] + (1.f - h.beta2) * grad[i] * grad[i];
    param[i] -= step_size * m[i] / (std::sqrt(v[i]) * inv_sqrt_bc2 + h.eps);
  }
}

// The same update for a row of compile-time length N, unrolled. Element for element the same
// arithmetic as AdamUpdateRow, so the results are bit-identical. The compiler may still leave it
// scalar (it did for the local map's rows, whose m and v share a record); x86 builds of the
// trainer use an explicit SSE row instead (trainer.cc).
template <int N>
inline void AdamUpdateFixedRow(const AdamHyper& h, float step_size, float inv_sqrt_bc2,
                               const float* grad, float* param, float* m, float* v) {
  float mm[N], vv[N], pp[N];
  for (int i = 0; i < N; ++i) {
    mm[i] = h.beta1 * m[i] + (1.f - h.beta1) * grad[i];
    vv[i] = h.beta2 * v[i] + (1.f - h.beta2) * grad[i] * grad[i];
    pp[i] = param[i] - step_size * mm[i] / (std::sqrt(vv[i]) * inv_sqrt_bc2 + h.eps);
  }
  for (int i = 0; i < N; ++i) {
    m[i] = mm[i];
    v[i] = vv[i];
    param[i] = pp[i];
  }
}

class Decoder {
 public:
  struct Layer {
    int in, out;
    size_t weight_offset, bias_offset;  // into params()
  };

  Decoder(int input_dim, const DecoderConfig& config);

  int input_dim() const { return input_dim_; }
  const std::vector<Layer>& layers() const { return layers_; }
  std::vector<float>& params() { return params_; }
  const std::vector<float>& params() const { return params_; }

  // SDF of n feature rows; with `dsdf_dfeatures` (n × input_dim) also the derivative of each
  // output with respect to its input row.
  void Forward(const float* features, int n, float* sdf, float* dsdf_dfeatures = nullptr) const;

  // Adam step on all parameters from their gradient (same layout as params()).
  void Step(const AdamHyper& hyper, const std::vector<float>& grad);
  // The optimiser's state, for a copy kept elsewhere (the GPU path's): step count and moments.
  int adam_step() const { return adam_step_; }
  const std::vector<float>& adam_m() const { return adam_m_; }
  const std::vector<float>& adam_v() const { return adam_v_; }
  absl::Status SetAdamState(int step, const std::vector<float>& m, const std::vector<float>& v);

  void Serialize(ByteWriter* w) const;
  absl::Status Deserialize(ByteReader* r);

 private:
  // Forward without the gradient, points in blocks across SIMD lanes (same bits per point).
  void ForwardBlocked(const float* features, int n, float* sdf) const;
  // Forward with d sdf / d features, the same way (same bits per point as one at a time).
  void ForwardGradBlocked(const float* features, int n, float* sdf, float* dsdf) const;

  int input_dim_;
  std::vector<Layer> layers_;
  std::vector<float> params_, adam_m_, adam_v_;
  int adam_step_ = 0;
  int max_width_ = 1;
};

}  // namespace rim
