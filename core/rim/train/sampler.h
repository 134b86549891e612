// Training samples along rays (§3.4 step 3, "Sample" and "Outside rays").
//
// Every sample is a point on a ray from the sensor origin o towards an endpoint at range d, at
// distance t from o. Its label is the signed distance to the endpoint along the ray, d − t:
// positive in front of the surface (free space), negative behind it.
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "rim/base/types.h"
#include "rim/base/worker_pool.h"
#include "rim/config/config.h"
#include "rim/train/point_buffer.h"

namespace rim {

struct SampleBatch {
  std::vector<float> xyz;     // 3 per sample, world frame
  std::vector<float> labels;  // d − t, metres
  // Indices of endpoint samples (label 0), where the optional eikonal term is applied.
  std::vector<int32_t> endpoints;

  size_t size() const { return labels.size(); }
  void Clear() {
    xyz.clear();
    labels.clear();
    endpoints.clear();
  }
};

// Rays of the current scan whose endpoint lies outside the local box.
struct OutsideRays {
  std::vector<Vec3f> points_W;
  std::vector<Vec3f> origins_W;
};

// Distance along a ray from `origin` (inside the box) to where it leaves the box [min, max].
float BoxExitDistance(const Vec3f& origin, const Vec3f& dir, const Vec3f& box_min,
                      const Vec3f& box_max);

// Distance along a ray from `origin` (anywhere) to where it enters the box [min, max]: 0 when the
// origin is inside, infinity when the ray misses the box.
float BoxEntryDistance(const Vec3f& origin, const Vec3f& dir, const Vec3f& box_min,
                       const Vec3f& box_max);

// A small, fast generator for the sampling pieces (xoshiro256**, state filled by splitmix64 from
// the seed): a few cycles per draw against a Mersenne twister's table refills.
class FastRng {
 public:
  using result_type = uint64_t;
  explicit FastRng(uint64_t seed);
  static constexpr result_type min() { return 0; }
  static constexpr result_type max() { return ~result_type(0); }
  result_type operator()() {
    const uint64_t result = Rotl(s_[1] * 5, 7) * 9;
    const uint64_t t = s_[1] << 17;
    s_[2] ^= s_[0];
    s_[3] ^= s_[1];
    s_[1] ^= s_[2];
    s_[0] ^= s_[3];
    s_[2] ^= t;
    s_[3] = Rotl(s_[3], 45);
    return result;
  }

 private:
  static uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  static uint64_t SplitMix(uint64_t* x);
  uint64_t s_[4];
};

class Sampler {
 public:
  Sampler(const SamplerConfig& config, float sigma_m, uint64_t seed);

  // Draws rays_per_iteration rays: round(newest_share · N) of them uniformly from the points the
  // buffer's newest frame added (none while it has none), the rest uniformly from the whole
  // buffer. Along each: Ns surface samples ~ N(d, σ²), Nf
  // stratified free samples in [free_min_ratio·d, free_max_ratio·d], and the endpoint. A ray whose
  // origin is outside the box (an old ray, or a deferred one seen from afar) is clipped to it:
  // its free samples are stratified over the part of that interval inside the box. With
  // outside rays enabled, also draws outside_rays_per_iteration rays of `outside` and samples
  // Nf stratified free-space points between the sensor and the box exit, labelled with the
  // distance to the real endpoint beyond the box. Samples outside the box are dropped.
  //
  // The rays are drawn in kPieces fixed pieces (inside and outside rays each), each with its own
  // generator seeded from rng(); with a pool the pieces run on its threads. The batch is the same
  // with or without one, and for any number of threads.
  //
  // `rays` > 0 draws that many rays instead of rays_per_iteration (a paced frame's batch,
  // paced_rays_per_iteration), and outside rays in the same proportion to
  // outside_rays_per_iteration; rng() advances by the same draws either way.
  void Sample(const PointBuffer& buffer, const OutsideRays& outside, const Vec3d& box_min_m,
              const Vec3d& box_max_m, SampleBatch* out, WorkerPool* pool = nullptr, int rays = 0);

  // The generator every batch starts from (what a checkpoint keeps).
  std::mt19937_64& rng() { return rng_; }

 private:
  static constexpr int kPieces = 8;
  // Batches of fewer rays are drawn without the pool (the same batch either way).
  static constexpr int kPoolMinRays = 1024;
  // The first `from_newest` of the `rays` come from the buffer's newest points.
  void SampleInside(const PointBuffer& buffer, const Vec3f& lo, const Vec3f& hi, int rays,
                    int from_newest, FastRng* rng, SampleBatch* out) const;
  void SampleOutside(const OutsideRays& outside, const Vec3f& lo, const Vec3f& hi, int rays,
                     FastRng* rng, SampleBatch* out) const;

  SamplerConfig config_;
  float sigma_m_;
  std::mt19937_64 rng_;
  // Per piece, reused from batch to batch; a cache line or more each, since pieces drawn on
  // different threads at once write their vectors' ends for every sample.
  struct alignas(64) Piece {
    SampleBatch batch;
  };
  Piece parts_[2 * kPieces];
};

}  // namespace rim
