#include "rim/train/mlp_step.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>

#include "absl/strings/str_cat.h"

#if defined(__x86_64__)
#include <immintrin.h>
#define RIM_MLP_VECTOR_KERNELS 1
#endif

namespace rim {
namespace {

#ifdef RIM_MLP_VECTOR_KERNELS
// Kernels for a decoder with one hidden layer of H = 8·V units on F = 8·U inputs, compiled for
// AVX2 and FMA only here (the target attribute; the rest of the build is baseline x86-64) and
// called only when the CPU reports both. They live in this file's anonymous namespace, so no
// other translation unit can end up linked to these instructions.
#define RIM_AVX2 __attribute__((target("avx2,fma")))

RIM_AVX2 inline float HorizontalSum(__m256 v) {
  __m128 s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
  s = _mm_add_ps(s, _mm_movehl_ps(s, s));
  s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
  return _mm_cvtss_f32(s);
}

// act0 = relu(x·W0ᵀ + b0) and y = act0·w1ᵀ + b1 per row; W0T is W0 transposed (F × H).
template <int V>
RIM_AVX2 void ForwardOneHidden(const float* X, int rows, int F, const float* W0T, const float* b0,
                               const float* w1, float b1, float* act0, float* y) {
  constexpr int H = 8 * V;
  const __m256 zero = _mm256_setzero_ps();
  for (int r = 0; r < rows; ++r) {
    const float* x = X + size_t(r) * F;
    __m256 acc[V];
    for (int j = 0; j < V; ++j) acc[j] = _mm256_loadu_ps(b0 + 8 * j);
    for (int i = 0; i < F; ++i) {
      const __m256 xi = _mm256_broadcast_ss(x + i);
      const float* w = W0T + size_t(i) * H;
      for (int j = 0; j < V; ++j) acc[j] = _mm256_fmadd_ps(_mm256_loadu_ps(w + 8 * j), xi, acc[j]);
    }
    float* a = act0 + size_t(r) * H;
    __m256 out = zero;
    for (int j = 0; j < V; ++j) {
      acc[j] = _mm256_max_ps(acc[j], zero);
      _mm256_storeu_ps(a + 8 * j, acc[j]);
      out = _mm256_fmadd_ps(acc[j], _mm256_loadu_ps(w1 + 8 * j), out);
    }
    y[r] = HorizontalSum(out) + b1;
  }
}

// Back through the ReLU and the first layer: g = dy·w1 where act0 > 0 (else 0), dX = g·W0.
// With grad_h, g is kept per row (rows × H) for the parameter gradients.
template <int V, int U>
RIM_AVX2 void BackwardOneHidden(const float* dy, const float* act0, const float* W0,
                                const float* w1, int rows, float* dX, float* grad_h) {
  constexpr int H = 8 * V, F = 8 * U;
  const __m256 zero = _mm256_setzero_ps();
  alignas(32) float g[H];
  for (int r = 0; r < rows; ++r) {
    const __m256 d = _mm256_broadcast_ss(dy + r);
    const float* a = act0 + size_t(r) * H;
    for (int j = 0; j < V; ++j) {
      const __m256 live = _mm256_cmp_ps(_mm256_loadu_ps(a + 8 * j), zero, _CMP_GT_OQ);
      const __m256 gj = _mm256_and_ps(_mm256_mul_ps(d, _mm256_loadu_ps(w1 + 8 * j)), live);
      _mm256_store_ps(g + 8 * j, gj);
      if (grad_h) _mm256_storeu_ps(grad_h + size_t(r) * H + 8 * j, gj);
    }
    __m256 acc[U];
    for (int u = 0; u < U; ++u) acc[u] = zero;
    for (int k = 0; k < H; ++k) {
      const __m256 gk = _mm256_broadcast_ss(g + k);
      const float* w = W0 + size_t(k) * F;
      for (int u = 0; u < U; ++u) acc[u] = _mm256_fmadd_ps(_mm256_loadu_ps(w + 8 * u), gk, acc[u]);
    }
    float* out = dX + size_t(r) * F;
    for (int u = 0; u < U; ++u) _mm256_storeu_ps(out + 8 * u, acc[u]);
  }
}

// Picks the instantiation for the shape; false when there is none (the caller uses Eigen).
template <int V>
bool ForwardFor(int h8, const float* X, int rows, int F, const float* W0T, const float* b0,
                const float* w1, float b1, float* act0, float* y) {
  if (h8 != V) {
    if constexpr (V > 1) return ForwardFor<V - 1>(h8, X, rows, F, W0T, b0, w1, b1, act0, y);
    return false;
  }
  ForwardOneHidden<V>(X, rows, F, W0T, b0, w1, b1, act0, y);
  return true;
}

template <int V, int U>
bool BackwardForU(int f8, const float* dy, const float* act0, const float* W0, const float* w1,
                  int rows, float* dX, float* grad_h) {
  if (f8 != U) {
    if constexpr (U > 1) return BackwardForU<V, U - 1>(f8, dy, act0, W0, w1, rows, dX, grad_h);
    return false;
  }
  BackwardOneHidden<V, U>(dy, act0, W0, w1, rows, dX, grad_h);
  return true;
}

template <int V>
bool BackwardFor(int h8, int f8, const float* dy, const float* act0, const float* W0,
                 const float* w1, int rows, float* dX, float* grad_h) {
  if (h8 != V) {
    if constexpr (V > 1) return BackwardFor<V - 1>(h8, f8, dy, act0, W0, w1, rows, dX, grad_h);
    return false;
  }
  return BackwardForU<V, 8>(f8, dy, act0, W0, w1, rows, dX, grad_h);
}
#endif  // RIM_MLP_VECTOR_KERNELS

double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// σ(x) without overflow for either sign.
inline float Sigmoid(float x) {
  if (x >= 0.f) return 1.f / (1.f + std::exp(-x));
  const float e = std::exp(x);
  return e / (1.f + e);
}

void RunChunks(WorkerPool* pool, int chunks, const std::function<void(int)>& fn) {
  if (pool) {
    pool->Run(chunks, fn);
  } else {
    for (int c = 0; c < chunks; ++c) fn(c);
  }
}

}  // namespace

bool MlpTrainStep::VectorKernelsAvailable() {
#ifdef RIM_MLP_VECTOR_KERNELS
  static const bool available = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return available;
#else
  return false;
#endif
}

absl::Status MlpTrainStep::Run(const Decoder& decoder, const TrainStepInput& in,
                               TrainStepOutput* out, WorkerPool* pool) {
  const auto& layers = decoder.layers();
  const int n = in.rows;
  const int F = decoder.input_dim();
  if (n < 0 || in.labelled < 0 || in.labelled > n || layers.empty() || layers.back().out != 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("training step: bad batch shape (rows ", n, ", labelled ", in.labelled, ")"));
  }
  using ConstMap = Eigen::Map<const RowMatrix>;
  const float* p = decoder.params().data();
  const ConstMap X(in.features, n, F);
  const int K = int(layers.size());
  const double t0 = Now();

