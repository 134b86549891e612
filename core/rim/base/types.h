// Small value types shared by the whole core: 3D vectors, integer voxel indices and their hash.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <functional>

namespace rim {

using Vec3f = Eigen::Vector3f;
using Vec3d = Eigen::Vector3d;
using Int3 = Eigen::Vector3i;

// Floor division that rounds toward minus infinity (C++ '/' truncates toward zero).
inline int FloorDiv(int a, int b) {
  int q = a / b;
  if ((a % b != 0) && ((a < 0) != (b < 0))) --q;
  return q;
}

// Non-negative remainder, so that storage slots of negative indices wrap correctly.
inline int PosMod(int a, int b) {
  int r = a % b;
  return r < 0 ? r + b : r;
}

inline Int3 FloorDiv(const Int3& a, const Int3& b) {
  return Int3(FloorDiv(a.x(), b.x()), FloorDiv(a.y(), b.y()), FloorDiv(a.z(), b.z()));
}

struct Int3Hash {
  size_t operator()(const Int3& v) const {
    // Large odd multipliers spread neighbouring indices over the table.
    uint64_t h = static_cast<uint64_t>(static_cast<uint32_t>(v.x())) * 0x9E3779B97F4A7C15ull;
    h ^= static_cast<uint64_t>(static_cast<uint32_t>(v.y())) * 0xC2B2AE3D27D4EB4Full;
    h ^= static_cast<uint64_t>(static_cast<uint32_t>(v.z())) * 0x165667B19E3779F9ull;
    return static_cast<size_t>(h ^ (h >> 29));
  }
};

struct Int3Equal {
  bool operator()(const Int3& a, const Int3& b) const { return a == b; }
};

}  // namespace rim
