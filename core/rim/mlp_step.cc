#include "rim/mlp_step.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>

#include "absl/strings/str_cat.h"

namespace rim {
namespace {

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
  auto forward = [&](int c) {
    const int begin = c * kChunkRows, rows = std::min(n - begin, kChunkRows);
    for (int k = 0; k < K; ++k) {
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
  };
  RunChunks(pool, chunks, forward);
  const float* y = act_.back().data();  // n × 1

  // Loss and d loss / d y. BCE with logits s = −y/σ against S(label) = σ(−label/σ), averaged over
  // the labelled rows; the same stable form libtorch uses: max(s,0) − s·t + log(1 + e^−|s|).
  grad_.resize(n, 1);
  grad_.setZero();
  float* dy = grad_.data();
  double loss = 0;
  const float inv_sigma = 1.f / in.sigma_m;
  if (in.labelled > 0) {
    const float scale = -inv_sigma / float(in.labelled);
    for (int i = 0; i < in.labelled; ++i) {
      const float s = -y[i] * inv_sigma;
      const float t = Sigmoid(-in.labels[i] * inv_sigma);
      loss += double(std::max(s, 0.f) - s * t + std::log1p(std::exp(-std::abs(s))));
      dy[i] = (Sigmoid(s) - t) * scale;
    }
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
