#include "support/analytic_scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <utility>

#include "rim/eval/nearest_neighbors.h"

namespace rim::testing_support {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr double kPi = 3.14159265358979323846;

// Own uniform/normal draws on top of mt19937: the std distributions are implementation-defined,
// and test fixtures must produce the same data with every standard library.
class Rng {
 public:
  explicit Rng(uint32_t seed) : engine_(seed) {}
  // [0, 1) with 53 bits.
  double Uniform() {
    const uint64_t hi = engine_() >> 5, lo = engine_() >> 6;
    return (static_cast<double>(hi) * 67108864.0 + static_cast<double>(lo)) *
           (1.0 / 9007199254740992.0);
  }
  double Gaussian() {
    // Box-Muller; 1 - u keeps the log argument in (0, 1].
    const double u1 = 1.0 - Uniform(), u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
  }

 private:
  std::mt19937 engine_;
};

bool HasGround(const AnalyticScene& s) { return std::isfinite(s.ground_z); }

float BoxSdf(const Box& b, const Eigen::Vector3f& p) {
  const Eigen::Vector3f c = 0.5f * (b.min + b.max), h = 0.5f * (b.max - b.min);
  const Eigen::Vector3f q = (p - c).cwiseAbs() - h;
  return q.cwiseMax(0.f).norm() + std::min(q.maxCoeff(), 0.f);
}

Eigen::Vector3f BoxNormal(const Box& b, const Eigen::Vector3f& p) {
  const Eigen::Vector3f c = 0.5f * (b.min + b.max), h = 0.5f * (b.max - b.min);
  const Eigen::Vector3f d = p - c;
  const Eigen::Vector3f q = d.cwiseAbs() - h;
  const Eigen::Vector3f sign(d.x() < 0 ? -1.f : 1.f, d.y() < 0 ? -1.f : 1.f,
                             d.z() < 0 ? -1.f : 1.f);
  if (q.maxCoeff() > 0.f) return sign.cwiseProduct(q.cwiseMax(0.f)).normalized();
  int axis;
  q.maxCoeff(&axis);
  return Eigen::Vector3f::Unit(axis) * sign[axis];
}

float SphereSdf(const Sphere& s, const Eigen::Vector3f& p) {
  return (p - s.center).norm() - s.radius;
}

Eigen::Vector3f SphereNormal(const Sphere& s, const Eigen::Vector3f& p) {
  const Eigen::Vector3f d = p - s.center;
  const float n = d.norm();
  return n > 0.f ? Eigen::Vector3f(d / n) : Eigen::Vector3f::UnitZ();
}

// Radial (dx) and axial (dz) signed distances to the infinite side and to the cap slab.
std::pair<float, float> CylinderParts(const Cylinder& c, const Eigen::Vector3f& p, float* rad) {
  *rad = (p.head<2>() - c.center_xy).norm();
  return {*rad - c.radius, std::max(c.z_min - p.z(), p.z() - c.z_max)};
}

float CylinderSdf(const Cylinder& c, const Eigen::Vector3f& p) {
  float rad;
  const auto [dx, dz] = CylinderParts(c, p, &rad);
  return std::hypot(std::max(dx, 0.f), std::max(dz, 0.f)) + std::min(std::max(dx, dz), 0.f);
}

Eigen::Vector3f CylinderNormal(const Cylinder& c, const Eigen::Vector3f& p) {
  float rad;
  const auto [dx, dz] = CylinderParts(c, p, &rad);
  const Eigen::Vector2f r2 =
      rad > 0.f ? Eigen::Vector2f((p.head<2>() - c.center_xy) / rad) : Eigen::Vector2f::UnitX();
  const Eigen::Vector3f radial(r2.x(), r2.y(), 0.f);
  const Eigen::Vector3f axial(0.f, 0.f, p.z() > 0.5f * (c.z_min + c.z_max) ? 1.f : -1.f);
  if (dx > 0.f || dz > 0.f) {
    return (radial * std::max(dx, 0.f) + axial * std::max(dz, 0.f)).normalized();
  }
  return dx > dz ? radial : axial;
}

// The parameter interval [t0, t1] over which a ray lies inside a solid; empty when t0 > t1.
struct Interval {
  double t0 = -std::numeric_limits<double>::infinity();
  double t1 = std::numeric_limits<double>::infinity();
  bool empty() const { return t0 > t1; }
  void Clip(double a, double b) {
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  }
  void SetEmpty() {
    t0 = 1.0;
    t1 = 0.0;
  }
};

// Restricts `iv` to lo <= o + t d <= hi along one axis. Handles d == 0 explicitly because the
// usual reciprocal trick yields 0 * inf = NaN when the origin lies on a slab plane.
void ClipSlab(double o, double d, double lo, double hi, Interval* iv) {
  if (d == 0.0) {
    if (o < lo || o > hi) iv->SetEmpty();
    return;
  }
  double a = (lo - o) / d, b = (hi - o) / d;
  if (a > b) std::swap(a, b);
  iv->Clip(a, b);
}

// Solving in double: in float, the quadratic's discriminant cancels catastrophically at ranges of
// tens of metres and the hit point drifts off the surface by ~1e-4.
Interval RayBox(const Box& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  Interval iv;
  for (int a = 0; a < 3 && !iv.empty(); ++a) ClipSlab(o[a], d[a], b.min[a], b.max[a], &iv);
  return iv;
}

Interval RaySphere(const Sphere& s, const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  Interval iv;
  const Eigen::Vector3d oc = o - s.center.cast<double>();
  const double bh = oc.dot(d), c = oc.squaredNorm() - double(s.radius) * s.radius;
  const double a = d.squaredNorm();
  const double disc = bh * bh - a * c;
  if (disc < 0.0) {
    iv.SetEmpty();
    return iv;
  }
  const double sq = std::sqrt(disc);
  iv.t0 = (-bh - sq) / a;
  iv.t1 = (-bh + sq) / a;
  return iv;
}

Interval RayCylinder(const Cylinder& cyl, const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  Interval iv;
  ClipSlab(o.z(), d.z(), cyl.z_min, cyl.z_max, &iv);
  if (iv.empty()) return iv;
  const Eigen::Vector2d oc = o.head<2>() - cyl.center_xy.cast<double>();
  const Eigen::Vector2d dxy = d.head<2>();
  const double a = dxy.squaredNorm(), c = oc.squaredNorm() - double(cyl.radius) * cyl.radius;
  if (a == 0.0) {
    if (c > 0.0) iv.SetEmpty();
    return iv;
  }
  const double bh = oc.dot(dxy);
  const double disc = bh * bh - a * c;
  if (disc < 0.0) {
    iv.SetEmpty();
    return iv;
  }
  const double sq = std::sqrt(disc);
  iv.Clip((-bh - sq) / a, (-bh + sq) / a);
  return iv;
}

// A piece of primitive surface that SampleSurface can draw from uniformly by area.
struct Patch {
  enum Kind { kRect, kSphere, kCylinderSide, kCylinderCap };
  Kind kind = kRect;
  double area = 0.0;
  // kRect: fixed axis `axis` at coordinate `level`, rectangle [lo, hi] over the next two axes
  // (cyclically). kCylinderCap: the cap's z is `level`.
  int axis = 0;
  float level = 0.f;
  Eigen::Vector2f lo = Eigen::Vector2f::Zero(), hi = Eigen::Vector2f::Zero();
  Eigen::Vector3f normal = Eigen::Vector3f::UnitZ();
  // Curved kinds: index into the scene's spheres / cylinders.
  int index = 0;
  // kCylinderSide: its z range clipped to the region.
  float z0 = 0.f, z1 = 0.f;
};

bool InRegion(const Eigen::Vector3f& p, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  return (p.array() >= lo.array()).all() && (p.array() <= hi.array()).all();
}

bool BoxesOverlap(const Eigen::Vector3f& a0, const Eigen::Vector3f& a1, const Eigen::Vector3f& b0,
                  const Eigen::Vector3f& b1) {
  return (a0.array() <= b1.array()).all() && (b0.array() <= a1.array()).all();
}

// Adds a rectangle with normal along +-axis at `level`, clipped to the region.
void AddRect(int axis, float level, float normal_sign, const Eigen::Vector3f& face_lo,
             const Eigen::Vector3f& face_hi, const Eigen::Vector3f& rlo, const Eigen::Vector3f& rhi,
             std::vector<Patch>* patches) {
  if (level < rlo[axis] || level > rhi[axis]) return;
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  Patch p;
  p.kind = Patch::kRect;
  p.axis = axis;
  p.level = level;
  p.lo = Eigen::Vector2f(std::max(face_lo[u], rlo[u]), std::max(face_lo[v], rlo[v]));
  p.hi = Eigen::Vector2f(std::min(face_hi[u], rhi[u]), std::min(face_hi[v], rhi[v]));
  if (!(p.hi.array() > p.lo.array()).all()) return;
  p.area = double(p.hi.x() - p.lo.x()) * double(p.hi.y() - p.lo.y());
  p.normal = Eigen::Vector3f::Unit(axis) * normal_sign;
  patches->push_back(p);
}

AnalyticScene::SurfacePoint DrawFromPatch(const AnalyticScene& scene, const Patch& patch,
                                          Rng* rng) {
  AnalyticScene::SurfacePoint sp;
  switch (patch.kind) {
    case Patch::kRect: {
      const int u = (patch.axis + 1) % 3, v = (patch.axis + 2) % 3;
      sp.p[patch.axis] = patch.level;
      sp.p[u] = patch.lo.x() + float(rng->Uniform()) * (patch.hi.x() - patch.lo.x());
      sp.p[v] = patch.lo.y() + float(rng->Uniform()) * (patch.hi.y() - patch.lo.y());
      sp.n = patch.normal;
      sp.on_flat_face = true;
      break;
    }
    case Patch::kSphere: {
      const Sphere& s = scene.spheres[patch.index];
      // Archimedes: z uniform in [-1, 1] and azimuth uniform is uniform by area on the sphere.
      const double z = 2.0 * rng->Uniform() - 1.0, phi = 2.0 * kPi * rng->Uniform();
      const double rxy = std::sqrt(std::max(0.0, 1.0 - z * z));
      sp.n = Eigen::Vector3d(rxy * std::cos(phi), rxy * std::sin(phi), z).cast<float>();
      sp.p = s.center + s.radius * sp.n;
      sp.on_flat_face = false;
      break;
    }
    case Patch::kCylinderSide: {
      const Cylinder& c = scene.cylinders[patch.index];
      const double phi = 2.0 * kPi * rng->Uniform();
      sp.n = Eigen::Vector3f(float(std::cos(phi)), float(std::sin(phi)), 0.f);
      sp.p.head<2>() = c.center_xy + c.radius * sp.n.head<2>();
      sp.p.z() = patch.z0 + float(rng->Uniform()) * (patch.z1 - patch.z0);
      sp.on_flat_face = false;
      break;
    }
    case Patch::kCylinderCap: {
      const Cylinder& c = scene.cylinders[patch.index];
      // sqrt makes the radius density proportional to r, i.e. uniform over the disc.
      const double r = c.radius * std::sqrt(rng->Uniform()), phi = 2.0 * kPi * rng->Uniform();
      sp.p = Eigen::Vector3f(c.center_xy.x() + float(r * std::cos(phi)),
                             c.center_xy.y() + float(r * std::sin(phi)), patch.level);
      sp.n = patch.normal;
      sp.on_flat_face = true;
      break;
    }
  }
  return sp;
}

}  // namespace

