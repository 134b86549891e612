#include "rim/train/sampler.h"

#include <algorithm>
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

float BoxEntryDistance(const Vec3f& origin, const Vec3f& dir, const Vec3f& box_min,
                       const Vec3f& box_max) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  float t_in = 0.f, t_out = kInf;
  for (int a = 0; a < 3; ++a) {
    if (dir[a] == 0.f) {
      if (origin[a] < box_min[a] || origin[a] > box_max[a]) return kInf;
      continue;
    }
    float t0 = (box_min[a] - origin[a]) / dir[a], t1 = (box_max[a] - origin[a]) / dir[a];
    if (t0 > t1) std::swap(t0, t1);
    t_in = std::max(t_in, t0);
    t_out = std::min(t_out, t1);
  }
  return t_in <= t_out ? t_in : kInf;
}

uint64_t FastRng::SplitMix(uint64_t* x) {
  uint64_t z = (*x += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

FastRng::FastRng(uint64_t seed) {
  for (uint64_t& w : s_) w = SplitMix(&seed);
}

Sampler::Sampler(const SamplerConfig& config, float sigma_m, uint64_t seed)
    : config_(config), sigma_m_(sigma_m), rng_(seed) {}

void Sampler::Sample(const PointBuffer& buffer, const OutsideRays& outside, const Vec3d& box_min_m,
                     const Vec3d& box_max_m, SampleBatch* out, WorkerPool* pool, int rays) {
  out->Clear();
  // The batch's ray counts: the configured ones, or `rays` with the outside rays in proportion.
  const int inside_n = rays > 0 ? rays : config_.rays_per_iteration;
  const int outside_n = rays > 0 ? int(std::lround(double(config_.outside_rays_per_iteration) *
                                                   rays / double(config_.rays_per_iteration)))
                                 : config_.outside_rays_per_iteration;
  // Fixed pieces, each with a generator seeded from rng_ in order: the samples are the same for
  // any number of threads, and rng_ (what checkpoints keep) advances by the same draws.
  const bool inside = buffer.size() > 0;
  const bool outside_rays =
      config_.outside_rays && !outside.points_W.empty() && config_.free_samples > 0;
  if (!inside && !outside_rays) return;
  const Vec3f lo = box_min_m.cast<float>() + Vec3f::Constant(kBoxMarginM);
  const Vec3f hi = box_max_m.cast<float>() - Vec3f::Constant(kBoxMarginM);
  const int newest_rays =
      buffer.newest() > 0 ? int(std::lround(double(config_.newest_share) * inside_n)) : 0;
  uint64_t seeds[2 * kPieces];
  for (uint64_t& s : seeds) s = rng_();
  auto run = [&](int task) {
    const int piece = task % kPieces;
    SampleBatch& part = parts_[task].batch;
    part.Clear();
    FastRng rng(seeds[task]);
    if (task < kPieces) {
      if (!inside) return;
      const int r0 = int(int64_t(inside_n) * piece / kPieces);
      const int r1 = int(int64_t(inside_n) * (piece + 1) / kPieces);
      // Rays [0, newest_rays) of the batch come from the newest frame's points.
      const int from_newest = std::clamp(newest_rays - r0, 0, r1 - r0);
      SampleInside(buffer, lo, hi, r1 - r0, from_newest, &rng, &part);
    } else {
      if (!outside_rays) return;
      const int r0 = int(int64_t(outside_n) * piece / kPieces);
      const int r1 = int(int64_t(outside_n) * (piece + 1) / kPieces);
      SampleOutside(outside, lo, hi, r1 - r0, &rng, &part);
    }
  };
  // A small batch (a paced frame's) is drawn on this thread: handing its pieces to the pool
  // cost more than drawing them under load (sampling went from 1.5 to 3.3 s of a 30 s run at the
  // target load when 2048-ray batches became four times as many 512-ray ones, BENCHMARK.md).
  const int drawn = (inside ? inside_n : 0) + (outside_rays ? outside_n : 0);
  if (pool != nullptr && pool->threads() > 1 && drawn >= kPoolMinRays) {
    pool->Run(2 * kPieces, run);
  } else {
    for (int t = 0; t < 2 * kPieces; ++t) run(t);
  }
  // In piece order: the rays inside, then the outside rays.
  size_t n = 0;
  for (const Piece& piece : parts_) n += piece.batch.size();
  out->xyz.reserve(3 * n);
  out->labels.reserve(n);
  for (const Piece& piece : parts_) {
    const SampleBatch& part = piece.batch;
    const int32_t base = int32_t(out->labels.size());
    out->xyz.insert(out->xyz.end(), part.xyz.begin(), part.xyz.end());
    out->labels.insert(out->labels.end(), part.labels.begin(), part.labels.end());
    for (int32_t e : part.endpoints) out->endpoints.push_back(base + e);
  }
}

namespace {
// Appends a sample if it lies in [lo, hi].
inline bool Add(const Vec3f& p, float label, const Vec3f& lo, const Vec3f& hi, SampleBatch* out) {
  if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) return false;
  out->xyz.insert(out->xyz.end(), {p.x(), p.y(), p.z()});
  out->labels.push_back(label);
  return true;
}
}  // namespace

void Sampler::SampleInside(const PointBuffer& buffer, const Vec3f& lo, const Vec3f& hi, int rays,
                           int from_newest, FastRng* rng, SampleBatch* out) const {
  std::normal_distribution<float> noise(0.f, sigma_m_);
  std::uniform_real_distribution<float> unit(0.f, 1.f);
  std::uniform_int_distribution<size_t> pick(0, buffer.size() - 1);
  const size_t newest = std::min(buffer.newest(), buffer.size());
  std::uniform_int_distribution<size_t> pick_newest(buffer.size() - std::max<size_t>(newest, 1),
                                                    buffer.size() - 1);
  const int Ns = config_.surface_samples, Nf = config_.free_samples;
  const float a = config_.free_min_ratio, b = config_.free_max_ratio;
  for (int r = 0; r < rays; ++r) {
    const size_t i = r < from_newest ? pick_newest(*rng) : pick(*rng);
    const Vec3f& o = buffer.origins()[i];
    const Vec3f& p = buffer.points()[i];
    const Vec3f ray = p - o;
    const float d = ray.norm();
    if (!(d > 1e-6f)) continue;
    const Vec3f dir = ray / d;
    for (int k = 0; k < Ns; ++k) {
      const float t = d + noise(*rng);
      Add(o + t * dir, d - t, lo, hi, out);
    }
    const bool origin_inside = (o.array() >= lo.array()).all() && (o.array() <= hi.array()).all();
    if (origin_inside) {
      for (int k = 0; k < Nf; ++k) {
        // Stratified: one uniform sample in each of Nf equal sub-intervals of [a·d, b·d].
        const float t = d * (a + (b - a) * (float(k) + unit(*rng)) / float(Nf));
        Add(o + t * dir, d - t, lo, hi, out);
      }
    } else {
      // The same strata over the part of [a·d, b·d] inside the box; none if it has no such part.
      const float t0 = std::max(a * d, BoxEntryDistance(o, dir, lo, hi)), t1 = b * d;
      for (int k = 0; k < Nf; ++k) {
        const float t = t0 + (t1 - t0) * (float(k) + unit(*rng)) / float(Nf);
        if (t0 < t1) Add(o + t * dir, d - t, lo, hi, out);
      }
    }
    if (Add(p, 0.f, lo, hi, out)) out->endpoints.push_back(int32_t(out->labels.size() - 1));
  }
}

void Sampler::SampleOutside(const OutsideRays& outside, const Vec3f& lo, const Vec3f& hi, int rays,
                            FastRng* rng, SampleBatch* out) const {
  std::uniform_real_distribution<float> unit(0.f, 1.f);
  std::uniform_int_distribution<size_t> pick(0, outside.points_W.size() - 1);
  const int Nf = config_.free_samples;
  const float a = config_.free_min_ratio;
  for (int r = 0; r < rays; ++r) {
    const size_t i = pick(*rng);
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
      const float t = t_exit * (a + (1.f - a) * (float(k) + unit(*rng)) / float(Nf));
      Add(o + t * dir, d - t, lo, hi, out);
    }
  }
}

}  // namespace rim
