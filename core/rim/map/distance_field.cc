#include "rim/map/distance_field.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <mutex>
#include <nanoflann.hpp>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"

namespace rim {
namespace {

// nanoflann reads surfel positions through this adaptor.
struct SurfelAdaptor {
  const std::vector<Surfel>* surfels;
  size_t kdtree_get_point_count() const { return surfels->size(); }
  float kdtree_get_pt(size_t i, size_t dim) const { return (*surfels)[i].p[dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

using Tree = nanoflann::KDTreeSingleIndexAdaptor<
    nanoflann::L2_Simple_Adaptor<float, SurfelAdaptor, float, uint32_t>, SurfelAdaptor, 3,
    uint32_t>;
constexpr size_t kMaxLeaf = 16;
// Disks this much farther than the nearest still turn the gradient (see Query).
constexpr float kBlend = 0.02f;

float Dot(const float* a, const float* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

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

// A nanoflann result set that keeps the nearest disk, and the disks within the blend width of the
// best distance seen so far (for the gradient): a surfel whose centre lies farther than that limit
// plus the disk radius can hold neither, which bounds the search.
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
  float Limit() const { return best + BlendWidth(best, rb); }
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

struct DistanceField::Part {
  Part(std::vector<Surfel> s, float r, float rb)
      : radius(r),
        blend(rb),
        surfels(std::move(s)),
        adaptor{&surfels},
        tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(kMaxLeaf)) {
    lo.setConstant(std::numeric_limits<float>::max());
    hi.setConstant(std::numeric_limits<float>::lowest());
    for (const Surfel& x : surfels)
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], x.p[a]);
        hi[a] = std::max(hi[a], x.p[a]);
      }
    if (radius == 0.f && !surfels.empty()) BuildNear();
  }

  // Points (returns) spread over a whole sub-map, so that their bounds do not tell a query
  // point in the street from one beside a facade. A grid of kNearCell cells over the bounds
  // marks the cells with a point in them or in a neighbouring cell: a query point whose cell is
  // unmarked has no point within kNearCell, and a search bounded by that can skip the tree.
  static constexpr float kNearCell = 0.5f;
  void BuildNear() {
    for (int a = 0; a < 3; ++a) dims[a] = int((hi[a] - lo[a]) / kNearCell) + 1;
    near.assign(size_t(dims.x()) * size_t(dims.y()) * size_t(dims.z()), 0);
    auto at = [&](int x, int y, int z) { return (size_t(x) * dims.y() + y) * dims.z() + z; };
    for (const Surfel& x : surfels) {
      Int3 c;
      for (int a = 0; a < 3; ++a)
        c[a] = std::min(dims[a] - 1, int((x.p[a] - lo[a]) * (1.f / kNearCell)));
      for (int dx = std::max(0, c.x() - 1); dx <= std::min(dims.x() - 1, c.x() + 1); ++dx)
        for (int dy = std::max(0, c.y() - 1); dy <= std::min(dims.y() - 1, c.y() + 1); ++dy)
          for (int dz = std::max(0, c.z() - 1); dz <= std::min(dims.z() - 1, c.z() + 1); ++dz)
            near[at(dx, dy, dz)] = 1;
    }
  }
  // False only when no point lies within kNearCell of q.
  bool MaybeNear(const float* q) const {
    Int3 c;
    for (int a = 0; a < 3; ++a) {
      const float t = (q[a] - lo[a]) * (1.f / kNearCell);
      if (!(t >= 0.f) || t >= float(dims[a])) return true;  // outside: the bounds decide
      c[a] = int(t);
    }
    return near[(size_t(c.x()) * dims.y() + c.y()) * dims.z() + c.z()] != 0;
  }

