// The GPU path (core/rim/gpu) against the CPU path, on random inputs (never zeros) with outputs
// poisoned before every kernel: encoding against EncodeLocal, SDF and gradient queries against
// FeatureReader and Decoder::Forward, the training iteration's loss and gradients against
// EncodeLocal + MlpTrainStep + SparseGradient, its Adam step against UpdateTouchedRows and
// Decoder::Step on the same gradients, and training over many iterations against the CPU's.
// Label `gpu`: runs on a machine with a CUDA device (tests/gpu/run.sh); elsewhere every case
// skips, naming why.
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <set>
#include <vector>

#include "gpu/gpu_common.h"
#include "gtest/gtest.h"
#include "rim/gpu/device_map.h"
#include "rim/map/submap_store.h"
#include "rim/model/encoder.h"
#include "rim/train/mlp_step.h"
#include "rim/train/trainer.h"

namespace rim {
namespace {

using gpu::DeviceMap;
using gpu::TrainSettings;
using gpu_testing::Batch;

// ‖a − b‖ / ‖b‖ over all elements; infinite when a has a NaN or b is all zero.
double RelativeError(const std::vector<float>& a, const std::vector<float>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    if (!std::isfinite(a[i])) return std::numeric_limits<double>::infinity();
    num += (double(a[i]) - b[i]) * (double(a[i]) - b[i]);
    den += double(b[i]) * b[i];
  }
  return den > 0 ? std::sqrt(num / den) : std::numeric_limits<double>::infinity();
}

MapperConfig SmallConfig() {
  absl::StatusOr<MapperConfig> c = MakePreset("maicity");
  EXPECT_TRUE(c.ok()) << c.status();
  EXPECT_TRUE(ApplyOverrides({"grid.half_extent_x_m=2", "grid.half_extent_y_m=2",
                              "grid.z_min_m=-1.2", "grid.z_max_m=1.2", "train.eikonal_weight=0.1"},
                             &*c)
                  .ok());
  return *c;
}

class GpuTest : public ::testing::Test {
 protected:
  GpuTest()
      : config_(SmallConfig()),
        geo_(config_.grid),
        map_(geo_),
        decoder_(geo_.encoding_dim(), config_.decoder) {}

  void SetUp() override {
    absl::StatusOr<gpu::DeviceInfo> info = gpu::OpenDevice(0);
    if (!info.ok()) GTEST_SKIP() << "no CUDA device: " << info.status();
    gpu_testing::PlaceAndFill(&map_, 7);
    gpu_testing::PerturbDecoder(&decoder_, 8);
    settings_ = TrainSettings::From(config_, geo_);
    absl::StatusOr<std::unique_ptr<DeviceMap>> dm = DeviceMap::Create(map_, decoder_, 0);
    ASSERT_TRUE(dm.ok()) << dm.status();
    dm_ = std::move(*dm);
    dm_->set_poison(true);
  }

  Batch MakeBatch(uint32_t seed, int labelled = 3000, int probed = 300) {
    return gpu_testing::SurfaceBatch(map_, labelled, probed, settings_.eikonal_step_m, seed);
  }

  // The CPU path's backward on `b` (what Trainer::PrepareBatch and Apply's scatter compute).
  struct CpuBackward {
    LocalEncoding enc;
    std::vector<float> features;
    TrainStepOutput out;
    SparseGradient grad;
  };
  void RunCpuBackward(LocalMap* map, const Decoder& decoder, const Batch& b, CpuBackward* cpu) {
    cpu->features.resize(size_t(b.rows) * geo_.encoding_dim());
    EncodeLocal(*map, b.xyz.data(), b.rows, &cpu->enc, cpu->features.data());
    TrainStepInput in;
    in.features = cpu->features.data();
    in.rows = b.rows;
    in.labelled = b.labelled;
    in.labels = b.labels.data();
    in.sigma_m = settings_.sigma_m;
    in.eikonal_weight = settings_.eikonal_weight;
    in.eikonal_step_m = settings_.eikonal_step_m;
    in.train_decoder = true;
    MlpTrainStep mlp;
    ASSERT_TRUE(mlp.Run(decoder, in, &cpu->out).ok());
    cpu->grad.Reset(*map);
    cpu->grad.BeginIteration(map);
    cpu->grad.Scatter(map, cpu->enc, cpu->out.grad_features.data());
  }

