#include "sim/geometry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

namespace rim::sim {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kParallel = 1e-12;

bool IntersectBox(const Box& b, const Vec3& o, const Vec3& d, double t_min, double t_max, double* t,
                  Vec3* n) {
  const Vec3 p = o - b.center;
  const double lo[3] = {b.cos_yaw * p.x() + b.sin_yaw * p.y(),
                        -b.sin_yaw * p.x() + b.cos_yaw * p.y(), p.z()};
  const double ld[3] = {b.cos_yaw * d.x() + b.sin_yaw * d.y(),
                        -b.sin_yaw * d.x() + b.cos_yaw * d.y(), d.z()};
  double t_near = -kInf, t_far = kInf;
  int axis = -1;
  double sign = 0.0;
  for (int i = 0; i < 3; ++i) {
    const double h = b.half[i];
    if (std::abs(ld[i]) < kParallel) {
      if (std::abs(lo[i]) > h) return false;
      continue;
    }
    const double inv = 1.0 / ld[i];
    double t1 = (-h - lo[i]) * inv;
    double t2 = (h - lo[i]) * inv;
    if (t1 > t2) std::swap(t1, t2);
    if (t1 > t_near) {
      t_near = t1;
      axis = i;
      sign = ld[i] > 0 ? -1.0 : 1.0;
    }
    t_far = std::min(t_far, t2);
  }
  if (t_near > t_far || t_far < t_min || t_near > t_max) return false;
  if (t_near < t_min || axis < 0) {  // origin inside
    *t = t_min;
    *n = -d;
    return true;
  }
  *t = t_near;
  if (axis == 2) {
    *n = Vec3(0, 0, sign);
  } else {
    const Vec2 w = axis == 0 ? BoxToWorld(b, sign, 0) : BoxToWorld(b, 0, sign);
    *n = Vec3(w.x(), w.y(), 0);
  }
  return true;
}

// The z slab [z0, z1] along the ray: sets the t interval, false if the ray misses it.
bool ZSlab(double oz, double dz, double z0, double z1, double* ta, double* tb) {
  if (std::abs(dz) < kParallel) {
    if (oz < z0 || oz > z1) return false;
    *ta = -kInf;
    *tb = kInf;
    return true;
  }
  const double inv = 1.0 / dz;
  *ta = (z0 - oz) * inv;
  *tb = (z1 - oz) * inv;
  if (*ta > *tb) std::swap(*ta, *tb);
  return true;
}

bool IntersectCylinder(const Cylinder& c, const Vec3& o, const Vec3& d, double t_min, double t_max,
                       double* t, Vec3* n) {
  const double px = o.x() - c.center.x(), py = o.y() - c.center.y();
  const double a = d.x() * d.x() + d.y() * d.y();
  const double b = px * d.x() + py * d.y();
  const double cc = px * px + py * py - c.radius * c.radius;
  double s0, s1;  // radial interval
  if (a < kParallel) {
    if (cc > 0) return false;
    s0 = -kInf;
    s1 = kInf;
  } else {
    const double disc = b * b - a * cc;
    if (disc < 0) return false;
    const double sq = std::sqrt(disc);
    s0 = (-b - sq) / a;
    s1 = (-b + sq) / a;
  }
  double z0, z1;
  if (!ZSlab(o.z(), d.z(), c.z_min, c.z_max, &z0, &z1)) return false;
  const double t_near = std::max(s0, z0), t_far = std::min(s1, z1);
  if (t_near > t_far || t_far < t_min || t_near > t_max) return false;
  if (t_near < t_min) {
    *t = t_min;
    *n = -d;
    return true;
  }
  *t = t_near;
  if (s0 >= z0) {
    const Vec2 r(px + t_near * d.x(), py + t_near * d.y());
    const double len = r.norm();
    *n = len > 0 ? Vec3(r.x() / len, r.y() / len, 0) : Vec3(-d.x(), -d.y(), 0).normalized();
  } else {
    *n = Vec3(0, 0, d.z() > 0 ? -1.0 : 1.0);
  }
  return true;
}

bool IntersectSphere(const Sphere& s, const Vec3& o, const Vec3& d, double t_min, double t_max,
                     double* t, Vec3* n) {
  const Vec3 p = o - s.center;
  const double b = p.dot(d);
  const double c = p.squaredNorm() - s.radius * s.radius;
  const double disc = b * b - c;
  if (disc < 0) return false;
  const double sq = std::sqrt(disc);
  const double t0 = -b - sq, t1 = -b + sq;
  if (t1 < t_min || t0 > t_max) return false;
  if (t0 < t_min) {
    *t = t_min;
    *n = -d;
    return true;
  }
  *t = t0;
  *n = (p + t0 * d) / s.radius;
  return true;
}

bool IntersectCone(const Cone& c, const Vec3& o, const Vec3& d, double t_min, double t_max,
                   double* t, Vec3* n) {
  const double k = c.radius / (c.z_apex - c.z_base);
  const double k2 = k * k;
  const Vec3 p(o.x() - c.center.x(), o.y() - c.center.y(), o.z() - c.z_apex);
  const double A = d.x() * d.x() + d.y() * d.y() - k2 * d.z() * d.z();
  const double B = p.x() * d.x() + p.y() * d.y() - k2 * p.z() * d.z();
  const double C = p.x() * p.x() + p.y() * p.y() - k2 * p.z() * p.z();
  // Up to two t intervals where the ray is inside the double cone.
  std::array<std::pair<double, double>, 2> iv;
  int count = 0;
  if (std::abs(A) < kParallel) {
    if (std::abs(B) < kParallel) {
      if (C > 0) return false;
      iv[count++] = {-kInf, kInf};
    } else {
      const double r = -C / (2 * B);
      iv[count++] = B > 0 ? std::make_pair(-kInf, r) : std::make_pair(r, kInf);
    }
  } else {
    const double disc = B * B - A * C;
    if (A > 0) {
      if (disc < 0) return false;
      const double sq = std::sqrt(disc);
      iv[count++] = {(-B - sq) / A, (-B + sq) / A};
    } else if (disc < 0) {
      iv[count++] = {-kInf, kInf};
    } else {
      const double sq = std::sqrt(disc);
      const double r0 = std::min((-B - sq) / A, (-B + sq) / A);
      const double r1 = std::max((-B - sq) / A, (-B + sq) / A);
      iv[count++] = {-kInf, r0};
      iv[count++] = {r1, kInf};
    }
  }
  double z0, z1;
  if (!ZSlab(o.z(), d.z(), c.z_base, c.z_apex, &z0, &z1)) return false;
  // The solid (lower nappe between base and apex) is convex, so at most one interval survives
  // the z slab; keep the longest in case rounding lets a point-sized one through at the apex.
  double best_near = kInf, best_far = -kInf, best_len = -1;
  bool base_entry = false;
  for (int i = 0; i < count; ++i) {
    const double a = std::max(iv[i].first, z0), b = std::min(iv[i].second, z1);
    if (a <= b && b - a > best_len) {
      best_len = b - a;
      best_near = a;
      best_far = b;
      base_entry = z0 >= iv[i].first && d.z() > 0;
    }
  }
  if (best_len < 0 || best_far < t_min || best_near > t_max) return false;
  if (best_near < t_min) {
    *t = t_min;
    *n = -d;
    return true;
  }
  *t = best_near;
  if (base_entry) {
    *n = Vec3(0, 0, -1);
  } else {
    const Vec3 q = p + best_near * d;
    const Vec3 g(q.x(), q.y(), -k2 * q.z());
    const double len = g.norm();
    *n = len > 0 ? Vec3(g / len) : Vec3(0, 0, 1);
  }
  return true;
}

bool IntersectShell(const RoomShell& s, const Vec3& o, const Vec3& d, double t_min, double t_max,
                    double* t, Vec3* n) {
  for (int i = 0; i < 3; ++i) {
    if (o[i] <= s.min[i] || o[i] >= s.max[i]) {  // origin in the solid
      if (t_min > t_max) return false;
      *t = t_min;
      *n = -d;
      return true;
    }
  }
  double best = kInf;
  int axis = -1;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(d[i]) < kParallel) continue;
    const double ti = d[i] > 0 ? (s.max[i] - o[i]) / d[i] : (s.min[i] - o[i]) / d[i];
    if (ti < best) {
      best = ti;
      axis = i;
    }
  }
  if (axis < 0 || best > t_max || best < t_min) return false;
  *t = best;
  *n = Vec3::Zero();
  (*n)[axis] = d[axis] > 0 ? -1.0 : 1.0;
  return true;
}