  float radius;  // of the disks (0: points)
  float blend;   // the radius BlendWidth takes for the gradient beside them
  std::vector<Surfel> surfels;
  SurfelAdaptor adaptor;
  Tree tree;
  Vec3f lo, hi;  // bounds of the surfel centres
  Int3 dims = Int3::Zero();
  std::vector<uint8_t> near;  // returns only: see BuildNear
};

DistanceField::DistanceField(const MapGeometry& geometry, float surfel_radius_m)
    : geometry_(geometry), radius_(surfel_radius_m) {}

DistanceField::~DistanceField() = default;

uint32_t DistanceField::VoxelIndex(const Int3& key, const Int3& g) const {
  const Int3 c = geometry_.cells(0);
  const Int3 l = g - key.cwiseProduct(c);
  return (uint32_t(l.x()) * uint32_t(c.y()) + uint32_t(l.y())) * uint32_t(c.z()) + uint32_t(l.z());
}

Int3 DistanceField::VoxelOf(const Int3& key, uint32_t index) const {
  const Int3 c = geometry_.cells(0);
  const int z = int(index % uint32_t(c.z()));
  index /= uint32_t(c.z());
  const int y = int(index % uint32_t(c.y()));
  const int x = int(index / uint32_t(c.y()));
  return key.cwiseProduct(c) + Int3(x, y, z);
}

DistanceField::PartPtr DistanceField::MakePart(std::vector<Surfel> surfels, float radius,
                                               float blend_radius) {
  return std::make_shared<const Part>(std::move(surfels), radius, blend_radius);
}

void DistanceField::FitNormals(const Int3& key, std::vector<Surfel>* surfels) const {
  // Positions on the zero level are accurate to millimetres; the field's gradient is not as
  // good a normal (it tilts where the field is steep or curved). A plane through the surfels of
  // the 3×3×3 voxels around a fresh one gives its normal where they are planar; the field's
  // normal orients it, and stays where the neighbourhood is not a plane (edges, thin parts).
  std::vector<Surfel>& s = *surfels;
  // The surfels are sorted by voxel index, (x·Cy + y)·Cz + z within the sub-map: a column of
  // neighbours (fixed x and y offsets, z − 1 … z + 1) is a run of consecutive indices. Fresh
  // surfels are visited in index order, so the lowest neighbour index of each of the 9 columns
  // only grows; a cursor per column follows it through the array, with no lookups.
  const Int3 c = geometry_.cells(0);
  const size_t total = s.size();
  const double leaf = geometry_.leaf_m();
  auto index_at = [&](size_t i) { return s[i].voxel & ~kFresh; };
  size_t cursor[9] = {};
  for (Surfel& x : s) {
    if (!(x.voxel & kFresh)) continue;
    x.voxel &= ~kFresh;
    const Int3 g = VoxelOf(key, x.voxel) - key.cwiseProduct(c);  // within the sub-map
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    Eigen::Matrix3d second = Eigen::Matrix3d::Zero();
    int count = 0;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy) {
        const int hx = g.x() + dx, hy = g.y() + dy;
        if (hx < 0 || hx >= c.x() || hy < 0 || hy >= c.y()) continue;
        const uint32_t column = (uint32_t(hx) * uint32_t(c.y()) + uint32_t(hy)) * uint32_t(c.z());
        const uint32_t first = column + uint32_t(std::max(g.z() - 1, 0));
        size_t& at = cursor[(dx + 1) * 3 + (dy + 1)];
        while (at < total && index_at(at) < first) ++at;
        size_t k = at;
        for (int dz = -1; dz <= 1; ++dz) {
          const int hz = g.z() + dz;
          if (hz < 0 || hz >= c.z()) continue;
          const uint32_t target = column + uint32_t(hz);
          while (k < total && index_at(k) < target) ++k;
          if (k == total || index_at(k) != target) continue;
          const Eigen::Vector3d p(s[k].p[0], s[k].p[1], s[k].p[2]);
          mean += p;
          second += p * p.transpose();
          ++count;
        }
      }
    if (count < 5) continue;
    mean /= count;
    const Eigen::Matrix3d cov = second / count - mean * mean.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
    eig.computeDirect(cov);
    const Eigen::Vector3d ev = eig.eigenvalues();  // ascending
    // Planar: thin across (within a few millimetres) and spread along two directions.
    if (!(ev[0] < 1e-5 && ev[1] > 0.1 * leaf * leaf * 0.5)) continue;
    Eigen::Vector3d n = eig.eigenvectors().col(0);
    const Eigen::Vector3d field(x.n[0], x.n[1], x.n[2]);
    if (n.dot(field) < 0) n = -n;
    // A fit far from the field's own normal is two surfaces meeting, not a plane.
    if (n.dot(field) < 0.7) continue;
    for (int a = 0; a < 3; ++a) x.n[a] = float(n[a]);
  }
}

void DistanceField::Replace(const Int3& key, const std::vector<IntBox>& regions,
                            std::vector<Surfel> fresh) {
  for (Surfel& s : fresh) s.voxel |= kFresh;
  PartPtr old;
  {
    std::shared_lock<std::shared_mutex> lock(mu_);
    auto it = parts_.find(key);
    if (it != parts_.end()) old = it->second;
  }
  if (old && !regions.empty()) {
    // Kept: the old surfels outside the regions, appended with no spare capacity (the part keeps
    // this vector).
    std::vector<uint32_t> kept;
    for (uint32_t i = 0; i < uint32_t(old->surfels.size()); ++i) {
      const Int3 g = VoxelOf(key, old->surfels[i].voxel);
      bool inside = false;
      for (const IntBox& b : regions) inside = inside || b.Contains(g);
      if (!inside) kept.push_back(i);
    }
    fresh.reserve(fresh.size() + kept.size());
    for (uint32_t i : kept) fresh.push_back(old->surfels[i]);
  }
  // A fixed order, whatever order the regions were extracted in: saved bytes and tree layout
  // depend on the map alone.
  std::sort(fresh.begin(), fresh.end(), [](const Surfel& a, const Surfel& b) {
    return (a.voxel & ~kFresh) < (b.voxel & ~kFresh);
  });
  FitNormals(key, &fresh);
  PartPtr part = fresh.empty() ? nullptr : MakePart(std::move(fresh), radius_, radius_);
  std::unique_lock<std::shared_mutex> lock(mu_);
  if (part)
    parts_[key] = std::move(part);
  else
    parts_.erase(key);
}

void DistanceField::ReplaceReturns(const Int3& key, std::vector<Surfel> returns) {
  PartPtr part = returns.empty() ? nullptr : MakePart(std::move(returns), 0.f, returns_blend_);
  std::unique_lock<std::shared_mutex> lock(mu_);
  if (part)
    returns_[key] = std::move(part);
  else
    returns_.erase(key);
}

std::shared_ptr<const std::vector<Surfel>> DistanceField::Surfels(const Int3& key) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  auto it = parts_.find(key);
  if (it == parts_.end()) return nullptr;
  return std::shared_ptr<const std::vector<Surfel>>(it->second, &it->second->surfels);
}

