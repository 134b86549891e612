#include "sim/room.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "sim/rng.h"

namespace rim::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kSink = 0.01;       // furniture reaches this far into the floor, walls, ceiling
constexpr double kPathClear = 0.45;  // furniture keeps this far from the camera path
constexpr double kPathMargin = 1.4;  // path ellipse: this far in from the walls

Vec3 PathPoint(const Room& room, double theta) {
  return Vec3(room.path_half_axes.x() * std::cos(theta), room.path_half_axes.y() * std::sin(theta),
              1.45 + 0.12 * std::sin(2.0 * theta));
}

// Where the camera at path angle theta looks: a point wandering near the room's centre.
Vec3 LookTarget(double theta) {
  return Vec3(0.5 * std::cos(theta + 2.5), 0.5 * std::sin(theta + 2.5),
              0.8 + 0.2 * std::sin(theta));
}

// A local frame on the floor: origin and yaw; furniture is built in it.
struct Frame2d {
  Vec2 origin;
  double yaw;
  Vec2 ToWorld(double x, double y) const {
    const double c = std::cos(yaw), s = std::sin(yaw);
    return origin + Vec2(c * x - s * y, s * x + c * y);
  }
};

class RoomBuilder {
 public:
  explicit RoomBuilder(uint64_t seed) : rng_(HashSeed(seed, 0x700Dull)) {}

  Room Build() {
    room_.size = Vec3(rng_.Uniform(6.5, 9.0), rng_.Uniform(5.5, 7.0), rng_.Uniform(2.6, 3.2));
    room_.path_half_axes =
        Vec2(0.5 * room_.size.x() - kPathMargin, 0.5 * room_.size.y() - kPathMargin);
    const Vec3 half(0.5 * room_.size.x(), 0.5 * room_.size.y(), 0.0);
    room_.scene.primitives.push_back(
        {RoomShell{Vec3(-half.x(), -half.y(), 0.0), Vec3(half.x(), half.y(), room_.size.z())},
         Material::kWall});
    for (int i = 0; i < 200; ++i) path_.push_back(PathPoint(room_, 2 * kPi * i / 200));

    Place([&] { return Table(); }, 10);
    const int stools = rng_.UniformInt(2, 4);
    for (int i = 0; i < stools; ++i) Place([&] { return Stool(); }, 10);
    const int shelves = rng_.UniformInt(1, 3);
    for (int i = 0; i < shelves; ++i) Place([&] { return Shelf(); }, 20);
    Place([&] { return Cabinet(); }, 20);
    Place([&] { return Sofa(); }, 20);
    Place([&] { return FloorLamp(); }, 20);
    Place([&] { return Bin(); }, 20);
    Place([&] { return WallPanel(); }, 20);
    Place([&] { return HangingLamp(); }, 10);
    return std::move(room_);
  }

 private:
  using Group = std::vector<Primitive>;

  // Tries up to `attempts` candidates from make(); keeps the first that stays clear of the camera
  // path and of the furniture already placed.
  template <typename F>
  void Place(F&& make, int attempts) {
    for (int a = 0; a < attempts; ++a) {
      Group g = make();
      if (Fits(g)) {
        Aabb box;
        for (const Primitive& p : g) {
          const Aabb b = Bounds(p.shape);
          box.Extend(b.min);
          box.Extend(b.max);
          room_.scene.primitives.push_back(p);
        }
        placed_.push_back(box);
        return;
      }
    }
  }

  bool Fits(const Group& g) const {
    Aabb box;
    for (const Primitive& p : g) {
      for (const Vec3& q : path_) {
        if (Contains(p.shape, q, -kPathClear)) return false;
      }
      const Aabb b = Bounds(p.shape);
      box.Extend(b.min);
      box.Extend(b.max);
    }
    constexpr double kGap = 0.05;
    for (const Aabb& o : placed_) {
      if ((box.min.array() < o.max.array() + kGap).all() &&
          (o.min.array() < box.max.array() + kGap).all()) {
        return false;
      }
    }
    return true;
  }

  static Primitive Furniture(const Shape& s) { return {s, Material::kFurniture}; }

  // A frame against a random wall: x along the wall, y into the room, origin on the wall line at
  // a random position that leaves `width` of room for the piece.
  Frame2d AgainstWall(double width) {
    const int wall = rng_.UniformInt(0, 3);
    const double hx = 0.5 * room_.size.x(), hy = 0.5 * room_.size.y();
    const double len = (wall % 2 == 0) ? room_.size.x() : room_.size.y();
    const double u = rng_.Uniform(-0.5 * len + 0.5 * width + 0.1, 0.5 * len - 0.5 * width - 0.1);
    switch (wall) {
      case 0:
        return {Vec2(u, -hy), 0.0};
      case 1:
        return {Vec2(hx, u), 0.5 * kPi};
      case 2:
        return {Vec2(-u, hy), kPi};
      default:
        return {Vec2(-hx, -u), 1.5 * kPi};
    }
  }

  // Box in a local frame: local centre (x, y), half extents, z range.
  static Primitive LocalBox(const Frame2d& f, double x, double y, double hx, double hy, double z0,
                            double z1) {
    return Furniture(MakeBoxZ(f.ToWorld(x, y), Vec2(hx, hy), f.yaw, z0, z1));
  }

