// An indexed triangle mesh: welded vertices and triangles as index triples.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace rim {

struct Mesh {
  // xyz per vertex, world frame, metres.
  std::vector<std::array<float, 3>> vertices;
  // Counter-clockwise seen from the free-space (positive SDF) side.
  std::vector<std::array<uint32_t, 3>> faces;

  bool empty() const { return faces.empty(); }
};

}  // namespace rim
