#include "rim/sampler.h"

#include <cmath>
#include <limits>

namespace rim {
namespace {
// Keeps samples strictly inside the box so that all 8 trilinear corners exist.
constexpr float kBoxMarginM = 1e-4f;
}  // namespace

float BoxExitDistance(const Vec3f& origin, const Vec3f& dir, const Vec3f& box_min,
                      const Vec3f& box_max) {
  float t = std::numeric_limits<float>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (dir[a] > 0.f) t = std::min(t, (box_max[a] - origin[a]) / dir[a]);
    if (dir[a] < 0.f) t = std::min(t, (box_min[a] - origin[a]) / dir[a]);
  }
  return std::max(t, 0.f);
}

Sampler::Sampler(const SamplerConfig& config, float sigma_m, uint64_t seed)
    : config_(config), sigma_m_(sigma_m), rng_(seed) {}

void Sampler::Sample(const PointBuffer& buffer, const OutsideRays& outside, const Vec3d& box_min_m,
                     const Vec3d& box_max_m, SampleBatch* out) {
  out->Clear();
  const Vec3f lo = box_min_m.cast<float>() + Vec3f::Constant(kBoxMarginM);
  const Vec3f hi = box_max_m.cast<float>() - Vec3f::Constant(kBoxMarginM);
  auto add = [&](const Vec3f& p, float label) {
    if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) return false;
    out->xyz.insert(out->xyz.end(), {p.x(), p.y(), p.z()});
    out->labels.push_back(label);
    return true;
  };
  std::normal_distribution<float> noise(0.f, sigma_m_);
  std::uniform_real_distribution<float> unit(0.f, 1.f);
  const int Ns = config_.surface_samples, Nf = config_.free_samples;
  const float a = config_.free_min_ratio, b = config_.free_max_ratio;

  if (buffer.size() > 0) {
    std::uniform_int_distribution<size_t> pick(0, buffer.size() - 1);
    for (int r = 0; r < config_.rays_per_iteration; ++r) {
      const size_t i = pick(rng_);
      const Vec3f& o = buffer.origins()[i];
      const Vec3f& p = buffer.points()[i];
      const Vec3f ray = p - o;
      const float d = ray.norm();
      if (!(d > 1e-6f)) continue;
      const Vec3f dir = ray / d;
      for (int k = 0; k < Ns; ++k) {
        const float t = d + noise(rng_);
        add(o + t * dir, d - t);
      }
      for (int k = 0; k < Nf; ++k) {
        // Stratified: one uniform sample in each of Nf equal sub-intervals of [a·d, b·d].
        const float t = d * (a + (b - a) * (float(k) + unit(rng_)) / float(Nf));
        add(o + t * dir, d - t);
      }
      if (add(p, 0.f)) out->endpoints.push_back(int32_t(out->labels.size() - 1));
    }
  }

  if (config_.outside_rays && !outside.points_W.empty() && Nf > 0) {
    std::uniform_int_distribution<size_t> pick(0, outside.points_W.size() - 1);
    for (int r = 0; r < config_.outside_rays_per_iteration; ++r) {
      const size_t i = pick(rng_);
      const Vec3f& o = outside.origins_W[i];
      if ((o.array() < lo.array()).any() || (o.array() > hi.array()).any()) continue;
      const Vec3f ray = outside.points_W[i] - o;
      const float d = ray.norm();
      if (!(d > 1e-6f)) continue;
      const Vec3f dir = ray / d;
      const float t_exit = std::min(BoxExitDistance(o, dir, lo, hi), d);
      // Free space runs from the sensor to the box exit; the label is measured to the real
      // endpoint beyond the box, not to the exit point.
      for (int k = 0; k < Nf; ++k) {
        const float t = t_exit * (a + (1.f - a) * (float(k) + unit(rng_)) / float(Nf));
        add(o + t * dir, d - t);
      }
    }
  }
}

}  // namespace rim
