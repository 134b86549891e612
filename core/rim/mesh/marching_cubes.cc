#include "rim/mesh/marching_cubes.h"

#include <array>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"

namespace rim {
namespace {

constexpr int kNumCorners = 8;
constexpr int kNumEdges = 12;
// A cube has at most 12 crossing edges and every closed loop of n of them yields n - 2
// triangles, so 12 triangle slots are always enough.
constexpr int kMaxTriangles = 12;

bool CornerBit(int corner, int axis) { return ((corner >> axis) & 1) != 0; }

// Edge id = axis * 4 + the two remaining corner bits of its lower corner, (axis+1) bit first.
int EdgeId(int corner_a, int corner_b) {
  const int diff = corner_a ^ corner_b;
  const int axis = diff == 1 ? 0 : (diff == 2 ? 1 : 2);
  const int lower = corner_a & corner_b;
  const int k =
      (CornerBit(lower, (axis + 1) % 3) ? 1 : 0) | (CornerBit(lower, (axis + 2) % 3) ? 2 : 0);
  return axis * 4 + k;
}

// Coordinate bit (0 or 1) of an edge along an axis other than its own, read from the edge id.
int EdgeSideBit(int edge, int axis) {
  const int edge_axis = edge / 4;
  return axis == (edge_axis + 1) % 3 ? (edge & 1) : ((edge >> 1) & 1);
}

// Two cube edges lie on a common face when both sit at the same side along a third axis.
bool EdgesShareFace(int edge_a, int edge_b) {
  for (int axis = 0; axis < 3; ++axis) {
    if (axis == edge_a / 4 || axis == edge_b / 4) continue;
    if (EdgeSideBit(edge_a, axis) == EdgeSideBit(edge_b, axis)) return true;
  }
  return false;
}

struct CaseTable {
  // Lower corner and axis of each edge id, for turning a table entry into a grid edge.
  std::array<uint8_t, kNumEdges> edge_lower_corner;
  std::array<uint8_t, kNumEdges> edge_axis;
  std::array<uint8_t, 256> num_triangles;
  // Triangles as edge ids, counter-clockwise seen from the positive side.
  std::array<std::array<std::array<uint8_t, 3>, kMaxTriangles>, 256> triangles;
};

// Fills one case: face rules give directed segments between crossing edges, the segments chain
// into closed loops, and each loop becomes a triangle fan.
void BuildCase(int mask, CaseTable* table) {
  auto inside = [mask](int corner) { return ((mask >> corner) & 1) != 0; };
  // next_edge[e] = the edge that the surface boundary reaches after e when walking a loop.
  std::array<int, kNumEdges> next_edge;
  next_edge.fill(-1);
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3;
    const int v = (axis + 2) % 3;
    for (int side = 0; side < 2; ++side) {
      // (u, v) in the order (0,0) (1,0) (1,1) (0,1) circles +axis counter-clockwise; the face at
      // side 0 looks toward -axis, so its walk is reversed. A shared cube edge is then walked in
      // opposite directions by its two faces, which is what makes segments chain head-to-tail.
      static constexpr int kU[4] = {0, 1, 1, 0};
      static constexpr int kV[4] = {0, 0, 1, 1};
      std::array<int, 4> walk;
      for (int k = 0; k < 4; ++k) {
        const int j = side == 1 ? k : 3 - k;
        walk[k] = (side << axis) | (kU[j] << u) | (kV[j] << v);
      }
      // Each +->- crossing is paired with the next -->+ crossing in walk order. Only the face's
      // own corner signs decide this, so both cells sharing the face agree; on the ambiguous face
      // it cuts off each inside corner separately.
      for (int k = 0; k < 4; ++k) {
        const int a = walk[k];
        const int b = walk[(k + 1) % 4];
        if (inside(a) || !inside(b)) continue;
        for (int step = 1; step < 4; ++step) {
          const int c = walk[(k + step) % 4];
          const int d = walk[(k + step + 1) % 4];
          if (inside(c) && !inside(d)) {
            assert(next_edge[EdgeId(a, b)] == -1);
            next_edge[EdgeId(a, b)] = EdgeId(c, d);
            break;
          }
        }
      }
    }
  }
  int num_triangles = 0;
  std::array<bool, kNumEdges> used;
  used.fill(false);
  for (int start = 0; start < kNumEdges; ++start) {
    if (next_edge[start] < 0 || used[start]) continue;
    std::vector<int> loop;
    for (int e = start; !used[e]; e = next_edge[e]) {
      used[e] = true;
      loop.push_back(e);
      assert(next_edge[e] >= 0);
    }
    // A loop can pass an ambiguous face twice. A fan diagonal between two vertices of one face
    // would lie in that face, where the neighbouring cell may use the same diagonal, giving an
    // edge with four triangles. Every loop of the table has an apex free of such diagonals.
    const size_t n = loop.size();
    size_t apex = 0;
    for (; apex < n; ++apex) {
      bool clean = true;
      for (size_t i = 2; i + 1 < n; ++i)
        clean = clean && !EdgesShareFace(loop[apex], loop[(apex + i) % n]);
      if (clean) break;
    }
    assert(apex < n);
    if (apex == n) apex = 0;
    for (size_t i = 1; i + 1 < n; ++i) {
      assert(num_triangles < kMaxTriangles);
      table->triangles[mask][num_triangles++] = {static_cast<uint8_t>(loop[apex]),
                                                 static_cast<uint8_t>(loop[(apex + i) % n]),
                                                 static_cast<uint8_t>(loop[(apex + i + 1) % n])};
    }
  }
  table->num_triangles[mask] = static_cast<uint8_t>(num_triangles);
}

CaseTable BuildCaseTable() {
  CaseTable table{};
  for (int a = 0; a < kNumCorners; ++a) {
    for (int axis = 0; axis < 3; ++axis) {
      if (CornerBit(a, axis)) continue;
      const int e = EdgeId(a, a | (1 << axis));
      table.edge_lower_corner[e] = static_cast<uint8_t>(a);
      table.edge_axis[e] = static_cast<uint8_t>(axis);
    }
  }
  for (int mask = 0; mask < 256; ++mask) BuildCase(mask, &table);
  return table;
}

const CaseTable& GetCaseTable() {
  // Function-local static: built once, thread-safe, and trivially destructible.
  static const CaseTable table = BuildCaseTable();
  return table;
}

Int3 CornerOffset(int corner) { return Int3(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1); }

struct Sample {
  float value = 0.0f;
  bool valid = false;
};

}  // namespace

