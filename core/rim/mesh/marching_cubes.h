// Marching cubes over a sparse set of grid cells, producing an indexed, crack-free triangle mesh.
//
// Cube corner numbering (used by the case mask): corner i of the cell with minimum corner g sits at
// grid point g + (i & 1, (i >> 1) & 1, (i >> 2) & 1), so bit 0 is x, bit 1 is y and bit 2 is z.
// Bit i of a case mask is set when corner i is inside (value < 0); values >= 0, including exactly
// zero, count as outside (free space).
//
// The case table is generated from face rules rather than hand-written: every cube face resolves
// its own ambiguity (two diagonal inside corners are kept apart), so neighbouring cells always
// agree on the shared face and the mesh is watertight wherever all cells are present.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <vector>

#include "rim/base/mesh.h"
#include "rim/base/types.h"

namespace rim {

// A scalar field sampled on a regular world-aligned grid: value at grid point g (integer index) is
// at world position origin_m + g * step_m. Callers give values only for the points they have.
struct GridSamples {
  float step_m = 0.05f;
  Eigen::Vector3f origin_m = Eigen::Vector3f::Zero();
  // Returns false if the point has no valid value (unobserved); then no cell touching it is
  // meshed. A non-finite value is treated like an unobserved point.
  std::function<bool(const Int3& g, float* value)> lookup;
};

// Runs marching cubes over the given cells (each cell named by its minimum-corner grid index; the
// cell spans g .. g+(1,1,1)). A cell is meshed only when all 8 corner values are available;
// repeated cells are meshed once.
//
// Output is indexed: a vertex lying on grid edge (g, axis) is created once and shared by all
// triangles that use it (welded by the integer edge key, never by float position). The vertex
// position is the linear zero crossing along the edge, computed from the two endpoint values with
// the lower grid index first, so two independent calls that see the same values on a shared edge
// produce bit-identical positions. Triangles are counter-clockwise seen from the positive side,
// i.e. their normals follow the field gradient. Each grid point is looked up at most once per
// call.
Mesh MarchingCubes(const std::vector<Int3>& cells, const GridSamples& samples);

// A grid edge: from grid point `lower` one step along `axis` (0 x, 1 y, 2 z).
struct GridEdge {
  Int3 lower = Int3::Zero();
  int axis = 0;
  bool operator==(const GridEdge& o) const { return axis == o.axis && lower == o.lower; }
};
struct GridEdgeHash {
  size_t operator()(const GridEdge& e) const {
    return Int3Hash()(e.lower) ^ (static_cast<size_t>(e.axis) * 0x9E3779B97F4A7C15ull);
  }
};

// The same, also giving each vertex's grid edge (vertex_edges[i] for mesh.vertices[i]), so that
// meshes of disjoint cell sets can be welded afterwards exactly as one call would have welded them.
Mesh MarchingCubes(const std::vector<Int3>& cells, const GridSamples& samples,
                   std::vector<GridEdge>* vertex_edges);

// A block of n × n × n grid points, first..first + (n-1, n-1, n-1): grid point first + m has the
// value values[index[(m.x·n + m.y)·n + m.z]], or none where that index is negative.
struct DenseGridSamples {
  float step_m = 0.05f;
  Eigen::Vector3f origin_m = Eigen::Vector3f::Zero();
  Int3 first = Int3::Zero();
  int n = 0;
  const int32_t* index = nullptr;  // n³ entries, each -1 or below `count`
  const float* values = nullptr;
  size_t count = 0;
};

// The same mesh as the GridSamples overload would give from the same values (same vertices in the
// same order, same faces), with the grid points in arrays instead of hash maps. Cells with a
// corner outside the block are not meshed.
Mesh MarchingCubes(const std::vector<Int3>& cells, const DenseGridSamples& samples,
                   std::vector<GridEdge>* vertex_edges);

// Per-point buffers the DenseGridSamples overload needs, for a caller that meshes many blocks to
// reuse (their contents do not carry over from call to call).
struct MarchScratch {
  std::vector<uint8_t> done;
  std::vector<uint32_t> edges;
};
Mesh MarchingCubes(const std::vector<Int3>& cells, const DenseGridSamples& samples,
                   std::vector<GridEdge>* vertex_edges, MarchScratch* scratch);

// Number of triangles the generated case table gives for a corner sign mask (bit i set = corner i
// negative, corner numbering as above). Exposed for tests.
int MarchingCubesTriangleCount(uint8_t case_mask);

}  // namespace rim
