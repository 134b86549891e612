// Triangulation of the analytic solids for the ground-truth mesh, and the 2-D polygon helpers
// the scenes use to place objects (declared in geometry.h).
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

#include "sim/geometry.h"

namespace rim::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;

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
  return {c + BoxToWorld(b, -hx, -hy), c + BoxToWorld(b, hx, -hy), c + BoxToWorld(b, hx, hy),
          c + BoxToWorld(b, -hx, hy)};
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

}  // namespace

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