  // Forward: act_[k] = relu(act_[k−1]·Wₖᵀ + bₖ), the last layer without ReLU, in fixed chunks of
  // rows (so that the result does not depend on the thread count).
  act_.resize(size_t(K));
  for (int k = 0; k < K; ++k) act_[size_t(k)].resize(n, layers[size_t(k)].out);
  const int chunks = (n + kChunkRows - 1) / kChunkRows;
  // One hidden layer of 8–64 units (a multiple of 8) on 8–64 inputs: the vector kernels.
  const int H = layers[0].out;
  const bool kernels = vector_kernels_ && VectorKernelsAvailable() && K == 2 && H % 8 == 0 &&
                       H <= 64 && F % 8 == 0 && F <= 64;
  if (kernels) {
    w0_transposed_.resize(size_t(F) * H);
    const float* W0 = p + layers[0].weight_offset;
    for (int k = 0; k < H; ++k)
      for (int i = 0; i < F; ++i) w0_transposed_[size_t(i) * H + k] = W0[size_t(k) * F + i];
  }
  // Loss and d loss / d y of the labelled rows, per chunk right after its forward pass. BCE with
  // logits s = −y/σ against S(label) = σ(−label/σ), averaged over the labelled rows; the same
  // stable form libtorch uses: max(s,0) − s·t + log(1 + e^−|s|). Chunk sums are added in chunk
  // order, so the loss does not depend on the thread count.
  grad_.resize(n, 1);
  grad_.setZero();
  float* dy = grad_.data();
  const float inv_sigma = 1.f / in.sigma_m;
  chunk_loss_.assign(size_t(chunks), 0.0);
  auto forward = [&](int c) {
    const int begin = c * kChunkRows, rows = std::min(n - begin, kChunkRows);
    bool done = false;
#ifdef RIM_MLP_VECTOR_KERNELS
    done = kernels && ForwardFor<8>(H / 8, in.features + size_t(begin) * F, rows, F,
                                    w0_transposed_.data(), p + layers[0].bias_offset,
                                    p + layers[1].weight_offset, p[layers[1].bias_offset],
                                    act_[0].data() + size_t(begin) * H, act_[1].data() + begin);
#endif
    for (int k = 0; k < K && !done; ++k) {
      const Decoder::Layer& L = layers[size_t(k)];
      const ConstMap W(p + L.weight_offset, L.out, L.in);
      const Eigen::Map<const Eigen::RowVectorXf> b(p + L.bias_offset, L.out);
      auto a = act_[size_t(k)].middleRows(begin, rows);
      if (k == 0) {
        a.noalias() = X.middleRows(begin, rows) * W.transpose();
      } else {
        a.noalias() = act_[size_t(k - 1)].middleRows(begin, rows) * W.transpose();
      }
      a.rowwise() += b;
      if (k + 1 < K) a = a.cwiseMax(0.f);
    }
    const float* y = act_.back().data();  // n × 1
    const float scale = in.labelled > 0 ? -inv_sigma / float(in.labelled) : 0.f;
    double sum = 0;
    for (int i = begin; i < std::min(begin + rows, in.labelled); ++i) {
      const float s = -y[i] * inv_sigma;
      const float t = Sigmoid(-in.labels[i] * inv_sigma);
      const float e = std::exp(-std::abs(s));  // shared by the log term and σ(s)
      sum += double(std::max(s, 0.f) - s * t + std::log1p(e));
      const float sigmoid_s = s >= 0.f ? 1.f / (1.f + e) : e / (1.f + e);
      dy[i] = (sigmoid_s - t) * scale;
    }
    chunk_loss_[size_t(c)] = sum;
  };
  RunChunks(pool, chunks, forward);
  const float* y = act_.back().data();  // n × 1
  double loss = 0;
  if (in.labelled > 0) {
    for (double part : chunk_loss_) loss += part;
    loss /= in.labelled;
  }
  // Eikonal term: w·mean over probe groups of (|g| − 1)², g by central differences of the six
  // probes (+x, −x, +y, −y, +z, −z).
  const int groups = (n - in.labelled) / 6;
  if (in.eikonal_weight > 0.f && groups > 0) {
    const float inv_2h = 1.f / (2.f * in.eikonal_step_m);
    double eik = 0;
    for (int g = 0; g < groups; ++g) {
      const int base = in.labelled + 6 * g;
      float grad[3];
      for (int a = 0; a < 3; ++a) grad[a] = (y[base + 2 * a] - y[base + 2 * a + 1]) * inv_2h;
      const float norm = std::sqrt(grad[0] * grad[0] + grad[1] * grad[1] + grad[2] * grad[2]);
      eik += double(norm - 1.f) * double(norm - 1.f);
      // d|g|/dg = g/|g|, taken as 0 at g = 0 (as libtorch's norm does).
      const float coef =
          norm > 0.f ? in.eikonal_weight * 2.f * (norm - 1.f) / (norm * float(groups)) : 0.f;
      for (int a = 0; a < 3; ++a) {
        dy[base + 2 * a] += coef * grad[a] * inv_2h;
        dy[base + 2 * a + 1] -= coef * grad[a] * inv_2h;
      }
    }
    loss += double(in.eikonal_weight) * eik / groups;
  }
  const double t1 = Now();