void DistanceField::Clear() {
  std::unique_lock<std::shared_mutex> lock(mu_);
  parts_.clear();
  returns_.clear();
}

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
    // Disks within kBlend of the nearest, over every part searched.
    std::array<Near, 2 * NearestDisk::kKeep> near;
    int kept = 0;
    for (size_t k = 0; k < m; ++k) {
      const Part& part = *order[k].part;
      const int rank = order[k].rank;
      const float bound = best + BlendWidth(best, part.blend) + part.radius;
      if (order[k].d2 >= bound * bound) {  // the rest of this rank lies farther still
        while (k + 1 < m && order[k + 1].rank == rank) ++k;
        continue;
      }
      if (rank == 2 && bound <= Part::kNearCell) continue;
      NearestDisk search{part.surfels.data(), q, part.radius, part.blend, best};
      part.tree.findNeighbors(search, q, nanoflann::SearchParams());
      if (search.index >= 0) {
        best = search.best;
        nearest = &part.surfels[size_t(search.index)];
        nearest_part = &part;
      }
      for (int j = 0; j < search.kept && kept < int(near.size()); ++j)
        near[kept++] = {search.near[j].first, &part.surfels[search.near[j].second], &part};
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

DistanceFieldStats DistanceField::Stats() const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  DistanceFieldStats st;
  auto bytes = [](const Part& part) {
    return int64_t(part.surfels.capacity() * sizeof(Surfel) +
                   const_cast<Tree&>(part.tree).usedMemory(const_cast<Tree&>(part.tree)));
  };
  for (const auto& [key, part] : parts_) {
    st.surfels += int64_t(part->surfels.size());
    st.bytes += bytes(*part);
    ++st.submaps;
  }
  for (const auto& [key, part] : returns_) {
    st.returns += int64_t(part->surfels.size());
    st.bytes += bytes(*part);
  }
  return st;
}

void DistanceField::WriteParts(const std::map<Int3, PartPtr, KeyLess>& parts, ByteWriter* w) {
  w->U64(parts.size());
  for (const auto& [key, part] : parts) {
    for (int a = 0; a < 3; ++a) w->I32(key[a]);
    w->PodVector(part->surfels);
  }
}

void DistanceField::Serialize(ByteWriter* w) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  w->F32(radius_);
  WriteParts(parts_, w);
}

