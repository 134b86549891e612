// A synthetic scene: analytic solids plus an optional ground plane, a ray caster over them, and
// the triangulated ground-truth surface.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "rim/base/mesh.h"
#include "sim/geometry.h"

namespace rim::sim {

// What a surface is made of; sets the simulated LiDAR intensity.
enum class Material : uint8_t {
  kGround,
  kBuilding,
  kTree,
  kPole,
  kCar,
  kPerson,
  kWall,
  kFurniture,
};

// Diffuse reflectivity in [0, 1] used for the LiDAR intensity channel.
double Reflectivity(Material material);

struct Primitive {
  Shape shape;
  Material material = Material::kBuilding;
};

// The union of the primitives' solids, plus the half-space below z = ground_z when has_ground.
struct Scene {
  std::vector<Primitive> primitives;
  bool has_ground = false;
  double ground_z = 0.0;
};

// Uniform grid over the xy plane that lists, per cell, the bounded primitives whose bounds
// overlap it (compressed rows). Unbounded primitives are kept apart in `unbounded()`.
class GridIndex {
 public:
  GridIndex(const std::vector<Primitive>& primitives, double cell);

  // Calls fn(index) once for each bounded primitive whose cell range meets [lo, hi].
  void ForEachInRect(const Vec2& lo, const Vec2& hi, const std::function<void(int)>& fn) const;

  double cell() const { return cell_; }
  const Vec2& origin() const { return origin_; }
  int nx() const { return nx_; }
  int ny() const { return ny_; }
  bool empty() const { return nx_ == 0; }
  // Items of cell (ix, iy) are items()[start(c)..start(c+1)), c = iy * nx + ix.
  uint32_t start(int c) const { return start_[c]; }
  const std::vector<uint32_t>& items() const { return items_; }
  float z_min(int c) const { return z_min_[c]; }
  float z_max(int c) const { return z_max_[c]; }
  const std::vector<int>& unbounded() const { return unbounded_; }

 private:
  double cell_;
  Vec2 origin_ = Vec2::Zero();
  int nx_ = 0, ny_ = 0;
  std::vector<uint32_t> start_, items_;
  std::vector<float> z_min_, z_max_;  // vertical extent of the cell's primitives
  std::vector<int> unbounded_;
  mutable std::vector<uint32_t> stamp_;  // for ForEachInRect de-duplication (single-threaded)
  mutable uint32_t stamp_value_ = 0;
};

struct RayHit {
  double t = 0.0;
  Vec3 normal = Vec3::UnitZ();  // unit, pointing into free space
  Material material = Material::kGround;
  int primitive = -1;  // index into Scene::primitives, -1 for the ground plane
};

// Casts rays into a scene (which must outlive the caster and not change). Thread-safe: Cast is
// const and touches no shared mutable state.
class RayCaster {
 public:
  // `cell` is the xy grid cell size in metres.
  RayCaster(const Scene& scene, double cell);

  // Nearest surface along o + t d (d unit) with t in [t_min, t_max]; false if none.
  bool Cast(const Vec3& o, const Vec3& d, double t_min, double t_max, RayHit* hit) const;

 private:
  const Scene& scene_;
  GridIndex grid_;
};

struct GroundTruthOptions {
  TessellationOptions tessellation;
  // Size of the quads the ground plane is split into.
  double ground_cell = 2.0;
  // The xy region the mesh covers: the ground is cut to it, and solids whose bounds overlap it are
  // kept whole (so their surface may reach somewhat beyond it).
  Vec2 region_min = Vec2::Constant(-1e300);
  Vec2 region_max = Vec2::Constant(1e300);
};

// Triangulates the surface of the scene's union of solids inside the region. Hidden surface is
// removed where it is easy to do exactly: footprints of solids standing on an upward face (the
// ground under buildings, a car roof under its cabin) are cut out of it, and so are the solids
// crossing a downward face (a balcony's underside inside its building); the sections of upright
// boxes and cylinders through an upright face are cut out of it (a facade behind a balcony slab
// or an annex, the slab's ends inside the building); triangles that lie entirely inside another
// solid are dropped. Solids just beyond the region still cut the faces of those inside it. Faces
// are counter-clockwise seen from free space; vertices shared bit-for-bit are welded.
rim::Mesh BuildGroundTruthMesh(const Scene& scene, const GroundTruthOptions& options);

}  // namespace rim::sim
