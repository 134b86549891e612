#include "rim/train/train_step.h"

#include <dlfcn.h>
#include <torch/torch.h>

#include <chrono>
#include <cstdlib>

#include "absl/strings/str_cat.h"
#include "rim/base/version.h"
#include "rim/model/encoder.h"

namespace rim {
namespace {

// libtorch's matrix products go through libblas.so.3. Where an administrator made that OpenBLAS
// (Debian's alternatives), its own thread pool would fight libtorch's threads for the cores over
// matrices this small: measured on 2 cores, one BLAS thread makes forward and backward faster and
// removes ~40 % of system time. OPENBLAS_NUM_THREADS, when set, wins. OpenBLAS reads its
// environment when loaded, before main, hence the call. (deploy/install-deps.sh does not install
// OpenBLAS: with it, prometheus-cpp's HTTP exposer fails to start; BENCHMARK.md.)
const bool kBlasThreadsSet = [] {
  if (std::getenv("OPENBLAS_NUM_THREADS") != nullptr) return false;
  using SetThreads = void (*)(int);
  auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
  if (set == nullptr) return false;
  set(1);
  return true;
}();
double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
}  // namespace

std::string TorchVersion() { return TORCH_VERSION; }

absl::StatusOr<TrainStepOutput> RunTrainStep(const Decoder& decoder, const TrainStepInput& in) {
  TrainStepOutput out;
  try {
    torch::AutoGradMode enable(true);  // callers may run under a no-grad guard
    const int F = decoder.input_dim();
    auto opts = torch::TensorOptions().dtype(torch::kFloat32);
    const double t0 = Now();
    torch::Tensor x = torch::from_blob(in.features, {in.rows, F}, opts).requires_grad_(true);
    // Wrap the decoder's parameter buffer without copying; its gradient comes back in one buffer.
    std::vector<float> params = decoder.params();  // autograd needs a writable leaf
    torch::Tensor flat = torch::from_blob(params.data(), {int64_t(params.size())}, opts)
                             .requires_grad_(in.train_decoder);
    torch::Tensor h = x;
    const auto& layers = decoder.layers();
    for (size_t k = 0; k < layers.size(); ++k) {
      const auto& L = layers[k];
      torch::Tensor W =
          flat.narrow(0, int64_t(L.weight_offset), int64_t(L.in) * L.out).view({L.out, L.in});
      torch::Tensor b = flat.narrow(0, int64_t(L.bias_offset), L.out);
      h = torch::addmm(b, h, W.t());
      if (k + 1 < layers.size()) h = torch::relu(h);
    }
    torch::Tensor sdf = h.squeeze(1);
    torch::Tensor pred = sdf.narrow(0, 0, in.labelled);
    torch::Tensor labels = torch::from_blob(const_cast<float*>(in.labels), {in.labelled}, opts);
    const float inv_sigma = 1.f / in.sigma_m;
    torch::Tensor target = torch::sigmoid(-labels * inv_sigma);
    torch::Tensor loss = torch::binary_cross_entropy_with_logits(-pred * inv_sigma, target);
    const int probes = in.rows - in.labelled;
    if (in.eikonal_weight > 0.f && probes >= 6) {
      torch::Tensor p = sdf.narrow(0, in.labelled, probes / 6 * 6).view({probes / 6, 3, 2});
      torch::Tensor grad = (p.select(2, 0) - p.select(2, 1)) / (2.f * in.eikonal_step_m);
      torch::Tensor eik = (grad.norm(2, 1) - 1.f).pow(2).mean();
      loss = loss + in.eikonal_weight * eik;
    }
    const double t1 = Now();
    loss.backward();
    const double t2 = Now();
    out.loss = loss.item<float>();
    out.grad_features.resize(size_t(in.rows) * F);
    torch::Tensor gx = x.grad().contiguous();
    std::memcpy(out.grad_features.data(), gx.data_ptr<float>(), out.grad_features.size() * 4);
    if (in.train_decoder) {
      out.grad_params.resize(params.size());
      torch::Tensor gp = flat.grad().contiguous();
      std::memcpy(out.grad_params.data(), gp.data_ptr<float>(), params.size() * 4);
    }
    out.forward_s = t1 - t0;
    out.backward_s = t2 - t1;
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("training step failed in libtorch: ", e.what()));
  }
  return out;
}

struct ReferenceTrainer::State {
  // Dense Adam moments per level, like the grids (or views of the local map's moment records:
  // m and v of a slot side by side).
  std::vector<torch::Tensor> m, v;
  std::vector<float> decoder_m, decoder_v;
  int64_t step = 0;  // one global step count, as torch::optim::Adam keeps per parameter
  LocalEncoding encoding;
};

