#include "rim/train_step.h"

#include <dlfcn.h>
#include <torch/torch.h>

#include <chrono>
#include <cstdlib>

#include "absl/strings/str_cat.h"
#include "rim/version.h"

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

}  // namespace rim
