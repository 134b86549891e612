#include "rim/train/free_space.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>

namespace rim {
namespace {

// Clips the segment o + t·d, t in [*t0, *t1], to the box [lo, hi); false when nothing is left.
bool ClipToBox(const Vec3d& o, const Vec3d& d, const Vec3d& lo, const Vec3d& hi, double* t0,
               double* t1) {
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12) {
      if (o[a] < lo[a] || o[a] >= hi[a]) return false;
      continue;
    }
    double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    *t0 = std::max(*t0, ta);
    *t1 = std::min(*t1, tb);
  }
  return *t0 < *t1;
}

// Sets bits in a flag byte that other threads of the same marking pass may be setting too. Most
// voxels a scan crosses were marked by earlier scans: those are only read, and their cache lines
// stay clean.
inline void SetFlagBits(uint8_t* flags, uint8_t bits) {
  if ((__atomic_load_n(flags, __ATOMIC_RELAXED) & bits) != bits)
    __atomic_fetch_or(flags, bits, __ATOMIC_RELAXED);
}

// Splits [0, n) into pieces over the pool's threads, or runs it here without one.
template <typename Fn>
void ForRanges(size_t n, WorkerPool* pool, Fn&& fn) {
  if (pool == nullptr || pool->threads() <= 1 || n < 256) {
    fn(size_t(0), n);
    return;
  }
  // A few pieces per thread: rays differ in length, and a thread that finishes early takes more.
  const int tasks = 4 * pool->threads();
  pool->Run(tasks,
            [&](int t) { fn(n * size_t(t) / size_t(tasks), n * size_t(t + 1) / size_t(tasks)); });
}

// The free-space walk of MarkFreeSpace, set up once per scan and run over ranges of rays.
class FreeWalk {
 public:
  FreeWalk(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W, float band_m,
           int max_rays, LocalMap* map)
      : points_(points_W), origins_(origins_W), band_(band_m), lv_(map->level(0)) {
    n_ = points_W.size();
    if (max_rays <= 0 || n_ == 0 || !map->placed()) return;
    s_ = map->geometry().leaf_m();
    lo_ = map->min_m();
    hi_ = map->max_m();
    dims_ = lv_.dims;
    axis_stride_[0] = int64_t(dims_.y()) * dims_.z();
    axis_stride_[1] = dims_.z();
    axis_stride_[2] = 1;
    for (int a = 0; a < 3; ++a) wrap_[a] = dims_[a] * axis_stride_[a];
    box_ = map->LatticeBox(0);
    for (int a = 0; a < 3; ++a) span_[a] = uint32_t(box_.hi[a] - box_.lo[a]);
    // Ray j of the walk is point floor(j · stride).
    stride_ = std::max(1.0, double(n_) / max_rays);
    rays_ = std::min(n_, size_t(std::ceil(double(n_) / stride_)));
  }
  size_t rays() const { return rays_; }

  void Walk(size_t j0, size_t j1) const {
    const double s = s_;
    for (size_t j = j0; j < j1; ++j) {
      const size_t i = std::min(n_ - 1, size_t(double(j) * stride_));
      const Vec3d o = origins_[i].cast<double>();
      Vec3d d = points_[i].cast<double>() - o;
      const double range = d.norm();
      if (range <= band_) continue;
      d /= range;
      double t0 = 0, t1 = range - band_;
      if (!ClipToBox(o, d, lo_, hi_, &t0, &t1)) continue;
      // Voxel walk (one step per voxel boundary crossed) from t0 to t1.
      const Vec3d p = o + t0 * d;
      Int3 g(int(std::floor(p.x() / s)), int(std::floor(p.y() / s)), int(std::floor(p.z() / s)));
      Int3 step;
      Vec3d t_max, t_delta;
      for (int a = 0; a < 3; ++a) {
        if (d[a] > 0) {
          step[a] = 1;
          t_max[a] = t0 + ((g[a] + 1) * s - p[a]) / d[a];
          t_delta[a] = s / d[a];
        } else if (d[a] < 0) {
          step[a] = -1;
          t_max[a] = t0 + (g[a] * s - p[a]) / d[a];
          t_delta[a] = -s / d[a];
        } else {
          step[a] = 0;
          t_max[a] = std::numeric_limits<double>::infinity();
          t_delta[a] = std::numeric_limits<double>::infinity();
        }
      }
      // The slot follows the walk: one step along axis a moves it by the axis's stride, and
      // by one ring length back where the ring wraps. No modulo per voxel.
      Int3 ring;
      int64_t slot = 0;
      for (int a = 0; a < 3; ++a) {
        ring[a] = PosMod(g[a], dims_[a]);
        slot = slot * dims_[a] + ring[a];
      }
      double t = t0;
      while (t < t1) {
        // Rounding at the box faces can put the first or last voxel just outside.
        if (uint32_t(g.x() - box_.lo.x()) <= span_[0] &&
            uint32_t(g.y() - box_.lo.y()) <= span_[1] && uint32_t(g.z() - box_.lo.z()) <= span_[2])
          SetFlagBits(&lv_.flags(slot), LocalMap::kSeenFree | LocalMap::kHasData);
        // The axis whose boundary comes first, chosen without branches: it changes at random
        // from voxel to voxel, and a mispredicted branch cost more than the rest of the step.
        const bool y_first = t_max[1] < t_max[0];
        const double t_xy = y_first ? t_max[1] : t_max[0];
        const int a = t_max[2] < t_xy ? 2 : int(y_first);
        t = t_max[a];
        t_max[a] += t_delta[a];
        g[a] += step[a];
        ring[a] += step[a];
        slot += step[a] * axis_stride_[a];
        if (ring[a] == dims_[a]) {
          ring[a] = 0;
          slot -= wrap_[a];
        } else if (ring[a] < 0) {
          ring[a] = dims_[a] - 1;
          slot += wrap_[a];
        }
      }
    }
  }