  // Backward, per chunk: g holds d loss / d (pre-activation of layer k) for the chunk's rows.
  // Parameter gradients are summed per chunk, then over chunks in chunk order.
  const size_t P = decoder.params().size();
  out->grad_features.resize(size_t(n) * F);
  chunk_grad_params_.resize(size_t(chunks));
  work_.resize(size_t(chunks));
  auto backward = [&](int c) {
    const int begin = c * kChunkRows, rows = std::min(n - begin, kChunkRows);
    Work& w = work_[size_t(c)];
    w.grad = grad_.middleRows(begin, rows);
    std::vector<float>& gp = chunk_grad_params_[size_t(c)];
    if (in.train_decoder) gp.assign(P, 0.f);
#ifdef RIM_MLP_VECTOR_KERNELS
    if (kernels) {
      // Feature gradient (and, when the decoder trains, the hidden layer's pre-activation
      // gradient) from the kernel; the parameter gradients from it as Eigen products.
      if (in.train_decoder) w.grad_prev.resize(rows, H);
      const bool done =
          BackwardFor<8>(H / 8, F / 8, grad_.data() + begin, act_[0].data() + size_t(begin) * H,
                         p + layers[0].weight_offset, p + layers[1].weight_offset, rows,
                         out->grad_features.data() + size_t(begin) * F,
                         in.train_decoder ? w.grad_prev.data() : nullptr);
      if (done) {
        if (in.train_decoder) {
          const Decoder::Layer& L0 = layers[0];
          const Decoder::Layer& L1 = layers[1];
          Eigen::Map<RowMatrix> gW1(gp.data() + L1.weight_offset, L1.out, L1.in);
          gW1.noalias() = w.grad.transpose() * act_[0].middleRows(begin, rows);
          gp[L1.bias_offset] = w.grad.sum();
          Eigen::Map<RowMatrix> gW0(gp.data() + L0.weight_offset, L0.out, L0.in);
          gW0.noalias() = w.grad_prev.transpose() * X.middleRows(begin, rows);
          Eigen::Map<Eigen::RowVectorXf> gb0(gp.data() + L0.bias_offset, L0.out);
          gb0 = w.grad_prev.colwise().sum();
        }
        return;
      }
    }
#endif
    for (int k = K - 1; k >= 0; --k) {
      const Decoder::Layer& L = layers[size_t(k)];
      const ConstMap W(p + L.weight_offset, L.out, L.in);
      if (in.train_decoder) {
        Eigen::Map<RowMatrix> gW(gp.data() + L.weight_offset, L.out, L.in);
        Eigen::Map<Eigen::RowVectorXf> gb(gp.data() + L.bias_offset, L.out);
        if (k == 0) {
          gW.noalias() = w.grad.transpose() * X.middleRows(begin, rows);
        } else {
          gW.noalias() = w.grad.transpose() * act_[size_t(k - 1)].middleRows(begin, rows);
        }
        gb = w.grad.colwise().sum();
      }
      if (k == 0) {
        Eigen::Map<RowMatrix> dX(out->grad_features.data() + size_t(begin) * F, rows, F);
        dX.noalias() = w.grad * W;
      } else {
        // Through the ReLU of layer k−1: the gradient passes where its output is positive.
        w.grad_prev.resize(rows, L.in);
        w.grad_prev.noalias() = w.grad * W;
        w.grad_prev =
            (act_[size_t(k - 1)].middleRows(begin, rows).array() > 0.f).select(w.grad_prev, 0.f);
        w.grad.swap(w.grad_prev);
      }
    }
  };
  RunChunks(pool, chunks, backward);
  if (in.train_decoder) {
    out->grad_params.assign(P, 0.f);
    for (int c = 0; c < chunks; ++c) {
      const std::vector<float>& gp = chunk_grad_params_[size_t(c)];
      for (size_t i = 0; i < P; ++i) out->grad_params[i] += gp[i];
    }
  } else {
    out->grad_params.clear();
  }
  const double t2 = Now();
  out->loss = float(loss);
  out->forward_s = t1 - t0;
  out->backward_s = t2 - t1;
  return absl::OkStatus();
}

}  // namespace rim