struct IntersectVisitor {
  const Vec3& o;
  const Vec3& d;
  double t_min, t_max;
  double* t;
  Vec3* n;
  bool operator()(const Box& s) const { return IntersectBox(s, o, d, t_min, t_max, t, n); }
  bool operator()(const Cylinder& s) const {
    return IntersectCylinder(s, o, d, t_min, t_max, t, n);
  }
  bool operator()(const Sphere& s) const { return IntersectSphere(s, o, d, t_min, t_max, t, n); }
  bool operator()(const Cone& s) const { return IntersectCone(s, o, d, t_min, t_max, t, n); }
  bool operator()(const RoomShell& s) const { return IntersectShell(s, o, d, t_min, t_max, t, n); }
};

}  // namespace

Box MakeBox(const Vec3& center, const Vec3& half, double yaw) {
  Box b;
  b.center = center;
  b.half = half;
  b.yaw = yaw;
  b.cos_yaw = std::cos(yaw);
  b.sin_yaw = std::sin(yaw);
  return b;
}

Box MakeBoxZ(const Vec2& center, const Vec2& half_xy, double yaw, double z_min, double z_max) {
  return MakeBox(Vec3(center.x(), center.y(), 0.5 * (z_min + z_max)),
                 Vec3(half_xy.x(), half_xy.y(), 0.5 * (z_max - z_min)), yaw);
}

