// DistanceField::Query: the signed distance to the nearest disk (or return) over the parts' k-d
// trees, its sign, the gaps of a plane, and the gradient's blend across neighbouring disks.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <mutex>
#include <nanoflann.hpp>
#include <shared_mutex>
#include <utility>
#include <vector>

#include "rim/map/distance_field.h"
#include "rim/map/distance_field_part.h"

namespace rim {
namespace {
using distance_field_internal::Dot;
using distance_field_internal::Tree;

// Disks this much farther than the nearest still turn the gradient (see Query).
constexpr float kBlend = 0.02f;

// Distance from q to the disk of radius r in surfel s's tangent plane.
inline float DiskDistance(const Surfel& s, const float* q, float r) {
  const float v[3] = {q[0] - s.p[0], q[1] - s.p[1], q[2] - s.p[2]};
  const float h = Dot(v, s.n);
  const float t2 = std::max(0.f, Dot(v, v) - h * h);  // squared offset within the plane
  if (t2 <= r * r) return std::abs(h);
  const float k = std::sqrt(t2) - r;
  return std::sqrt(h * h + k * k);
}

// The gradient of the signed distance to s's disk at q: the unit vector from the disk's nearest
// point to q, turned to point toward larger values (the normal for a point on the disk); also the
// distance, and the side of the disk's plane (+1 on the normal's side).
Vec3f AwayFrom(const Surfel& s, const float* q, float r, float* d, float* sign,
               bool* on_face = nullptr) {
  const float v[3] = {q[0] - s.p[0], q[1] - s.p[1], q[2] - s.p[2]};
  const float h = Dot(v, s.n);
  const float t[3] = {v[0] - h * s.n[0], v[1] - h * s.n[1], v[2] - h * s.n[2]};
  const float tl = std::sqrt(Dot(t, t));
  // The offset q - c: h·n within the disk, plus the part of the in-plane offset beyond the rim.
  const float keep = tl > r ? 1.f - r / tl : 0.f;
  if (on_face) *on_face = tl <= r;
  Vec3f diff;
  for (int a = 0; a < 3; ++a) diff[a] = h * s.n[a] + keep * t[a];
  *d = diff.norm();
  *sign = h >= 0.f ? 1.f : -1.f;
  if (*d > 1e-9f) return diff / *d * *sign;
  return Vec3f(s.n[0], s.n[1], s.n[2]);
}

// How far beyond the nearest disk (at distance `best`) the disks that turn the gradient may lie
// (see Query): none at the surface, kBlend at most, and far out no wider than reaches disks about
// 2.5 radii to the side. best + BlendWidth(best) grows with best (where the last term decides, its
// slope is 1 - 3 r^2 / best^2 > 0), so a search may drop every disk beyond the current best's
// limit: the final best's limit is no larger.
inline float BlendWidth(float best, float r) {
  return std::max(0.f, std::min({kBlend, 0.1f * best, 3.f * r * r / best}));
}

// A nanoflann result set that keeps the nearest disk, and (kGradient) the disks within the blend
// width of the best distance seen so far, for the gradient: a surfel whose centre lies farther
// than that limit plus the disk radius can hold neither, which bounds the search. Without the
// gradient the limit is the best distance itself: a query for distances alone visits only the
// disks that could be nearer, not the ring of those the gradient would blend.
template <bool kGradient>
struct NearestDisk {
  static constexpr int kKeep = 16;
  const Surfel* surfels;
  const float* q;
  float r;
  float rb;  // blend radius (BlendWidth's): r for surfels, larger for returns
  float best;
  int64_t index = -1;
  int kept = 0;
  std::array<std::pair<float, uint32_t>, kKeep> near{};
  // Disks at or beyond this distance matter neither for the value nor for the gradient.
  float Limit() const { return kGradient ? best + BlendWidth(best, rb) : best; }
  float worstDist() const {
    const float w = Limit() + r;
    return w * w;
  }
  bool full() const { return true; }
  bool addPoint(float, uint32_t i) {
    const float d = DiskDistance(surfels[i], q, r);
    if (d < best) {
      best = d;
      index = i;
    }
    if constexpr (!kGradient) return true;
    const float limit = Limit();
    if (d < limit) {
      if (kept == kKeep) {  // drop those the best has left behind, then the farthest
        int w = 0;
        for (int k = 0; k < kept; ++k)
          if (near[k].first < limit) near[w++] = near[k];
        kept = w;
        if (kept == kKeep) {
          int far = 0;
          for (int k = 1; k < kept; ++k)
            if (near[k].first > near[far].first) far = k;
          if (near[far].first <= d) return true;
          near[far] = near[--kept];
        }
      }
      near[kept++] = {d, i};
    }
    return true;
  }
};

// A nanoflann result set that collects every surfel whose centre lies within a radius.
struct WithinRadius {
  float radius2;
  std::array<uint32_t, 64> found{};
  int count = 0;
  float worstDist() const { return radius2; }
  bool full() const { return true; }
  bool addPoint(float d2, uint32_t i) {
    if (d2 < radius2 && count < int(found.size())) found[count++] = i;
    return true;
  }
};

// Whether q, beside every disk and near the surface, lies in a gap of a plane rather than past
// its edge. Disks of radius r on a plane sampled once per voxel leave gaps where their rims do
// not meet: at the corners of an axis-aligned plane's voxels (0.707 voxel from four centres)
// when r is under that. There the surface runs on, and its distance is the plane's and its
// gradient the plane's normal; past an edge it is the rim's. A gap: the coplanar disks around q
// (normals within 18 degrees of the nearest's, planes within a tenth of a voxel of its plane at
// q, centres within in-plane reach) lie around it, not to one side (the mean of the unit
// in-plane directions to their centres is under one half). On success, `normal` is the mean of
// their normals (unit) and `height` q's signed distance to the nearest disk's plane.
bool InPlaneGap(const Tree& tree, const std::vector<Surfel>& surfels, const Surfel& nearest,
                const float* q, float r, float leaf, Vec3f* normal, float* height) {
  const Vec3f n(nearest.n[0], nearest.n[1], nearest.n[2]);
  const Vec3f qv(q[0], q[1], q[2]);
  const Vec3f v0 = qv - Vec3f(nearest.p[0], nearest.p[1], nearest.p[2]);
  const float h = v0.dot(n);
  // A corner's gap lies within 0.707 voxel of the nearest centre, in its plane: farther out, q is
  // past an edge (and needs no search).
  const float base = std::max(r, 0.6f * leaf);
  if ((v0 - h * n).squaredNorm() > (base + 0.15f * leaf) * (base + 0.15f * leaf)) return false;
  // Around a voxel corner the four centres lie 0.707 voxel away in the plane; a point in the gap
  // but off the corner, a little farther from some of them.
  const float reach = base + 0.3f * leaf;
  WithinRadius search{reach * reach + h * h};
  tree.findNeighbors(search, q, nanoflann::SearchParams());
  Vec3f around = Vec3f::Zero(), sum = Vec3f::Zero();
  int count = 0;
  for (int k = 0; k < search.count; ++k) {
    const Surfel& s = surfels[search.found[k]];
    const Vec3f nj(s.n[0], s.n[1], s.n[2]);
    if (nj.dot(n) < 0.95f) continue;
    const Vec3f v = qv - Vec3f(s.p[0], s.p[1], s.p[2]);
    if (std::abs(v.dot(nj) - h) > 0.1f * leaf) continue;
    const Vec3f in_plane = -(v - v.dot(n) * n);
    const float len = in_plane.norm();
    if (len < 1e-6f) continue;
    around += in_plane / len;
    sum += nj;
    ++count;
  }
  if (count < 2 || around.norm() >= 0.5f * float(count)) return false;
  *normal = sum.normalized();
  *height = h;
  return true;
}

// Squared distance from q to an axis-aligned box.
float BoxDistance2(const float* q, const Vec3f& lo, const Vec3f& hi) {
  float d2 = 0;
  for (int a = 0; a < 3; ++a) {
    const float e = std::max({lo[a] - q[a], 0.f, q[a] - hi[a]});
    d2 += e * e;
  }
  return d2;
}

}  // namespace

void DistanceField::Query(const float* xyz, size_t n, float max_distance_m, float* sdf,
                          float* gradient, uint8_t* saturated, const uint8_t* with_returns) const {
  if (n == 0) return;
  // The parts that can hold a surface within reach of some point of the batch.
  Vec3f lo = Vec3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
  for (size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], xyz[3 * i + a]);
      hi[a] = std::max(hi[a], xyz[3 * i + a]);
    }
  // Returns are points (radius 0 <= radius_), so the surfels' radius bounds every part's reach.
  const float reach = max_distance_m + radius_;
  const float leaf = float(geometry_.leaf_m());
  std::vector<PartPtr> parts;
  {
    std::shared_lock<std::shared_mutex> lock(mu_);
    for (const auto* set : {&parts_, &returns_})
      for (const auto& [key, part] : *set) {
        bool apart = false;
        for (int a = 0; a < 3; ++a)
          apart = apart || part->lo[a] > hi[a] + reach || part->hi[a] < lo[a] - reach;
        if (!apart) parts.push_back(part);
      }
  }
  struct Order {
    float d2;  // squared distance to the part's bounds
    int rank;  // 0: returns within Part::kNearCell of q, 1: surfels, 2: other returns
    const Part* part;
  };
  std::vector<Order> order(parts.size());
  // Points in a spatially coherent order (by 0.5 m cell), each search seeded with its distance to
  // the previous point's nearest disk: a bound that prunes the trees from the start, where a
  // search from the bound alone first wanders through every disk within max_distance_m. The
  // distance found is the same whatever the seed.
  std::vector<std::pair<uint64_t, uint32_t>> visit(n);
  for (size_t i = 0; i < n; ++i) {
    uint64_t key = 0;
    for (int a = 0; a < 3; ++a)
      key = (key << 21) |
            (uint64_t(int64_t(std::floor(xyz[3 * i + a] * 2.f)) + (1 << 20)) & ((1u << 21) - 1));
    visit[i] = {key, uint32_t(i)};
  }
  std::sort(visit.begin(), visit.end());
  const Surfel* previous = nullptr;
  const Part* previous_part = nullptr;
  struct Near {
    float d;
    const Surfel* surfel;
    const Part* part;
  };
  for (const auto& [cell, index] : visit) {
    const size_t i = index;
    const float* q = xyz + 3 * i;
    const bool returns = !with_returns || with_returns[i];
    size_t m = 0;
    for (const PartPtr& p : parts) {
      if (!returns && p->radius == 0.f) continue;
      const float d2 = BoxDistance2(q, p->lo, p->hi);
      if (d2 >= reach * reach) continue;
      const int rank = p->radius != 0.f ? 1 : p->MaybeNear(q) ? 0 : 2;
      order[m++] = {d2, rank, p.get()};
    }
    // Returns right beside q first: their distance then bounds the surfels' searches, which
    // from a loose bound wander through every disk within it. Then the surfels, nearest parts
    // first; then the other returns, which a bound under Part::kNearCell rules out unsearched.
    // The distance does not depend on the order; the gradient's blend can, by a disk or two,
    // where a search keeps its most (NearestDisk::kKeep) disks.
    std::sort(order.begin(), order.begin() + m, [](const Order& a, const Order& b) {
      return a.rank != b.rank ? a.rank < b.rank : a.d2 < b.d2;
    });
    float best = max_distance_m;
    const Surfel* nearest = nullptr;
    const Part* nearest_part = nullptr;
    if (previous && (returns || previous_part->radius != 0.f)) {
      const float d = DiskDistance(*previous, q, previous_part->radius);
      if (d < best) best = d, nearest = previous, nearest_part = previous_part;
    }
    // Disks within kBlend of the nearest, over every part searched (for the gradient only: a
    // query for distances alone searches the nearest disk's bound, which is tighter).
    std::array<Near, 2 * NearestDisk<true>::kKeep> near;
    int kept = 0;
    for (size_t k = 0; k < m; ++k) {
      const Part& part = *order[k].part;
      const int rank = order[k].rank;
      const float bound = best + (gradient ? BlendWidth(best, part.blend) : 0.f) + part.radius;
      if (order[k].d2 >= bound * bound) {  // the rest of this rank lies farther still
        while (k + 1 < m && order[k + 1].rank == rank) ++k;
        continue;
      }
      if (rank == 2 && bound <= Part::kNearCell) continue;
      auto search_part = [&](auto&& search) {
        part.tree.findNeighbors(search, q, nanoflann::SearchParams());
        if (search.index >= 0) {
          best = search.best;
          nearest = &part.surfels[size_t(search.index)];
          nearest_part = &part;
        }
        for (int j = 0; j < search.kept && kept < int(near.size()); ++j)
          near[kept++] = {search.near[j].first, &part.surfels[search.near[j].second], &part};
      };
      if (gradient)
        search_part(NearestDisk<true>{part.surfels.data(), q, part.radius, part.blend, best});
      else
        search_part(NearestDisk<false>{part.surfels.data(), q, part.radius, part.blend, best});
    }
    previous = nearest;
    previous_part = nearest_part;
    float* g = gradient ? gradient + 3 * i : nullptr;
    if (!nearest) {
      sdf[i] = max_distance_m;
      if (g) g[0] = g[1] = g[2] = 0.f;
      if (saturated) saturated[i] = 1;
      continue;
    }
    float d = 0, sign = 1;
    bool on_face = false;
    const Vec3f away = AwayFrom(*nearest, q, nearest_part->radius, &d, &sign, &on_face);
    Vec3f plane_normal;
    float h = 0;
    if (!on_face && nearest_part->radius > 0.f && d < leaf &&
        InPlaneGap(nearest_part->tree, nearest_part->surfels, *nearest, q, nearest_part->radius,
                   leaf, &plane_normal, &h)) {
      // In a gap of a plane: the plane's distance (the nearest disk's, at q) and normal.
      sdf[i] = std::clamp(h, -max_distance_m, max_distance_m);
      if (saturated) saturated[i] = 0;
      if (g)
        for (int a = 0; a < 3; ++a) g[a] = plane_normal[a];
      continue;
    }
    sdf[i] = sign * std::min(d, max_distance_m);
    if (saturated) saturated[i] = 0;
    if (!g) continue;
    if (on_face) {  // over the nearest disk: its normal, exactly
      for (int a = 0; a < 3; ++a) g[a] = away[a];
      continue;
    }
    // Beside every disk, the nearest point is a rim: in a gap between neighbouring disks, or past
    // an edge. The gradient: the directions away from the disks nearly as near as the nearest,
    // weighted down to zero at `blend` farther, so that it turns smoothly across gaps and the
    // medial surfaces between two faces instead of tilting toward whichever rim is nearest.
    // The width: none at the surface, where a neighbouring disk's rim lies in the surface's own
    // plane and its direction would tilt the normal; and far out no wider than reaches disks
    // about 2.5 radii to the side (a width w at distance d reaches sqrt(2 d w)), which spans
    // the gaps between disks without a lopsided crowd of them.
    const float blend = BlendWidth(best, nearest_part->blend);
    Vec3f sum = Vec3f::Zero();
    bool covered = false;
    for (int j = 0; j < kept && !covered; ++j) {
      const float w = blend > 0.f ? 1.f - (near[j].d - best) / blend : 0.f;
      if (w <= 0.f) continue;
      float dj, sj;
      bool face_j = false;
      const Vec3f away_j = AwayFrom(*near[j].surfel, q, near[j].part->radius, &dj, &sj, &face_j);
      // A disk over q that lost to a rim by float rounding: q is over a face after all.
      if (face_j)
        sum = away_j, covered = true;
      else
        sum += w * away_j;
    }
    const Vec3f dir = sum.norm() > 1e-6f ? Vec3f(sum.normalized()) : away;
    for (int a = 0; a < 3; ++a) g[a] = dir[a];
  }
}

}  // namespace rim