float AnalyticScene::Sdf(const Eigen::Vector3f& p) const {
  float d = HasGround(*this) ? p.z() - ground_z : kInf;
  for (const Box& b : boxes) d = std::min(d, BoxSdf(b, p));
  for (const Sphere& s : spheres) d = std::min(d, SphereSdf(s, p));
  for (const Cylinder& c : cylinders) d = std::min(d, CylinderSdf(c, p));
  return d;
}

Eigen::Vector3f AnalyticScene::Normal(const Eigen::Vector3f& p) const {
  float best = HasGround(*this) ? p.z() - ground_z : kInf;
  Eigen::Vector3f n = Eigen::Vector3f::UnitZ();
  for (const Box& b : boxes) {
    const float d = BoxSdf(b, p);
    if (d < best) {
      best = d;
      n = BoxNormal(b, p);
    }
  }
  for (const Sphere& s : spheres) {
    const float d = SphereSdf(s, p);
    if (d < best) {
      best = d;
      n = SphereNormal(s, p);
    }
  }
  for (const Cylinder& c : cylinders) {
    const float d = CylinderSdf(c, p);
    if (d < best) {
      best = d;
      n = CylinderNormal(c, p);
    }
  }
  return n;
}

float AnalyticScene::Raycast(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir,
                             float max_range) const {
  const Eigen::Vector3d o = origin.cast<double>(), d = dir.cast<double>();
  double nearest = std::numeric_limits<double>::infinity();
  // The ray enters a solid at max(t0, 0) unless the solid lies entirely behind the origin.
  auto consider = [&nearest](const Interval& iv) {
    if (!iv.empty() && iv.t1 >= 0.0) nearest = std::min(nearest, std::max(iv.t0, 0.0));
  };
  if (HasGround(*this)) {
    Interval iv;
    ClipSlab(o.z(), d.z(), -std::numeric_limits<double>::infinity(), ground_z, &iv);
    consider(iv);
  }
  for (const Box& b : boxes) consider(RayBox(b, o, d));
  for (const Sphere& s : spheres) consider(RaySphere(s, o, d));
  for (const Cylinder& c : cylinders) consider(RayCylinder(c, o, d));
  return nearest <= max_range ? static_cast<float>(nearest) : kInf;
}

