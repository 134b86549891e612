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
  const Int3 dims = lv.dims;
  const int64_t axis_stride[3] = {int64_t(dims.y()) * dims.z(), dims.z(), 1};
  const int64_t wrap[3] = {dims.x() * axis_stride[0], dims.y() * axis_stride[1],
                           dims.z() * axis_stride[2]};
  const IntBox box = map->LatticeBox(0);
  const uint32_t span[3] = {uint32_t(box.hi.x() - box.lo.x()), uint32_t(box.hi.y() - box.lo.y()),
                            uint32_t(box.hi.z() - box.lo.z())};
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
      // The slot follows the walk: one step along axis a moves it by the axis's stride, and
      // by one ring length back where the ring wraps. No modulo per voxel.
      Int3 ring;
      int64_t slot = 0;
      for (int a = 0; a < 3; ++a) {
        ring[a] = PosMod(g[a], dims[a]);
        slot = slot * dims[a] + ring[a];
      }
      double t = t0;
      while (t < t1) {
        // Rounding at the box faces can put the first or last voxel just outside.
        if (uint32_t(g.x() - box.lo.x()) <= span[0] && uint32_t(g.y() - box.lo.y()) <= span[1] &&
            uint32_t(g.z() - box.lo.z()) <= span[2])
          SetFlagBits(&lv.flags(slot), LocalMap::kSeenFree | LocalMap::kHasData);
        // The axis whose boundary comes first, chosen without branches: it changes at random
        // from voxel to voxel, and a mispredicted branch cost more than the rest of the step.
        const bool y_first = t_max[1] < t_max[0];
        const double t_xy = y_first ? t_max[1] : t_max[0];
        const int a = t_max[2] < t_xy ? 2 : int(y_first);
        t = t_max[a];
        t_max[a] += t_delta[a];
        g[a] += step[a];
        ring[a] += step[a];
        slot += step[a] * axis_stride[a];
        if (ring[a] == dims[a]) {
          ring[a] = 0;
          slot -= wrap[a];
        } else if (ring[a] < 0) {
          ring[a] = dims[a] - 1;
          slot += wrap[a];
        }
      }
    }
  });
}

void MarkSurfaceVoxels(const std::vector<Vec3f>& points_W, LocalMap* map, WorkerPool* pool) {
  if (!map->placed()) return;
  const double inv_s = 1.0 / map->geometry().leaf_m();
  LocalMap::Level& lv = map->level(0);
  // A point in the box is at most one ring length past the box corner's ring position, so its
  // ring position per axis is one compare and subtract away: no modulo per point.
  const IntBox box = map->LatticeBox(0);
  const Int3 dims = lv.dims;
  int lo_ring[3];
  uint32_t span[3];
  for (int a = 0; a < 3; ++a) {
    lo_ring[a] = PosMod(box.lo[a], dims[a]);
    span[a] = uint32_t(box.hi[a] - box.lo[a]);
  }
  ForRanges(points_W.size(), pool, [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      const Vec3f& p = points_W[i];
      const Int3 g(int(std::floor(p.x() * inv_s)), int(std::floor(p.y() * inv_s)),
                   int(std::floor(p.z() * inv_s)));
      uint32_t r[3];  // below the box: a huge unsigned value
      for (int a = 0; a < 3; ++a) r[a] = uint32_t(g[a] - box.lo[a]);
      if (r[0] > span[0] || r[1] > span[1] || r[2] > span[2]) continue;
      int ring[3];
      for (int a = 0; a < 3; ++a) {
        ring[a] = lo_ring[a] + int(r[a]);
        if (ring[a] >= dims[a]) ring[a] -= dims[a];
      }
      const int64_t slot = (int64_t(ring[0]) * dims.y() + ring[1]) * dims.z() + ring[2];
      SetFlagBits(&lv.flags(slot), LocalMap::kObserved | LocalMap::kHasData);
    }
  });
}

}  // namespace rim
