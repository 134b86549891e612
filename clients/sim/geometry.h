// Analytic solids for the synthetic scenes: exact ray intersection, point containment and a
// triangulation that stays within a given distance of the true surface.
//
// Every shape except RoomShell (the complement of a box: the solid around a room) is a closed
// convex solid, so a triangle whose corners all lie inside one of them lies inside it entirely;
// ContainsAll handles the shell, and the ground-truth mesh builder uses it to drop hidden faces.
//
// World frame: x, y horizontal, z up, metres.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <variant>
#include <vector>

namespace rim::sim {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;

struct Aabb {
  Vec3 min = Vec3::Constant(1e300);
  Vec3 max = Vec3::Constant(-1e300);

  void Extend(const Vec3& p) {
    min = min.cwiseMin(p);
    max = max.cwiseMax(p);
  }
  bool IsFinite() const { return min.allFinite() && max.allFinite(); }
};

// A box rotated by `yaw` (radians, counter-clockwise seen from above) about the vertical axis
// through its centre. Build it with MakeBox so that the cached cosine and sine are set.
struct Box {
  Vec3 center = Vec3::Zero();
  Vec3 half = Vec3::Zero();  // half extents along the box's own axes
  double yaw = 0.0;
  double cos_yaw = 1.0, sin_yaw = 0.0;
};
Box MakeBox(const Vec3& center, const Vec3& half, double yaw);
// A box given by its z range and its footprint (centre, half extents in x and y, yaw).
Box MakeBoxZ(const Vec2& center, const Vec2& half_xy, double yaw, double z_min, double z_max);
// Rotates a vector of the box's own xy frame into the world frame.
inline Vec2 BoxToWorld(const Box& b, double x, double y) {
  return Vec2(b.cos_yaw * x - b.sin_yaw * y, b.sin_yaw * x + b.cos_yaw * y);
}

// Vertical cylinder with flat caps.
struct Cylinder {
  Vec2 center = Vec2::Zero();
  double radius = 0.0;
  double z_min = 0.0, z_max = 0.0;
};

struct Sphere {
  Vec3 center = Vec3::Zero();
  double radius = 0.0;
};

// Vertical cone: a disc of `radius` at z_base tapering to the apex at z_apex (> z_base).
struct Cone {
  Vec2 center = Vec2::Zero();
  double radius = 0.0;
  double z_base = 0.0, z_apex = 0.0;
};

// The solid around a room: everything outside the box [min, max]. Rays from inside the room hit
// its walls, floor and ceiling from the inside.
struct RoomShell {
  Vec3 min = Vec3::Zero();
  Vec3 max = Vec3::Zero();
};

using Shape = std::variant<Box, Cylinder, Sphere, Cone, RoomShell>;

// Nearest intersection of the ray o + t d (d unit length) with the solid's surface for t in
// [t_min, t_max]. On a hit sets *t and the unit outward normal *n (pointing into free space).
// An origin inside the solid counts as a hit at t_min.
bool Intersect(const Shape& shape, const Vec3& o, const Vec3& d, double t_min, double t_max,
               double* t, Vec3* n);

// True if p lies inside the solid with at least `margin` to spare (margin may be negative to
// inflate the solid; the inflation is approximate at edges and corners, always conservative, i.e.
// it never shrinks the inflated solid).
bool Contains(const Shape& shape, const Vec3& p, double margin);

// True if the convex hull of the n points lies inside the solid with `margin` to spare. For the
// convex shapes that is Contains for every point; the RoomShell is not convex, so there all points
// must lie beyond the same wall (or floor, or ceiling).
bool ContainsAll(const Shape& shape, const Vec3* points, int n, double margin);

// Axis-aligned bounds; infinite for RoomShell.
Aabb Bounds(const Shape& shape);

// One planar convex face of a triangulated solid, corners counter-clockwise seen from outside.
struct Polygon {
  std::vector<Vec3> corners;
  // True for faces that look straight up (box tops, cylinder tops, floors): these get the
  // footprints of solids standing on them cut out.
  bool faces_up = false;
};

// Triangulation parameters for the ground-truth mesh.
struct TessellationOptions {
  // Largest distance between the analytic surface and its triangulation (curved shapes are
  // inscribed polyhedra with all vertices on the surface).
  double tolerance = 0.005;
  // Nothing at or below this height is emitted (the ground): side walls start there and bottom
  // faces that sit at or below it are left out.
  double floor_z = -1e300;
  // Cell size of the grid that room walls and ceilings are split into, so that patches hidden
  // behind furniture can be dropped.
  double shell_cell = 0.25;
};

// Appends the solid's surface as planar convex polygons.
void Tessellate(const Shape& shape, const TessellationOptions& options, std::vector<Polygon>* out);

// The solid's cross-section with the horizontal plane at height z as a convex polygon
// (counter-clockwise), or empty when the plane misses it. Curved sections are the inscribed
// polygon of Tessellate, so the footprint never reaches outside the solid.
std::vector<Vec2> Footprint(const Shape& shape, double z, const TessellationOptions& options);

// Number of segments around a circle of radius r so that its inscribed polygon stays within
// `tolerance` of it (at least 8).
int CircleSegments(double radius, double tolerance);

// Subdivision level n of the icosphere used for a sphere of `radius` (20 n^2 triangles).
int SphereSubdivisions(double radius, double tolerance);

// Clipping helpers on convex 2-D polygons (counter-clockwise).
// The part of `poly` on the left of the directed line a->b (inside for a CCW clipper edge).
std::vector<Vec2> ClipLeft(const std::vector<Vec2>& poly, const Vec2& a, const Vec2& b);
// poly minus the convex `hole`, as convex pieces. Pieces with (almost) no area are dropped.
std::vector<std::vector<Vec2>> SubtractConvex(const std::vector<Vec2>& poly,
                                              const std::vector<Vec2>& hole);
double PolygonArea(const std::vector<Vec2>& poly);

}  // namespace rim::sim