std::vector<AnalyticScene::SurfacePoint> AnalyticScene::SampleSurface(
    const Eigen::Vector3f& region_min, const Eigen::Vector3f& region_max, int count,
    uint32_t seed) const {
  const Eigen::Vector3f& rlo = region_min;
  const Eigen::Vector3f& rhi = region_max;
  std::vector<Patch> patches;
  // The ground is infinite, so only its part inside the region is a patch.
  if (HasGround(*this)) {
    AddRect(2, ground_z, 1.f, rlo, rhi, rlo, rhi, &patches);
  }
  for (const Box& b : boxes) {
    for (int axis = 0; axis < 3; ++axis) {
      AddRect(axis, b.min[axis], -1.f, b.min, b.max, rlo, rhi, &patches);
      AddRect(axis, b.max[axis], 1.f, b.min, b.max, rlo, rhi, &patches);
    }
  }
  // Curved patches are not clipped analytically; out-of-region draws are rejected below, which
  // keeps the distribution uniform by area.
  for (size_t i = 0; i < spheres.size(); ++i) {
    const Sphere& s = spheres[i];
    const Eigen::Vector3f r = Eigen::Vector3f::Constant(s.radius);
    if (!BoxesOverlap(s.center - r, s.center + r, rlo, rhi)) continue;
    Patch p;
    p.kind = Patch::kSphere;
    p.index = static_cast<int>(i);
    p.area = 4.0 * kPi * double(s.radius) * s.radius;
    patches.push_back(p);
  }
  for (size_t i = 0; i < cylinders.size(); ++i) {
    const Cylinder& c = cylinders[i];
    const Eigen::Vector3f lo(c.center_xy.x() - c.radius, c.center_xy.y() - c.radius, c.z_min);
    const Eigen::Vector3f hi(c.center_xy.x() + c.radius, c.center_xy.y() + c.radius, c.z_max);
    if (!BoxesOverlap(lo, hi, rlo, rhi)) continue;
    Patch side;
    side.kind = Patch::kCylinderSide;
    side.index = static_cast<int>(i);
    side.z0 = std::max(c.z_min, rlo.z());
    side.z1 = std::min(c.z_max, rhi.z());
    side.area = 2.0 * kPi * c.radius * double(side.z1 - side.z0);
    if (side.area > 0.0) patches.push_back(side);
    for (const float sign : {-1.f, 1.f}) {
      Patch cap;
      cap.kind = Patch::kCylinderCap;
      cap.index = static_cast<int>(i);
      cap.level = sign < 0.f ? c.z_min : c.z_max;
      cap.normal = Eigen::Vector3f::UnitZ() * sign;
      cap.area = kPi * double(c.radius) * c.radius;
      if (cap.level >= rlo.z() && cap.level <= rhi.z()) patches.push_back(cap);
    }
  }

  std::vector<SurfacePoint> out;
  if (patches.empty() || count <= 0) return out;
  std::vector<double> cdf(patches.size());
  double total = 0.0;
  for (size_t i = 0; i < patches.size(); ++i) cdf[i] = (total += patches[i].area);
  if (!(total > 0.0)) return out;

  out.reserve(count);
  Rng rng(seed);
  // A point is exposed when stepping off it along its normal leads into free space: that rejects
  // both points buried inside another solid and coincident faces (box bottom on the ground).
  constexpr float kBuried = -1e-4f, kStep = 1e-3f;
  // Bounds the work when the region holds almost no exposed surface.
  const int64_t max_attempts = 200 * int64_t{count} + 10000;
  for (int64_t attempt = 0; attempt < max_attempts && int(out.size()) < count; ++attempt) {
    const double pick = rng.Uniform() * total;
    const size_t k = std::min<size_t>(std::upper_bound(cdf.begin(), cdf.end(), pick) - cdf.begin(),
                                      patches.size() - 1);
    const SurfacePoint sp = DrawFromPatch(*this, patches[k], &rng);
    if (!InRegion(sp.p, rlo, rhi)) continue;
    if (Sdf(sp.p) < kBuried || !(Sdf(sp.p + kStep * sp.n) > 0.f)) continue;
    out.push_back(sp);
  }
  return out;
}