  // Lazy Adam on every level's touched rows with the given gradient rows (dense, per level).
  void RunCpuAdam(LocalMap* map, CpuBackward& cpu, const std::vector<std::vector<float>>& dense) {
    const AdamBiasTable bias(settings_.adam);
    for (int l = 0; l < geo_.levels(); ++l) {
      SparseGradient::Level g;
      g.touched = cpu.grad.level(l).touched;
      for (int64_t slot : g.touched)
        g.grad.insert(g.grad.end(), dense[l].begin() + slot * 8, dense[l].begin() + slot * 8 + 8);
      UpdateTouchedRows(settings_.adam, bias, g, 0, g.touched.size(), &map->level(l));
    }
  }

  // Trainer::MarkObserved on the batch's labelled samples.
  void MarkObserved(LocalMap* map, const Batch& b, const LocalEncoding& enc) {
    const size_t L = size_t(geo_.levels());
    for (int i = 0; i < b.labelled; ++i) {
      const float label = b.labels[i];
      uint8_t bits = 0;
      if (std::abs(label) < settings_.observed_band_m) {
        bits = LocalMap::kObserved;
      } else if (label > 0) {
        bits = LocalMap::kSeenFree;
      } else {
        continue;
      }
      map->level(0).flags(enc.slots[size_t(i) * L * 8]) |= bits | LocalMap::kHasData;
    }
  }

  LocalMap Copy(const LocalMap& from) {
    LocalMap to(geo_);
    to.PlaceWithoutLoading(from.coarse_origin());
    for (int l = 0; l < geo_.levels(); ++l) {
      const LocalMap::Level& a = from.level(l);
      LocalMap::Level& b = to.level(l);
      for (int64_t s = 0; s < a.slots(); ++s) {
        std::memcpy(b.features(s), a.features(s), 32);
        std::memcpy(b.adam_m(s), a.adam_m(s), 32);
        std::memcpy(b.adam_v(s), a.adam_v(s), 32);
        b.adam_steps(s) = a.adam_steps(s);
        b.flags(s) = a.flags(s);
      }
    }
    return to;
  }

  void ExpectSameMap(const LocalMap& a, const LocalMap& b, float feature_tol, float moment_tol) {
    for (int l = 0; l < geo_.levels(); ++l) {
      const LocalMap::Level& x = a.level(l);
      const LocalMap::Level& y = b.level(l);
      int bad = 0;
      for (int64_t s = 0; s < x.slots() && bad < 5; ++s) {
        for (int d = 0; d < 8; ++d) {
          if (!(std::abs(x.features(s)[d] - y.features(s)[d]) <= feature_tol) ||
              !(std::abs(x.adam_m(s)[d] - y.adam_m(s)[d]) <= moment_tol) ||
              !(std::abs(x.adam_v(s)[d] - y.adam_v(s)[d]) <= moment_tol)) {
            ADD_FAILURE() << "level " << l << " slot " << s << " d " << d << ": feature "
                          << x.features(s)[d] << " vs " << y.features(s)[d] << ", m "
                          << x.adam_m(s)[d] << " vs " << y.adam_m(s)[d] << ", v " << x.adam_v(s)[d]
                          << " vs " << y.adam_v(s)[d];
            ++bad;
            break;
          }
        }
        if (x.adam_steps(s) != y.adam_steps(s)) {
          ADD_FAILURE() << "level " << l << " slot " << s << " steps " << x.adam_steps(s) << " vs "
                        << y.adam_steps(s);
          ++bad;
        }
        if (l == 0 && x.flags(s) != y.flags(s)) {
          ADD_FAILURE() << "slot " << s << " flags " << int(x.flags(s)) << " vs "
                        << int(y.flags(s));
          ++bad;
        }
      }
    }
  }

