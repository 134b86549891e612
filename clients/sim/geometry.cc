#include "sim/geometry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

namespace rim::sim {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kPi = 3.14159265358979323846;
constexpr double kParallel = 1e-12;

// Rotates a local (box-frame) xy vector into the world frame.
Vec2 ToWorld(const Box& b, double x, double y) {
  return Vec2(b.cos_yaw * x - b.sin_yaw * y, b.sin_yaw * x + b.cos_yaw * y);
}

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
    const Vec2 w = axis == 0 ? ToWorld(b, sign, 0) : ToWorld(b, 0, sign);
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

// Unit icosahedron, faces counter-clockwise seen from outside.
struct Icosahedron {
  std::array<Vec3, 12> v;
  std::array<std::array<int, 3>, 20> f;
};

const Icosahedron& UnitIcosahedron() {
  static const Icosahedron ico = [] {
    Icosahedron r;
    const double g = (1.0 + std::sqrt(5.0)) / 2.0;
    const double raw[12][3] = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0},
                               {0, -1, g}, {0, 1, g}, {0, -1, -g}, {0, 1, -g},
                               {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
    for (int i = 0; i < 12; ++i) r.v[i] = Vec3(raw[i][0], raw[i][1], raw[i][2]).normalized();
    const int faces[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                              {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                              {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                              {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    for (int i = 0; i < 20; ++i) {
      std::array<int, 3> t = {faces[i][0], faces[i][1], faces[i][2]};
      const Vec3 nrm = (r.v[t[1]] - r.v[t[0]]).cross(r.v[t[2]] - r.v[t[0]]);
      if (nrm.dot(r.v[t[0]]) < 0) std::swap(t[1], t[2]);
      r.f[i] = t;
    }
    return r;
  }();
  return ico;
}

// Point (i, j) of the n-subdivided face (a, b, c): weights a: n-i-j, b: i, c: j, projected to the
// unit sphere. The weighted sum runs in ascending vertex-index order so that points on an edge
// shared by two faces come out bit-identical (and weld).
Vec3 IcoPoint(const std::array<int, 3>& face, int n, int i, int j) {
  const Icosahedron& ico = UnitIcosahedron();
  std::array<std::pair<int, double>, 3> w = {std::make_pair(face[0], double(n - i - j)),
                                             std::make_pair(face[1], double(i)),
                                             std::make_pair(face[2], double(j))};
  std::sort(w.begin(), w.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
  Vec3 s = Vec3::Zero();
  for (const auto& [idx, wt] : w) {
    if (wt != 0.0) s += wt * ico.v[idx];
  }
  return s / s.norm();
}

template <typename F>
void ForEachIcoTriangle(int n, F&& emit) {
  for (const auto& face : UnitIcosahedron().f) {
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j + i < n; ++j) {
        emit(IcoPoint(face, n, i, j), IcoPoint(face, n, i + 1, j), IcoPoint(face, n, i, j + 1));
        if (i + j < n - 1) {
          emit(IcoPoint(face, n, i + 1, j), IcoPoint(face, n, i + 1, j + 1),
               IcoPoint(face, n, i, j + 1));
        }
      }
    }
  }
}

constexpr int kMaxSphereSubdivisions = 48;

// Largest gap between the unit sphere and its n-subdivided icosphere: 1 minus the smallest
// distance from the centre to a triangle's plane (an upper bound on the true gap).
double UnitIcosphereGap(int n) {
  double min_plane = 1.0;
  ForEachIcoTriangle(n, [&](const Vec3& a, const Vec3& b, const Vec3& c) {
    const Vec3 nrm = (b - a).cross(c - a).normalized();
    min_plane = std::min(min_plane, std::abs(nrm.dot(a)));
  });
  return 1.0 - min_plane;
}

std::vector<Vec2> CirclePolygon(const Vec2& center, double radius, int segments) {
  std::vector<Vec2> poly(segments);
  for (int i = 0; i < segments; ++i) {
    const double a = 2.0 * kPi * i / segments;
    poly[i] = center + radius * Vec2(std::cos(a), std::sin(a));
  }
  return poly;
}

// Appends the prism over `ring` (CCW) from z_lo to z_hi: sides, top, and the bottom if wanted.
void EmitPrism(const std::vector<Vec2>& ring, double z_lo, double z_hi, bool bottom,
               std::vector<Polygon>* out) {
  if (z_hi <= z_lo) return;
  const size_t m = ring.size();
  for (size_t i = 0; i < m; ++i) {
    const Vec2& a = ring[i];
    const Vec2& b = ring[(i + 1) % m];
    out->push_back(Polygon{{Vec3(a.x(), a.y(), z_lo), Vec3(b.x(), b.y(), z_lo),
                            Vec3(b.x(), b.y(), z_hi), Vec3(a.x(), a.y(), z_hi)},
                           false});
  }
  Polygon top{{}, true};
  for (const Vec2& p : ring) top.corners.emplace_back(p.x(), p.y(), z_hi);
  out->push_back(std::move(top));
  if (bottom) {
    Polygon bot{{}, false};
    for (size_t i = m; i-- > 0;) bot.corners.emplace_back(ring[i].x(), ring[i].y(), z_lo);
    out->push_back(std::move(bot));
  }
}

std::vector<Vec2> BoxRing(const Box& b) {
  const double hx = b.half.x(), hy = b.half.y();
  const Vec2 c = b.center.head<2>();
  return {c + ToWorld(b, -hx, -hy), c + ToWorld(b, hx, -hy), c + ToWorld(b, hx, hy),
          c + ToWorld(b, -hx, hy)};
}

// A planar grid of quads origin + s u + r v, s, r in [0, 1]; normal along u x v.
void EmitGrid(const Vec3& origin, const Vec3& u, const Vec3& v, double cell, bool faces_up,
              std::vector<Polygon>* out) {
  const int nu = std::max(1, static_cast<int>(std::ceil(u.norm() / cell - 1e-9)));
  const int nv = std::max(1, static_cast<int>(std::ceil(v.norm() / cell - 1e-9)));
  auto at = [&](int i, int j) -> Vec3 {
    return origin + u * (static_cast<double>(i) / nu) + v * (static_cast<double>(j) / nv);
  };
  for (int i = 0; i < nu; ++i) {
    for (int j = 0; j < nv; ++j) {
      out->push_back(Polygon{{at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)}, faces_up});
    }
  }
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

int CircleSegments(double radius, double tolerance) {
  if (tolerance >= radius) return 8;
  const double half_angle = std::acos(1.0 - tolerance / radius);
  return std::clamp(static_cast<int>(std::ceil(kPi / half_angle)), 8, 4096);
}

int SphereSubdivisions(double radius, double tolerance) {
  static const std::array<double, kMaxSphereSubdivisions + 1> gaps = [] {
    std::array<double, kMaxSphereSubdivisions + 1> g{};
    g[0] = 1.0;
    for (int n = 1; n <= kMaxSphereSubdivisions; ++n) g[n] = UnitIcosphereGap(n);
    return g;
  }();
  for (int n = 1; n <= kMaxSphereSubdivisions; ++n) {
    if (radius * gaps[n] <= tolerance) return n;
  }
  return kMaxSphereSubdivisions;
}

void Tessellate(const Shape& shape, const TessellationOptions& options, std::vector<Polygon>* out) {
  const double floor_z = options.floor_z;
  if (const auto* b = std::get_if<Box>(&shape)) {
    const double z_min = b->center.z() - b->half.z(), z_max = b->center.z() + b->half.z();
    EmitPrism(BoxRing(*b), std::max(z_min, floor_z), z_max, z_min > floor_z, out);
  } else if (const auto* c = std::get_if<Cylinder>(&shape)) {
    const std::vector<Vec2> ring =
        CirclePolygon(c->center, c->radius, CircleSegments(c->radius, options.tolerance));
    EmitPrism(ring, std::max(c->z_min, floor_z), c->z_max, c->z_min > floor_z, out);
  } else if (const auto* s = std::get_if<Sphere>(&shape)) {
    const int n = SphereSubdivisions(s->radius, options.tolerance);
    ForEachIcoTriangle(n, [&](const Vec3& a, const Vec3& b, const Vec3& c) {
      out->push_back(
          Polygon{{s->center + s->radius * a, s->center + s->radius * b, s->center + s->radius * c},
                  false});
    });
  } else if (const auto* k = std::get_if<Cone>(&shape)) {
    const std::vector<Vec2> ring =
        CirclePolygon(k->center, k->radius, CircleSegments(k->radius, options.tolerance));
    const Vec3 apex(k->center.x(), k->center.y(), k->z_apex);
    const size_t m = ring.size();
    for (size_t i = 0; i < m; ++i) {
      const Vec2& a = ring[i];
      const Vec2& b = ring[(i + 1) % m];
      out->push_back(
          Polygon{{Vec3(a.x(), a.y(), k->z_base), Vec3(b.x(), b.y(), k->z_base), apex}, false});
    }
    Polygon base{{}, false};
    for (size_t i = m; i-- > 0;) base.corners.emplace_back(ring[i].x(), ring[i].y(), k->z_base);
    out->push_back(std::move(base));
  } else {
    const auto& r = std::get<RoomShell>(shape);
    const Vec3 e = r.max - r.min;
    const Vec3 ex(e.x(), 0, 0), ey(0, e.y(), 0), ez(0, 0, e.z());
    const double cell = options.shell_cell;
    if (r.min.z() > floor_z) EmitGrid(r.min, ex, ey, cell, /*faces_up=*/true, out);
    EmitGrid(Vec3(r.min.x(), r.min.y(), r.max.z()), ey, ex, cell, false, out);  // ceiling
    EmitGrid(r.min, ey, ez, cell, false, out);                                  // x = min
    EmitGrid(Vec3(r.max.x(), r.min.y(), r.min.z()), ez, ey, cell, false, out);  // x = max
    EmitGrid(r.min, ez, ex, cell, false, out);                                  // y = min
    EmitGrid(Vec3(r.min.x(), r.max.y(), r.min.z()), ex, ez, cell, false, out);  // y = max
  }
}

std::vector<Vec2> Footprint(const Shape& shape, double z, const TessellationOptions& options) {
  if (const auto* b = std::get_if<Box>(&shape)) {
    if (std::abs(z - b->center.z()) < b->half.z()) return BoxRing(*b);
  } else if (const auto* c = std::get_if<Cylinder>(&shape)) {
    if (z > c->z_min && z < c->z_max) {
      return CirclePolygon(c->center, c->radius, CircleSegments(c->radius, options.tolerance));
    }
  } else if (const auto* s = std::get_if<Sphere>(&shape)) {
    const double dz = z - s->center.z();
    if (std::abs(dz) < s->radius) {
      const double rho = std::sqrt(s->radius * s->radius - dz * dz);
      return CirclePolygon(s->center.head<2>(), rho, CircleSegments(rho, options.tolerance));
    }
  } else if (const auto* k = std::get_if<Cone>(&shape)) {
    if (z > k->z_base && z < k->z_apex) {
      const double scale = (k->z_apex - z) / (k->z_apex - k->z_base);
      return CirclePolygon(k->center, k->radius * scale,
                           CircleSegments(k->radius, options.tolerance));
    }
  }
  return {};
}

double PolygonArea(const std::vector<Vec2>& poly) {
  double a = 0;
  for (size_t i = 0, m = poly.size(); i < m; ++i) {
    const Vec2& p = poly[i];
    const Vec2& q = poly[(i + 1) % m];
    a += p.x() * q.y() - q.x() * p.y();
  }
  return 0.5 * a;
}

std::vector<Vec2> ClipLeft(const std::vector<Vec2>& poly, const Vec2& a, const Vec2& b) {
  std::vector<Vec2> out;
  const size_t m = poly.size();
  if (m == 0) return out;
  const Vec2 e = b - a;
  auto side = [&](const Vec2& p) { return e.x() * (p.y() - a.y()) - e.y() * (p.x() - a.x()); };
  for (size_t i = 0; i < m; ++i) {
    const Vec2& p = poly[i];
    const Vec2& q = poly[(i + 1) % m];
    const double sp = side(p), sq = side(q);
    if (sp >= 0) out.push_back(p);
    if ((sp >= 0) != (sq >= 0)) {
      const double s = sp / (sp - sq);
      out.push_back(p + s * (q - p));
    }
  }
  return out;
}

std::vector<std::vector<Vec2>> SubtractConvex(const std::vector<Vec2>& poly,
                                              const std::vector<Vec2>& hole) {
  constexpr double kMinArea = 1e-9;
  if (hole.size() < 3) return {poly};
  std::vector<std::vector<Vec2>> pieces;
  std::vector<Vec2> rest = poly;
  for (size_t i = 0, m = hole.size(); i < m && rest.size() >= 3; ++i) {
    const Vec2& a = hole[i];
    const Vec2& b = hole[(i + 1) % m];
    std::vector<Vec2> outside = ClipLeft(rest, b, a);
    if (outside.size() >= 3 && PolygonArea(outside) > kMinArea) pieces.push_back(outside);
    rest = ClipLeft(rest, a, b);
    if (PolygonArea(rest) <= kMinArea) rest.clear();
  }
  return pieces;
}

}  // namespace rim::sim