 private:
  const std::vector<Vec3f>& points_;
  const std::vector<Vec3f>& origins_;
  const float band_;
  LocalMap::Level& lv_;
  size_t n_ = 0, rays_ = 0;
  double s_ = 0, stride_ = 1;
  Vec3d lo_, hi_;
  Int3 dims_;
  int64_t axis_stride_[3] = {}, wrap_[3] = {};
  IntBox box_;
  uint32_t span_[3] = {};
};

// MarkSurfaceVoxels, set up once per scan and run over ranges of points. A point in the box is
// at most one ring length past the box corner's ring position, so its ring position per axis is
// one compare and subtract away: no modulo per point.
class SurfaceMark {
 public:
  SurfaceMark(const std::vector<Vec3f>& points_W, LocalMap* map)
      : points_(points_W), lv_(map->level(0)), placed_(map->placed()) {
    if (!placed_) return;
    inv_s_ = 1.0 / map->geometry().leaf_m();
    box_ = map->LatticeBox(0);
    dims_ = lv_.dims;
    for (int a = 0; a < 3; ++a) {
      lo_ring_[a] = PosMod(box_.lo[a], dims_[a]);
      span_[a] = uint32_t(box_.hi[a] - box_.lo[a]);
    }
  }
  size_t points() const { return placed_ ? points_.size() : 0; }

  void Mark(size_t begin, size_t end) const {
    for (size_t i = begin; i < end; ++i) {
      const Vec3f& p = points_[i];
      const Int3 g(int(std::floor(p.x() * inv_s_)), int(std::floor(p.y() * inv_s_)),
                   int(std::floor(p.z() * inv_s_)));
      uint32_t r[3];  // below the box: a huge unsigned value
      for (int a = 0; a < 3; ++a) r[a] = uint32_t(g[a] - box_.lo[a]);
      if (r[0] > span_[0] || r[1] > span_[1] || r[2] > span_[2]) continue;
      int ring[3];
      for (int a = 0; a < 3; ++a) {
        ring[a] = lo_ring_[a] + int(r[a]);
        if (ring[a] >= dims_[a]) ring[a] -= dims_[a];
      }
      const int64_t slot = (int64_t(ring[0]) * dims_.y() + ring[1]) * dims_.z() + ring[2];
      SetFlagBits(&lv_.flags(slot), LocalMap::kObserved | LocalMap::kHasData);
    }
  }

 private:
  const std::vector<Vec3f>& points_;
  LocalMap::Level& lv_;
  const bool placed_;
  double inv_s_ = 0;
  IntBox box_;
  Int3 dims_;
  int lo_ring_[3] = {};
  uint32_t span_[3] = {};
};

}  // namespace

void MarkFreeSpace(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W,
                   float band_m, int max_rays, LocalMap* map, WorkerPool* pool) {
  const FreeWalk walk(points_W, origins_W, band_m, max_rays, map);
  ForRanges(walk.rays(), pool, [&](size_t j0, size_t j1) { walk.Walk(j0, j1); });
}

void MarkSurfaceVoxels(const std::vector<Vec3f>& points_W, LocalMap* map, WorkerPool* pool) {
  const SurfaceMark mark(points_W, map);
  ForRanges(mark.points(), pool, [&](size_t begin, size_t end) { mark.Mark(begin, end); });
}

void MarkScan(const std::vector<Vec3f>& inside_p, const std::vector<Vec3f>& inside_o,
              const std::vector<Vec3f>& outside_p, const std::vector<Vec3f>& outside_o,
              float band_m, int inside_rays, int outside_rays, LocalMap* map, WorkerPool* pool,
              const std::function<void()>& also) {
  const SurfaceMark surface(inside_p, map);
  const FreeWalk inside(inside_p, inside_o, band_m, inside_rays, map);
  const FreeWalk outside(outside_p, outside_o, band_m, outside_rays, map);
  // Task 0 is `also`, so that one thread starts it while the other starts marking; then a few
  // pieces per thread of each kind, the long inside rays first.
  const int pieces = pool ? 4 * pool->threads() : 1;
  auto run = [&](int t) {
    if (t == 0) {
      if (also) also();
      return;
    }
    const int kind = (t - 1) / pieces, k = (t - 1) % pieces;
    auto range = [&](size_t n, auto&& fn) {
      fn(n * size_t(k) / size_t(pieces), n * size_t(k + 1) / size_t(pieces));
    };
    if (kind == 0) range(inside.rays(), [&](size_t a, size_t b) { inside.Walk(a, b); });
    if (kind == 1) range(outside.rays(), [&](size_t a, size_t b) { outside.Walk(a, b); });
    if (kind == 2) range(surface.points(), [&](size_t a, size_t b) { surface.Mark(a, b); });
  };
  if (pool && pool->threads() > 1) {
    pool->Run(1 + 3 * pieces, run);
  } else {
    for (int t = 0; t < 1 + 3 * pieces; ++t) run(t);
  }
}

}  // namespace rim
