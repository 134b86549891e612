#include "sim/scene.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "rim/io/mesh_io.h"

namespace rim::sim {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// Cap on grid cells so that a huge sparse scene cannot blow up memory; the cell grows instead.
constexpr double kMaxCells = 4e6;

}  // namespace

double Reflectivity(Material material) {
  switch (material) {
    case Material::kGround:
      return 0.25;
    case Material::kBuilding:
      return 0.45;
    case Material::kTree:
      return 0.6;
    case Material::kPole:
      return 0.7;
    case Material::kCar:
      return 0.8;
    case Material::kPerson:
      return 0.35;
    case Material::kWall:
      return 0.5;
    case Material::kFurniture:
      return 0.4;
  }
  return 0.5;
}

GridIndex::GridIndex(const std::vector<Primitive>& primitives, double cell) : cell_(cell) {
  Aabb all;
  std::vector<Aabb> bounds(primitives.size());
  for (size_t i = 0; i < primitives.size(); ++i) {
    bounds[i] = Bounds(primitives[i].shape);
    if (!bounds[i].IsFinite()) {
      unbounded_.push_back(static_cast<int>(i));
      continue;
    }
    all.Extend(bounds[i].min);
    all.Extend(bounds[i].max);
  }
  if (!all.IsFinite() || all.min.x() > all.max.x()) return;  // nothing bounded
  const Vec2 size = (all.max - all.min).head<2>();
  while ((size.x() / cell_ + 1) * (size.y() / cell_ + 1) > kMaxCells) cell_ *= 2;
  origin_ = all.min.head<2>();
  nx_ = static_cast<int>(std::floor(size.x() / cell_)) + 1;
  ny_ = static_cast<int>(std::floor(size.y() / cell_)) + 1;
  const size_t cells = static_cast<size_t>(nx_) * ny_;
  start_.assign(cells + 1, 0);
  z_min_.assign(cells, std::numeric_limits<float>::infinity());
  z_max_.assign(cells, -std::numeric_limits<float>::infinity());
  stamp_.assign(primitives.size(), 0);
  auto range = [&](const Aabb& b, int* x0, int* x1, int* y0, int* y1) {
    *x0 = std::clamp(static_cast<int>(std::floor((b.min.x() - origin_.x()) / cell_)), 0, nx_ - 1);
    *x1 = std::clamp(static_cast<int>(std::floor((b.max.x() - origin_.x()) / cell_)), 0, nx_ - 1);
    *y0 = std::clamp(static_cast<int>(std::floor((b.min.y() - origin_.y()) / cell_)), 0, ny_ - 1);
    *y1 = std::clamp(static_cast<int>(std::floor((b.max.y() - origin_.y()) / cell_)), 0, ny_ - 1);
  };
  // Two passes: count per cell, then fill.
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<uint32_t> fill;
    if (pass == 1) {
      for (size_t c = 0; c < cells; ++c) start_[c + 1] += start_[c];
      items_.resize(start_[cells]);
      fill.assign(start_.begin(), start_.end() - 1);
    }
    for (size_t i = 0; i < primitives.size(); ++i) {
      if (!bounds[i].IsFinite()) continue;
      int x0, x1, y0, y1;
      range(bounds[i], &x0, &x1, &y0, &y1);
      for (int y = y0; y <= y1; ++y) {
        for (int x = x0; x <= x1; ++x) {
          const size_t c = static_cast<size_t>(y) * nx_ + x;
          if (pass == 0) {
            ++start_[c + 1];
            z_min_[c] = std::min(z_min_[c], static_cast<float>(bounds[i].min.z()));
            z_max_[c] = std::max(z_max_[c], static_cast<float>(bounds[i].max.z()));
          } else {
            items_[fill[c]++] = static_cast<uint32_t>(i);
          }
        }
      }
    }
  }
}

void GridIndex::ForEachInRect(const Vec2& lo, const Vec2& hi,
                              const std::function<void(int)>& fn) const {
  if (nx_ == 0) return;
  if (++stamp_value_ == 0) {
    std::fill(stamp_.begin(), stamp_.end(), 0);
    stamp_value_ = 1;
  }
  const int x0 =
      std::clamp(static_cast<int>(std::floor((lo.x() - origin_.x()) / cell_)), 0, nx_ - 1);
  const int x1 =
      std::clamp(static_cast<int>(std::floor((hi.x() - origin_.x()) / cell_)), 0, nx_ - 1);
  const int y0 =
      std::clamp(static_cast<int>(std::floor((lo.y() - origin_.y()) / cell_)), 0, ny_ - 1);
  const int y1 =
      std::clamp(static_cast<int>(std::floor((hi.y() - origin_.y()) / cell_)), 0, ny_ - 1);
  for (int y = y0; y <= y1; ++y) {
    for (int x = x0; x <= x1; ++x) {
      const int c = y * nx_ + x;
      for (uint32_t k = start_[c]; k < start_[c + 1]; ++k) {
        const uint32_t i = items_[k];
        if (stamp_[i] == stamp_value_) continue;
        stamp_[i] = stamp_value_;
        fn(static_cast<int>(i));
      }
    }
  }
}