  MapperConfig config_;
  MapGeometry geo_;
  LocalMap map_;
  Decoder decoder_;
  TrainSettings settings_;
  std::unique_ptr<DeviceMap> dm_;
};

TEST_F(GpuTest, UploadDownloadRoundTripIsExact) {
  LocalMap back(geo_);
  back.PlaceWithoutLoading(map_.coarse_origin());
  ASSERT_TRUE(dm_->Download(&back).ok());
  ExpectSameMap(back, map_, 0.f, 0.f);
  Decoder d(geo_.encoding_dim(), config_.decoder);
  ASSERT_TRUE(dm_->DownloadDecoder(&d).ok());
  EXPECT_EQ(d.params(), decoder_.params());
}

TEST_F(GpuTest, EncodeMatchesEncodeLocal) {
  std::vector<float> xyz = gpu_testing::RandomPointsInBox(map_, 20000, 1e-3, 11);
  const int inside = 20000;
  // Outside the box and NaN: NaN features.
  xyz.insert(xyz.end(), {float(map_.max_m().x() + 0.5), 0.f, 0.f, std::nanf(""), 0.f, 0.f});
  const int n = int(xyz.size() / 3);
  const int F = geo_.encoding_dim();
  std::vector<float> gpu(size_t(n) * F, -7.f);
  ASSERT_TRUE(dm_->Encode(xyz.data(), n, gpu.data()).ok());
  LocalEncoding enc;
  std::vector<float> cpu(size_t(inside) * F);
  EncodeLocal(map_, xyz.data(), inside, &enc, cpu.data());
  std::vector<float> head(gpu.begin(), gpu.begin() + cpu.size());
  EXPECT_LT(RelativeError(head, cpu), 1e-6);
  float worst = 0;
  for (size_t i = 0; i < cpu.size(); ++i) worst = std::max(worst, std::abs(head[i] - cpu[i]));
  EXPECT_LT(worst, 1e-5f);
  for (int r = inside; r < n; ++r)
    for (int i = 0; i < F; ++i) EXPECT_TRUE(std::isnan(gpu[size_t(r) * F + i])) << r;
}

TEST_F(GpuTest, QueriesMatchTheCpuPath) {
  const int n = 20000;
  std::vector<float> xyz = gpu_testing::RandomPointsInBox(map_, n, 1e-3, 12);
  xyz.insert(xyz.end(), {0.f, float(map_.min_m().y() - 1.0), 0.f});
  std::vector<float> sdf(n + 1, -7.f), grad(3 * (n + 1), -7.f), sdf_only(n + 1, -7.f);
  ASSERT_TRUE(dm_->Query(xyz.data(), n + 1, sdf.data(), grad.data()).ok());
  ASSERT_TRUE(dm_->Query(xyz.data(), n + 1, sdf_only.data(), nullptr).ok());
  SubmapStore store(geo_, config_.submap);
  FeatureReader reader(map_, store);
  const int F = geo_.encoding_dim();
  std::vector<float> feat(F), jac(size_t(F) * 3), dsdf(F);
  std::vector<float> cpu_sdf, cpu_grad;
  for (int i = 0; i < n; ++i) {
    reader.Encode(Vec3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]), feat.data(), jac.data());
    float y;
    decoder_.Forward(feat.data(), 1, &y, dsdf.data());
    cpu_sdf.push_back(y);
    for (int a = 0; a < 3; ++a) {
      double g = 0;
      for (int k = 0; k < F; ++k) g += double(dsdf[k]) * jac[size_t(k) * 3 + a];
      cpu_grad.push_back(float(g));
    }
  }
  std::vector<float> gs(sdf.begin(), sdf.begin() + n), gg(grad.begin(), grad.begin() + 3 * n),
      so(sdf_only.begin(), sdf_only.begin() + n);
  EXPECT_LT(RelativeError(gs, cpu_sdf), 1e-5);
  EXPECT_LT(RelativeError(so, cpu_sdf), 1e-5);
  EXPECT_LT(RelativeError(gg, cpu_grad), 1e-4);
  EXPECT_TRUE(std::isnan(sdf[n]));
  EXPECT_TRUE(std::isnan(sdf_only[n]));
  for (int a = 0; a < 3; ++a) EXPECT_TRUE(std::isnan(grad[3 * n + a]));
  // The gradient against central differences of the GPU's own SDF (h = 1 mm, inside cells).
  int checked = 0;
  for (int i = 0; i < 200; ++i) {
    std::vector<float> q;
    for (int a = 0; a < 3; ++a)
      for (float s : {1e-3f, -1e-3f}) {
        float p[3] = {xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]};
        p[a] += s;
        q.insert(q.end(), {p[0], p[1], p[2]});
      }
    std::vector<float> v(6);
    ASSERT_TRUE(dm_->Query(q.data(), 6, v.data(), nullptr).ok());
    for (int a = 0; a < 3; ++a) {
      const float fd = (v[2 * a] - v[2 * a + 1]) / 2e-3f;
      // A cell or ReLU boundary between the probes makes the difference meaningless.
      if (std::abs(fd - grad[3 * i + a]) < 0.02f * (1.f + std::abs(fd))) ++checked;
    }
  }
  EXPECT_GT(checked, 540);  // of 600: nearly all probes lie inside one cell and one ReLU region
}

