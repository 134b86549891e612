#include "rim/train/trainer.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>
#include <vector>

#include "rim/train/train_step.h"
#include "rim/train/transient.h"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace rim {
namespace {
void CpuRelax() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#else
  std::this_thread::yield();
#endif
}
double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
// Eikonal probes are taken around at most this many endpoint samples per iteration.
constexpr int kMaxEikonalPoints = 1024;
}  // namespace

void OrderBatchByCell(const LocalMap& map, SampleBatch* batch, BatchOrderScratch* scratch) {
  const size_t n = batch->size();
  if (n < 2 || !map.placed()) return;
  // Cells of S times the coarsest level's size, numbered in the box (x slowest, z fastest, as the
  // storage's slots).
  constexpr int S = BatchOrderScratch::kCellScale;
  const int lc = map.geometry().levels() - 1;
  const Int3 cells = (map.geometry().cells(lc) + Int3::Constant(S - 1)) / S;
  const Int3 lo = map.LatticeBox(lc).lo;
  const float inv = float(1.0 / (S * map.geometry().voxel_m(lc)));
  const float lo_f[3] = {float(lo[0]) / S, float(lo[1]) / S, float(lo[2]) / S};
  const size_t buckets = size_t(cells.x()) * size_t(cells.y()) * size_t(cells.z());
  std::vector<uint32_t>& key = scratch->keys;
  std::vector<uint32_t>& start = scratch->starts;
  key.resize(n);
  start.assign(buckets + 1, 0);
  const float* xyz = batch->xyz.data();
  for (size_t i = 0; i < n; ++i) {
    int g[3];
    // Truncation is the floor for the box's cells (u >= 0); anything else is clamped into the box.
    // (std::floor is a library call without SSE4.1: about a tenth of the sort.) Only the order
    // depends on it, never a value.
    for (int a = 0; a < 3; ++a)
      g[a] = std::clamp(int(xyz[3 * i + a] * inv - lo_f[a]), 0, cells[a] - 1);
    key[i] = uint32_t((size_t(g[0]) * size_t(cells.y()) + size_t(g[1])) * size_t(cells.z()) +
                      size_t(g[2]));
    ++start[key[i] + 1];
  }
  for (size_t k = 1; k <= buckets; ++k) start[k] += start[k - 1];
  // A stable counting sort: within a cell, the samples keep the sampler's order. (Split over the
  // pool's two threads it was slower: two more regions, and each thread's writes land in the
  // other's cache.)
  std::vector<float>& xyz_out = scratch->xyz;
  std::vector<float>& labels_out = scratch->labels;
  std::vector<int32_t>& moved_to = scratch->moved_to;
  // The batch's arrays and these trade places: with the same capacity, so that the sampler's next
  // batch fills them without a reallocation (and fresh pages) each iteration.
  xyz_out.reserve(batch->xyz.capacity());
  labels_out.reserve(batch->labels.capacity());
  xyz_out.resize(3 * n);
  labels_out.resize(n);
  moved_to.resize(n);
  const float* labels = batch->labels.data();
  for (size_t i = 0; i < n; ++i) {
    const uint32_t at = start[key[i]]++;
    moved_to[i] = int32_t(at);
    float* to = &xyz_out[3 * size_t(at)];  // three stores (std::copy_n became a memmove call)
    to[0] = xyz[3 * i];
    to[1] = xyz[3 * i + 1];
    to[2] = xyz[3 * i + 2];
    labels_out[at] = labels[i];
  }
  batch->xyz.swap(xyz_out);
  batch->labels.swap(labels_out);
  for (int32_t& e : batch->endpoints) e = moved_to[size_t(e)];
}

Trainer::Trainer(const MapperConfig& config, LocalMap* map, Decoder* decoder)
    : config_(config),
      map_(map),
      decoder_(decoder),
      sampler_(config.sampler, config.train.sigma_m, config.sampler.seed),
      bias_(AdamHyper{config.train.learning_rate, config.train.adam_beta1, config.train.adam_beta2,
                      config.train.adam_eps}),
      pool_(config.train.threads) {
  if (config.train.step == "reference")
    reference_ = std::make_unique<ReferenceTrainer>(config, map, decoder, /*moments_in_map=*/true);
}

void Trainer::AddEikonalProbes() {
  const float h = float(0.5 * map_->geometry().leaf_m());
  const Vec3f lo = map_->min_m().cast<float>() + Vec3f::Constant(h + 1e-3f);
  const Vec3f hi = map_->max_m().cast<float>() - Vec3f::Constant(h + 1e-3f);
  int added = 0;
  for (int32_t idx : batch_.endpoints) {
    if (added >= kMaxEikonalPoints) break;
    const Vec3f p(batch_.xyz[3 * idx], batch_.xyz[3 * idx + 1], batch_.xyz[3 * idx + 2]);
    if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) continue;
    for (int a = 0; a < 3; ++a)
      for (float s : {h, -h}) {
        Vec3f q = p;
        q[a] += s;
        xyz_.insert(xyz_.end(), {q.x(), q.y(), q.z()});
      }
    ++added;
  }
}