absl::Status DistanceField::Deserialize(ByteReader* r) {
  float radius;
  uint64_t count;
  RIM_RETURN_IF_ERROR(r->F32(&radius));
  if (radius != radius_)
    return absl::DataLossError(
        absl::StrCat("surfel radius ", radius, " m, the config gives ", radius_));
  RIM_RETURN_IF_ERROR(r->U64(&count));
  if (count > r->remaining() / 20)
    return absl::DataLossError(absl::StrCat(count, " sub-maps do not fit in the file"));
  const Int3 cells = geometry_.cells(0);
  const uint64_t voxels = uint64_t(cells.x()) * cells.y() * cells.z();
  const double leaf = geometry_.leaf_m();
  std::map<Int3, PartPtr, KeyLess> parts;
  for (uint64_t k = 0; k < count; ++k) {
    Int3 key;
    for (int a = 0; a < 3; ++a) RIM_RETURN_IF_ERROR(r->I32(&key[a]));
    if ((key.cwiseAbs().array() > (1 << 20)).any() || parts.count(key))
      return absl::DataLossError(absl::StrCat("sub-map ", k, " has a bad or repeated key"));
    std::vector<Surfel> surfels;
    RIM_RETURN_IF_ERROR(r->PodVector(&surfels));
    for (size_t i = 0; i < surfels.size(); ++i) {
      const Surfel& s = surfels[i];
      bool ok = s.voxel < voxels && (i == 0 || surfels[i - 1].voxel <= s.voxel);
      const float n2 = Dot(s.n, s.n);
      ok = ok && std::isfinite(n2) && std::abs(n2 - 1.f) < 1e-3f;
      if (ok) {
        const Int3 g = VoxelOf(key, s.voxel);
        for (int a = 0; a < 3; ++a)
          ok = ok && std::isfinite(s.p[a]) && s.p[a] >= (g[a] - 1) * leaf &&
               s.p[a] <= (g[a] + 2) * leaf;
      }
      if (!ok)
        return absl::DataLossError(absl::StrCat("surfel ", i, " of sub-map (", key.x(), ",",
                                                key.y(), ",", key.z(), ") is out of order, ",
                                                "outside its voxel or not finite"));
    }
    if (!surfels.empty()) parts[key] = MakePart(std::move(surfels), radius_, radius_);
  }
  std::unique_lock<std::shared_mutex> lock(mu_);
  parts_ = std::move(parts);
  return absl::OkStatus();
}

void DistanceField::SerializeReturns(ByteWriter* w) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  WriteParts(returns_, w);
}

absl::Status DistanceField::DeserializeReturns(ByteReader* r) {
  uint64_t count;
  RIM_RETURN_IF_ERROR(r->U64(&count));
  if (count > r->remaining() / 20)
    return absl::DataLossError(absl::StrCat(count, " sub-maps of returns do not fit in the file"));
  std::map<Int3, PartPtr, KeyLess> parts;
  for (uint64_t k = 0; k < count; ++k) {
    Int3 key;
    for (int a = 0; a < 3; ++a) RIM_RETURN_IF_ERROR(r->I32(&key[a]));
    if ((key.cwiseAbs().array() > (1 << 20)).any() || parts.count(key))
      return absl::DataLossError(
          absl::StrCat("returns of sub-map ", k, " have a bad or repeated key"));
    std::vector<Surfel> returns;
    RIM_RETURN_IF_ERROR(r->PodVector(&returns));
    for (size_t i = 0; i < returns.size(); ++i) {
      const Surfel& s = returns[i];
      const float n2 = Dot(s.n, s.n);
      bool ok = (i == 0 || returns[i - 1].voxel < s.voxel) && std::isfinite(n2) &&
                std::abs(n2 - 1.f) < 1e-3f;
      for (int a = 0; a < 3; ++a) ok = ok && std::isfinite(s.p[a]);
      if (!ok)
        return absl::DataLossError(absl::StrCat("return ", i, " of sub-map (", key.x(), ",",
                                                key.y(), ",", key.z(),
                                                ") is out of order or not finite"));
    }
    if (!returns.empty()) parts[key] = MakePart(std::move(returns), 0.f, returns_blend_);
  }
  std::unique_lock<std::shared_mutex> lock(mu_);
  returns_ = std::move(parts);
  return absl::OkStatus();
}

}  // namespace rim