bool Intersect(const Shape& shape, const Vec3& o, const Vec3& d, double t_min, double t_max,
               double* t, Vec3* n) {
  return std::visit(IntersectVisitor{o, d, t_min, t_max, t, n}, shape);
}

bool Contains(const Shape& shape, const Vec3& p, double margin) {
  if (const auto* b = std::get_if<Box>(&shape)) {
    const Vec3 q = p - b->center;
    const double lx = b->cos_yaw * q.x() + b->sin_yaw * q.y();
    const double ly = -b->sin_yaw * q.x() + b->cos_yaw * q.y();
    return std::abs(lx) <= b->half.x() - margin && std::abs(ly) <= b->half.y() - margin &&
           std::abs(q.z()) <= b->half.z() - margin;
  }
  if (const auto* c = std::get_if<Cylinder>(&shape)) {
    return (p.head<2>() - c->center).norm() <= c->radius - margin && p.z() >= c->z_min + margin &&
           p.z() <= c->z_max - margin;
  }
  if (const auto* s = std::get_if<Sphere>(&shape)) {
    return (p - s->center).norm() <= s->radius - margin;
  }
  if (const auto* c = std::get_if<Cone>(&shape)) {
    const double k = c->radius / (c->z_apex - c->z_base);
    if (p.z() < c->z_base + margin || p.z() > c->z_apex - margin) return false;
    // Distance to the slanted side is (k (z_apex - z) - r) / sqrt(1 + k^2).
    return k * (c->z_apex - p.z()) - (p.head<2>() - c->center).norm() >=
           margin * std::sqrt(1 + k * k);
  }
  const auto& s = std::get<RoomShell>(shape);
  for (int i = 0; i < 3; ++i) {
    if (p[i] <= s.min[i] - margin || p[i] >= s.max[i] + margin) return true;
  }
  return false;
}

bool ContainsAll(const Shape& shape, const Vec3* points, int n, double margin) {
  if (const auto* s = std::get_if<RoomShell>(&shape)) {
    for (int i = 0; i < 3; ++i) {
      bool below = true, above = true;
      for (int k = 0; k < n; ++k) {
        below = below && points[k][i] <= s->min[i] - margin;
        above = above && points[k][i] >= s->max[i] + margin;
      }
      if (below || above) return true;
    }
    return false;
  }
  for (int k = 0; k < n; ++k) {
    if (!Contains(shape, points[k], margin)) return false;
  }
  return true;
}

Aabb Bounds(const Shape& shape) {
  Aabb box;
  if (const auto* b = std::get_if<Box>(&shape)) {
    const double ex = std::abs(b->cos_yaw) * b->half.x() + std::abs(b->sin_yaw) * b->half.y();
    const double ey = std::abs(b->sin_yaw) * b->half.x() + std::abs(b->cos_yaw) * b->half.y();
    const Vec3 e(ex, ey, b->half.z());
    box.min = b->center - e;
    box.max = b->center + e;
  } else if (const auto* c = std::get_if<Cylinder>(&shape)) {
    box.min = Vec3(c->center.x() - c->radius, c->center.y() - c->radius, c->z_min);
    box.max = Vec3(c->center.x() + c->radius, c->center.y() + c->radius, c->z_max);
  } else if (const auto* s = std::get_if<Sphere>(&shape)) {
    box.min = s->center - Vec3::Constant(s->radius);
    box.max = s->center + Vec3::Constant(s->radius);
  } else if (const auto* k = std::get_if<Cone>(&shape)) {
    box.min = Vec3(k->center.x() - k->radius, k->center.y() - k->radius, k->z_base);
    box.max = Vec3(k->center.x() + k->radius, k->center.y() + k->radius, k->z_apex);
  } else {
    box.min = Vec3::Constant(-kInf);
    box.max = Vec3::Constant(kInf);
  }
  return box;
}

}  // namespace rim::sim
