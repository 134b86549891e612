// Unit tests of the decoder (§3.1): the plain C++ forward and its input derivative against
// libtorch and finite differences, the analytic position gradient of the whole pipeline, batch
// determinism, Adam against torch::optim::Adam, and the training loss/gradients of RunTrainStep
// against a hand computation in double.
#include "rim/model/decoder.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/map/map_geometry.h"
#include "rim/map/submap_store.h"
#include "rim/model/encoder.h"
#include "rim/train/train_step.h"

namespace rim {
namespace {

constexpr int kInput = 24;  // L·D of the maicity preset

DecoderConfig MakeDecoderConfig(int hidden_layers, uint64_t seed = 42) {
  DecoderConfig c;
  c.hidden_layers = hidden_layers;
  c.hidden_width = 32;
  c.seed = seed;
  return c;
}

std::vector<float> RandomVector(size_t n, float lo, float hi, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(lo, hi);
  std::vector<float> v(n);
  for (float& x : v) x = u(rng);
  return v;
}

// Reference MLP in double, written from the documented layout (per layer: weights out × in
// row-major at weight_offset, bias at bias_offset; ReLU between layers, none after the last).
// `pattern` (optional) receives the ReLU on/off bits, to detect kinks between nearby inputs.
double RefForward(const Decoder& dec, const std::vector<double>& params, const double* x,
                  std::vector<bool>* pattern = nullptr) {
  std::vector<double> a(x, x + dec.input_dim());
  if (pattern) pattern->clear();
  const auto& layers = dec.layers();
  for (size_t k = 0; k < layers.size(); ++k) {
    const Decoder::Layer& L = layers[k];
    std::vector<double> next(L.out);
    for (int o = 0; o < L.out; ++o) {
      double s = params[L.bias_offset + o];
      for (int i = 0; i < L.in; ++i) s += params[L.weight_offset + size_t(o) * L.in + i] * a[i];
      if (k + 1 < layers.size()) {
        if (pattern) pattern->push_back(s > 0);
        s = std::max(s, 0.0);
      }
      next[o] = s;
    }
    a = std::move(next);
  }
  return a[0];
}

std::vector<double> ToDouble(const std::vector<float>& v) {
  return std::vector<double>(v.begin(), v.end());
}

// The same decoder as libtorch modules' functional form, in double.
torch::Tensor TorchForward(const Decoder& dec, const torch::Tensor& x) {
  namespace F = torch::nn::functional;
  auto opts = torch::TensorOptions().dtype(torch::kFloat32);
  torch::Tensor flat = torch::from_blob(const_cast<float*>(dec.params().data()),
                                        {int64_t(dec.params().size())}, opts)
                           .to(torch::kFloat64);
  torch::Tensor h = x;
  const auto& layers = dec.layers();
  for (size_t k = 0; k < layers.size(); ++k) {
    const Decoder::Layer& L = layers[k];
    torch::Tensor W =
        flat.narrow(0, int64_t(L.weight_offset), int64_t(L.in) * L.out).view({L.out, L.in});
    torch::Tensor b = flat.narrow(0, int64_t(L.bias_offset), L.out);
    h = F::linear(h, W, b);
    if (k + 1 < layers.size()) h = torch::relu(h);
  }
  return h.squeeze(1);
}

TEST(DecoderTest, LayoutMatchesConfig) {
  for (int hidden = 0; hidden <= 2; ++hidden) {
    Decoder dec(kInput, MakeDecoderConfig(hidden));
    ASSERT_EQ(int(dec.layers().size()), hidden + 1);
    size_t expect = 0;
    int in = kInput;
    for (int k = 0; k <= hidden; ++k) {
      const int out = k == hidden ? 1 : 32;
      EXPECT_EQ(dec.layers()[k].in, in);
      EXPECT_EQ(dec.layers()[k].out, out);
      expect += size_t(in) * out + out;
      in = out;
    }
    EXPECT_EQ(dec.params().size(), expect);
  }
}

TEST(DecoderTest, ForwardMatchesTorchAndDerivativeMatchesAutograd) {
  const int n = 64;
  for (int hidden = 0; hidden <= 2; ++hidden) {
    SCOPED_TRACE("hidden_layers " + std::to_string(hidden));
    Decoder dec(kInput, MakeDecoderConfig(hidden, 100 + hidden));
    std::vector<float> x = RandomVector(size_t(n) * kInput, -1.f, 1.f, 7 + hidden);
    std::vector<float> sdf(n), dsdf(size_t(n) * kInput);
    dec.Forward(x.data(), n, sdf.data(), dsdf.data());

    torch::Tensor xt = torch::from_blob(x.data(), {n, kInput}, torch::kFloat32)
                           .to(torch::kFloat64)
                           .requires_grad_(true);
    torch::Tensor ref = TorchForward(dec, xt);
    ref.sum().backward();
    torch::Tensor ref_grad = xt.grad();
    auto r = ref.accessor<double, 1>();
    auto rg = ref_grad.accessor<double, 2>();
    const std::vector<double> pd = ToDouble(dec.params());
    for (int i = 0; i < n; ++i) {
      // Float vs double over ≤ 3 layers of ≤ 32-term sums of O(1) values: ≲ 1e-6.
      EXPECT_NEAR(sdf[i], r[i], 1e-5) << "row " << i;
      EXPECT_NEAR(sdf[i], RefForward(dec, pd, &ToDouble(x)[size_t(i) * kInput]), 1e-5);
      for (int k = 0; k < kInput; ++k)
        EXPECT_NEAR(dsdf[size_t(i) * kInput + k], rg[i][k], 1e-5) << "row " << i << " k " << k;
    }
    // Without the derivative output the values are the same.
    std::vector<float> sdf2(n);
    dec.Forward(x.data(), n, sdf2.data());
    EXPECT_EQ(sdf, sdf2);
  }
}

TEST(DecoderTest, DerivativeMatchesFiniteDifferencesOfForward) {
  // The decoder is piecewise linear in its input, so a central difference that stays on one side
  // of every ReLU kink is exact up to rounding: ≈ 2·(float error of sdf ≈ 1e-6) / (2·1e-2) = 1e-4.
  // Kink crossings are detected with the double reference's activation pattern and skipped.
  const int n = 10;
  const float step = 1e-2f;
  for (int hidden = 0; hidden <= 2; ++hidden) {
    SCOPED_TRACE("hidden_layers " + std::to_string(hidden));
    Decoder dec(kInput, MakeDecoderConfig(hidden, 200 + hidden));
    const std::vector<double> pd = ToDouble(dec.params());
    std::vector<float> x = RandomVector(size_t(n) * kInput, -1.f, 1.f, 30 + hidden);
    std::vector<float> sdf(n), dsdf(size_t(n) * kInput);
    dec.Forward(x.data(), n, sdf.data(), dsdf.data());
    int checked = 0, skipped = 0;
    for (int i = 0; i < n; ++i) {
      std::vector<float> row(x.begin() + size_t(i) * kInput, x.begin() + size_t(i + 1) * kInput);
      std::vector<bool> pat0, patp, patm;
      RefForward(dec, pd, ToDouble(row).data(), &pat0);
      for (int k = 0; k < kInput; ++k) {
        std::vector<float> xp = row, xm = row;
        xp[k] += step;
        xm[k] -= step;
        RefForward(dec, pd, ToDouble(xp).data(), &patp);
        RefForward(dec, pd, ToDouble(xm).data(), &patm);
        if (patp != pat0 || patm != pat0) {
          ++skipped;
          continue;
        }
        float sp, sm;
        dec.Forward(xp.data(), 1, &sp);
        dec.Forward(xm.data(), 1, &sm);
        const double fd = (double(sp) - sm) / (double(xp[k]) - xm[k]);
        EXPECT_NEAR(dsdf[size_t(i) * kInput + k], fd, 2e-4) << "row " << i << " k " << k;
        ++checked;
      }
    }
    EXPECT_GT(checked, n * kInput * 3 / 4) << skipped << " skipped at kinks";
  }
}

TEST(DecoderTest, ForwardIsBitIdenticalWhateverTheBatch) {
  const int n = 1003;  // not a whole number of the SDF-only path's blocks
  for (int hidden = 0; hidden <= 2; ++hidden) {
    Decoder dec(kInput, MakeDecoderConfig(hidden));
    std::vector<float> x = RandomVector(size_t(n) * kInput, -1.f, 1.f, 40 + hidden);
    std::vector<float> sdf(n), dsdf(size_t(n) * kInput);
    dec.Forward(x.data(), n, sdf.data(), dsdf.data());
    // SDF only (points in blocks across SIMD lanes): every row the same bits as with the
    // gradient (one point at a time).
    std::vector<float> sdf_only(n);
    dec.Forward(x.data(), n, sdf_only.data());
    EXPECT_EQ(std::memcmp(sdf_only.data(), sdf.data(), n * sizeof(float)), 0) << hidden;
    for (int i : {0, 537, 1002}) {
      float one, done[kInput];
      dec.Forward(&x[size_t(i) * kInput], 1, &one, done);
      EXPECT_EQ(std::memcmp(&one, &sdf[i], sizeof(float)), 0) << "row " << i;
      EXPECT_EQ(std::memcmp(done, &dsdf[size_t(i) * kInput], sizeof(done)), 0) << "row " << i;
      // The same row inside a different batch (at another position) gives the same bits too.
      std::vector<float> other = RandomVector(size_t(7) * kInput, -1.f, 1.f, 50 + i);
      std::copy_n(&x[size_t(i) * kInput], kInput, &other[size_t(3) * kInput]);
      float sdf7[7];
      dec.Forward(other.data(), 7, sdf7);
      EXPECT_EQ(std::memcmp(&sdf7[3], &sdf[i], sizeof(float)), 0) << "row " << i;
    }
  }
}

// The gradient path against plain one-point loops (bias, then inputs in order; the backward pass
// over outputs in order, skipping outputs whose ReLU was off): the same bits, which the SDF-only
// blocks must match too (ForwardIsBitIdenticalWhateverTheBatch).
TEST(DecoderTest, GradientPathEqualsTheOnePointLoopsBitForBit) {
  const int n = 203;
  for (int hidden = 0; hidden <= 2; ++hidden) {
    Decoder dec(kInput, MakeDecoderConfig(hidden));
    std::vector<float> x = RandomVector(size_t(n) * kInput, -1.f, 1.f, 70 + hidden);
    std::vector<float> sdf(n), dsdf(size_t(n) * kInput);
    dec.Forward(x.data(), n, sdf.data(), dsdf.data());
    const auto& layers = dec.layers();
    const std::vector<float>& params = dec.params();
    const int nl = int(layers.size());
    for (int p = 0; p < n; ++p) {
      std::vector<std::vector<float>> act(size_t(nl) + 1);
      act[0].assign(x.begin() + size_t(p) * kInput, x.begin() + size_t(p + 1) * kInput);
      for (int k = 0; k < nl; ++k) {
        const Decoder::Layer& L = layers[size_t(k)];
        act[size_t(k) + 1].resize(size_t(L.out));
        for (int o = 0; o < L.out; ++o) {
          float s = params[L.bias_offset + size_t(o)];
          for (int i = 0; i < L.in; ++i)
            s += params[L.weight_offset + size_t(o) * L.in + size_t(i)] * act[size_t(k)][size_t(i)];
          act[size_t(k) + 1][size_t(o)] = k + 1 < nl ? std::max(s, 0.f) : s;
        }
      }
      std::vector<float> delta{1.f}, prev;
      for (int k = nl - 1; k >= 0; --k) {
        const Decoder::Layer& L = layers[size_t(k)];
        prev.assign(size_t(L.in), 0.f);
        for (int o = 0; o < L.out; ++o) {
          if (delta[size_t(o)] == 0.f) continue;
          for (int i = 0; i < L.in; ++i)
            prev[size_t(i)] +=
                delta[size_t(o)] * params[L.weight_offset + size_t(o) * L.in + size_t(i)];
        }
        delta.assign(size_t(L.in), 0.f);
        for (int i = 0; i < L.in; ++i)
          delta[size_t(i)] = act[size_t(k)][size_t(i)] > 0.f ? prev[size_t(i)] : 0.f;
      }
      ASSERT_EQ(std::memcmp(&act[size_t(nl)][0], &sdf[size_t(p)], sizeof(float)), 0)
          << hidden << " " << p;
      ASSERT_EQ(std::memcmp(prev.data(), &dsdf[size_t(p) * kInput], kInput * sizeof(float)), 0)
          << hidden << " " << p;
    }
  }
}

TEST(DecoderTest, AnalyticPositionGradientMatchesFiniteDifferences) {
  absl::StatusOr<MapperConfig> config = MakePreset("maicity");
  ASSERT_TRUE(config.ok());
  ASSERT_TRUE(ApplyOverrides({"grid.half_extent_x_m=2", "grid.half_extent_y_m=2",
                              "grid.z_min_m=-1.2", "grid.z_max_m=1.2"},
                             &*config)
                  .ok());
  const MapGeometry geo(config->grid);
  ASSERT_EQ(geo.encoding_dim(), kInput);
  LocalMap map(geo);
  map.MoveTo(Int3(-2, 1, -1), LocalMap::SaveFn(),
             [](int, const Int3&, float*, uint8_t*) { return false; });
  std::mt19937 rng(60);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (int l = 0; l < geo.levels(); ++l)
    for (int64_t s = 0; s < map.level(l).slots(); ++s)
      for (int d = 0; d < map.geometry().feature_dim(); ++d) map.level(l).features(s)[d] = u(rng);
  SubmapStore store(geo, config->submap);
  FeatureReader reader(map, store);

  for (int hidden = 0; hidden <= 2; ++hidden) {
    SCOPED_TRACE("hidden_layers " + std::to_string(hidden));
    Decoder dec(kInput, MakeDecoderConfig(hidden, 300 + hidden));
    const std::vector<double> pd = ToDouble(dec.params());
    auto sdf_at = [&](const Vec3d& p, std::vector<bool>* pattern) {
      float f[kInput], s;
      reader.Encode(p, f, nullptr);
      dec.Forward(f, 1, &s);
      std::vector<double> fd(f, f + kInput);
      RefForward(dec, pd, fd.data(), pattern);
      return double(s);
    };
    // Within one voxel of every level and one ReLU region, sdf is linear along each axis, so the
    // central difference is exact up to rounding: sdf is float (≈ 1e-6 error) over 2·1e-3 m,
    // ≈ 1e-3; gradients are O(10) per metre, so 5e-3 + 1e-4 relative leaves a real check.
    const double step = 1e-3;
    std::uniform_real_distribution<double> ux(0, 1);
    int checked = 0;
    for (int i = 0; i < 200 && checked < 40; ++i) {
      const Vec3d p = map.min_m() +
                      Vec3d(ux(rng), ux(rng), ux(rng))
                          .cwiseProduct(map.max_m() - map.min_m() - Vec3d::Constant(0.01)) +
                      Vec3d::Constant(0.005);
      bool away = true;
      for (int l = 0; l < geo.levels(); ++l)
        for (int a = 0; a < 3; ++a) {
          const double t = p[a] / geo.voxel_m(l) - std::floor(p[a] / geo.voxel_m(l));
          away = away && t > 0.02 && t < 0.98;
        }
      if (!away) continue;
      float f[kInput], jac[kInput * 3], s, dsdf[kInput];
      reader.Encode(p, f, jac);
      dec.Forward(f, 1, &s, dsdf);
      Vec3d grad = Vec3d::Zero();
      for (int k = 0; k < kInput; ++k)
        for (int a = 0; a < 3; ++a) grad[a] += double(dsdf[k]) * jac[k * 3 + a];
      std::vector<bool> pat0, patp, patm;
      sdf_at(p, &pat0);
      bool kink = false;
      Vec3d fd;
      for (int a = 0; a < 3; ++a) {
        Vec3d dp = Vec3d::Zero();
        dp[a] = step;
        const double sp = sdf_at(p + dp, &patp), sm = sdf_at(p - dp, &patm);
        kink = kink || patp != pat0 || patm != pat0;
        fd[a] = (sp - sm) / (2 * step);
      }
      if (kink) continue;
      ++checked;
      for (int a = 0; a < 3; ++a)
        EXPECT_NEAR(grad[a], fd[a], 5e-3 + 1e-4 * std::abs(fd[a]))
            << "point " << i << " axis " << a;
    }
    EXPECT_GE(checked, 20);
  }
}

// Runs `steps` Adam steps through torch::optim::Adam on a float tensor with the given gradients.
std::vector<float> TorchAdam(const std::vector<float>& init,
                             const std::vector<std::vector<float>>& grads, const AdamHyper& h) {
  torch::Tensor p = torch::tensor(init, torch::kFloat32).requires_grad_(true);
  torch::optim::Adam opt({p}, torch::optim::AdamOptions(h.lr).betas({h.beta1, h.beta2}).eps(h.eps));
  for (const std::vector<float>& g : grads) {
    opt.zero_grad();
    p.mutable_grad() = torch::tensor(g, torch::kFloat32);
    opt.step();
  }
  torch::Tensor c = p.detach().contiguous();
  return std::vector<float>(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
}

void ExpectRelNear(const std::vector<float>& got, const std::vector<float>& want, double rel) {
  ASSERT_EQ(got.size(), want.size());
  for (size_t i = 0; i < got.size(); ++i)
    EXPECT_NEAR(got[i], want[i], rel * std::max(std::abs(double(want[i])), 1e-2)) << "index " << i;
}

TEST(DecoderTest, AdamUpdateMatchesTorchAdam) {
  const int n = 16, steps = 6;
  for (float eps : {1e-8f, 1e-15f}) {
    const AdamHyper h{1e-2f, 0.9f, 0.999f, eps};
    // Small parameters, so that float rounding of the parameter itself (≈ 4e-9) stays far below
    // 1e-6 of the total displacement (≈ steps·lr): the displacement is checked to 1e-6 relative.
    const std::vector<float> init = RandomVector(n, -0.05f, 0.05f, 70);
    std::vector<std::vector<float>> grads;
    for (int s = 0; s < steps; ++s) {
      // Gradients of mixed scales and signs, one entry always zero.
      std::vector<float> g = RandomVector(n, -1.f, 1.f, 71 + s);
      for (int i = 0; i < n; ++i) g[i] *= std::pow(10.f, float(i % 4) - 2.f);
      g[5] = 0.f;
      grads.push_back(g);
    }
    const std::vector<float> want = TorchAdam(init, grads, h);
    std::vector<float> param = init, m(n, 0.f), v(n, 0.f);
    for (int s = 0; s < steps; ++s)
      AdamUpdate(h, s + 1, n, grads[s].data(), param.data(), m.data(), v.data());
    SCOPED_TRACE("eps " + std::to_string(eps));
    ExpectRelNear(param, want, 1e-6);
    for (int i = 0; i < n; ++i) {
      const double moved = double(want[i]) - init[i], got = double(param[i]) - init[i];
      if (i == 5) {  // never had a gradient: must not move at all
        EXPECT_EQ(param[i], init[i]);
        continue;
      }
      EXPECT_GT(std::abs(moved), 1e-3) << "index " << i;  // about lr per step
      EXPECT_NEAR(got, moved, 1e-6 * std::abs(moved)) << "index " << i;
    }
  }
}

TEST(DecoderTest, DecoderStepMatchesTorchAdam) {
  Decoder dec(kInput, MakeDecoderConfig(1));
  const std::vector<float> init = dec.params();
  const AdamHyper h{1e-2f, 0.9f, 0.999f, 1e-15f};
  std::vector<std::vector<float>> grads;
  for (int s = 0; s < 4; ++s) grads.push_back(RandomVector(init.size(), -0.1f, 0.1f, 80 + s));
  for (const auto& g : grads) dec.Step(h, g);
  ExpectRelNear(dec.params(), TorchAdam(init, grads, h), 1e-6);
}

// ----- RunTrainStep -----

double Sigmoid(double z) { return 1.0 / (1.0 + std::exp(-z)); }

// BCE(S(label), S(pred)) with S(d) = sigmoid(−d/σ), written literally (fine for moderate pred).
double LiteralBce(double pred, double label, double sigma) {
  const double t = Sigmoid(-label / sigma), s = Sigmoid(-pred / sigma);
  return -(t * std::log(s) + (1 - t) * std::log(1 - s));
}

// The same with logits z = −pred/σ: max(z, 0) − z·t + log(1 + e^−|z|), safe for any pred.
double SafeBce(double pred, double label, double sigma) {
  const double t = Sigmoid(-label / sigma), z = -pred / sigma;
  return std::max(z, 0.0) - z * t + std::log1p(std::exp(-std::abs(z)));
}

struct Problem {
  std::vector<float> features;
  std::vector<float> labels;
  int rows = 0, labelled = 0;
  float sigma = 0.05f;
  float eikonal_weight = 0.f, eikonal_step = 0.05f;

  TrainStepInput Input(bool train_decoder = true) {
    TrainStepInput in;
    in.features = features.data();
    in.rows = rows;
    in.labelled = labelled;
    in.labels = labels.data();
    in.sigma_m = sigma;
    in.eikonal_weight = eikonal_weight;
    in.eikonal_step_m = eikonal_step;
    in.train_decoder = train_decoder;
    return in;
  }
};

Problem MakeProblem(int labelled, int probes, uint32_t seed) {
  Problem p;
  p.labelled = labelled;
  p.rows = labelled + probes;
  p.features = RandomVector(size_t(p.rows) * kInput, -1.f, 1.f, seed);
  p.labels = RandomVector(labelled, -0.2f, 0.2f, seed + 1);
  return p;
}

// The full loss in double from the reference forward: mean BCE over labelled rows plus
// w · mean over probe groups of (|∇f| − 1)², ∇f by central differences over 2h.
double RefLoss(const Decoder& dec, const std::vector<double>& params,
               const std::vector<double>& features, const Problem& p,
               std::vector<bool>* patterns = nullptr) {
  if (patterns) patterns->clear();
  std::vector<double> sdf(p.rows);
  for (int i = 0; i < p.rows; ++i) {
    std::vector<bool> pat;
    sdf[i] = RefForward(dec, params, &features[size_t(i) * kInput], &pat);
    if (patterns) patterns->insert(patterns->end(), pat.begin(), pat.end());
  }
  double bce = 0;
  for (int i = 0; i < p.labelled; ++i) bce += SafeBce(sdf[i], p.labels[i], p.sigma);
  double loss = bce / p.labelled;
  const int groups = (p.rows - p.labelled) / 6;
  if (p.eikonal_weight > 0 && groups > 0) {
    double eik = 0;
    for (int g = 0; g < groups; ++g) {
      const double* s = &sdf[p.labelled + 6 * g];
      const Vec3d grad((s[0] - s[1]) / (2.0 * p.eikonal_step),
                       (s[2] - s[3]) / (2.0 * p.eikonal_step),
                       (s[4] - s[5]) / (2.0 * p.eikonal_step));
      eik += (grad.norm() - 1) * (grad.norm() - 1);
    }
    loss += double(p.eikonal_weight) * eik / groups;
  }
  return loss;
}

TEST(TrainStepTest, LossIsTheBceOfSquashedSdfs) {
  for (int hidden = 0; hidden <= 2; ++hidden) {
    SCOPED_TRACE("hidden_layers " + std::to_string(hidden));
    Decoder dec(kInput, MakeDecoderConfig(hidden, 400 + hidden));
    Problem p = MakeProblem(16, 0, 90 + hidden);
    absl::StatusOr<TrainStepOutput> out = RunTrainStep(dec, p.Input());
    ASSERT_TRUE(out.ok()) << out.status();
    std::vector<float> pred(p.rows);
    dec.Forward(p.features.data(), p.rows, pred.data());
    double literal = 0;
    for (int i = 0; i < p.labelled; ++i) literal += LiteralBce(pred[i], p.labels[i], p.sigma);
    literal /= p.labelled;
    EXPECT_GT(literal, 0.05);  // not a trivial value
    EXPECT_NEAR(out->loss, literal, 1e-5 * literal + 1e-6);
    EXPECT_NEAR(out->loss, RefLoss(dec, ToDouble(dec.params()), ToDouble(p.features), p),
                1e-5 * literal + 1e-6);
    EXPECT_EQ(out->grad_features.size(), size_t(p.rows) * kInput);
    EXPECT_EQ(out->grad_params.size(), dec.params().size());
  }
}

TEST(TrainStepTest, GradientsMatchFiniteDifferencesOfTheLoss) {
  // Finite differences of the double-precision reference loss (step 1e-4; truncation ~1e-8,
  // ReLU kink crossings detected and skipped) against the float gradients from libtorch.
  for (int hidden = 0; hidden <= 2; ++hidden) {
    SCOPED_TRACE("hidden_layers " + std::to_string(hidden));
    Decoder dec(kInput, MakeDecoderConfig(hidden, 500 + hidden));
    Problem p = MakeProblem(16, 0, 110 + hidden);
    absl::StatusOr<TrainStepOutput> out = RunTrainStep(dec, p.Input());
    ASSERT_TRUE(out.ok()) << out.status();
    const std::vector<double> params = ToDouble(dec.params());
    std::vector<double> feats = ToDouble(p.features);
    std::vector<bool> pat0, patp, patm;
    RefLoss(dec, params, feats, p, &pat0);
    const double step = 1e-4;
    double max_grad = 0;
    int checked = 0;
    for (int e = 0; e < 40; ++e) {
      const size_t k = (size_t(e) * 9973) % feats.size();
      const double x0 = feats[k];
      feats[k] = x0 + step;
      const double lp = RefLoss(dec, params, feats, p, &patp);
      feats[k] = x0 - step;
      const double lm = RefLoss(dec, params, feats, p, &patm);
      feats[k] = x0;
      if (patp != pat0 || patm != pat0) continue;
      const double fd = (lp - lm) / (2 * step);
      max_grad = std::max(max_grad, std::abs(fd));
      EXPECT_NEAR(out->grad_features[k], fd, 1e-5 + 1e-3 * std::abs(fd)) << "feature " << k;
      ++checked;
    }
    EXPECT_GE(checked, 30);
    EXPECT_GT(max_grad, 1e-3);  // gradients are not trivially zero

    std::vector<double> pp = params;
    checked = 0;
    std::vector<size_t> probe;
    for (const Decoder::Layer& L : dec.layers()) {
      probe.push_back(L.weight_offset);
      probe.push_back(L.weight_offset + size_t(L.in) * L.out - 1);
      probe.push_back(L.bias_offset);
      probe.push_back(L.bias_offset + L.out - 1);
    }
    for (size_t k : probe) {
      const double x0 = pp[k];
      pp[k] = x0 + step;
      const double lp = RefLoss(dec, pp, feats, p, &patp);
      pp[k] = x0 - step;
      const double lm = RefLoss(dec, pp, feats, p, &patm);
      pp[k] = x0;
      if (patp != pat0 || patm != pat0) continue;
      const double fd = (lp - lm) / (2 * step);
      EXPECT_NEAR(out->grad_params[k], fd, 1e-5 + 1e-3 * std::abs(fd)) << "param " << k;
      ++checked;
    }
    EXPECT_GE(checked, int(probe.size()) - 2);
  }
}

TEST(TrainStepTest, LossIsFiniteForHugePredictions) {
  Decoder dec(kInput, MakeDecoderConfig(1));
  const Decoder::Layer last = dec.layers().back();
  Problem p = MakeProblem(8, 0, 130);
  for (float bias : {1e4f, -1e4f}) {
    SCOPED_TRACE("bias " + std::to_string(bias));
    // The last bias dominates: every prediction is ≈ ±1e4 m, i.e. logits of ∓2e5.
    dec.params()[last.bias_offset] = bias;
    std::vector<float> pred(p.rows);
    dec.Forward(p.features.data(), p.rows, pred.data());
    double safe = 0, literal = 0;
    for (int i = 0; i < p.labelled; ++i) {
      ASSERT_GT(std::abs(pred[i]), 9e3);
      safe += SafeBce(pred[i], p.labels[i], p.sigma);
      literal += LiteralBce(pred[i], p.labels[i], p.sigma);
    }
    safe /= p.labelled;
    EXPECT_FALSE(std::isfinite(literal));  // the naive form would overflow: the check matters
    absl::StatusOr<TrainStepOutput> out = RunTrainStep(dec, p.Input());
    ASSERT_TRUE(out.ok()) << out.status();
    ASSERT_TRUE(std::isfinite(out->loss));
    EXPECT_NEAR(out->loss, safe, 1e-5 * safe);
    for (float g : out->grad_features) ASSERT_TRUE(std::isfinite(g));
    for (float g : out->grad_params) ASSERT_TRUE(std::isfinite(g));
  }
}

TEST(TrainStepTest, EikonalTermAddsWeightTimesSquaredNormError) {
  Decoder dec(kInput, MakeDecoderConfig(1, 600));
  Problem p = MakeProblem(16, 6, 140);
  p.eikonal_step = 0.05f;
  const std::vector<double> params = ToDouble(dec.params());

  // Without the term the probe rows do not count and get no gradient.
  absl::StatusOr<TrainStepOutput> base = RunTrainStep(dec, p.Input());
  ASSERT_TRUE(base.ok()) << base.status();
  for (size_t k = size_t(p.labelled) * kInput; k < base->grad_features.size(); ++k)
    EXPECT_EQ(base->grad_features[k], 0.f);

  p.eikonal_weight = 0.1f;
  absl::StatusOr<TrainStepOutput> with = RunTrainStep(dec, p.Input());
  ASSERT_TRUE(with.ok()) << with.status();
  // By hand: probes +x, −x, +y, −y, +z, −z; ∇f by central differences over 2h.
  std::vector<double> s(6);
  for (int j = 0; j < 6; ++j)
    s[j] = RefForward(dec, params, &ToDouble(p.features)[size_t(p.labelled + j) * kInput]);
  const double h = p.eikonal_step;
  const Vec3d g((s[0] - s[1]) / (2 * h), (s[2] - s[3]) / (2 * h), (s[4] - s[5]) / (2 * h));
  const double term = double(p.eikonal_weight) * (g.norm() - 1) * (g.norm() - 1);
  EXPECT_GT(term, 1e-3);
  EXPECT_NEAR(with->loss - base->loss, term, 1e-5 * term + 2e-6);
  EXPECT_NEAR(with->loss, RefLoss(dec, params, ToDouble(p.features), p), 1e-5 * with->loss);
  double probe_grad = 0;
  for (size_t k = size_t(p.labelled) * kInput; k < with->grad_features.size(); ++k)
    probe_grad += std::abs(with->grad_features[k]);
  EXPECT_GT(probe_grad, 0);

  // Two probe groups: the term is the mean over groups.
  Problem q = MakeProblem(16, 12, 150);
  q.eikonal_weight = 0.3f;
  absl::StatusOr<TrainStepOutput> two = RunTrainStep(dec, q.Input());
  ASSERT_TRUE(two.ok()) << two.status();
  const double ref = RefLoss(dec, params, ToDouble(q.features), q);
  EXPECT_NEAR(two->loss, ref, 1e-5 * ref);
}

TEST(TrainStepTest, FrozenDecoderHasNoParamGradient) {
  Decoder dec(kInput, MakeDecoderConfig(1));
  Problem p = MakeProblem(16, 0, 160);
  absl::StatusOr<TrainStepOutput> trained = RunTrainStep(dec, p.Input(true));
  absl::StatusOr<TrainStepOutput> frozen = RunTrainStep(dec, p.Input(false));
  ASSERT_TRUE(trained.ok()) << trained.status();
  ASSERT_TRUE(frozen.ok()) << frozen.status();
  EXPECT_TRUE(frozen->grad_params.empty());
  EXPECT_FALSE(trained->grad_params.empty());
  EXPECT_EQ(frozen->loss, trained->loss);
  ASSERT_EQ(frozen->grad_features.size(), trained->grad_features.size());
  for (size_t k = 0; k < frozen->grad_features.size(); ++k)
    EXPECT_NEAR(frozen->grad_features[k], trained->grad_features[k], 1e-7);
}

}  // namespace
}  // namespace rim