AnalyticScene AnalyticScene::Default() {
  AnalyticScene s;
  s.ground_z = 0.f;
  // Bases sit 0.5 m below ground (spheres 0.1 m) so no face coincides with the ground plane.
  s.boxes = {
      {{2.f, 3.f, -0.5f}, {8.f, 7.f, 3.f}},         // building, left
      {{12.f, -8.f, -0.5f}, {17.f, -3.f, 4.f}},     // tall building, right
      {{22.f, 2.5f, -0.5f}, {24.f, 4.f, 2.f}},      // small box, left
      {{28.f, -4.5f, -0.5f}, {29.5f, -3.f, 1.5f}},  // small box, right
      {{35.f, 3.f, -0.5f}, {40.f, 8.f, 3.5f}},      // building, left
  };
  s.spheres = {
      {{10.f, -3.2f, 0.9f}, 1.0f},  // resting on the ground
      {{26.f, -3.0f, 1.8f}, 0.6f},  // floating, so its underside is seen too
  };
  s.cylinders = {
      {{6.f, -2.6f}, 0.25f, -0.5f, 4.f},
      {{33.f, 2.6f}, 0.35f, -0.5f, 3.5f},
  };
  return s;
}

std::vector<Eigen::Vector3f> SimulateScan(const AnalyticScene& scene, const LidarModel& lidar,
                                          const Eigen::Isometry3f& T_world_sensor, uint32_t seed) {
  std::vector<Eigen::Vector3f> points;
  if (lidar.beams <= 0 || lidar.columns <= 0) return points;
  points.reserve(size_t(lidar.beams) * lidar.columns);
  Rng rng(seed);
  const Eigen::Matrix3f R = T_world_sensor.linear();
  const Eigen::Vector3f origin = T_world_sensor.translation();
  std::vector<float> cos_az(lidar.columns), sin_az(lidar.columns);
  for (int c = 0; c < lidar.columns; ++c) {
    const double az = 2.0 * kPi * c / lidar.columns;
    cos_az[c] = float(std::cos(az));
    sin_az[c] = float(std::sin(az));
  }
  for (int b = 0; b < lidar.beams; ++b) {
    const double t = lidar.beams > 1 ? double(b) / (lidar.beams - 1) : 0.5;
    const double elev =
        (lidar.elev_min_deg + t * (lidar.elev_max_deg - lidar.elev_min_deg)) * kPi / 180.0;
    const float ce = float(std::cos(elev)), se = float(std::sin(elev));
    for (int c = 0; c < lidar.columns; ++c) {
      const Eigen::Vector3f dir_s(ce * cos_az[c], ce * sin_az[c], se);
      const float range = scene.Raycast(origin, R * dir_s, lidar.max_range_m);
      if (!std::isfinite(range)) continue;
      float measured = range;
      if (lidar.noise_stddev_m > 0.f) measured += lidar.noise_stddev_m * float(rng.Gaussian());
      // A return cannot come from behind the sensor.
      if (measured <= 0.f) continue;
      points.push_back(measured * dir_s);
    }
  }
  return points;
}