absl::StatusOr<float> Trainer::Iterate(const PointBuffer& buffer, const OutsideRays& outside,
                                       bool train_decoder, IterationTiming* timing) {
  RIM_RETURN_IF_ERROR(Prepare(buffer, outside, train_decoder, timing));
  return Apply(train_decoder, timing);
}

absl::Status Trainer::Prepare(const PointBuffer& buffer, const OutsideRays& outside,
                              bool train_decoder, IterationTiming* timing, int rays) {
  if (!grad_ready_) {
    grad_.Reset(*map_);
    grad_ready_ = true;
  }
  DrawBatch(buffer, outside, timing, rays);
  return PrepareBatch(train_decoder, timing);
}

absl::Status Trainer::SampleRows(const PointBuffer& buffer, const OutsideRays& outside,
                                 IterationTiming* timing, int rays) {
  DrawBatch(buffer, outside, timing, rays);
  const double t0 = Now();
  xyz_.clear();
  if (batch_.size() > 0) BuildRows();
  if (timing) timing->sample_s += Now() - t0;
  return absl::OkStatus();
}

void Trainer::BuildRows() {
  OrderBatchByCell(*map_, &batch_, &order_scratch_);
  xyz_ = batch_.xyz;
  if (config_.train.eikonal_weight > 0.f) AddEikonalProbes();
}

void Trainer::DrawBatch(const PointBuffer& buffer, const OutsideRays& outside,
                        IterationTiming* timing, int rays) {
  const double t0 = Now();
  sampler_.Sample(buffer, outside, map_->min_m(), map_->max_m(), &batch_, &pool_, rays);
  const TransientConfig& tr = config_.transient;
  if (cleared_ != nullptr && cleared_->size() > 0 && tr.clear_samples_per_iteration > 0) {
    // Drawn only while there is something to clear, so that a map without moving things takes
    // the same batches as before.
    const int configured = config_.sampler.rays_per_iteration;
    const int n =
        rays > 0 && rays != configured
            ? std::max(1, int(int64_t(tr.clear_samples_per_iteration) * rays / configured))
            : tr.clear_samples_per_iteration;
    FastRng rng(sampler_.rng()());
    cleared_->Sample(n, 3.f * config_.train.sigma_m, tr.clear_label_m, map_->min_m().cast<float>(),
                     map_->max_m().cast<float>(), &rng, &batch_);
  }
  if (timing) timing->sample_s += Now() - t0;
}

absl::StatusOr<float> Trainer::IterateOn(const SampleBatch& batch, bool train_decoder,
                                         IterationTiming* timing) {
  if (!grad_ready_) {
    grad_.Reset(*map_);
    grad_ready_ = true;
  }
  batch_ = batch;
  RIM_RETURN_IF_ERROR(PrepareBatch(train_decoder, timing));
  return Apply(train_decoder, timing);
}

absl::Status Trainer::PrepareBatch(bool train_decoder, IterationTiming* timing) {
  prepared_ = false;
  if (batch_.size() == 0) return absl::OkStatus();
  const double t0 = Now();
  BuildRows();
  const int rows = int(xyz_.size() / 3);
  const double t1 = Now();
  features_.resize(size_t(rows) * map_->geometry().encoding_dim());
  EncodeLocal(*map_, xyz_.data(), rows, &encoding_, features_.data(), &pool_);
  const double t2 = Now();
  if (timing) {
    timing->sample_s += t1 - t0;
    timing->encode_s += t2 - t1;
  }
  prepared_ = true;
  // The reference trains in one pass that writes the map: all of it is Apply's.
  if (reference_) return absl::OkStatus();

  TrainStepInput in;
  in.features = features_.data();
  in.rows = rows;
  in.labelled = int(batch_.size());
  in.labels = batch_.labels.data();
  in.sigma_m = config_.train.sigma_m;
  in.eikonal_weight = config_.train.eikonal_weight;
  in.eikonal_step_m = float(0.5 * map_->geometry().leaf_m());
  in.train_decoder = train_decoder;
  if (config_.train.step == "libtorch") {
    auto ref = RunTrainStep(*decoder_, in);
    if (!ref.ok()) {
      prepared_ = false;
      return ref.status();
    }
    step_out_ = *std::move(ref);
  } else if (absl::Status s = mlp_.Run(*decoder_, in, &step_out_, &pool_); !s.ok()) {
    prepared_ = false;
    return s;
  }
  if (timing) {
    timing->forward_s += step_out_.forward_s;
    timing->backward_s +=
        step_out_.backward_s + (Now() - t2 - step_out_.forward_s - step_out_.backward_s);
  }
  return absl::OkStatus();
}

