// The procedural room for the depth-camera mode: walls, floor and ceiling with furniture, and a
// hand-held camera path around it.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "sim/scene.h"

namespace rim::sim {

struct Room {
  // The room's inside is [-size/2, size/2] in x and y and [0, size.z] in z; the scene holds the
  // solid around it (walls, floor, ceiling) and the furniture. No ground plane.
  Scene scene;
  Vec3 size = Vec3::Zero();
  // Camera path: an ellipse around the room's centre that all furniture keeps clear of.
  Vec2 path_half_axes = Vec2::Zero();
};

// Deterministic for a given seed.
Room GenerateRoom(uint64_t seed);

// World-from-camera poses (x right, y down, z forward) of `frames` frames about `step` metres
// apart along the path, looking into the room and slightly down.
std::vector<Eigen::Isometry3d> RoomTrajectory(const Room& room, int frames, double step);

}  // namespace rim::sim