int MarchingCubesTriangleCount(uint8_t case_mask) {
  return GetCaseTable().num_triangles[case_mask];
}

Mesh MarchingCubes(const std::vector<Int3>& cells, const GridSamples& samples) {
  return MarchingCubes(cells, samples, nullptr);
}

namespace {

// The marching itself, shared by the sparse and the dense entry points so that both give the same
// mesh (same vertices in the same order, same faces) from the same values. `Grid` supplies
//   bool FirstVisit(const Int3& cell): false for a cell already meshed in this call;
//   bool Corners(const Int3& cell, float values[8], int* mask): the corner values and the case
//     mask, false if a corner has no valid value;
//   uint32_t& VertexSlot(const GridEdge& e): the vertex on edge e, kNoVertex until created.
constexpr uint32_t kNoVertex = ~0u;

template <typename Grid>
Mesh March(const std::vector<Int3>& cells, float step_m, const Eigen::Vector3f& origin_m,
           Grid& grid, std::vector<GridEdge>* vertex_edges) {
  Mesh mesh;
  if (vertex_edges) vertex_edges->clear();
  const CaseTable& table = GetCaseTable();
  for (const Int3& cell : cells) {
    if (!grid.FirstVisit(cell)) continue;
    std::array<float, kNumCorners> values;
    int mask = 0;
    if (!grid.Corners(cell, values.data(), &mask) || mask == 0 || mask == 0xFF) continue;

    for (int t = 0; t < table.num_triangles[mask]; ++t) {
      std::array<uint32_t, 3> face;
      for (int k = 0; k < 3; ++k) {
        const int e = table.triangles[mask][t][k];
        const int lo = table.edge_lower_corner[e];
        const int axis = table.edge_axis[e];
        const GridEdge key{cell + CornerOffset(lo), axis};
        uint32_t& slot = grid.VertexSlot(key);
        if (slot == kNoVertex) {
          slot = static_cast<uint32_t>(mesh.vertices.size());
          // Only the two edge values enter, lower grid point first, so any call that sees the
          // same values computes the same bits for this vertex.
          const float v0 = values[lo];
          const float v1 = values[lo | (1 << axis)];
          const float frac = v0 / (v0 - v1);
          std::array<float, 3> p;
          for (int i = 0; i < 3; ++i) {
            float coord = static_cast<float>(key.lower[i]);
            if (i == axis) coord += frac;
            p[i] = origin_m[i] + step_m * coord;
          }
          mesh.vertices.push_back(p);
          if (vertex_edges) vertex_edges->push_back(key);
        }
        face[k] = slot;
      }
      if (face[0] == face[1] || face[1] == face[2] || face[0] == face[2]) continue;
      mesh.faces.push_back(face);
    }
  }
  return mesh;
}

// Grid points in hash maps, values from the caller's lookup.
class SparseGrid {
 public:
  SparseGrid(const GridSamples& samples, size_t cells) : samples_(samples) {
    cache_.reserve(cells * 2);
    done_.reserve(cells);
  }
  bool FirstVisit(const Int3& cell) { return done_.insert(cell).second; }
  const Sample& At(const Int3& g) {
    auto [it, inserted] = cache_.try_emplace(g);
    if (inserted) {
      float value = 0.0f;
      it->second.valid = samples_.lookup(g, &value) && std::isfinite(value);
      it->second.value = value;
    }
    return it->second;
  }
  uint32_t& VertexSlot(const GridEdge& e) { return edges_.try_emplace(e, kNoVertex).first->second; }
  bool Corners(const Int3& cell, float* values, int* mask) {
    for (int c = 0; c < kNumCorners; ++c) {
      // Stop at the first missing corner: the cell is dropped anyway and lookups may be costly.
      const Sample& s = At(cell + CornerOffset(c));
      if (!s.valid) return false;
      values[c] = s.value;
      if (s.value < 0.0f) *mask |= 1 << c;
    }
    return true;
  }

