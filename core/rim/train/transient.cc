#include "rim/train/transient.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace rim {
namespace {

constexpr float kPi = 3.14159265358979323846f;
constexpr float kInf = std::numeric_limits<float>::infinity();

// atan(x) for |x| <= 1, within 2e-8 rad (Abramowitz and Stegun 4.4.49): a range image bins
// about 100k returns and as many buffered points a frame, where std::atan2 would cost more than
// the rest of the judgement.
inline float AtanUnit(float x) {
  const float x2 = x * x;
  float p = 0.0028662257f;
  p = p * x2 - 0.0161657367f;
  p = p * x2 + 0.0429096138f;
  p = p * x2 - 0.0752896400f;
  p = p * x2 + 0.1065626393f;
  p = p * x2 - 0.1420889944f;
  p = p * x2 + 0.1999355085f;
  p = p * x2 - 0.3333314528f;
  return x + x * x2 * p;
}

inline float FastAtan2(float y, float x) {
  const float ax = std::abs(x), ay = std::abs(y);
  if (ax == 0.f && ay == 0.f) return 0.f;
  float a = ay <= ax ? AtanUnit(ay / ax) : 0.5f * kPi - AtanUnit(ax / ay);
  if (x < 0.f) a = kPi - a;
  return y < 0.f ? -a : a;
}

}  // namespace

RangeImage::RangeImage(float bin_deg) {
  const float bin_rad = bin_deg * kPi / 180.f;
  inv_bin_rad_ = 1.f / bin_rad;
  na_ = int(std::ceil(2.f * kPi / bin_rad));
  ne_ = int(std::ceil(kPi / bin_rad));
  range_.assign(size_t(na_) * ne_, kInf);
}

void RangeImage::BinOf(const Vec3f& d, int* azimuth, int* elevation) const {
  const float az = FastAtan2(d.y(), d.x());                              // (−π, π]
  const float el = FastAtan2(d.z(), std::sqrt(d.x() * d.x() + d.y() * d.y()));  // [−π/2, π/2]
  int a = int((az + kPi) * inv_bin_rad_);
  int e = int((el + 0.5f * kPi) * inv_bin_rad_);
  *azimuth = a >= na_ ? a - na_ : a;
  *elevation = std::clamp(e, 0, ne_ - 1);
}

void RangeImage::Fill(const std::vector<Vec3f>& points_S, float min_range_m, float max_range_m) {
  std::fill(range_.begin(), range_.end(), kInf);
  for (const Vec3f& p : points_S) {
    const float r = p.norm();
    if (!(r >= min_range_m && r <= max_range_m)) continue;
    int a, e;
    BinOf(p, &a, &e);
    float& slot = range_[size_t(e) * na_ + a];
    slot = std::min(slot, r);
  }
}

bool SeenThrough(const RangeImage& image, const TransientConfig& c, const Vec3f& p_S) {
  const float r = p_S.norm();
  if (!(r >= c.min_range_m && r <= c.max_range_m)) return false;
  const float beyond = r + c.margin_m + c.margin_per_m * r;
  int a0, e0;
  image.BinOf(p_S, &a0, &e0);
  bool left = false, right = false, below = false, above = false;
  const int e_lo = std::max(0, e0 - c.window_elevation_bins);
  const int e_hi = std::min(image.elevation_bins() - 1, e0 + c.window_elevation_bins);
  for (int e = e_lo; e <= e_hi; ++e) {
    for (int da = -c.window_azimuth_bins; da <= c.window_azimuth_bins; ++da) {
      const float v = image.At(a0 + da, e);
      if (v == kInf) continue;
      // Any return in the window that does not end clearly beyond p: p may still be there.
      if (v < beyond) return false;
      left |= da < 0;
      right |= da > 0;
      below |= e < e0;
      above |= e > e0;
    }
  }
  return left && right && below && above;
}

void ClearedPoints::Add(const Vec3f& p_W, const Vec3f& dir_W, int64_t frame) {
  points_.push_back(p_W);
  dirs_.push_back(dir_W);
  frames_.push_back(frame);
}

