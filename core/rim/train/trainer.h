// One training iteration (§3.4 step 3): sample rays, encode, decode, loss, backward, then Adam on
// the decoder and on only the voxels the batch touched.
#pragma once

#include <atomic>
#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "rim/base/worker_pool.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/model/decoder.h"
#include "rim/model/encoder.h"
#include "rim/train/mlp_step.h"
#include "rim/train/sampler.h"
#include "rim/train/train_step.h"

namespace rim {

class ClearedPoints;

struct IterationTiming {
  double sample_s = 0, encode_s = 0, forward_s = 0, backward_s = 0, step_s = 0;
  double sync_s = 0;  // of step_s, on the GPU path: the syncs with the host map (docs/gpu.md)
};

// Lazy Adam on touched rows [begin, end) of one level: each row moves with its own step count and
// is marked as holding data. Rows are distinct slots, so disjoint ranges may run concurrently.
void UpdateTouchedRows(const AdamHyper& hyper, const AdamBiasTable& bias,
                       const SparseGradient::Level& g, size_t begin, size_t end,
                       LocalMap::Level* lv);

// Reorders a batch's samples (positions, labels; endpoint indices follow) by the cell of the box
// that holds them (cells of twice the coarsest level's size), stably. The encode, the gradient
// scatter and the Adam pass each visit every sample's corner rows in batch order, and they are
// bound by how many cache lines are in flight: in the sampler's order (rays drawn at random) nearly
// every row is a miss, while samples of one cell share most of their rows and neighbouring cells'
// rows lie close in memory. Frame/far (2048-ray batches): step −8 to −18 %, encode −6 to −10 %,
// the frame −2 to −7 % with the sort's 0.15–0.2 ms an iteration paid (BENCHMARK.md,
// "Prefetch distances, and training samples in cell order"). The map learns the same sums in
// another order: C-L1 the same within 0.2 % on held-out cities.
struct BatchOrderScratch {
  static constexpr int kCellScale = 2;  // cells of this many coarsest-level cells a side
  std::vector<uint32_t> keys, starts;
  std::vector<float> xyz, labels;
  std::vector<int32_t> moved_to;
};
void OrderBatchByCell(const LocalMap& map, SampleBatch* batch, BatchOrderScratch* scratch);

class Trainer {
 public:
  Trainer(const MapperConfig& config, LocalMap* map, Decoder* decoder);

  // Runs one iteration; returns the loss (0 when there is nothing to learn from yet).
  absl::StatusOr<float> Iterate(const PointBuffer& buffer, const OutsideRays& outside,
                                bool train_decoder, IterationTiming* timing);

  // One iteration in two parts, for a caller that shares the map with readers (Mapper). Prepare
  // samples, encodes and runs the network forward and backward: it reads the map, the decoder,
  // the buffer and the outside rays and writes only the trainer's own state, so other readers may
  // run beside it. Apply writes: the features' Adam step, the observed flags, the decoder's step;
  // it needs the map alone. Iterate is Prepare then Apply, with the same bits.
  // `rays` > 0: a batch of that many rays (Sampler::Sample).
  absl::Status Prepare(const PointBuffer& buffer, const OutsideRays& outside, bool train_decoder,
                       IterationTiming* timing, int rays = 0);
  absl::StatusOr<float> Apply(bool train_decoder, IterationTiming* timing);

  // One iteration on the given samples instead of sampled ones (the same steps after sampling):
  // what tests use to run this trainer and the reference on identical batches.
  absl::StatusOr<float> IterateOn(const SampleBatch& batch, bool train_decoder,
                                  IterationTiming* timing);

  // Free-space samples where moving things stood (train/transient.h): every batch gets
  // transient.clear_samples_per_iteration of them (scaled to a smaller batch's rays) while
  // `cleared` holds any. nullptr: none.
  void SetCleared(const ClearedPoints* cleared) { cleared_ = cleared; }

  // The samples of one iteration without training on them, for the GPU path (docs/gpu.md): the
  // same batch Prepare draws, labelled samples then eikonal probes in rows_xyz(), the labels in
  // last_batch().labels. `rays` as for Prepare.
  absl::Status SampleRows(const PointBuffer& buffer, const OutsideRays& outside,
                          IterationTiming* timing, int rays = 0);
  const std::vector<float>& rows_xyz() const { return xyz_; }

  Sampler& sampler() { return sampler_; }
  // The training threads, for other work of the mapper's between iterations (never during one).
  WorkerPool& pool() { return pool_; }
  const SampleBatch& last_batch() const { return batch_; }

 private:
  absl::Status PrepareBatch(bool train_decoder, IterationTiming* timing);
  // Prepare's sampling: the batch (and the cleared samples where moving things stood).
  void DrawBatch(const PointBuffer& buffer, const OutsideRays& outside, IterationTiming* timing,
                 int rays);
  // The batch in cell order, then xyz_: its positions and the eikonal probes.
  void BuildRows();
  void AddEikonalProbes();
  // Gradient scatter, lazy Adam on the touched rows and observed marking, in one pool region.
  void UpdateFeatures(const float* grad_features);
  void MarkObserved();

  MapperConfig config_;
  LocalMap* map_;
  Decoder* decoder_;
  Sampler sampler_;
  SampleBatch batch_;
  BatchOrderScratch order_scratch_;
  std::vector<float> xyz_;  // labelled samples, then eikonal probes
  LocalEncoding encoding_;
  std::vector<float> features_;
  MlpTrainStep mlp_;
  TrainStepOutput step_out_;
  SparseGradient grad_;
  AdamBiasTable bias_;
  // UpdateFeatures: which levels are scattered. One cache line each, so that the Adam tasks
  // spinning on a flag never read a line that the scatter on the other thread writes (a guard:
  // aligning these alone did not change the step; aligning SparseGradient::Level did,
  // BENCHMARK.md, "False sharing in the training step").
  struct alignas(64) StageFlag {
    std::atomic<int> done{0};
  };
  std::vector<StageFlag> stage_flags_;
  bool grad_ready_ = false;
  bool prepared_ = false;  // Prepare left a batch for Apply
  const ClearedPoints* cleared_ = nullptr;
  std::unique_ptr<ReferenceTrainer> reference_;  // train.step = "reference" only
  WorkerPool pool_;  // last: its threads stop before the buffers they use go away
};

}  // namespace rim