RayCaster::RayCaster(const Scene& scene, double cell)
    : scene_(scene), grid_(scene.primitives, cell) {}

bool RayCaster::Cast(const Vec3& o, const Vec3& d, double t_min, double t_max, RayHit* hit) const {
  double best = t_max;
  bool found = false;
  auto consider = [&](int index, double t, const Vec3& n) {
    best = t;
    found = true;
    hit->t = t;
    hit->normal = n;
    hit->primitive = index;
    hit->material = index < 0 ? Material::kGround : scene_.primitives[index].material;
  };
  if (scene_.has_ground) {
    if (o.z() < scene_.ground_z) {
      if (t_min <= t_max) consider(-1, t_min, -d);
      return found;
    }
    if (d.z() < -1e-12) {
      const double t = (scene_.ground_z - o.z()) / d.z();
      if (t >= t_min && t <= best) consider(-1, t, Vec3::UnitZ());
    }
  }
  double t;
  Vec3 n;
  for (int index : grid_.unbounded()) {
    if (Intersect(scene_.primitives[index].shape, o, d, t_min, best, &t, &n)) consider(index, t, n);
  }
  if (grid_.empty()) return found;

  // Clip the ray to the grid's xy extent.
  const double cell = grid_.cell();
  const Vec2 lo = grid_.origin();
  const Vec2 hi = lo + Vec2(grid_.nx() * cell, grid_.ny() * cell);
  double t0 = t_min, t1 = best;
  for (int a = 0; a < 2; ++a) {
    if (std::abs(d[a]) < 1e-15) {
      if (o[a] < lo[a] || o[a] > hi[a]) return found;
      continue;
    }
    double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  if (t0 > t1) return found;

  // 2-D DDA over the cells the ray's xy projection crosses.
  const Vec3 start = o + t0 * d;
  int ix = std::clamp(static_cast<int>(std::floor((start.x() - lo.x()) / cell)), 0, grid_.nx() - 1);
  int iy = std::clamp(static_cast<int>(std::floor((start.y() - lo.y()) / cell)), 0, grid_.ny() - 1);
  const int step_x = d.x() > 0 ? 1 : -1, step_y = d.y() > 0 ? 1 : -1;
  auto boundary_t = [&](int a, int i, int step) {
    if (std::abs(d[a]) < 1e-15) return kInf;
    const double edge = lo[a] + (i + (step > 0 ? 1 : 0)) * cell;
    return (edge - o[a]) / d[a];
  };
  double next_x = boundary_t(0, ix, step_x), next_y = boundary_t(1, iy, step_y);
  const double delta_x = std::abs(d.x()) < 1e-15 ? kInf : cell / std::abs(d.x());
  const double delta_y = std::abs(d.y()) < 1e-15 ? kInf : cell / std::abs(d.y());
  double t_cur = t0;
  const std::vector<uint32_t>& items = grid_.items();
  while (true) {
    const double t_exit = std::min({next_x, next_y, best});
    const int c = iy * grid_.nx() + ix;
    const uint32_t begin = grid_.start(c), end = grid_.start(c + 1);
    if (begin != end) {
      const double za = o.z() + t_cur * d.z(), zb = o.z() + t_exit * d.z();
      if (std::max(za, zb) >= grid_.z_min(c) && std::min(za, zb) <= grid_.z_max(c)) {
        for (uint32_t k = begin; k < end; ++k) {
          const int index = static_cast<int>(items[k]);
          if (Intersect(scene_.primitives[index].shape, o, d, t_min, best, &t, &n)) {
            consider(index, t, n);
          }
        }
      }
    }
    if (best <= t_exit) break;
    if (next_x < next_y) {
      ix += step_x;
      t_cur = next_x;
      next_x += delta_x;
    } else {
      iy += step_y;
      t_cur = next_y;
      next_y += delta_y;
    }
    if (t_cur > best || ix < 0 || iy < 0 || ix >= grid_.nx() || iy >= grid_.ny()) break;
  }
  return found;
}

namespace {

struct OwnedTriangle {
  Vec3 v[3];
  int owner;  // primitive index, -1 for the ground
};

bool Overlaps2d(const Aabb& b, const Vec2& lo, const Vec2& hi) {
  return b.max.x() >= lo.x() && b.min.x() <= hi.x() && b.max.y() >= lo.y() && b.min.y() <= hi.y();
}

// The interval of the line p + s u (u unit, horizontal) that lies strictly inside the convex
// counter-clockwise ring (by more than 1e-9 m), or false where it has (almost) none: a line along
// one of the ring's edges has none.
bool LineInside(const std::vector<Vec2>& ring, const Vec2& p, const Vec2& u, double* s0,
                double* s1) {
  double lo = -kInf, hi = kInf;
  for (size_t i = 0, m = ring.size(); i < m; ++i) {
    const Vec2 e = ring[(i + 1) % m] - ring[i];
    const double len = e.norm();
    if (len < 1e-12) continue;
    // Signed distance to the edge's line, positive inside: f0 + s * f1.
    const double f0 = (e.x() * (p.y() - ring[i].y()) - e.y() * (p.x() - ring[i].x())) / len;
    const double f1 = (e.x() * u.y() - e.y() * u.x()) / len;
    constexpr double kStrict = 1e-9;
    if (std::abs(f1) < 1e-12) {
      if (f0 <= kStrict) return false;
      continue;
    }
    const double s = (kStrict - f0) / f1;
    if (f1 > 0) {
      lo = std::max(lo, s);
    } else {
      hi = std::min(hi, s);
    }
  }
  *s0 = lo;
  *s1 = hi;
  return hi - lo > 1e-9;
}

// Emits a face that does not look straight up, with the parts of it that lie inside other solids
// cut out where that is exact and cheap: from a face that looks straight down, the footprints of
// the solids it crosses (a balcony slab's underside inside its building); from an upright face,
// its sections through upright prisms (boxes and cylinders) that it crosses (a facade behind a
// balcony or an annex, the ends of the slab inside the building). Other faces go out whole.
template <typename Emit>
void CutHiddenParts(const Polygon& poly, int owner, const std::vector<Primitive>& prims,
                    const std::vector<Aabb>& bounds, const GridIndex& index,
                    const TessellationOptions& tess, Emit&& emit) {
  const std::vector<Vec3>& c = poly.corners;
  Vec3 normal = Vec3::Zero();
  for (size_t k = 1; k + 1 < c.size(); ++k) normal += (c[k] - c[0]).cross(c[k + 1] - c[0]);
  const double area2 = normal.norm();
  if (c.size() < 3 || area2 < 1e-18) {
    emit(c, owner);
    return;
  }
  normal /= area2;
  const bool down = normal.z() < -1.0 + 1e-12;
  const bool upright = std::abs(normal.z()) < 1e-12;
  if (!down && !upright) {
    emit(c, owner);
    return;
  }
  Vec3 lo3 = c[0], hi3 = c[0];
  for (const Vec3& p : c) {
    lo3 = lo3.cwiseMin(p);
    hi3 = hi3.cwiseMax(p);
  }
  const Vec2 lo = lo3.head<2>(), hi = hi3.head<2>();
  std::vector<int> cutters;
  index.ForEachInRect(lo, hi, [&](int i) {
    if (i == owner || !Overlaps2d(bounds[i], lo, hi)) return;
    if (down ? (bounds[i].min.z() < lo3.z() && bounds[i].max.z() > lo3.z())
             : (bounds[i].min.z() < hi3.z() && bounds[i].max.z() > lo3.z() &&
                (std::holds_alternative<Box>(prims[i].shape) ||
                 std::holds_alternative<Cylinder>(prims[i].shape)))) {
      cutters.push_back(i);
    }
  });
  if (cutters.empty()) {
    emit(c, owner);
    return;
  }
  std::sort(cutters.begin(), cutters.end());
  // The face in 2-D, counter-clockwise: (x, y) seen from below for a downward face, (s, z) with
  // s along u = z x normal for an upright one (seen from outside).
  const Vec2 u = Vec2(-normal.y(), normal.x()).normalized();
  const Vec2 origin = c[0].head<2>();
  auto to2d = [&](const Vec3& p) {
    return down ? Vec2(p.x(), -p.y()) : Vec2((p.head<2>() - origin).dot(u), p.z());
  };
  auto to3d = [&](const Vec2& q) {
    return down ? Vec3(q.x(), -q.y(), c[0].z())
                : Vec3(origin.x() + q.x() * u.x(), origin.y() + q.x() * u.y(), q.y());
  };
  std::vector<std::vector<Vec2>> pieces(1);
  for (const Vec3& p : c) pieces[0].push_back(to2d(p));
  const bool flip = PolygonArea(pieces[0]) < 0;  // never, but for rounding
  if (flip) std::reverse(pieces[0].begin(), pieces[0].end());
  for (int i : cutters) {
    std::vector<Vec2> hole;
    if (down) {
      for (const Vec2& p : Footprint(prims[i].shape, lo3.z(), tess))
        hole.emplace_back(p.x(), -p.y());
      std::reverse(hole.begin(), hole.end());
    } else {
      const double z_mid = 0.5 * (bounds[i].min.z() + bounds[i].max.z());
      double s0, s1;
      if (!LineInside(Footprint(prims[i].shape, z_mid, tess), origin, u, &s0, &s1)) continue;
      const double z0 = bounds[i].min.z(), z1 = bounds[i].max.z();
      hole = {Vec2(s0, z0), Vec2(s1, z0), Vec2(s1, z1), Vec2(s0, z1)};
    }
    if (hole.size() < 3) continue;
    std::vector<std::vector<Vec2>> next;
    for (const auto& piece : pieces) {
      for (auto& part : SubtractConvex(piece, hole)) next.push_back(std::move(part));
    }
    pieces = std::move(next);
    if (pieces.empty()) return;
  }
  for (const auto& piece : pieces) {
    std::vector<Vec3> out;
    for (const Vec2& q : piece) out.push_back(to3d(q));
    if (flip) std::reverse(out.begin(), out.end());
    emit(out, owner);
  }
}

}  // namespace

rim::Mesh BuildGroundTruthMesh(const Scene& scene, const GroundTruthOptions& options) {
  const TessellationOptions& tess = options.tessellation;
  TessellationOptions solid_tess = tess;
  if (scene.has_ground) solid_tess.floor_z = std::max(tess.floor_z, scene.ground_z);

  // Solids that touch the region, re-indexed, then those that reach into the bounds of these
  // (a car's cabin beyond the region on a body inside it): these hide parts of the first but are
  // not emitted themselves.
  Scene kept;
  kept.has_ground = scene.has_ground;
  kept.ground_z = scene.ground_z;
  Vec2 reach_min = options.region_min, reach_max = options.region_max;
  for (const Primitive& p : scene.primitives) {
    const Aabb b = Bounds(p.shape);
    if (!b.IsFinite() || Overlaps2d(b, options.region_min, options.region_max)) {
      kept.primitives.push_back(p);
      if (b.IsFinite()) {
        reach_min = reach_min.cwiseMin(b.min.head<2>());
        reach_max = reach_max.cwiseMax(b.max.head<2>());
      }
    }
  }
  const size_t emitted = kept.primitives.size();
  for (const Primitive& p : scene.primitives) {
    const Aabb b = Bounds(p.shape);
    if (b.IsFinite() && !Overlaps2d(b, options.region_min, options.region_max) &&
        Overlaps2d(b, reach_min, reach_max)) {
      kept.primitives.push_back(p);
    }
  }
  const std::vector<Primitive>& prims = kept.primitives;
  std::vector<Aabb> bounds(prims.size());
  for (size_t i = 0; i < prims.size(); ++i) bounds[i] = Bounds(prims[i].shape);
  const GridIndex index(prims, 4.0);

  // Planar faces with their owners.
  std::vector<std::pair<Polygon, int>> faces;
  std::vector<Polygon> scratch;
  for (size_t i = 0; i < emitted; ++i) {
    scratch.clear();
    Tessellate(prims[i].shape, solid_tess, &scratch);
    for (Polygon& p : scratch) faces.emplace_back(std::move(p), static_cast<int>(i));
  }
  if (scene.has_ground && options.region_min.allFinite() && options.region_max.allFinite()) {
    const double cell = options.ground_cell;
    const Vec2 lo = options.region_min, hi = options.region_max;
    const int nx = std::max(1, static_cast<int>(std::ceil((hi.x() - lo.x()) / cell - 1e-9)));
    const int ny = std::max(1, static_cast<int>(std::ceil((hi.y() - lo.y()) / cell - 1e-9)));
    auto gx = [&](int i) { return i == nx ? hi.x() : lo.x() + i * cell; };
    auto gy = [&](int j) { return j == ny ? hi.y() : lo.y() + j * cell; };
    const double z = scene.ground_z;
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        faces.emplace_back(Polygon{{Vec3(gx(i), gy(j), z), Vec3(gx(i + 1), gy(j), z),
                                    Vec3(gx(i + 1), gy(j + 1), z), Vec3(gx(i), gy(j + 1), z)},
                                   true},
                           -1);
      }
    }
  }

  // Cut footprints of solids out of upward faces, then fan-triangulate.
  std::vector<OwnedTriangle> tris;
  auto emit_fan = [&](const std::vector<Vec3>& c, int owner) {
    for (size_t k = 1; k + 1 < c.size(); ++k) tris.push_back({{c[0], c[k], c[k + 1]}, owner});
  };
  for (const auto& [poly, owner] : faces) {
    if (!poly.faces_up) {
      CutHiddenParts(poly, owner, prims, bounds, index, tess, emit_fan);
      continue;
    }
    const double z = poly.corners[0].z();
    std::vector<std::vector<Vec2>> pieces(1);
    Vec2 lo = Vec2::Constant(kInf), hi = Vec2::Constant(-kInf);
    for (const Vec3& c : poly.corners) {
      pieces[0].push_back(c.head<2>());
      lo = lo.cwiseMin(c.head<2>());
      hi = hi.cwiseMax(c.head<2>());
    }
    std::vector<int> cutters;
    index.ForEachInRect(lo, hi, [&](int i) {
      if (i != owner && Overlaps2d(bounds[i], lo, hi) && bounds[i].min.z() < z &&
          bounds[i].max.z() > z) {
        cutters.push_back(i);
      }
    });
    std::sort(cutters.begin(), cutters.end());
    // A room shell is solid outside its box: keep the part of the face inside the room.
    for (int i : index.unbounded()) {
      const auto* shell = std::get_if<RoomShell>(&prims[i].shape);
      if (i == owner || shell == nullptr || z <= shell->min.z() || z >= shell->max.z()) continue;
      const Vec2 a = shell->min.head<2>(), c = shell->max.head<2>();
      const Vec2 b(c.x(), a.y()), d(a.x(), c.y());
      std::vector<std::vector<Vec2>> next;
      for (const auto& piece : pieces) {
        std::vector<Vec2> in =
            ClipLeft(ClipLeft(ClipLeft(ClipLeft(piece, a, b), b, c), c, d), d, a);
        if (in.size() >= 3 && PolygonArea(in) > 1e-9) next.push_back(std::move(in));
      }
      pieces = std::move(next);
    }
    for (int i : cutters) {
      const std::vector<Vec2> hole = Footprint(prims[i].shape, z, tess);
      if (hole.size() < 3) continue;
      std::vector<std::vector<Vec2>> next;
      for (const auto& piece : pieces) {
        for (auto& part : SubtractConvex(piece, hole)) next.push_back(std::move(part));
      }
      pieces = std::move(next);
      if (pieces.empty()) break;
    }
    for (const auto& piece : pieces) {
      std::vector<Vec3> c;
      for (const Vec2& p : piece) c.emplace_back(p.x(), p.y(), z);
      emit_fan(c, owner);
    }
  }

  // Drop triangles buried inside another solid (or under the ground).
  constexpr double kBuried = 1e-5;
  rim::Mesh mesh;
  mesh.vertices.reserve(tris.size() * 3);
  mesh.faces.reserve(tris.size());
  for (const OwnedTriangle& tri : tris) {
    const Vec3 e = (tri.v[1] - tri.v[0]).cross(tri.v[2] - tri.v[0]);
    if (e.squaredNorm() < 1e-20) continue;
    bool buried = false;
    if (scene.has_ground && tri.owner >= 0) {
      buried = tri.v[0].z() < scene.ground_z - kBuried && tri.v[1].z() < scene.ground_z - kBuried &&
               tri.v[2].z() < scene.ground_z - kBuried;
    }
    if (!buried) {
      const Vec2 lo = tri.v[0].head<2>().cwiseMin(tri.v[1].head<2>()).cwiseMin(tri.v[2].head<2>());
      const Vec2 hi = tri.v[0].head<2>().cwiseMax(tri.v[1].head<2>()).cwiseMax(tri.v[2].head<2>());
      auto inside = [&](int i) {
        return i != tri.owner && ContainsAll(prims[i].shape, tri.v, 3, kBuried);
      };
      index.ForEachInRect(lo, hi, [&](int i) { buried = buried || inside(i); });
      for (int i : index.unbounded()) buried = buried || inside(i);
    }
    if (buried) continue;
    const uint32_t base = static_cast<uint32_t>(mesh.vertices.size());
    for (const Vec3& v : tri.v) {
      mesh.vertices.push_back(
          {static_cast<float>(v.x()), static_cast<float>(v.y()), static_cast<float>(v.z())});
    }
    mesh.faces.push_back({base, base + 1, base + 2});
  }
  return rim::WeldIdenticalVertices(mesh);
}

}  // namespace rim::sim
