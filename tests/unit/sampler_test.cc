// Training samples along rays (DESIGN.md §3.4 step 3): surface and stratified free-space samples
// with labels measured along the ray, dropping of out-of-box samples, outside rays cut at the box
// exit but labelled with the real range, and the ray/box exit distance.
#include "rim/train/sampler.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <set>
#include <vector>

#include "gtest/gtest.h"
#include "rim/config/config.h"
#include "rim/train/point_buffer.h"

namespace rim {
namespace {

Vec3f SampleAt(const SampleBatch& b, size_t i) {
  return Vec3f(b.xyz[3 * i], b.xyz[3 * i + 1], b.xyz[3 * i + 2]);
}

PointBuffer OneRayBuffer(const Vec3f& point, const Vec3f& origin) {
  PointBuffer buffer(BufferConfig{}, /*seed=*/1);
  buffer.AddFrame({point}, {origin});
  return buffer;
}

SamplerConfig RayConfig(int rays) {
  SamplerConfig c;
  c.rays_per_iteration = rays;
  c.surface_samples = 3;
  c.free_samples = 3;
  c.free_min_ratio = 0.3f;
  c.free_max_ratio = 0.9f;
  c.outside_rays = false;
  return c;
}

TEST(SamplerTest, APoolDrawsTheSameBatch) {
  // A buffer of many rays and outside rays, some leaving the box: the pieces drop samples
  // unevenly and the endpoints must still index the right samples.
  PointBuffer buffer(BufferConfig{}, /*seed=*/1);
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<float> u(-12.f, 12.f);
  std::vector<Vec3f> points, origins;
  for (int i = 0; i < 5000; ++i) {
    points.push_back(Vec3f(u(rng), u(rng), u(rng) / 4));
    origins.push_back(Vec3f(u(rng) / 6, u(rng) / 6, 0.f));
  }
  buffer.AddFrame(points, origins);
  OutsideRays outside;
  for (int i = 0; i < 500; ++i) {
    outside.points_W.push_back(Vec3f(30.f + u(rng), u(rng), 0.f));
    outside.origins_W.push_back(Vec3f::Zero());
  }
  SamplerConfig config = RayConfig(2048);
  config.outside_rays = true;
  config.outside_rays_per_iteration = 300;
  const Vec3d lo(-10, -10, -3), hi(10, 10, 3);
  SampleBatch want;
  for (const int threads : {2, 3}) {
    Sampler pooled(config, 0.05f, /*seed=*/8);
    Sampler reference(config, 0.05f, /*seed=*/8);
    WorkerPool pool(threads);
    for (int iteration = 0; iteration < 3; ++iteration) {
      SampleBatch got;
      reference.Sample(buffer, outside, lo, hi, &want);
      pooled.Sample(buffer, outside, lo, hi, &got, &pool);
      ASSERT_GT(want.size(), 2048u * 5);
      EXPECT_EQ(got.xyz, want.xyz) << threads << " threads, iteration " << iteration;
      EXPECT_EQ(got.labels, want.labels);
      EXPECT_EQ(got.endpoints, want.endpoints);
      for (int32_t e : want.endpoints) ASSERT_EQ(want.labels[e], 0.f);
    }
  }
  // Every batch advances the generator a checkpoint keeps by the same number of draws.
  Sampler a(config, 0.05f, 8), b(config, 0.05f, 8);
  SampleBatch batch;
  a.Sample(buffer, outside, lo, hi, &batch);
  WorkerPool pool(2);
  b.Sample(buffer, outside, lo, hi, &batch, &pool);
  EXPECT_EQ(a.rng(), b.rng());
}

// Half the rays (sampler.newest_share) come from the points the newest frame added, the rest
// from the whole buffer; with a share of 0 every ray is drawn uniformly, as before.
TEST(SamplerTest, TheNewestShareOfRaysComesFromTheNewestFrame) {
  PointBuffer buffer(BufferConfig{}, /*seed=*/1);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(1.f, 8.f);
  std::vector<Vec3f> old_p, old_o, new_p, new_o;
  for (int i = 0; i < 1000; ++i) {  // an older frame: endpoints at x < 0
    old_p.push_back(Vec3f(-u(rng), u(rng) - 4.5f, -1.f));
    old_o.push_back(Vec3f::Zero());
  }
  for (int i = 0; i < 100; ++i) {  // the newest: endpoints at x > 0
    new_p.push_back(Vec3f(u(rng), u(rng) - 4.5f, -1.f));
    new_o.push_back(Vec3f::Zero());
  }
  buffer.AddFrame(old_p, old_o);
  buffer.AddFrame(new_p, new_o);
  ASSERT_EQ(buffer.newest(), 100u);
  const Vec3d lo(-10, -10, -3), hi(10, 10, 3);
  for (const float share : {0.5f, 0.f}) {
    SamplerConfig config = RayConfig(2000);
    config.newest_share = share;
    Sampler sampler(config, 0.05f, /*seed=*/4);
    SampleBatch batch;
    WorkerPool pool(2);
    sampler.Sample(buffer, OutsideRays{}, lo, hi, &batch, &pool);
    ASSERT_EQ(batch.endpoints.size(), 2000u);
    int newest = 0, newest_in_first_half = 0;
    for (size_t k = 0; k < batch.endpoints.size(); ++k) {
      const bool is_new = SampleAt(batch, size_t(batch.endpoints[k])).x() > 0;
      newest += is_new;
      if (k < 1000) newest_in_first_half += is_new;
    }
    if (share > 0) {
      // Rays 0-999 from the newest frame; 1000 more uniform, of which 1/11 land there too.
      EXPECT_EQ(newest_in_first_half, 1000);
      EXPECT_NEAR(newest, 1000 + 1000 / 11, 40);
    } else {
      EXPECT_NEAR(newest, 2000 / 11, 40);
    }
  }
}

// A paced frame's batch (Sample's `rays`): that many rays, the newest share of them from the
// newest frame, outside rays in proportion; the generator moves on as for a full batch, so the
// batches after it do not depend on the size of the ones before.
TEST(SamplerTest, ASmallerBatchKeepsItsSharesAndTheGeneratorsPace) {
  PointBuffer buffer(BufferConfig{}, /*seed=*/1);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> u(1.f, 8.f);
  std::vector<Vec3f> old_p, new_p, origins(100, Vec3f::Zero());
  for (int i = 0; i < 100; ++i) old_p.push_back(Vec3f(-u(rng), u(rng) - 4.5f, -1.f));
  for (int i = 0; i < 100; ++i) new_p.push_back(Vec3f(u(rng), u(rng) - 4.5f, -1.f));
  buffer.AddFrame(old_p, origins);
  buffer.AddFrame(new_p, origins);
  OutsideRays outside;
  outside.points_W = {Vec3f(0.f, 40.f, 2.f)};  // beyond the box, seen from inside it
  outside.origins_W = {Vec3f(0.f, 0.f, 0.f)};
  const Vec3d lo(-10, -10, -3), hi(10, 10, 3);
  SamplerConfig config = RayConfig(2000);
  config.outside_rays = true;
  config.outside_rays_per_iteration = 1000;
  const int Nf = config.free_samples;
  auto outside_samples = [](const SampleBatch& b) {
    size_t n = 0;
    for (size_t i = 0; i < b.size(); ++i) n += b.labels[i] > 25.f;  // inside rays: under 10
    return n;
  };

  Sampler small(config, 0.05f, /*seed=*/9), full(config, 0.05f, /*seed=*/9);
  WorkerPool pool(2);
  SampleBatch a, b;
  small.Sample(buffer, outside, lo, hi, &a, &pool, /*rays=*/500);
  full.Sample(buffer, outside, lo, hi, &b, &pool);
  ASSERT_EQ(a.endpoints.size(), 500u);
  ASSERT_EQ(b.endpoints.size(), 2000u);
  int newest_first = 0;
  for (size_t k = 0; k < 250; ++k) newest_first += SampleAt(a, size_t(a.endpoints[k])).x() > 0;
  EXPECT_EQ(newest_first, 250);  // newest_share 0.5 of 500
  // 250 outside rays against 1000, Nf samples each (none leaves this box).
  EXPECT_EQ(outside_samples(a), size_t(250 * Nf));
  EXPECT_EQ(outside_samples(b), size_t(1000 * Nf));

  // The next full batches are the same whichever batch came before.
  small.Sample(buffer, outside, lo, hi, &a, &pool);
  full.Sample(buffer, outside, lo, hi, &b, &pool);
  EXPECT_EQ(a.xyz, b.xyz);
  EXPECT_EQ(a.labels, b.labels);
}

TEST(SamplerTest, KnownRayAlongX) {
  const float d = 10.f, sigma = 0.05f;
  const int rays = 4000;
  const SamplerConfig config = RayConfig(rays);
  const int Ns = config.surface_samples, Nf = config.free_samples;
  PointBuffer buffer = OneRayBuffer(Vec3f(d, 0, 0), Vec3f(0, 0, 0));
  Sampler sampler(config, sigma, /*seed=*/3);
  SampleBatch batch;
  sampler.Sample(buffer, OutsideRays{}, Vec3d(-20, -20, -20), Vec3d(20, 20, 20), &batch);

  // The whole ray is in the box: nothing is dropped.
  const int per_ray = Ns + Nf + 1;
  ASSERT_EQ(batch.size(), size_t(rays * per_ray));
  ASSERT_EQ(batch.xyz.size(), 3 * batch.size());
  ASSERT_EQ(batch.endpoints.size(), size_t(rays));
  const std::set<int32_t> endpoints(batch.endpoints.begin(), batch.endpoints.end());
  EXPECT_EQ(endpoints.size(), size_t(rays));

  double sum = 0, sum2 = 0;
  int surface = 0;
  for (size_t i = 0; i < batch.size(); ++i) {
    const Vec3f p = SampleAt(batch, i);
    // On the ray: the origin is 0 and the direction exactly +x, so y, z are exactly 0 and the
    // distance from the origin is x.
    ASSERT_EQ(p.y(), 0.f) << i;
    ASSERT_EQ(p.z(), 0.f) << i;
    const float t = p.x();
    ASSERT_EQ(batch.labels[i], d - t) << "sample " << i << " at t=" << t;
    if (endpoints.count(int32_t(i))) {
      EXPECT_EQ(batch.labels[i], 0.f);
      EXPECT_EQ(t, d);
    } else if (t > 0.95f * d) {
      ++surface;
      sum += t;
      sum2 += double(t) * t;
    } else {
      EXPECT_GE(t, 0.3f * d * (1 - 1e-6f)) << i;
      EXPECT_LE(t, 0.9f * d * (1 + 1e-6f)) << i;
    }
  }
  ASSERT_EQ(surface, rays * Ns);
  const double mean = sum / surface;
  const double stddev = std::sqrt(sum2 / surface - mean * mean);
  EXPECT_NEAR(mean, d, 5 * sigma / std::sqrt(double(surface)));
  EXPECT_NEAR(stddev, sigma, 0.05 * sigma);

  // Stratified: per ray, exactly one free sample in each of the Nf equal sub-intervals of
  // [0.3 d, 0.9 d]. With nothing dropped, each ray contributes per_ray consecutive samples.
  std::vector<int> strata_total(Nf, 0);
  for (int r = 0; r < rays; ++r) {
    std::vector<float> free_t;
    int endpoint_count = 0;
    for (int k = 0; k < per_ray; ++k) {
      const size_t i = size_t(r) * per_ray + k;
      const float t = SampleAt(batch, i).x();
      if (endpoints.count(int32_t(i))) {
        ++endpoint_count;
      } else if (t <= 0.95f * d) {
        free_t.push_back(t);
      }
    }
    ASSERT_EQ(endpoint_count, 1) << "ray " << r;
    ASSERT_EQ(free_t.size(), size_t(Nf)) << "ray " << r;
    std::sort(free_t.begin(), free_t.end());
    for (int j = 0; j < Nf; ++j) {
      // Position in units of strata; stratum j is [j, j+1).
      const double s = (double(free_t[j]) / d - 0.3) / (0.9 - 0.3) * Nf;
      ASSERT_GE(s, j - 1e-4) << "ray " << r << " free sample " << j;
      ASSERT_LE(s, j + 1 + 1e-4) << "ray " << r << " free sample " << j;
      ++strata_total[std::clamp(int(std::floor(s)), 0, Nf - 1)];
    }
  }
  for (int j = 0; j < Nf; ++j) EXPECT_NEAR(strata_total[j], rays, rays * 0.001) << j;
}

TEST(SamplerTest, ObliqueRaySamplesLieOnTheRay) {
  const Vec3f o(1.25f, -0.75f, 0.5f);
  const Vec3f p(-3.5f, 4.f, -1.25f);
  const float d = (p - o).norm();
  const Vec3f dir = (p - o) / d;
  PointBuffer buffer = OneRayBuffer(p, o);
  Sampler sampler(RayConfig(500), 0.05f, /*seed=*/9);
  SampleBatch batch;
  sampler.Sample(buffer, OutsideRays{}, Vec3d(-10, -10, -10), Vec3d(10, 10, 10), &batch);
  ASSERT_EQ(batch.size(), 500u * 7);
  for (size_t i = 0; i < batch.size(); ++i) {
    const Vec3f q = SampleAt(batch, i);
    const float t = (q - o).dot(dir);
    EXPECT_LT(((q - o) - t * dir).norm(), 1e-5f) << i;
    EXPECT_NEAR(batch.labels[i], d - t, 2e-5f) << i;
  }
  for (int32_t e : batch.endpoints) {
    EXPECT_EQ(batch.labels[e], 0.f);
    EXPECT_EQ(SampleAt(batch, e), p);
  }
}

TEST(SamplerTest, SamplesOutsideTheBoxAreDropped) {
  // The ray leaves the box at x = 5 before its endpoint at x = 10.
  PointBuffer buffer = OneRayBuffer(Vec3f(10, 0, 0), Vec3f(0, 0, 0));
  const int rays = 1000;
  Sampler sampler(RayConfig(rays), 0.05f, /*seed=*/4);
  SampleBatch batch;
  const Vec3d lo(-1, -1, -1), hi(5, 1, 1);
  sampler.Sample(buffer, OutsideRays{}, lo, hi, &batch);
  ASSERT_GT(batch.size(), 0u);
  EXPECT_LT(batch.size(), size_t(rays) * 7);
  EXPECT_TRUE(batch.endpoints.empty());
  int below = 0;
  for (size_t i = 0; i < batch.size(); ++i) {
    const Vec3f q = SampleAt(batch, i);
    EXPECT_TRUE((q.cast<double>().array() > lo.array()).all() &&
                (q.cast<double>().array() < hi.array()).all())
        << "sample " << i << " at " << q.transpose() << " is outside the box";
    EXPECT_EQ(batch.labels[i], 10.f - q.x());
    below += q.x() < 5.f;
  }
  EXPECT_EQ(below, int(batch.size()));
  // Free samples lie in [3, 9]; the part in [3, 5) is about a third of them.
  EXPECT_NEAR(double(batch.size()) / (rays * 3), 2.0 / 6.0, 0.05);
}

TEST(SamplerTest, EmptyBufferAndNoOutsideRaysGiveNoSamples) {
  PointBuffer buffer(BufferConfig{}, 1);
  Sampler sampler(RayConfig(100), 0.05f, 1);
  SampleBatch batch;
  batch.labels.push_back(1.f);  // Sample clears what was there
  sampler.Sample(buffer, OutsideRays{}, Vec3d(-1, -1, -1), Vec3d(1, 1, 1), &batch);
  EXPECT_EQ(batch.size(), 0u);
  EXPECT_TRUE(batch.xyz.empty());
  EXPECT_TRUE(batch.endpoints.empty());
}

TEST(SamplerTest, OutsideRaysStopAtTheBoxExitButMeasureToTheEndpoint) {
  SamplerConfig config = RayConfig(1);
  config.outside_rays = true;
  config.outside_rays_per_iteration = 3000;
  const int Nf = config.free_samples;
  const Vec3d box_lo(-2, -2, -1), box_hi(2, 2, 1);
  const Vec3f o(0.5f, 0.2f, -0.1f);
  const Vec3f p(30.f, 5.f, 3.f);  // far beyond the box
  const float d = (p - o).norm();
  const Vec3f dir = (p - o) / d;
  const float t_exit = BoxExitDistance(o, dir, box_lo.cast<float>(), box_hi.cast<float>());
  ASSERT_GT(t_exit, 0.f);
  ASSERT_LT(t_exit, d);

  OutsideRays outside;
  outside.points_W = {p};
  outside.origins_W = {o};
  PointBuffer empty(BufferConfig{}, 1);
  Sampler sampler(config, 0.05f, /*seed=*/12);
  SampleBatch batch;
  sampler.Sample(empty, outside, box_lo, box_hi, &batch);
  ASSERT_GT(batch.size(), size_t(config.outside_rays_per_iteration * Nf) * 9 / 10);
  EXPECT_LE(batch.size(), size_t(config.outside_rays_per_iteration * Nf));
  EXPECT_TRUE(batch.endpoints.empty());
  float t_min = 1e9f, t_max = 0.f;
  for (size_t i = 0; i < batch.size(); ++i) {
    const Vec3f q = SampleAt(batch, i);
    const float t = (q - o).dot(dir);
    ASSERT_LT(((q - o) - t * dir).norm(), 1e-5f) << "sample " << i << " is off the ray";
    // Between the sensor and the box exit.
    ASSERT_GE(t, 0.f);
    ASSERT_LE(t, t_exit + 1e-5f);
    // Labelled with the distance to the real endpoint, which is beyond the exit.
    ASSERT_NEAR(batch.labels[i], d - t, 2e-5f);
    ASSERT_GT(batch.labels[i], t_exit - t);
    ASSERT_GE(batch.labels[i], d - t_exit - 1e-4f);
    t_min = std::min(t_min, t);
    t_max = std::max(t_max, t);
  }
  // They cover the free space up to the exit.
  EXPECT_GT(t_max, 0.98f * t_exit);
  EXPECT_LT(t_min, 0.5f * t_exit);

  // Disabled: no outside samples.
  config.outside_rays = false;
  Sampler off(config, 0.05f, 12);
  off.Sample(empty, outside, box_lo, box_hi, &batch);
  EXPECT_EQ(batch.size(), 0u);

  // An outside ray whose sensor is itself outside the box gives nothing.
  config.outside_rays = true;
  Sampler far(config, 0.05f, 12);
  outside.origins_W = {Vec3f(10, 0, 0)};
  far.Sample(empty, outside, box_lo, box_hi, &batch);
  EXPECT_EQ(batch.size(), 0u);
}

TEST(BoxExitDistanceTest, HandComputedCases) {
  const Vec3f zero(0, 0, 0);
  const Vec3f lo(-1, -1, -1), hi(2, 2, 2);
  EXPECT_FLOAT_EQ(BoxExitDistance(zero, Vec3f(1, 0, 0), lo, hi), 2.f);
  EXPECT_FLOAT_EQ(BoxExitDistance(zero, Vec3f(-1, 0, 0), lo, hi), 1.f);
  EXPECT_FLOAT_EQ(BoxExitDistance(zero, Vec3f(0, 1, 0), lo, hi), 2.f);
  EXPECT_FLOAT_EQ(BoxExitDistance(zero, Vec3f(0, 0, -1), lo, hi), 1.f);
  // Diagonal: x runs out first, at x = 1 after √2.
  EXPECT_FLOAT_EQ(
      BoxExitDistance(zero, Vec3f(1, 1, 0).normalized(), Vec3f(-1, -1, -1), Vec3f(1, 3, 1)),
      std::sqrt(2.f));
  // (0.6, -0.8, 0): y = -1 after 1.25, x = 2 only after 3.33.
  EXPECT_FLOAT_EQ(BoxExitDistance(zero, Vec3f(0.6f, -0.8f, 0), Vec3f(-2, -1, -1), Vec3f(2, 1, 1)),
                  1.25f);
  // Off-centre origin, straight down.
  EXPECT_FLOAT_EQ(
      BoxExitDistance(Vec3f(0.5f, 0.5f, 0.25f), Vec3f(0, 0, -1), Vec3f(0, 0, 0), Vec3f(1, 1, 1)),
      0.25f);
  // Corner-ward: all three axes at once.
  EXPECT_FLOAT_EQ(
      BoxExitDistance(zero, Vec3f(1, 1, 1).normalized(), Vec3f(-1, -1, -1), Vec3f(1, 1, 1)),
      std::sqrt(3.f));
  // On the face, moving out: 0. Moving in: the far face.
  EXPECT_FLOAT_EQ(BoxExitDistance(Vec3f(2, 0, 0), Vec3f(1, 0, 0), lo, hi), 0.f);
  EXPECT_FLOAT_EQ(BoxExitDistance(Vec3f(2, 0, 0), Vec3f(-1, 0, 0), lo, hi), 3.f);
}

}  // namespace
}  // namespace rim
