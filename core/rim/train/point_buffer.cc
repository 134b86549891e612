#include "rim/train/point_buffer.h"

#include <cstring>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"

namespace rim {

PointBuffer::PointBuffer(const BufferConfig& config, uint64_t seed) : config_(config), rng_(seed) {}

void PointBuffer::AddFrame(const std::vector<Vec3f>& points_W,
                           const std::vector<Vec3f>& origins_W) {
  const size_t n = points_W.size();
  const size_t keep = std::min<size_t>(n, size_t(config_.max_points_per_frame));
  std::vector<uint32_t> idx(n);
  for (size_t i = 0; i < n; ++i) idx[i] = uint32_t(i);
  // Partial Fisher-Yates: the first `keep` entries become a uniform random subset.
  for (size_t i = 0; i < keep; ++i) {
    std::uniform_int_distribution<size_t> pick(i, n - 1);
    std::swap(idx[i], idx[pick(rng_)]);
  }
  for (size_t i = 0; i < keep; ++i) {
    points_.push_back(points_W[idx[i]]);
    origins_.push_back(origins_W[idx[i]]);
  }
  passes_.resize(points_.size(), 0);
  newest_ = keep;
  TrimToBound();
}

void PointBuffer::AddPoints(const std::vector<Vec3f>& points_W,
                            const std::vector<Vec3f>& origins_W) {
  points_.insert(points_.end(), points_W.begin(), points_W.end());
  origins_.insert(origins_.end(), origins_W.begin(), origins_W.end());
  passes_.resize(points_.size(), 0);
  newest_ += points_W.size();
  TrimToBound();
}

void PointBuffer::TrimToBound() {
  while (points_.size() > size_t(config_.max_points)) {
    const size_t older = points_.size() - newest_;
    if (older == 0) {  // a frame alone over the bound: drop among its own points
      std::uniform_int_distribution<size_t> pick(0, points_.size() - 1);
      const size_t j = pick(rng_);
      points_[j] = points_.back();
      origins_[j] = origins_.back();
      passes_[j] = passes_.back();
      points_.pop_back();
      origins_.pop_back();
      passes_.pop_back();
      --newest_;
      continue;
    }
    // A random older point goes: the last older point takes its place, and the last point (one
    // of the newest) takes that one's, so the newest stay at the end.
    std::uniform_int_distribution<size_t> pick(0, older - 1);
    const size_t j = pick(rng_);
    points_[j] = points_[older - 1];
    origins_[j] = origins_[older - 1];
    passes_[j] = passes_[older - 1];
    points_[older - 1] = points_.back();
    origins_[older - 1] = origins_.back();
    passes_[older - 1] = passes_.back();
    points_.pop_back();
    origins_.pop_back();
    passes_.pop_back();
  }
}

void PointBuffer::RemoveOutside(const Vec3d& min_m, const Vec3d& max_m) {
  const Eigen::Array3f lo = min_m.cast<float>().array(), hi = max_m.cast<float>().array();
  std::vector<uint32_t> drop;
  for (size_t i = 0; i < points_.size(); ++i)
    if (!((points_[i].array() >= lo).all() && (points_[i].array() < hi).all()))
      drop.push_back(uint32_t(i));
  Remove(drop);
}

void PointBuffer::Filter(const std::vector<bool>& keep) {
  std::vector<uint32_t> drop;
  for (size_t i = 0; i < points_.size(); ++i)
    if (!keep[i]) drop.push_back(uint32_t(i));
  Remove(drop);
}

void PointBuffer::Remove(const std::vector<uint32_t>& drop) {
  static_assert(sizeof(Vec3f) == 3 * sizeof(float), "Vec3f is three packed floats");
  if (drop.empty()) return;
  // The points between two dropped ones move down as one run: a frame drops a few hundred of
  // about a hundred thousand, and a copy per point (or a flag read per point) cost more than
  // moving the runs. Points before the first dropped one stay where they are.
  const size_t n = points_.size(), newest_from = n - newest_;
  size_t out = drop[0];
  for (size_t k = 0; k < drop.size(); ++k) {
    if (drop[k] >= newest_from) --newest_;
    const size_t begin = size_t(drop[k]) + 1, end = k + 1 < drop.size() ? drop[k + 1] : n;
    if (end > begin) {
      // Three packed floats a point (as Serialize reads them), moved down over themselves.
      std::memmove(points_[out].data(), points_[begin].data(), (end - begin) * sizeof(Vec3f));
      std::memmove(origins_[out].data(), origins_[begin].data(), (end - begin) * sizeof(Vec3f));
      std::memmove(&passes_[out], &passes_[begin], end - begin);
    }
    out += end - begin;
  }
  points_.resize(out);
  origins_.resize(out);
  passes_.resize(out);
}

void PointBuffer::Serialize(ByteWriter* w) const {
  std::ostringstream rng;
  rng << rng_;
  w->String(rng.str());
  // Eigen vectors are not trivially copyable types, but are three packed floats.
  w->FloatArray(points_.empty() ? nullptr : points_[0].data(), points_.size() * 3);
  w->FloatArray(origins_.empty() ? nullptr : origins_[0].data(), origins_.size() * 3);
}

absl::Status PointBuffer::Deserialize(ByteReader* r) {
  std::string rng_state;
  RIM_RETURN_IF_ERROR(r->String(&rng_state));
  std::vector<float> p, o;
  RIM_RETURN_IF_ERROR(r->FloatArray(&p));
  RIM_RETURN_IF_ERROR(r->FloatArray(&o));
  if (p.size() != o.size() || p.size() % 3 != 0)
    return absl::DataLossError("point buffer: point and origin counts differ");
  std::vector<Vec3f> points(p.size() / 3), origins(o.size() / 3);
  // What AddFrame can have stored: finite rays no longer than buffer.max_range_m (Preprocess drops
  // longer ones). Training samples along every ray, and a corrupt origin far away (or NaN) would
  // put samples where the lattice arithmetic overflows. The slack covers the float transform.
  const float max_range = config_.max_range_m * 1.001f + 0.01f;
  for (size_t i = 0; i < points.size(); ++i) {
    points[i] = Vec3f(p[3 * i], p[3 * i + 1], p[3 * i + 2]);
    origins[i] = Vec3f(o[3 * i], o[3 * i + 1], o[3 * i + 2]);
    if (!points[i].allFinite() || !origins[i].allFinite() ||
        !((points[i] - origins[i]).norm() <= max_range))
      return absl::DataLossError(absl::StrCat("point buffer: ray ", i,
                                              " is not finite or longer than buffer.max_range_m"));
  }
  std::istringstream in(rng_state);
  std::mt19937_64 rng;
  in >> rng;
  if (in.fail()) return absl::DataLossError("point buffer: bad random generator state");
  rng_ = rng;
  points_ = std::move(points);
  origins_ = std::move(origins);
  passes_.assign(points_.size(), 0);
  newest_ = 0;  // set by the next frame, before anything samples
  return absl::OkStatus();
}

}  // namespace rim