ReferenceTrainer::ReferenceTrainer(const MapperConfig& config, LocalMap* map, Decoder* decoder,
                                   bool moments_in_map)
    : config_(config), map_(map), decoder_(decoder), state_(std::make_unique<State>()) {
  const int64_t D = map->geometry().feature_dim();
  for (int l = 0; l < map->geometry().levels(); ++l) {
    LocalMap::Level& lv = map->level(l);
    const int64_t rows = lv.slots();
    if (!moments_in_map) {
      state_->m.push_back(torch::zeros({rows, D}));
      state_->v.push_back(torch::zeros({rows, D}));
      continue;
    }
    const int64_t record = rows > 1 ? int64_t(lv.adam_m(1) - lv.adam_m(0)) : 2 * D;
    const torch::Tensor moments = torch::from_blob(lv.adam_m(0), {rows, record},
                                                   torch::TensorOptions().dtype(torch::kFloat32));
    state_->m.push_back(moments.narrow(1, 0, D));
    state_->v.push_back(moments.narrow(1, lv.adam_v(0) - lv.adam_m(0), D));
  }
  state_->decoder_m.assign(decoder->params().size(), 0.f);
  state_->decoder_v.assign(decoder->params().size(), 0.f);
}

ReferenceTrainer::~ReferenceTrainer() = default;

absl::StatusOr<float> ReferenceTrainer::Iterate(const float* xyz, const float* labels, int n,
                                                bool train_decoder) {
  try {
    torch::AutoGradMode enable(true);
    const MapGeometry& geo = map_->geometry();
    const int L = geo.levels(), D = geo.feature_dim();
    auto f32 = torch::TensorOptions().dtype(torch::kFloat32);
    // Corner slots and trilinear weights are geometry only (no parameter): take them from the
    // encoder, then do the differentiable part, gather and blend, in libtorch.
    std::vector<float> unused(size_t(n) * geo.encoding_dim());
    EncodeLocal(*map_, xyz, n, &state_->encoding, unused.data());
    const torch::Tensor slots =
        torch::from_blob(state_->encoding.slots.data(), {n, L, 8}, torch::kInt64);
    const torch::Tensor weights = torch::from_blob(state_->encoding.weights.data(), {n, L, 8}, f32);
    std::vector<torch::Tensor> grids, per_level;
    for (int l = 0; l < L; ++l) {
      LocalMap::Level& lv = map_->level(l);
      grids.push_back(torch::from_blob(lv.features(0), {lv.slots(), D}, f32).requires_grad_(true));
      const torch::Tensor corners =
          grids.back().index_select(0, slots.select(1, l).reshape({-1})).view({n, 8, D});
      per_level.push_back((corners * weights.select(1, l).unsqueeze(2)).sum(1));
    }
    torch::Tensor h = torch::cat(per_level, 1);
    std::vector<float> params = decoder_->params();
    torch::Tensor flat =
        torch::from_blob(params.data(), {int64_t(params.size())}, f32).requires_grad_(true);
    const auto& layers = decoder_->layers();
    for (size_t k = 0; k < layers.size(); ++k) {
      const auto& Lk = layers[k];
      torch::Tensor W =
          flat.narrow(0, int64_t(Lk.weight_offset), int64_t(Lk.in) * Lk.out).view({Lk.out, Lk.in});
      h = torch::addmm(flat.narrow(0, int64_t(Lk.bias_offset), Lk.out), h, W.t());
      if (k + 1 < layers.size()) h = torch::relu(h);
    }
    const float inv_sigma = 1.f / config_.train.sigma_m;
    const torch::Tensor target =
        torch::sigmoid(-torch::from_blob(const_cast<float*>(labels), {n}, f32) * inv_sigma);
    torch::Tensor loss = torch::binary_cross_entropy_with_logits(-h.squeeze(1) * inv_sigma, target);
    loss.backward();

    // Dense Adam over every row of every grid, and over the decoder.
    torch::NoGradGuard no_grad;
    const TrainConfig& t = config_.train;
    const int64_t step = ++state_->step;
    const double bc1 = 1.0 - std::pow(double(t.adam_beta1), double(step));
    const double bc2 = 1.0 - std::pow(double(t.adam_beta2), double(step));
    const float step_size = float(double(t.learning_rate) / bc1);
    const float inv_sqrt_bc2 = float(1.0 / std::sqrt(bc2));
    auto adam = [&](torch::Tensor p, const torch::Tensor& g, torch::Tensor m, torch::Tensor v) {
      m.mul_(t.adam_beta1).add_(g, 1.f - t.adam_beta1);
      v.mul_(t.adam_beta2).addcmul_(g, g, 1.f - t.adam_beta2);
      p.sub_(step_size * m / (v.sqrt() * inv_sqrt_bc2 + t.adam_eps));
    };
    for (int l = 0; l < L; ++l) adam(grids[l], grids[l].grad(), state_->m[l], state_->v[l]);
    if (train_decoder) {
      const int64_t P = int64_t(params.size());
      adam(torch::from_blob(decoder_->params().data(), {P}, f32), flat.grad(),
           torch::from_blob(state_->decoder_m.data(), {P}, f32),
           torch::from_blob(state_->decoder_v.data(), {P}, f32));
    }
    return loss.item<float>();
  } catch (const std::exception& e) {
    return absl::InternalError(
        absl::StrCat("reference training step failed in libtorch: ", e.what()));
  }
}

}  // namespace rim