absl::StatusOr<float> Trainer::Apply(bool train_decoder, IterationTiming* timing) {
  if (!prepared_) return 0.f;  // nothing sampled yet: nothing to learn from
  prepared_ = false;
  const double t0 = Now();
  if (reference_) {
    // The whole iteration through the dense reference (labelled samples only: it has no eikonal
    // term); the encode of Prepare serves the observed marking, as in the fast path.
    auto loss = reference_->Iterate(batch_.xyz.data(), batch_.labels.data(), int(batch_.size()),
                                    train_decoder);
    if (!loss.ok()) return loss.status();
    // A slot holds data (is saved when it leaves, checkpointed) when flagged or when it has a step
    // count; the reference keeps one global count, so give every slot it trained one here. The
    // coarse levels have no flags: without this their trained rows were dropped on leaving.
    const int L = map_->geometry().levels();
    for (size_t i = 0; i < batch_.size(); ++i)
      for (int l = 0; l < L; ++l) {
        LocalMap::Level& lv = map_->level(l);
        for (int c = 0; c < 8; ++c) {
          int32_t& steps = lv.adam_steps(encoding_.slots[(i * size_t(L) + size_t(l)) * 8 + c]);
          if (steps == 0) steps = 1;
        }
      }
    MarkObserved();
    if (timing) timing->step_s += Now() - t0;
    return *loss;
  }
  grad_.BeginIteration(map_);
  UpdateFeatures(step_out_.grad_features.data());
  if (train_decoder) {
    const AdamHyper hyper{config_.train.learning_rate, config_.train.adam_beta1,
                          config_.train.adam_beta2, config_.train.adam_eps};
    decoder_->Step(hyper, step_out_.grad_params);
  }
  if (timing) timing->step_s += Now() - t0;
  return step_out_.loss;
}

namespace {
// How far ahead the Adam pass asks for a row's lines. Each row needs three random lines (features,
// moments, step count); 8 rows ahead left the pass waiting on rows still in flight. With batches
// in random order 16 took 9 % off the step and 32 did no better; in cell order (OrderBatchByCell)
// 32 took another 4–10 % off, and 64 did no better (BENCHMARK.md, "Prefetch distances, and
// training samples in cell order").
constexpr size_t kPrefetchRows = 32;

#if defined(__x86_64__)
// AdamUpdateRow for one D = 8 row, four lanes at a time: the same multiplies, adds, square roots
// and divisions in the same order (SSE has no fused multiply-add), so the bits are the same.
// Written out because the compiler left the fixed-length loop scalar: it could not rule out that
// m and v (one record) overlap the feature row, and the scalar square roots and divisions were
// most of the Adam pass (`perf annotate`).
inline void AdamRow8Sse(const AdamHyper& h, float step_size, float inv_sqrt_bc2, const float* grad,
                        float* param, float* m, float* v) {
  const __m128 b1 = _mm_set1_ps(h.beta1), c1 = _mm_set1_ps(1.f - h.beta1);
  const __m128 b2 = _mm_set1_ps(h.beta2), c2 = _mm_set1_ps(1.f - h.beta2);
  const __m128 ss = _mm_set1_ps(step_size), ib = _mm_set1_ps(inv_sqrt_bc2);
  const __m128 eps = _mm_set1_ps(h.eps);
  for (int k = 0; k < 8; k += 4) {
    const __m128 g = _mm_loadu_ps(grad + k);
    const __m128 mm = _mm_add_ps(_mm_mul_ps(b1, _mm_loadu_ps(m + k)), _mm_mul_ps(c1, g));
    const __m128 vv =
        _mm_add_ps(_mm_mul_ps(b2, _mm_loadu_ps(v + k)), _mm_mul_ps(_mm_mul_ps(c2, g), g));
    const __m128 den = _mm_add_ps(_mm_mul_ps(_mm_sqrt_ps(vv), ib), eps);
    const __m128 pp = _mm_sub_ps(_mm_loadu_ps(param + k), _mm_div_ps(_mm_mul_ps(ss, mm), den));
    _mm_storeu_ps(m + k, mm);
    _mm_storeu_ps(v + k, vv);
    _mm_storeu_ps(param + k, pp);
  }
}
#endif
}  // namespace