TEST_F(GpuTest, BackwardMatchesTheCpuPath) {
  const Batch b = MakeBatch(21);
  absl::StatusOr<float> loss =
      dm_->Backward(b.xyz.data(), b.rows, b.labelled, b.labels.data(), settings_, true);
  ASSERT_TRUE(loss.ok()) << loss.status();
  CpuBackward cpu;
  LocalMap cpu_map = Copy(map_);
  RunCpuBackward(&cpu_map, decoder_, b, &cpu);
  EXPECT_NEAR(*loss, cpu.out.loss, 1e-5 * std::abs(cpu.out.loss));
  std::vector<float> gdec;
  ASSERT_TRUE(dm_->DownloadDecoderGradient(&gdec).ok());
  EXPECT_LT(RelativeError(gdec, cpu.out.grad_params), 1e-4);
  for (int l = 0; l < geo_.levels(); ++l) {
    std::vector<float> dense;
    ASSERT_TRUE(dm_->DownloadGradients(l, &dense).ok());
    SparseGradient::Level& g = cpu.grad.level(l);
    std::vector<float> want(dense.size(), 0.f);
    for (size_t r = 0; r < g.touched.size(); ++r)
      std::copy_n(&g.grad[r * 8], 8, &want[size_t(g.touched[r]) * 8]);
    EXPECT_LT(RelativeError(dense, want), 1e-4) << "level " << l;
    // Rows the batch did not touch stay exactly zero.
    const std::set<int64_t> touched(g.touched.begin(), g.touched.end());
    int stray = 0;
    for (int64_t s = 0; s < int64_t(dense.size() / 8); ++s)
      if (!touched.count(s))
        for (int d = 0; d < 8; ++d) stray += dense[size_t(s) * 8 + d] != 0.f;
    EXPECT_EQ(stray, 0) << "level " << l;
  }
  ASSERT_TRUE(dm_->Step(settings_, true).ok());
}

TEST_F(GpuTest, StepMatchesCpuAdamOnTheSameGradients) {
  const Batch b = MakeBatch(22);
  ASSERT_TRUE(
      dm_->Backward(b.xyz.data(), b.rows, b.labelled, b.labels.data(), settings_, true).ok());
  std::vector<std::vector<float>> dense(size_t(geo_.levels()));
  for (int l = 0; l < geo_.levels(); ++l) ASSERT_TRUE(dm_->DownloadGradients(l, &dense[l]).ok());
  std::vector<float> gdec;
  ASSERT_TRUE(dm_->DownloadDecoderGradient(&gdec).ok());
  ASSERT_TRUE(dm_->Step(settings_, true).ok());

  LocalMap want = Copy(map_);
  CpuBackward cpu;
  RunCpuBackward(&want, decoder_, b, &cpu);  // for the touched rows and slots
  RunCpuAdam(&want, cpu, dense);
  MarkObserved(&want, b, cpu.enc);
  Decoder want_decoder = decoder_;
  want_decoder.Step(settings_.adam, gdec);

  LocalMap got(geo_);
  got.PlaceWithoutLoading(map_.coarse_origin());
  ASSERT_TRUE(dm_->Download(&got).ok());
  ExpectSameMap(got, want, 2e-6f, 1e-7f);
  Decoder got_decoder(geo_.encoding_dim(), config_.decoder);
  ASSERT_TRUE(dm_->DownloadDecoder(&got_decoder).ok());
  EXPECT_LT(RelativeError(got_decoder.params(), want_decoder.params()), 1e-6);
  EXPECT_EQ(got_decoder.adam_step(), 1);
  // Step leaves every gradient row zero for the next iteration.
  for (int l = 0; l < geo_.levels(); ++l) {
    std::vector<float> after;
    ASSERT_TRUE(dm_->DownloadGradients(l, &after).ok());
    EXPECT_EQ(std::count(after.begin(), after.end(), 0.f), int64_t(after.size())) << l;
  }
  ASSERT_TRUE(dm_->DownloadDecoderGradient(&gdec).ok());
  EXPECT_EQ(std::count(gdec.begin(), gdec.end(), 0.f), int64_t(gdec.size()));
}