std::vector<Eigen::Isometry3f> StraightTrajectory(float x0, float x1, int n,
                                                  float sensor_height_m) {
  std::vector<Eigen::Isometry3f> poses;
  for (int i = 0; i < n; ++i) {
    const float t = n > 1 ? float(i) / float(n - 1) : 0.f;
    // Incommensurate with the pose index so consecutive yaws never repeat a pattern.
    const float yaw = float(3.0 * kPi / 180.0 * std::sin(1.3 * i));
    Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
    T.linear() = Eigen::AngleAxisf(yaw, Eigen::Vector3f::UnitZ()).toRotationMatrix();
    T.translation() = Eigen::Vector3f(x0 + t * (x1 - x0), 0.f, sensor_height_m);
    poses.push_back(T);
  }
  return poses;
}

MeshErrors EvaluateMesh(const Mesh& mesh, const AnalyticScene& scene,
                        const Eigen::Vector3f& region_min, const Eigen::Vector3f& region_max,
                        int samples, uint32_t seed,
                        const std::function<bool(const Eigen::Vector3f&)>& truth_filter) {
  constexpr double kInfD = std::numeric_limits<double>::infinity();
  MeshErrors errors{kInfD, kInfD, kInfD, 0};
  auto vertex = [&mesh](uint32_t i) {
    const auto& v = mesh.vertices[i];
    return Eigen::Vector3f(v[0], v[1], v[2]);
  };

  // Only triangles that can reach the region are sampled, so a large mesh evaluated on a small
  // region still spends its samples where they count.
  std::vector<std::array<Eigen::Vector3f, 3>> tris;
  std::vector<double> cdf;
  double total = 0.0;
  for (const auto& f : mesh.faces) {
    if (f[0] >= mesh.vertices.size() || f[1] >= mesh.vertices.size() ||
        f[2] >= mesh.vertices.size()) {
      continue;
    }
    const std::array<Eigen::Vector3f, 3> t = {vertex(f[0]), vertex(f[1]), vertex(f[2])};
    const Eigen::Vector3f lo = t[0].cwiseMin(t[1]).cwiseMin(t[2]);
    const Eigen::Vector3f hi = t[0].cwiseMax(t[1]).cwiseMax(t[2]);
    if (!BoxesOverlap(lo, hi, region_min, region_max)) continue;
    const double area = 0.5 * double((t[1] - t[0]).cross(t[2] - t[0]).norm());
    if (!(area > 0.0)) continue;
    tris.push_back(t);
    cdf.push_back(total += area);
  }
  if (tris.empty() || samples <= 0) return errors;

  Rng rng(seed);
  std::vector<Eigen::Vector3f> mesh_points;
  mesh_points.reserve(samples);
  double abs_sdf_sum = 0.0;
  for (int i = 0; i < samples; ++i) {
    const double pick = rng.Uniform() * total;
    const size_t k = std::min<size_t>(std::upper_bound(cdf.begin(), cdf.end(), pick) - cdf.begin(),
                                      tris.size() - 1);
    // Square-root warp makes barycentrics uniform over the triangle's area.
    const float s = float(std::sqrt(rng.Uniform())), u = float(rng.Uniform());
    const auto& t = tris[k];
    const Eigen::Vector3f p = (1.f - s) * t[0] + s * (1.f - u) * t[1] + s * u * t[2];
    if (!InRegion(p, region_min, region_max)) continue;
    abs_sdf_sum += std::abs(scene.Sdf(p));
    mesh_points.push_back(p);
  }
  errors.mesh_samples = mesh_points.size();
  if (mesh_points.empty()) return errors;
  errors.accuracy_m = abs_sdf_sum / double(mesh_points.size());

  // A different stream than the mesh samples so the two sides are independent.
  std::vector<AnalyticScene::SurfacePoint> truth =
      scene.SampleSurface(region_min, region_max, samples, seed ^ 0x9E3779B9u);
  if (truth_filter) {
    truth.erase(
        std::remove_if(truth.begin(), truth.end(),
                       [&](const AnalyticScene::SurfacePoint& sp) { return !truth_filter(sp.p); }),
        truth.end());
  }
  std::vector<rim::eval::Point3f> mesh_xyz;
  mesh_xyz.reserve(mesh_points.size());
  for (const Eigen::Vector3f& p : mesh_points) mesh_xyz.push_back({p.x(), p.y(), p.z()});
  const rim::eval::NearestNeighbors tree(std::move(mesh_xyz));
  double dist_sum = 0.0;
  for (const auto& sp : truth) {
    dist_sum += std::sqrt(tree.NearestSquaredDistance({sp.p.x(), sp.p.y(), sp.p.z()}));
  }
  // With no exposed surface in the region there is nothing to miss.
  errors.completeness_m = truth.empty() ? 0.0 : dist_sum / double(truth.size());
  errors.chamfer_l1_m = 0.5 * (errors.accuracy_m + errors.completeness_m);
  return errors;
}

}  // namespace rim::testing_support