  Group Table() {
    const Frame2d f{Vec2(rng_.Uniform(-0.3, 0.3), rng_.Uniform(-0.2, 0.2)),
                    rng_.Uniform(-0.3, 0.3)};
    const double hx = 0.5 * rng_.Uniform(1.2, 1.8), hy = 0.5 * rng_.Uniform(0.7, 1.0);
    const double top = rng_.Uniform(0.72, 0.78);
    Group g = {LocalBox(f, 0, 0, hx, hy, top - 0.04, top)};
    for (int sx : {-1, 1}) {
      for (int sy : {-1, 1}) {
        g.push_back(LocalBox(f, sx * (hx - 0.09), sy * (hy - 0.09), 0.03, 0.03, -kSink,
                             top - 0.04 + kSink));
      }
    }
    return g;
  }

  Group Stool() {
    const double a = rng_.Uniform(0, 2 * kPi), d = rng_.Uniform(0.9, 1.3);
    const Vec2 c(d * std::cos(a), 0.8 * d * std::sin(a));
    return {Furniture(Cylinder{c, rng_.Uniform(0.16, 0.22), -kSink, rng_.Uniform(0.44, 0.5)})};
  }

  Group Shelf() {
    const double width = rng_.Uniform(0.8, 1.6), depth = rng_.Uniform(0.3, 0.4);
    const double height = rng_.Uniform(1.6, 2.2);
    const Frame2d f = AgainstWall(width);
    const double hw = 0.5 * width, hd = 0.5 * depth;
    Group g;
    g.push_back(LocalBox(f, 0, 0.01 - kSink, hw, 0.01, -kSink, height));  // back panel
    for (int s : {-1, 1}) g.push_back(LocalBox(f, s * (hw - 0.015), hd, 0.015, hd, -kSink, height));
    const int boards = rng_.UniformInt(4, 5);
    for (int b = 0; b < boards; ++b) {
      const double z = 0.05 + (height - 0.08) * b / (boards - 1);
      g.push_back(LocalBox(f, 0, hd, hw - 0.02, hd - 0.005, z, z + 0.03));
    }
    return g;
  }

  Group Cabinet() {
    const double width = rng_.Uniform(1.0, 2.0), depth = rng_.Uniform(0.45, 0.6);
    const Frame2d f = AgainstWall(width);
    return {LocalBox(f, 0, 0.5 * depth - kSink, 0.5 * width, 0.5 * depth, -kSink,
                     rng_.Uniform(0.8, 1.0))};
  }

  Group Sofa() {
    const double width = rng_.Uniform(1.8, 2.2), depth = 0.85;
    const Frame2d f = AgainstWall(width);
    const double hw = 0.5 * width;
    Group g;
    g.push_back(LocalBox(f, 0, 0.5 * depth, hw - 0.2, 0.5 * depth - 0.1, -kSink, 0.42));  // seat
    g.push_back(LocalBox(f, 0, 0.1 - kSink, hw, 0.1, -kSink, 0.85));                      // back
    for (int s : {-1, 1})
      g.push_back(LocalBox(f, s * (hw - 0.1), 0.5 * depth, 0.1, 0.5 * depth, -kSink, 0.6));
    return g;
  }

  Group FloorLamp() {
    const Frame2d f = AgainstWall(0.6);
    const Vec2 c = f.ToWorld(0, 0.35);
    const double h = rng_.Uniform(1.4, 1.7);
    const double shade = rng_.Uniform(0.14, 0.2);
    return {Furniture(Cylinder{c, 0.15, -kSink, 0.03}),
            Furniture(Cylinder{c, 0.02, 0.0, h - shade + 0.02}),
            Furniture(Sphere{Vec3(c.x(), c.y(), h), shade})};
  }

  Group Bin() {
    const Frame2d f = AgainstWall(0.5);
    return {Furniture(
        Cylinder{f.ToWorld(0, 0.25), rng_.Uniform(0.13, 0.18), -kSink, rng_.Uniform(0.35, 0.5)})};
  }

  // A picture or screen hanging on a wall.
  Group WallPanel() {
    const double width = rng_.Uniform(0.8, 1.4);
    const Frame2d f = AgainstWall(width);
    const double z0 = rng_.Uniform(1.1, 1.4);
    return {LocalBox(f, 0, 0.02 - kSink, 0.5 * width, 0.03, z0, z0 + rng_.Uniform(0.5, 0.8))};
  }

  // A sphere lamp hanging on a cord over the middle of the room.
  Group HangingLamp() {
    const Vec2 c(rng_.Uniform(-0.4, 0.4), rng_.Uniform(-0.3, 0.3));
    const double r = rng_.Uniform(0.15, 0.25);
    const double z = room_.size.z() - rng_.Uniform(0.7, 1.0);
    return {Furniture(Sphere{Vec3(c.x(), c.y(), z), r}),
            Furniture(Cylinder{c, 0.01, z + r - 0.02, room_.size.z() + kSink})};
  }

  Rng rng_;
  Room room_;
  std::vector<Vec3> path_;
  std::vector<Aabb> placed_;
};

}  // namespace

Room GenerateRoom(uint64_t seed) { return RoomBuilder(seed).Build(); }

std::vector<Eigen::Isometry3d> RoomTrajectory(const Room& room, int frames, double step) {
  const double mean_radius = 0.5 * (room.path_half_axes.x() + room.path_half_axes.y());
  std::vector<Eigen::Isometry3d> poses;
  poses.reserve(std::max(frames, 0));
  for (int k = 0; k < frames; ++k) {
    const double theta = k * step / mean_radius;
    const Vec3 p = PathPoint(room, theta);
    const Vec3 z = (LookTarget(theta) - p).normalized();
    const Vec3 x = z.cross(Vec3::UnitZ()).normalized();
    const Vec3 y = z.cross(x);
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear().col(0) = x;
    pose.linear().col(1) = y;
    pose.linear().col(2) = z;
    pose.translation() = p;
    poses.push_back(pose);
  }
  return poses;
}

}  // namespace rim::sim