TEST_F(GpuTest, TrainingFollowsTheCpuPath) {
  const Batch b = MakeBatch(23);
  LocalMap cpu_map = Copy(map_);
  Decoder cpu_decoder = decoder_;
  const AdamBiasTable bias(settings_.adam);
  float first = 0, gpu_loss = 0, cpu_loss = 0;
  for (int it = 0; it < 60; ++it) {
    absl::StatusOr<float> g =
        dm_->Iterate(b.xyz.data(), b.rows, b.labelled, b.labels.data(), settings_, true);
    ASSERT_TRUE(g.ok()) << g.status();
    CpuBackward cpu;
    RunCpuBackward(&cpu_map, cpu_decoder, b, &cpu);
    for (int l = 0; l < geo_.levels(); ++l) {
      SparseGradient::Level& lv = cpu.grad.level(l);
      UpdateTouchedRows(settings_.adam, bias, lv, 0, lv.touched.size(), &cpu_map.level(l));
    }
    cpu_decoder.Step(settings_.adam, cpu.out.grad_params);
    if (it == 0) first = cpu.out.loss;
    gpu_loss = *g;
    cpu_loss = cpu.out.loss;
  }
  EXPECT_LT(cpu_loss, 0.7f * first);
  EXPECT_NEAR(gpu_loss, cpu_loss, 0.03f * cpu_loss);
  // The maps agree where it matters: SDF over the batch's points.
  const Batch q = MakeBatch(24, 4000, 0);
  std::vector<float> got(size_t(q.rows));
  ASSERT_TRUE(dm_->Query(q.xyz.data(), q.rows, got.data(), nullptr).ok());
  SubmapStore store(geo_, config_.submap);
  FeatureReader reader(cpu_map, store);
  std::vector<float> feat(size_t(geo_.encoding_dim())), want;
  for (int i = 0; i < q.rows; ++i) {
    reader.Encode(Vec3d(q.xyz[3 * i], q.xyz[3 * i + 1], q.xyz[3 * i + 2]), feat.data(), nullptr);
    float y;
    cpu_decoder.Forward(feat.data(), 1, &y);
    want.push_back(y);
  }
  EXPECT_LT(RelativeError(got, want), 0.02);
}

