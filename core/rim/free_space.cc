#include "rim/free_space.h"

#include <algorithm>
#include <cmath>
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

}  // namespace

void MarkFreeSpace(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W,
                   float band_m, int max_rays, LocalMap* map, WorkerPool* pool) {
  if (max_rays <= 0 || points_W.empty() || !map->placed()) return;
  const double s = map->geometry().leaf_m();
  const Vec3d lo = map->min_m(), hi = map->max_m();
  LocalMap::Level& lv = map->level(0);
  const size_t n = points_W.size();
  // Ray j of the walk is point floor(j · stride).
  const double stride = std::max(1.0, double(n) / max_rays);
  const size_t rays = std::min(n, size_t(std::ceil(double(n) / stride)));
  ForRanges(rays, pool, [&](size_t j0, size_t j1) {
    for (size_t j = j0; j < j1; ++j) {
      const size_t i = std::min(n - 1, size_t(double(j) * stride));
      const Vec3d o = origins_W[i].cast<double>();
      Vec3d d = points_W[i].cast<double>() - o;
      const double range = d.norm();
      if (range <= band_m) continue;
      d /= range;
      double t0 = 0, t1 = range - band_m;
      if (!ClipToBox(o, d, lo, hi, &t0, &t1)) continue;
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
      double t = t0;
      while (t < t1) {
        // Rounding at the box faces can put the first or last voxel just outside.
        if (map->InBox(0, g))
          SetFlagBits(&lv.flags(map->Slot(0, g)), LocalMap::kSeenFree | LocalMap::kHasData);
        int a = 0;
        if (t_max[1] < t_max[a]) a = 1;
        if (t_max[2] < t_max[a]) a = 2;
        t = t_max[a];
        t_max[a] += t_delta[a];
        g[a] += step[a];
      }
    }
  });
}

void MarkSurfaceVoxels(const std::vector<Vec3f>& points_W, LocalMap* map, WorkerPool* pool) {
  if (!map->placed()) return;
  const double inv_s = 1.0 / map->geometry().leaf_m();
  LocalMap::Level& lv = map->level(0);
  ForRanges(points_W.size(), pool, [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      const Vec3f& p = points_W[i];
      const Int3 g(int(std::floor(p.x() * inv_s)), int(std::floor(p.y() * inv_s)),
                   int(std::floor(p.z() * inv_s)));
      if (map->InBox(0, g))
        SetFlagBits(&lv.flags(map->Slot(0, g)), LocalMap::kObserved | LocalMap::kHasData);
    }
  });
}

}  // namespace rim
