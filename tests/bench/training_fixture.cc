#include "bench/training_fixture.h"

#include <algorithm>

#include "bench/bench_common.h"
#include "rim/base/binary_io.h"

namespace rim::bench {
namespace {

AdamHyper Hyper(const TrainConfig& t) {
  return AdamHyper{t.learning_rate, t.adam_beta1, t.adam_beta2, t.adam_eps};
}

}  // namespace

TrainingFixture::TrainingFixture(const MapperConfig& config, const std::vector<PosedScan>& frames,
                                 int warmup_frames)
    : config_(config),
      geometry_(std::make_unique<MapGeometry>(config.grid)),
      map_(std::make_unique<LocalMap>(*geometry_)),
      decoder_(std::make_unique<Decoder>(geometry_->encoding_dim(), config.decoder)),
      buffer_(std::make_unique<PointBuffer>(config.buffer, config.sampler.seed ^ 0x5bd1e995ull)),
      trainer_(std::make_unique<Trainer>(config, map_.get(), decoder_.get())),
      // A sampler of its own, so that the stage benchmarks leave the trainer's stream alone.
      sampler_(config.sampler, config.train.sigma_m, config.sampler.seed + 1),
      bias_(Hyper(config.train)) {
  const int n = std::min<int>(warmup_frames, int(frames.size()));
  for (int k = 0; k < n; ++k) {
    AddFrame(frames[k]);
    const bool train_decoder = k < config_.decoder.freeze_after_frames;
    for (int i = 0; i < config_.train.iterations; ++i)
      CheckOk(trainer_->Iterate(*buffer_, outside_, train_decoder, nullptr).status(),
              "Trainer::Iterate");
  }
  gradient_.Reset(*map_);
}

TrainingFixture& SharedTrainingFixture() {
  static TrainingFixture* fixture = [] {
    auto* f = new TrainingFixture(Preset("maicity"), CitySequence(), Options().warmup_frames);
    f->PrepareBatch();
    return f;
  }();
  return *fixture;
}

void TrainingFixture::AddFrame(const PosedScan& scan) {
  const Int3 origin = geometry_->BoxOriginFor(scan.T_world_sensor.translation());
  if (!map_->placed() || origin != map_->coarse_origin()) {
    map_->MoveTo(
        origin, [](SlabBatch&&) {}, [](int, const Int3&, float*, uint8_t*) { return false; });
  }
  const Eigen::Isometry3f T = scan.T_world_sensor.cast<float>();
  const Vec3f sensor_W = T.translation();
  std::vector<Vec3f> inside_p, inside_o;
  outside_.points_W.clear();
  outside_.origins_W.clear();
  for (const Vec3f& p_S : scan.points_S) {
    const float range = p_S.norm();
    if (range < config_.buffer.min_range_m || range > config_.buffer.max_range_m) continue;
    const Vec3f p_W = T * p_S;
    if (map_->Contains(p_W.cast<double>())) {
      inside_p.push_back(p_W);
      inside_o.push_back(sensor_W);
    } else {
      outside_.points_W.push_back(p_W);
      outside_.origins_W.push_back(sensor_W);
    }
  }
  buffer_->AddFrame(inside_p, inside_o);
  buffer_->RemoveOutside(map_->min_m(), map_->max_m());
}

void TrainingFixture::PrepareBatch() {
  Sample();
  Encode();
  TrainStep(/*train_decoder=*/true);
  Scatter();
}

void TrainingFixture::Sample() {
  sampler_.Sample(*buffer_, outside_, map_->min_m(), map_->max_m(), &batch_);
}

void TrainingFixture::Encode() {
  const int rows = int(batch_.size());
  features_.resize(size_t(rows) * geometry_->encoding_dim());
  EncodeLocal(*map_, batch_.xyz.data(), rows, &encoding_, features_.data());
}

void TrainingFixture::TrainStep(bool train_decoder) {
  TrainStepInput in;
  in.features = features_.data();
  in.rows = int(batch_.size());
  in.labelled = in.rows;
  in.labels = batch_.labels.data();
  in.sigma_m = config_.train.sigma_m;
  in.train_decoder = train_decoder;
  absl::StatusOr<TrainStepOutput> out = RunTrainStep(*decoder_, in);
  CheckOk(out.status(), "RunTrainStep");
  step_output_ = *std::move(out);
}

void TrainingFixture::Scatter() {
  gradient_.BeginIteration(map_.get());
  gradient_.Scatter(map_.get(), encoding_, step_output_.grad_features.data());
}

// What Trainer::UpdateFeatures runs after the scatter, on one thread.
void TrainingFixture::AdamFeatures() {
  const AdamHyper hyper = Hyper(config_.train);
  for (int l = 0; l < geometry_->levels(); ++l) {
    const SparseGradient::Level& g = gradient_.level(l);
    UpdateTouchedRows(hyper, bias_, g, 0, g.touched.size(), &map_->level(l));
  }
}

void TrainingFixture::AdamDecoder() {
  decoder_->Step(Hyper(config_.train), step_output_.grad_params);
}

void TrainingFixture::PlainForward() {
  const int rows = int(batch_.size());
  sdf_.resize(rows);
  dsdf_.resize(size_t(rows) * geometry_->encoding_dim());
  decoder_->Forward(features_.data(), rows, sdf_.data(), dsdf_.data());
}

size_t TrainingFixture::TouchedRows() {
  size_t rows = 0;
  for (int l = 0; l < geometry_->levels(); ++l) rows += gradient_.level(l).touched.size();
  return rows;
}

void TrainingFixture::SaveOptimiserState() {
  const int D = geometry_->feature_dim();
  saved_levels_.assign(geometry_->levels(), SavedLevel());
  for (int l = 0; l < geometry_->levels(); ++l) {
    const LocalMap::Level& lv = map_->level(l);
    SavedLevel& s = saved_levels_[l];
    for (int64_t slot : gradient_.level(l).touched) {
      s.features.insert(s.features.end(), lv.features(slot), lv.features(slot) + D);
      s.adam_m.insert(s.adam_m.end(), lv.adam_m(slot), lv.adam_m(slot) + D);
      s.adam_v.insert(s.adam_v.end(), lv.adam_v(slot), lv.adam_v(slot) + D);
      s.adam_steps.push_back(lv.adam_steps(slot));
      s.flags.push_back(lv.flags(slot));
    }
  }
  ByteWriter w;
  decoder_->Serialize(&w);
  saved_decoder_ = w.Release();
}

void TrainingFixture::RestoreOptimiserState() {
  const int D = geometry_->feature_dim();
  for (int l = 0; l < int(saved_levels_.size()); ++l) {
    LocalMap::Level& lv = map_->level(l);
    const SavedLevel& s = saved_levels_[l];
    const std::vector<int64_t>& touched = gradient_.level(l).touched;
    for (size_t r = 0; r < touched.size(); ++r) {
      const int64_t slot = touched[r];
      std::copy_n(&s.features[r * D], D, lv.features(slot));
      std::copy_n(&s.adam_m[r * D], D, lv.adam_m(slot));
      std::copy_n(&s.adam_v[r * D], D, lv.adam_v(slot));
      lv.adam_steps(slot) = s.adam_steps[r];
      lv.flags(slot) = s.flags[r];
    }
  }
  ByteReader r(saved_decoder_, "saved decoder");
  CheckOk(decoder_->Deserialize(&r), "Decoder::Deserialize");
}

}  // namespace rim::bench