TEST_F(GpuTest, BadBatchesAreRejectedAndChangeNothing) {
  Batch b = MakeBatch(31);
  b.xyz[3 * 17 + 1] = std::nanf("");
  absl::StatusOr<float> loss =
      dm_->Iterate(b.xyz.data(), b.rows, b.labelled, b.labels.data(), settings_, true);
  ASSERT_FALSE(loss.ok());
  EXPECT_EQ(loss.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(loss.status().message().find("point 17"), std::string::npos) << loss.status();
  b.xyz[3 * 17 + 1] = float(map_.max_m().y() + 3.0);
  loss = dm_->Iterate(b.xyz.data(), b.rows, b.labelled, b.labels.data(), settings_, true);
  ASSERT_FALSE(loss.ok());
  EXPECT_NE(loss.status().message().find("outside the local box"), std::string::npos);
  EXPECT_FALSE(dm_->Iterate(b.xyz.data(), -1, 0, b.labels.data(), settings_, true).ok());
  EXPECT_FALSE(dm_->Iterate(b.xyz.data(), 10, 11, b.labels.data(), settings_, true).ok());
  EXPECT_FALSE(dm_->Query(b.xyz.data(), -5, b.labels.data(), nullptr).ok());
  LocalMap got(geo_);
  got.PlaceWithoutLoading(map_.coarse_origin());
  ASSERT_TRUE(dm_->Download(&got).ok());
  ExpectSameMap(got, map_, 0.f, 0.f);
  Decoder d(geo_.encoding_dim(), config_.decoder);
  ASSERT_TRUE(dm_->DownloadDecoder(&d).ok());
  EXPECT_EQ(d.params(), decoder_.params());
  // A good batch still trains afterwards.
  const Batch good = MakeBatch(32);
  EXPECT_TRUE(
      dm_->Iterate(good.xyz.data(), good.rows, good.labelled, good.labels.data(), settings_, true)
          .ok());
}

TEST_F(GpuTest, DeviceMemoryStaysFlat) {
  const Batch b = MakeBatch(41);
  ASSERT_TRUE(
      dm_->Iterate(b.xyz.data(), b.rows, b.labelled, b.labels.data(), settings_, true).ok());
  const int64_t before = dm_->device_bytes();
  for (int i = 0; i < 300; ++i) {
    const Batch c = MakeBatch(100 + i % 7, 2500 + 100 * (i % 5), 250);
    ASSERT_TRUE(
        dm_->Iterate(c.xyz.data(), c.rows, c.labelled, c.labels.data(), settings_, false).ok());
  }
  EXPECT_EQ(dm_->device_bytes(), before);
}

TEST_F(GpuTest, SyncFollowsTheSlideAndBringsBackTheUpdatedRows) {
  // The box slides by (2, 1, 0) coarse cells; the entering rows get random data from the
  // "store".
  std::mt19937 rng(51);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  const Int3 moved = map_.coarse_origin() + Int3(2, 1, 0);
  map_.MoveTo(moved, LocalMap::SaveFn(), [&](int, const Int3&, float* features, uint8_t* observed) {
    for (int d = 0; d < 8; ++d) features[d] = u(rng);
    *observed = LocalMap::kObserved;
    return true;
  });
  ASSERT_TRUE(dm_->SyncFromHost(map_).ok());
  EXPECT_GT(dm_->rows_uploaded(), 0);
  EXPECT_LT(dm_->rows_uploaded(), map_.level(0).slots());  // the slabs, not the whole map
  LocalMap got(geo_);
  got.PlaceWithoutLoading(map_.coarse_origin());
  ASSERT_TRUE(dm_->Download(&got).ok());
  ExpectSameMap(got, map_, 0.f, 0.f);
  // The device copy's box moved with it: encodings in the new box match the host's.
  const std::vector<float> xyz = gpu_testing::RandomPointsInBox(map_, 5000, 1e-3, 52);
  std::vector<float> gpu_f(size_t(5000) * geo_.encoding_dim()), cpu_f(gpu_f.size());
  ASSERT_TRUE(dm_->Encode(xyz.data(), 5000, gpu_f.data()).ok());
  LocalEncoding enc;
  EncodeLocal(map_, xyz.data(), 5000, &enc, cpu_f.data());
  EXPECT_LT(RelativeError(gpu_f, cpu_f), 1e-6);
  // Training, then the rows it changed back: the host map equals the device copy again.
  for (int i = 0; i < 5; ++i) {
    const Batch b = MakeBatch(60 + i);
    ASSERT_TRUE(
        dm_->Iterate(b.xyz.data(), b.rows, b.labelled, b.labels.data(), settings_, true).ok());
  }
  Decoder host_decoder = decoder_;
  ASSERT_TRUE(dm_->SyncToHost(&map_, &host_decoder).ok());
  EXPECT_GT(dm_->rows_downloaded(), 0);
  LocalMap after(geo_);
  after.PlaceWithoutLoading(map_.coarse_origin());
  ASSERT_TRUE(dm_->Download(&after).ok());
  ExpectSameMap(after, map_, 0.f, 0.f);
  Decoder device_decoder(geo_.encoding_dim(), config_.decoder);
  ASSERT_TRUE(dm_->DownloadDecoder(&device_decoder).ok());
  EXPECT_EQ(host_decoder.params(), device_decoder.params());
  EXPECT_NE(host_decoder.params(), decoder_.params());
}

TEST(GpuShapes, UnsupportedShapesNameTheSetting) {
  if (!gpu::OpenDevice(0).ok()) GTEST_SKIP() << "no CUDA device";
  MapperConfig c = SmallConfig();
  ASSERT_TRUE(ApplyOverrides({"grid.feature_dim=4"}, &c).ok());
  MapGeometry geo(c.grid);
  LocalMap map(geo);
  Decoder dec(geo.encoding_dim(), c.decoder);
  auto dm = DeviceMap::Create(map, dec, 0);
  ASSERT_FALSE(dm.ok());
  EXPECT_NE(dm.status().message().find("grid.feature_dim"), std::string::npos);
  MapperConfig h = SmallConfig();
  ASSERT_TRUE(ApplyOverrides({"decoder.hidden_width=48"}, &h).ok());
  MapGeometry geo2(h.grid);
  LocalMap map2(geo2);
  Decoder dec2(geo2.encoding_dim(), h.decoder);
  dm = DeviceMap::Create(map2, dec2, 0);
  ASSERT_FALSE(dm.ok());
  EXPECT_NE(dm.status().message().find("decoder.hidden_width"), std::string::npos);
  EXPECT_FALSE(DeviceMap::Create(map2, dec2, 99).ok());
}

}  // namespace
}  // namespace rim