void UpdateTouchedRows(const AdamHyper& hyper, const AdamBiasTable& bias,
                       const SparseGradient::Level& g, size_t begin, size_t end,
                       LocalMap::Level* lv) {
  const int D = lv->feature_dim();
  for (size_t r = begin; r < end; ++r) {
    // Rows are scattered over the dense grid: start loading a later row's features, moments,
    // and step count now, so that the misses overlap instead of queueing one after
    // another.
    if (r + kPrefetchRows < end) {
      const int64_t ahead = g.touched[r + kPrefetchRows];
      __builtin_prefetch(lv->features(ahead), 1);
      __builtin_prefetch(lv->adam_m(ahead), 1);
      __builtin_prefetch(&lv->adam_steps(ahead), 1);
    }
    const int64_t slot = g.touched[r];
    float step_size, inv_sqrt_bc2;
    bias.Get(++lv->adam_steps(slot), &step_size, &inv_sqrt_bc2);
    if (D == 8) {  // every preset
#if defined(__x86_64__)
      AdamRow8Sse(hyper, step_size, inv_sqrt_bc2, &g.grad[r * 8], lv->features(slot),
                  lv->adam_m(slot), lv->adam_v(slot));
#else
      AdamUpdateFixedRow<8>(hyper, step_size, inv_sqrt_bc2, &g.grad[r * 8], lv->features(slot),
                            lv->adam_m(slot), lv->adam_v(slot));
#endif
    } else {
      AdamUpdateRow(hyper, step_size, inv_sqrt_bc2, D, &g.grad[r * D], lv->features(slot),
                    lv->adam_m(slot), lv->adam_v(slot));
    }
  }
}

void Trainer::UpdateFeatures(const float* grad_features) {
  const AdamHyper hyper{config_.train.learning_rate, config_.train.adam_beta1,
                        config_.train.adam_beta2, config_.train.adam_eps};
  const int L = map_->geometry().levels();
  // Four Adam chunks per thread and level: the last chunks are small, so the threads finish
  // together (with one chunk per thread, one of them idled ~0.4 ms at the end of the region).
  const int chunks = 4 * pool_.threads();
  // One region, three kinds of task, numbered in the order the pool hands them out:
  //   [0, L)              scatter of level l (its rows and sums need no other level);
  //   L                   observed marking (level 0's flag bytes, which nothing else here
  //                       writes: the Adam pass keeps step counts, not flags);
  //   [L + 1, …)          lazy Adam on a chunk of level l's touched rows, once level l is
  //                       scattered (rows are distinct slots: chunks never share one).
  // A task only ever waits for tasks with smaller numbers, which some thread has already taken,
  // so the waits end; with one thread nothing waits. Without barriers between the stages, the
  // levels' unequal scatters and Adam passes do not leave a thread idle.
  std::vector<StageFlag>& scattered = stage_flags_;  // per level
  if (int(scattered.size()) != L) scattered = std::vector<StageFlag>(L);
  for (auto& f : scattered) f.done.store(0, std::memory_order_relaxed);
  const int mark_task = L;
  pool_.Run(L + 1 + L * chunks, [&](int task) {
    if (task < L) {
      grad_.ScatterLevel(map_, encoding_, grad_features, task);
      scattered[task].done.store(1, std::memory_order_release);
    } else if (task != mark_task) {
      const int adam = task - L - 1;
      const int l = adam / chunks, c = adam % chunks;
      while (scattered[l].done.load(std::memory_order_acquire) == 0) CpuRelax();
      SparseGradient::Level& g = grad_.level(l);
      // Lazy Adam: only rows with a gradient this iteration move, each with its own step count.
      const size_t n = g.touched.size();
      const size_t begin = n * size_t(c) / size_t(chunks);
      const size_t end = n * size_t(c + 1) / size_t(chunks);
      UpdateTouchedRows(hyper, bias_, g, begin, end, &map_->level(l));
    } else {
      MarkObserved();
    }
  });
}

void Trainer::MarkObserved() {
  LocalMap::Level& lv = map_->level(0);
  const size_t L = size_t(map_->geometry().levels());
  const float band = config_.sampler.observed_band_m;
  for (size_t i = 0; i < batch_.size(); ++i) {
    // Near the surface: observed and meshed. Well in front of it: seen free, so a query there
    // reports a measured (positive) distance. Far behind a surface nothing was seen.
    const float label = batch_.labels[i];
    uint8_t bits;
    if (std::abs(label) < band) {
      bits = LocalMap::kObserved;
    } else if (label > 0) {
      bits = LocalMap::kSeenFree;
    } else {
      continue;
    }
    // The finest voxel holding the sample is the minimum corner (corner 0) of its level-0 cell,
    // whose slot the encode already found.
    lv.flags(encoding_.slots[i * L * 8]) |= bits | LocalMap::kHasData;
  }
}

}  // namespace rim
