// The training state of a mapper, taken apart so that each stage of one iteration (§3.4 step 3)
// can be timed on its own: the live local map, the decoder, the point buffer and a trainer, warmed
// up on the first frames of the city sequence the way Mapper::IntegrateScan would (slide, split,
// buffer, iterate), then one labelled batch carried through every stage so that each stage
// benchmark starts from the previous stage's real output.
//
// Differences from the mapper, none of which the timed stages depend on: leaving slabs are
// dropped instead of saved, and free-space marking and sub-map activity are skipped.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "rim/base/scan.h"
#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/map/map_geometry.h"
#include "rim/model/decoder.h"
#include "rim/model/encoder.h"
#include "rim/train/point_buffer.h"
#include "rim/train/sampler.h"
#include "rim/train/train_step.h"
#include "rim/train/trainer.h"

namespace rim::bench {

class TrainingFixture {
 public:
  // Integrates `warmup_frames` frames of `frames` at `config`'s iterations per frame.
  TrainingFixture(const MapperConfig& config, const std::vector<PosedScan>& frames,
                  int warmup_frames);

  // Slides the box to the scan and adds its inside points to the buffer (Alg. 1 steps 1–2).
  void AddFrame(const PosedScan& scan);

  // Samples, encodes and runs the loss on a fresh batch, and scatters its gradient, so that
  // batch(), encoding(), features(), step_output() and gradient() hold one iteration's data.
  void PrepareBatch();

  // The stages, each on the data the previous one left (PrepareBatch first).
  void Sample();
  void Encode();
  void TrainStep(bool train_decoder);  // forward + backward through libtorch
  void Scatter();
  void AdamFeatures();  // lazy Adam over the rows the batch touched (Trainer's feature update)
  void AdamDecoder();
  // Not a stage of the trainer: the decoder's plain C++ forward with the input gradient (what
  // queries use) on the same batch, the floor for a hand-written forward+backward once the
  // decoder is frozen.
  void PlainForward();

  const MapperConfig& config() const { return config_; }
  LocalMap& map() { return *map_; }
  Trainer& trainer() { return *trainer_; }
  const PointBuffer& buffer() const { return *buffer_; }
  const OutsideRays& outside() const { return outside_; }
  const SampleBatch& batch() const { return batch_; }
  const TrainStepOutput& step_output() const { return step_output_; }
  const std::vector<float>& features() const { return features_; }
  const Decoder& decoder() const { return *decoder_; }
  Decoder& mutable_decoder() { return *decoder_; }
  SparseGradient& gradient() { return gradient_; }
  AdamBiasTable& bias() { return bias_; }
  // Rows (voxels) with a feature gradient this iteration, summed over levels.
  size_t TouchedRows();

  // The optimiser stages, repeated thousands of times on one gradient, would walk the touched
  // features and the decoder far from anything training produces: benchmarks of them save what
  // they change first and put it back after.
  void SaveOptimiserState();
  void RestoreOptimiserState();

 private:
  MapperConfig config_;
  std::unique_ptr<MapGeometry> geometry_;
  std::unique_ptr<LocalMap> map_;
  std::unique_ptr<Decoder> decoder_;
  std::unique_ptr<PointBuffer> buffer_;
  std::unique_ptr<Trainer> trainer_;
  OutsideRays outside_;

  Sampler sampler_;
  SampleBatch batch_;
  LocalEncoding encoding_;
  std::vector<float> features_;
  TrainStepOutput step_output_;
  std::vector<float> sdf_, dsdf_;
  SparseGradient gradient_;
  AdamBiasTable bias_;

  struct SavedLevel {
    std::vector<float> features, adam_m, adam_v;
    std::vector<int32_t> adam_steps;
    std::vector<uint8_t> flags;
  };
  std::vector<SavedLevel> saved_levels_;
  std::string saved_decoder_;
};

// One fixture for every stage benchmark: the maicity preset warmed up on the first
// Options().warmup_frames frames of the city sequence, with a prepared batch. Built on first use.
TrainingFixture& SharedTrainingFixture();

}  // namespace rim::bench