void ClearedPoints::Expire(int64_t frame, int lifetime_frames, size_t max_points, const Vec3d& lo,
                           const Vec3d& hi) {
  const Eigen::Array3f l = lo.cast<float>().array(), h = hi.cast<float>().array();
  // Oldest first: beyond the bound the oldest go.
  const size_t over = points_.size() > max_points ? points_.size() - max_points : 0;
  size_t out = 0;
  for (size_t i = 0; i < points_.size(); ++i) {
    if (i < over || frames_[i] < frame - lifetime_frames) continue;
    if (!((points_[i].array() >= l).all() && (points_[i].array() < h).all())) continue;
    points_[out] = points_[i];
    dirs_[out] = dirs_[i];
    frames_[out] = frames_[i];
    ++out;
  }
  points_.resize(out);
  dirs_.resize(out);
  frames_.resize(out);
}

void ClearedPoints::Sample(int n, float band_m, float label_m, const Vec3f& lo, const Vec3f& hi,
                           FastRng* rng, SampleBatch* out) const {
  if (points_.empty() || n <= 0) return;
  const Eigen::Array3f l = lo.array(), h = hi.array();
  for (int k = 0; k < n; ++k) {
    const size_t i = size_t((*rng)() % points_.size());
    const float u = (float((*rng)() >> 40) * (1.f / float(1ull << 24)) * 2.f - 1.f) * band_m;
    const Vec3f q = points_[i] + u * dirs_[i];
    if (!((q.array() >= l).all() && (q.array() < h).all())) continue;
    out->xyz.insert(out->xyz.end(), {q.x(), q.y(), q.z()});
    out->labels.push_back(label_m);
  }
}

void ClearedPoints::Clear() {
  points_.clear();
  dirs_.clear();
  frames_.clear();
}

TransientFilter::TransientFilter(const TransientConfig& config)
    : config_(config), image_(config.bin_deg) {}

void TransientFilter::Apply(const std::vector<Vec3f>& points_S,
                            const Eigen::Isometry3f& T_world_sensor, float scan_min_range_m,
                            float scan_max_range_m, int64_t frame, PointBuffer* buffer,
                            DeferredPoints* deferred, std::mutex* aux_mu, WorkerPool* pool) {
  image_.Fill(points_S, scan_min_range_m, scan_max_range_m);
  const Eigen::Matrix3f R_SW = T_world_sensor.linear().transpose();
  const Vec3f sensor_W = T_world_sensor.translation();
  const int period = config_.period_frames;
  const int phase = int(frame % period);
  auto seen_through = [&](const Vec3f& p_W) {
    return SeenThrough(image_, config_, R_SW * (p_W - sensor_W));
  };

  // The buffer: points judged in pieces over the pool, each piece writing its own flags.
  const std::vector<Vec3f>& points = buffer->points();
  const size_t n = points.size();
  drop_.assign(n, 0);
  constexpr int kPieces = 8;
  auto piece = [&](int k) {
    const size_t begin = n * size_t(k) / kPieces, end = n * size_t(k + 1) / kPieces;
    for (size_t i = begin; i < end; ++i)
      if (int(i % size_t(period)) == phase) drop_[i] = seen_through(points[i]);
  };
  if (pool && n >= 4096) {
    pool->Run(kPieces, piece);
  } else {
    for (int k = 0; k < kPieces; ++k) piece(k);
  }
  std::vector<bool> keep(n, true);
  int64_t dropped = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!drop_[i]) continue;
    keep[i] = false;
    ++dropped;
    const Vec3f d = points[i] - buffer->origins()[i];
    const float len = d.norm();
    cleared_.Add(points[i], len > 0.f ? Vec3f(d / len) : Vec3f::UnitZ(), frame);
  }
  std::lock_guard<std::mutex> lock(*aux_mu);  // stats_ too: Mapper::Stats reads them under it
  stats_.judged += int64_t((n + period - 1 - phase) / period);
  if (dropped > 0) buffer->Filter(keep);
  stats_.buffer_removed += dropped;
  if (deferred) {
    stats_.deferred_removed +=
        deferred->RemoveIf(sensor_W, config_.max_range_m, period, phase, seen_through);
  }
}

}  // namespace rim
