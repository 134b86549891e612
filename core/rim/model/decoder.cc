#include "rim/model/decoder.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"

namespace rim {

void AdamUpdate(const AdamHyper& h, int step, int n, const float* grad, float* param, float* m,
                float* v) {
  // Bias corrections in double, as torch::optim::Adam does: 1 − β^t in float cancels badly for
  // small t (≈ 7e-6 relative error in 1 − β₂² already).
  const double bc1 = 1.0 - std::pow(double(h.beta1), step);
  const double bc2 = 1.0 - std::pow(double(h.beta2), step);
  AdamUpdateRow(h, float(double(h.lr) / bc1), float(1.0 / std::sqrt(bc2)), n, grad, param, m, v);
}

AdamBiasTable::AdamBiasTable(const AdamHyper& h) {
  constexpr int kMaxSteps = 1 << 21;
  for (int t = 0;; ++t) {
    const double b1t = std::pow(double(h.beta1), t), b2t = std::pow(double(h.beta2), t);
    step_size_.push_back(t == 0 ? 0.f : float(double(h.lr) / (1.0 - b1t)));
    inv_sqrt_bc2_.push_back(t == 0 ? 0.f : float(1.0 / std::sqrt(1.0 - b2t)));
    if ((t > 0 && b1t < 1e-9 && b2t < 1e-9) || t == kMaxSteps) break;
  }
}

Decoder::Decoder(int input_dim, const DecoderConfig& config) : input_dim_(input_dim) {
  int in = input_dim;
  size_t offset = 0;
  for (int k = 0; k <= config.hidden_layers; ++k) {
    const int out = k == config.hidden_layers ? 1 : config.hidden_width;
    layers_.push_back({in, out, offset, offset + size_t(in) * out});
    offset += size_t(in) * out + out;
    max_width_ = std::max(max_width_, std::max(in, out));
    in = out;
  }
  params_.resize(offset);
  adam_m_.assign(offset, 0.f);
  adam_v_.assign(offset, 0.f);
  // Uniform(±1/sqrt(fan_in)) for weights and biases, from our own seeded generator so that a
  // session's initialisation does not depend on any global random state.
  std::mt19937_64 rng(config.seed);
  for (const Layer& L : layers_) {
    const float bound = 1.f / std::sqrt(float(L.in));
    std::uniform_real_distribution<float> u(-bound, bound);
    for (size_t i = L.weight_offset; i < L.bias_offset + L.out; ++i) params_[i] = u(rng);
  }
}

void Decoder::Forward(const float* features, int n, float* sdf, float* dsdf_dfeatures) const {
  if (dsdf_dfeatures == nullptr) {
    ForwardBlocked(features, n, sdf);
    return;
  }
  ForwardGradBlocked(features, n, sdf, dsdf_dfeatures);
}

namespace {
// The layers of one block of kLanes points, activations lane-minor (a[i·kLanes + j] is input i of
// point j): the innermost loops run across points and vectorise. Each lane does exactly the
// one-point loop's arithmetic in the same order (bias, then the products added one input at a
// time); multiplies and adds stay separate (no fused multiply-add in either path), so the bits
// are the same whatever vector width the compiler picks.
constexpr int kLanes = 8;

// One block's lane values as a vector: the compiler maps it to one AVX register, or two SSE ones
// in the baseline build. Its arithmetic is lane-wise, so each lane computes the same bits as the
// one-point loop. The accumulators of a group live in registers; as arrays of floats the compiler
// kept them on the stack, a load and a store around every add.
using Lanes = float __attribute__((vector_size(kLanes * sizeof(float))));

// Lanes are loaded and stored by memcpy (no alignment needed) and never passed by value, so no
// function signature depends on the vector ABI of a target.
#define RIM_LOAD_LANES(v, p) __builtin_memcpy(&(v), (p), sizeof(Lanes))
#define RIM_STORE_LANES(p, v) __builtin_memcpy((p), &(v), sizeof(Lanes))

// Outputs o, o + G, ... of layer L in groups of G (while a whole group fits), for one block of
// kLanes points; returns the first output not done.
template <int G, typename Layer>
__attribute__((always_inline)) inline int OutputGroups(const Layer& L, const float* W,
                                                       const float* b, bool relu, const float* in,
                                                       float* out, int o) {
  for (; o + G <= L.out; o += G) {
    Lanes s[G];
    const float* w[G];
    for (int q = 0; q < G; ++q) {
      w[q] = W + size_t(o + q) * L.in;
      float bias[kLanes];
      std::fill_n(bias, kLanes, b[o + q]);
      RIM_LOAD_LANES(s[q], bias);
    }
    for (int i = 0; i < L.in; ++i) {
      Lanes x;
      RIM_LOAD_LANES(x, in + size_t(i) * kLanes);
      for (int q = 0; q < G; ++q) s[q] += w[q][i] * x;
    }
    const Lanes zero = {};
    for (int q = 0; q < G; ++q) {
      // std::max(s, 0.f): zero where s < 0, else s (so -0 and NaN stay as they are).
      const Lanes r = relu ? (s[q] < zero ? zero : s[q]) : s[q];
      RIM_STORE_LANES(out + (o + q) * kLanes, r);
    }
  }
  return o;
}

template <typename Layers>
__attribute__((always_inline)) inline const float* LayersForBlock(const Layers& layers,
                                                                  const float* params, float* in,
                                                                  float* out) {
  const int nl = int(layers.size());
  for (int k = 0; k < nl; ++k) {
    const auto& L = layers[k];
    const float* W = params + L.weight_offset;
    const float* b = params + L.bias_offset;
    const bool relu = k + 1 < nl;
    int o = 0;
    // Several outputs at a time: independent chains of adds (eight hide the add latency on
    // current cores; four where fewer are left), each output's sum still taken in the one-point
    // order.
    o = OutputGroups<8>(L, W, b, relu, in, out, o);
    o = OutputGroups<4>(L, W, b, relu, in, out, o);
    OutputGroups<1>(L, W, b, relu, in, out, o);
    std::swap(in, out);
  }
  return in;
}

// Blocks of points through the layers; a short last block is padded with zero features.
// Always inlined, so that each caller compiles it for its own target (AVX2 or baseline).
template <typename Layers>
__attribute__((always_inline)) inline void ForwardBlocks(const Layers& layers, const float* params,
                                                         int input_dim, int max_width,
                                                         const float* features, int n, float* sdf) {
  std::vector<float> buf(size_t(2) * max_width * kLanes);
  for (int p0 = 0; p0 < n; p0 += kLanes) {
    const int m = std::min(kLanes, n - p0);
    float* a = buf.data();
    for (int i = 0; i < input_dim; ++i)
      for (int j = 0; j < kLanes; ++j)
        a[i * kLanes + j] = j < m ? features[size_t(p0 + j) * input_dim + i] : 0.f;
    const float* y = LayersForBlock(layers, params, a, a + size_t(max_width) * kLanes);
    for (int j = 0; j < m; ++j) sdf[p0 + j] = y[j];
  }
}

// Input gradients g[i] = sum over outputs o, in order, of delta[o]·W[o][i], for inputs i, i + 1,
// ... in groups of G, one block of kLanes points; returns the first input not done. Each sum stays
// in registers across the outputs. The one-point loop skips outputs whose delta is zero (the ReLU
// was off); adding their product instead gives the same bits: it is ±0, a sum that starts at +0
// never becomes -0, and x + ±0 is x (the weights are finite). Without the test the loop vectorises.
template <int G, typename Layer>
__attribute__((always_inline)) inline int InputGradGroups(const Layer& L, const float* W,
                                                          const float* delta, float* g, int i) {
  for (; i + G <= L.in; i += G) {
    Lanes s[G];
    for (int q = 0; q < G; ++q) s[q] = Lanes{};
    for (int o = 0; o < L.out; ++o) {
      Lanes d;
      RIM_LOAD_LANES(d, delta + size_t(o) * kLanes);
      const float* w = W + size_t(o) * L.in + i;
      for (int q = 0; q < G; ++q) s[q] += d * w[q];
    }
    for (int q = 0; q < G; ++q) RIM_STORE_LANES(g + (i + q) * kLanes, s[q]);
  }
  return i;
}

// Values and d sdf / d features for blocks of points, lane-minor like ForwardBlocks. Each lane does
// the one-point arithmetic in its order: forward as LayersForBlock; backward from delta = 1 at the
// output, each input's gradient summed over the layer's outputs in order (skipping outputs whose
// delta is zero) and masked where the input's ReLU was off. So values have the SDF-only path's
// bits, and a point's gradient does not depend on its batch.
template <typename Layers>
__attribute__((always_inline)) inline void ForwardGradBlocks(const Layers& layers,
                                                             const float* params, int input_dim,
                                                             int max_width, const float* features,
                                                             int n, float* sdf, float* dsdf) {
  const int nl = int(layers.size());
  const size_t stride = size_t(max_width) * kLanes;
  std::vector<float> act(size_t(nl + 1) * stride), delta(stride), grad(stride);
  for (int p0 = 0; p0 < n; p0 += kLanes) {
    const int m = std::min(kLanes, n - p0);
    for (int i = 0; i < input_dim; ++i)
      for (int j = 0; j < kLanes; ++j)
        act[size_t(i) * kLanes + j] = j < m ? features[size_t(p0 + j) * input_dim + i] : 0.f;
    for (int k = 0; k < nl; ++k) {
      const auto& L = layers[k];
      const float* W = params + L.weight_offset;
      const float* b = params + L.bias_offset;
      const bool relu = k + 1 < nl;
      const float* in = act.data() + size_t(k) * stride;
      float* out = act.data() + size_t(k + 1) * stride;
      int o = OutputGroups<8>(L, W, b, relu, in, out, 0);
      o = OutputGroups<4>(L, W, b, relu, in, out, o);
      OutputGroups<1>(L, W, b, relu, in, out, o);
    }
    const float* y = act.data() + size_t(nl) * stride;
    for (int j = 0; j < m; ++j) sdf[p0 + j] = y[j];
    for (int j = 0; j < kLanes; ++j) delta[j] = 1.f;
    for (int k = nl - 1; k >= 0; --k) {
      const auto& L = layers[k];
      const float* W = params + L.weight_offset;
      int i = InputGradGroups<8>(L, W, delta.data(), grad.data(), 0);
      i = InputGradGroups<4>(L, W, delta.data(), grad.data(), i);
      InputGradGroups<1>(L, W, delta.data(), grad.data(), i);
      if (k > 0) {
        const float* a_in = act.data() + size_t(k) * stride;
        for (int t = 0; t < L.in * kLanes; ++t) delta[t] = a_in[t] > 0.f ? grad[t] : 0.f;
      }
    }
    for (int j = 0; j < m; ++j)
      for (int i = 0; i < input_dim; ++i)
        dsdf[size_t(p0 + j) * input_dim + i] = grad[size_t(i) * kLanes + j];
  }
}

__attribute__((target("avx2"))) void ForwardGradBlocksAvx2(
    const std::vector<Decoder::Layer>& layers, const float* params, int input_dim, int max_width,
    const float* features, int n, float* sdf, float* dsdf) {
  ForwardGradBlocks(layers, params, input_dim, max_width, features, n, sdf, dsdf);
}

void ForwardGradBlocksBaseline(const std::vector<Decoder::Layer>& layers, const float* params,
                               int input_dim, int max_width, const float* features, int n,
                               float* sdf, float* dsdf) {
  ForwardGradBlocks(layers, params, input_dim, max_width, features, n, sdf, dsdf);
}

// The same code compiled for 8-wide AVX registers (still without FMA), chosen at run time.
__attribute__((target("avx2"))) void ForwardBlocksAvx2(const std::vector<Decoder::Layer>& layers,
                                                       const float* params, int input_dim,
                                                       int max_width, const float* features, int n,
                                                       float* sdf) {
  ForwardBlocks(layers, params, input_dim, max_width, features, n, sdf);
}

void ForwardBlocksBaseline(const std::vector<Decoder::Layer>& layers, const float* params,
                           int input_dim, int max_width, const float* features, int n, float* sdf) {
  ForwardBlocks(layers, params, input_dim, max_width, features, n, sdf);
}
}  // namespace

void Decoder::ForwardBlocked(const float* features, int n, float* sdf) const {
  // Points go through in blocks across SIMD lanes with the one-point arithmetic per lane, so a
  // point's SDF is bit-identical to the gradient path's and does not depend on the batch it came
  // in: tiles meshed apart agree on their shared faces.
  static const bool avx2 = __builtin_cpu_supports("avx2");
  (avx2 ? ForwardBlocksAvx2 : ForwardBlocksBaseline)(layers_, params_.data(), input_dim_,
                                                     max_width_, features, n, sdf);
}

void Decoder::ForwardGradBlocked(const float* features, int n, float* sdf, float* dsdf) const {
  static const bool avx2 = __builtin_cpu_supports("avx2");
  (avx2 ? ForwardGradBlocksAvx2 : ForwardGradBlocksBaseline)(layers_, params_.data(), input_dim_,
                                                             max_width_, features, n, sdf, dsdf);
}

void Decoder::Step(const AdamHyper& hyper, const std::vector<float>& grad) {
  ++adam_step_;
  AdamUpdate(hyper, adam_step_, int(params_.size()), grad.data(), params_.data(), adam_m_.data(),
             adam_v_.data());
}

absl::Status Decoder::SetAdamState(int step, const std::vector<float>& m,
                                   const std::vector<float>& v) {
  if (step < 0 || m.size() != params_.size() || v.size() != params_.size()) {
    return absl::InvalidArgumentError("decoder Adam state: wrong size or negative step count");
  }
  adam_step_ = step;
  adam_m_ = m;
  adam_v_ = v;
  return absl::OkStatus();
}

void Decoder::Serialize(ByteWriter* w) const {
  w->I32(input_dim_);
  w->I32(int32_t(layers_.size()));
  for (const Layer& L : layers_) {
    w->I32(L.in);
    w->I32(L.out);
  }
  w->I32(adam_step_);
  w->FloatArray(params_.data(), params_.size());
  w->FloatArray(adam_m_.data(), adam_m_.size());
  w->FloatArray(adam_v_.data(), adam_v_.size());
}

absl::Status Decoder::Deserialize(ByteReader* r) {
  int32_t input_dim, nl;
  RIM_RETURN_IF_ERROR(r->I32(&input_dim));
  RIM_RETURN_IF_ERROR(r->I32(&nl));
  if (input_dim != input_dim_ || nl != int32_t(layers_.size()))
    return absl::DataLossError(absl::StrCat("decoder shape (input ", input_dim, ", ", nl,
                                            " layers) does not match the config"));
  for (const Layer& L : layers_) {
    int32_t in, out;
    RIM_RETURN_IF_ERROR(r->I32(&in));
    RIM_RETURN_IF_ERROR(r->I32(&out));
    if (in != L.in || out != L.out)
      return absl::DataLossError("decoder layer widths do not match the config");
  }
  int32_t step;
  std::vector<float> params, m, v;
  RIM_RETURN_IF_ERROR(r->I32(&step));
  RIM_RETURN_IF_ERROR(r->FloatArray(&params));
  RIM_RETURN_IF_ERROR(r->FloatArray(&m));
  RIM_RETURN_IF_ERROR(r->FloatArray(&v));
  if (params.size() != params_.size() || m.size() != params_.size() || v.size() != params_.size())
    return absl::DataLossError("decoder parameter count does not match the config");
  adam_step_ = step;
  params_ = std::move(params);
  adam_m_ = std::move(m);
  adam_v_ = std::move(v);
  return absl::OkStatus();
}

}  // namespace rim