 private:
  const GridSamples& samples_;
  absl::flat_hash_map<Int3, Sample, Int3Hash, Int3Equal> cache_;
  absl::flat_hash_map<GridEdge, uint32_t, GridEdgeHash> edges_;
  absl::flat_hash_set<Int3, Int3Hash, Int3Equal> done_;
};

// Grid points of one dense block: values, vertices and visits are kept per point of the
// caller's list (its index), so nothing of size n³ is allocated or cleared per call.
class DenseGrid {
 public:
  DenseGrid(const DenseGridSamples& d, MarchScratch* scratch)
      : d_(d), done_(scratch->done), edges_(scratch->edges) {
    done_.assign(d.count, 0);
    edges_.assign(3 * d.count, kNoVertex);
    const size_t n = size_t(d.n);
    for (int c = 0; c < kNumCorners; ++c)
      corner_offset_[c] = (c & 1) * n * n + (c >> 1 & 1) * n + (c >> 2 & 1);
  }
  bool FirstVisit(const Int3& cell) {
    const Int3 m = cell - d_.first;
    // A cell must have all its corners in the block: one that does not is never complete.
    if ((m.array() < 0).any() || (m.array() >= d_.n - 1).any()) return false;
    base_ = (size_t(m.x()) * d_.n + m.y()) * d_.n + m.z();
    const int32_t i = d_.index[base_];
    if (i < 0) return true;  // a missing corner: Corners() drops the cell
    uint8_t& done = done_[size_t(i)];
    if (done) return false;
    done = 1;
    return true;
  }
  // The cell of the last FirstVisit() that returned true.
  bool Corners(const Int3& /*cell*/, float* values, int* mask) {
    for (int c = 0; c < kNumCorners; ++c) {
      const int32_t i = d_.index[base_ + corner_offset_[c]];
      if (i < 0) return false;
      const float v = d_.values[size_t(i)];
      if (!std::isfinite(v)) return false;
      values[c] = v;
      if (v < 0.0f) *mask |= 1 << c;
    }
    return true;
  }
  // Only called for an edge of a complete cell, whose lower point has an index.
  uint32_t& VertexSlot(const GridEdge& e) {
    const Int3 m = e.lower - d_.first;
    const int32_t i = d_.index[(size_t(m.x()) * d_.n + m.y()) * d_.n + m.z()];
    return edges_[3 * size_t(i) + size_t(e.axis)];
  }

 private:
  const DenseGridSamples& d_;
  size_t corner_offset_[kNumCorners];
  size_t base_ = 0;
  std::vector<uint8_t>& done_;
  std::vector<uint32_t>& edges_;
};

}  // namespace

Mesh MarchingCubes(const std::vector<Int3>& cells, const GridSamples& samples,
                   std::vector<GridEdge>* vertex_edges) {
  if (!samples.lookup) {
    if (vertex_edges) vertex_edges->clear();
    return Mesh();
  }
  SparseGrid grid(samples, cells.size());
  return March(cells, samples.step_m, samples.origin_m, grid, vertex_edges);
}

Mesh MarchingCubes(const std::vector<Int3>& cells, const DenseGridSamples& samples,
                   std::vector<GridEdge>* vertex_edges) {
  MarchScratch scratch;
  return MarchingCubes(cells, samples, vertex_edges, &scratch);
}

Mesh MarchingCubes(const std::vector<Int3>& cells, const DenseGridSamples& samples,
                   std::vector<GridEdge>* vertex_edges, MarchScratch* scratch) {
  DenseGrid grid(samples, scratch);
  return March(cells, samples.step_m, samples.origin_m, grid, vertex_edges);
}

}  // namespace rim
