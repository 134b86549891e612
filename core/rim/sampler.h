// Training samples along rays (§3.4 step 3, "Sample" and "Outside rays").
//
// Every sample is a point on a ray from the sensor origin o towards an endpoint at range d, at
// distance t from o. Its label is the signed distance to the endpoint along the ray, d − t:
// positive in front of the surface (free space), negative behind it.
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "rim/config.h"
#include "rim/point_buffer.h"
#include "rim/types.h"

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

class Sampler {
 public:
  Sampler(const SamplerConfig& config, float sigma_m, uint64_t seed);

  // Draws rays_per_iteration rays uniformly from the buffer: Ns surface samples ~ N(d, σ²), Nf
  // stratified free samples in [free_min_ratio·d, free_max_ratio·d], and the endpoint. With
  // outside rays enabled, also draws outside_rays_per_iteration rays of `outside` and samples
  // Nf stratified free-space points between the sensor and the box exit, labelled with the
  // distance to the real endpoint beyond the box. Samples outside the box are dropped.
  void Sample(const PointBuffer& buffer, const OutsideRays& outside, const Vec3d& box_min_m,
              const Vec3d& box_max_m, SampleBatch* out);

  std::mt19937_64& rng() { return rng_; }

 private:
  SamplerConfig config_;
  float sigma_m_;
  std::mt19937_64 rng_;
};

}  // namespace rim
