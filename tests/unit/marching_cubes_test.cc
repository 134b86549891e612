#include "rim/mesh/marching_cubes.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <random>
#include <set>
#include <unordered_map>
#include <utility>
#include <vector>

#include "rim/io/mesh_io.h"

namespace rim {
namespace {

constexpr float kStep = 0.05f;
constexpr double kRadius = 0.7;
constexpr int kHalfExtent = 17;  // grid points -17..17 cover the sphere with a margin.

Eigen::Vector3f Pos(const Mesh& m, uint32_t i) {
  return Eigen::Vector3f(m.vertices[i][0], m.vertices[i][1], m.vertices[i][2]);
}

Eigen::Vector3f TriangleNormal(const Mesh& m, const std::array<uint32_t, 3>& f) {
  return (Pos(m, f[1]) - Pos(m, f[0])).cross(Pos(m, f[2]) - Pos(m, f[0]));
}

// True when every directed half-edge occurs once and its twin occurs once: a closed, consistently
// oriented 2-manifold surface (up to vertex pinches, which the Euler check catches).
bool IsClosedAndOriented(const std::vector<std::array<uint32_t, 3>>& faces) {
  std::map<std::pair<uint32_t, uint32_t>, int> half_edges;
  for (const auto& f : faces) {
    for (int k = 0; k < 3; ++k) ++half_edges[{f[k], f[(k + 1) % 3]}];
  }
  for (const auto& [e, n] : half_edges) {
    if (n != 1) return false;
    auto twin = half_edges.find({e.second, e.first});
    if (twin == half_edges.end() || twin->second != 1) return false;
  }
  return true;
}

int EulerCharacteristic(const Mesh& m) {
  std::set<uint32_t> used;
  std::set<std::pair<uint32_t, uint32_t>> edges;
  for (const auto& f : m.faces) {
    for (int k = 0; k < 3; ++k) {
      used.insert(f[k]);
      edges.insert(std::minmax(f[k], f[(k + 1) % 3]));
    }
  }
  return static_cast<int>(used.size()) - static_cast<int>(edges.size()) +
         static_cast<int>(m.faces.size());
}

std::vector<Int3> CellsInBox(int lo, int hi) {
  std::vector<Int3> cells;
  for (int z = lo; z < hi; ++z)
    for (int y = lo; y < hi; ++y)
      for (int x = lo; x < hi; ++x) cells.emplace_back(x, y, z);
  return cells;
}

// Signed distance to a sphere at the world origin; the grid origin is deliberately off-centre.
GridSamples SphereSamples(std::map<std::array<int, 3>, int>* lookup_counts = nullptr) {
  GridSamples s;
  s.step_m = kStep;
  s.origin_m = Eigen::Vector3f(0.013f, -0.021f, 0.007f);
  const Eigen::Vector3f origin = s.origin_m;
  s.lookup = [origin, lookup_counts](const Int3& g, float* value) {
    if (lookup_counts != nullptr) ++(*lookup_counts)[{g.x(), g.y(), g.z()}];
    const Eigen::Vector3d p = (origin + g.cast<float>() * kStep).cast<double>();
    *value = static_cast<float>(p.norm() - kRadius);
    return true;
  };
  return s;
}

TEST(MarchingCubesTest, SphereIsClosedAccurateAndOutwardFacing) {
  std::map<std::array<int, 3>, int> lookup_counts;
  const Mesh mesh =
      MarchingCubes(CellsInBox(-kHalfExtent, kHalfExtent), SphereSamples(&lookup_counts));
  ASSERT_GT(mesh.faces.size(), 1000u);
  for (const auto& [g, n] : lookup_counts) ASSERT_EQ(n, 1) << "grid point looked up repeatedly";

  EXPECT_TRUE(IsClosedAndOriented(mesh.faces));
  EXPECT_EQ(EulerCharacteristic(mesh), 2);

  // The zero of the linear interpolant on an edge of length h is where |f - L| <= h^2/8 max|f''|.
  // Along any line, |x| - r has f'' <= 1/|x|, and a crossing edge stays within h of the surface,
  // so |f(vertex)| <= h^2 / (8 (r - h)) ~= 4.8e-4; the rest of the margin covers float rounding.
  const double tolerance = kStep * kStep / (8.0 * (kRadius - kStep)) + 2e-5;
  double max_error = 0.0;
  for (uint32_t i = 0; i < mesh.vertices.size(); ++i) {
    max_error = std::max(max_error, std::abs(Pos(mesh, i).cast<double>().norm() - kRadius));
  }
  EXPECT_LE(max_error, tolerance);

  int outward = 0;
  double area = 0.0;
  for (const auto& f : mesh.faces) {
    const Eigen::Vector3f n = TriangleNormal(mesh, f);
    const Eigen::Vector3f centroid = (Pos(mesh, f[0]) + Pos(mesh, f[1]) + Pos(mesh, f[2])) / 3.0f;
    if (n.dot(centroid) > 0.0f) ++outward;
    area += 0.5 * n.cast<double>().norm();
  }
  EXPECT_GT(outward, 0.99 * mesh.faces.size());
  const double true_area = 4.0 * M_PI * kRadius * kRadius;
  EXPECT_NEAR(area, true_area, 0.02 * true_area);
}

TEST(MarchingCubesTest, RepeatedCellsAreMeshedOnce) {
  std::vector<Int3> cells = CellsInBox(-kHalfExtent, kHalfExtent);
  const Mesh once = MarchingCubes(cells, SphereSamples());
  const size_t n = cells.size();
  for (size_t i = 0; i < n; i += 3) cells.push_back(cells[i]);
  const Mesh twice = MarchingCubes(cells, SphereSamples());
  EXPECT_EQ(once.faces, twice.faces);
  EXPECT_EQ(once.vertices, twice.vertices);
}

std::array<uint32_t, 3> Bits(const std::array<float, 3>& v) {
  std::array<uint32_t, 3> b;
  std::memcpy(b.data(), v.data(), sizeof(b));
  return b;
}

TEST(MarchingCubesTest, SeparateCallsShareBitIdenticalBorderVertices) {
  const GridSamples samples = SphereSamples();
  const std::vector<Int3> all = CellsInBox(-kHalfExtent, kHalfExtent);
  std::vector<Int3> left, right;
  for (const Int3& c : all) (c.x() < 0 ? left : right).push_back(c);
  // Mesh the right half in reverse order so vertex creation order differs from the left half.
  std::reverse(right.begin(), right.end());
  const Mesh full = MarchingCubes(all, samples);
  const Mesh a = MarchingCubes(left, samples);
  const Mesh b = MarchingCubes(right, samples);

  // Border vertices lie on the grid plane x index 0, whose world x is exactly origin.x.
  auto border = [&](const Mesh& m) {
    std::set<std::array<uint32_t, 3>> s;
    for (const auto& v : m.vertices) {
      if (v[0] == samples.origin_m.x()) s.insert(Bits(v));
    }
    return s;
  };
  const auto border_a = border(a);
  EXPECT_GT(border_a.size(), 20u);
  EXPECT_EQ(border_a, border(b));
  EXPECT_FALSE(IsClosedAndOriented(a.faces));

  Mesh joined;
  AppendMesh(a, &joined);
  AppendMesh(b, &joined);
  const Mesh welded = WeldIdenticalVertices(joined);
  EXPECT_EQ(welded.vertices.size(), full.vertices.size());
  EXPECT_EQ(welded.faces.size(), full.faces.size());
  EXPECT_TRUE(IsClosedAndOriented(welded.faces));
  EXPECT_EQ(EulerCharacteristic(welded), 2);
}

TEST(MarchingCubesTest, UnobservedPointsProduceNoTriangles) {
  GridSamples samples = SphereSamples();
  const auto full_lookup = samples.lookup;
  const float cut_x = 0.2f;
  const Eigen::Vector3f origin = samples.origin_m;
  std::map<std::array<int, 3>, int> counts;
  samples.lookup = [&](const Int3& g, float* value) {
    ++counts[{g.x(), g.y(), g.z()}];
    if (origin.x() + g.x() * kStep > cut_x) return false;
    return full_lookup(g, value);
  };
  const std::vector<Int3> cells = CellsInBox(-kHalfExtent, kHalfExtent);
  const Mesh full = MarchingCubes(cells, SphereSamples());
  const Mesh partial = MarchingCubes(cells, samples);
  ASSERT_FALSE(partial.empty());
  EXPECT_LT(partial.faces.size(), full.faces.size());
  for (const auto& v : partial.vertices) EXPECT_LE(v[0], cut_x + 1e-6f);
  for (const auto& [g, n] : counts) ASSERT_EQ(n, 1);

  // A single NaN sample acts like an unobserved point too.
  GridSamples nan_samples = SphereSamples();
  nan_samples.lookup = [&](const Int3& /*g*/, float* value) {
    *value = std::nanf("");
    return true;
  };
  EXPECT_TRUE(MarchingCubes(cells, nan_samples).empty());
}

TEST(MarchingCubesTest, CaseTableBasics) {
  EXPECT_EQ(MarchingCubesTriangleCount(0x00), 0);
  EXPECT_EQ(MarchingCubesTriangleCount(0xFF), 0);
  for (int c = 0; c < 8; ++c) {
    EXPECT_EQ(MarchingCubesTriangleCount(static_cast<uint8_t>(1 << c)), 1);
    EXPECT_EQ(MarchingCubesTriangleCount(static_cast<uint8_t>(0xFF ^ (1 << c))), 1);
  }
  EXPECT_EQ(MarchingCubesTriangleCount(0x0F), 2);  // the z = 0 half: one quad.
  EXPECT_EQ(MarchingCubesTriangleCount(0x81), 2);  // corners 0 and 7: two separate triangles.
}

// Noise exercises every case, ambiguous faces included, across neighbouring cells. With positive
// values on the grid boundary the surface must have no cracks: every directed edge is matched by
// its reverse.
TEST(MarchingCubesTest, RandomFieldsGiveCrackFreeSurfaces) {
  static constexpr int kN = 12;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> noise(-1.0f, 1.0f);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<float> field(kN * kN * kN);
    for (float& v : field) v = noise(rng);
    GridSamples s;
    s.step_m = 0.1f;
    s.lookup = [&field](const Int3& g, float* value) {
      if ((g.array() < 0).any() || (g.array() >= kN).any()) return false;
      const bool border = (g.array() == 0).any() || (g.array() == kN - 1).any();
      *value = border ? 1.0f : field[(g.z() * kN + g.y()) * kN + g.x()];
      return true;
    };
    const Mesh mesh = MarchingCubes(CellsInBox(0, kN - 1), s);
    ASSERT_GT(mesh.faces.size(), 100u);
    std::map<std::pair<uint32_t, uint32_t>, int> half_edges;
    for (const auto& f : mesh.faces) {
      for (int k = 0; k < 3; ++k) ++half_edges[{f[k], f[(k + 1) % 3]}];
    }
    for (const auto& [e, n] : half_edges) {
      auto twin = half_edges.find({e.second, e.first});
      ASSERT_TRUE(twin != half_edges.end() && twin->second == n) << "crack at trial " << trial;
    }
    EXPECT_TRUE(IsClosedAndOriented(mesh.faces)) << "non-manifold edge at trial " << trial;
  }
}

// The dense overload (a block's values in arrays, as the mesher gives them) must give exactly the
// sparse overload's mesh: the same vertices in the same order, the same faces and vertex edges.
// Random values with unobserved points, a NaN, repeated cells and cells that leave the block.
TEST(MarchingCubesTest, DenseBlockGivesTheSparseMeshBitForBit) {
  constexpr int kN = 11;
  const Int3 first(-4, 7, 2);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> noise(-1.0f, 1.0f);
  for (int trial = 0; trial < 10; ++trial) {
    std::vector<float> values;
    std::vector<int32_t> index(kN * kN * kN, -1);
    for (size_t i = 0; i < index.size(); ++i) {
      if (rng() % 9 == 0) continue;  // unobserved
      index[i] = int32_t(values.size());
      values.push_back(rng() % 500 == 0 ? std::nanf("") : noise(rng));
    }
    std::vector<Int3> cells;
    for (int k = 0; k < 900; ++k)
      cells.push_back(first + Int3(int(rng() % (kN + 1)) - 1, int(rng() % kN), int(rng() % kN)));
    DenseGridSamples dense;
    dense.step_m = 0.05f;
    dense.origin_m = Eigen::Vector3f(0.3f, -0.2f, 1.1f);
    dense.first = first;
    dense.n = kN;
    dense.index = index.data();
    dense.values = values.data();
    dense.count = values.size();
    GridSamples sparse;
    sparse.step_m = dense.step_m;
    sparse.origin_m = dense.origin_m;
    sparse.lookup = [&](const Int3& g, float* value) {
      const Int3 m = g - first;
      if ((m.array() < 0).any() || (m.array() >= kN).any()) return false;
      const int32_t i = index[size_t((m.x() * kN + m.y()) * kN + m.z())];
      if (i < 0) return false;
      *value = values[size_t(i)];
      return true;
    };
    std::vector<GridEdge> dense_edges, sparse_edges;
    const Mesh a = MarchingCubes(cells, dense, &dense_edges);
    const Mesh b = MarchingCubes(cells, sparse, &sparse_edges);
    ASSERT_GT(b.faces.size(), 50u) << "trial " << trial;
    ASSERT_EQ(a.vertices.size(), b.vertices.size());
    EXPECT_EQ(0, std::memcmp(a.vertices.data(), b.vertices.data(),
                             a.vertices.size() * sizeof(a.vertices[0])));
    EXPECT_EQ(a.faces, b.faces);
    EXPECT_EQ(dense_edges, sparse_edges);
  }
}

// Runs marching cubes on the unit cell at the origin with step 1 and the given corner values.
Mesh MeshSingleCube(const std::array<float, 8>& values) {
  GridSamples s;
  s.step_m = 1.0f;
  s.lookup = [&values](const Int3& g, float* value) {
    if ((g.array() < 0).any() || (g.array() > 1).any()) return false;
    *value = values[g.x() | (g.y() << 1) | (g.z() << 2)];
    return true;
  };
  return MarchingCubes({Int3(0, 0, 0)}, s);
}

Eigen::Vector3d CornerPos(int c) { return Eigen::Vector3d(c & 1, (c >> 1) & 1, (c >> 2) & 1); }

// Key of the cube edge between two corners: (lower corner, axis).
std::pair<int, int> EdgeOf(int a, int b) {
  const int diff = a ^ b;
  return {a & b, diff == 1 ? 0 : (diff == 2 ? 1 : 2)};
}

// For every sign pattern and random magnitudes: the cube's triangles plus the inside part of each
// cube face must form a closed, consistently oriented surface around the inside region with
// positive volume. That checks both that the loops close on the cube faces and that normals point
// toward the positive side.
TEST(MarchingCubesTest, AllCasesCloseAgainstCubeFacesAndFaceThePositiveSide) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> magnitude(0.05f, 1.0f);
  for (int mask = 0; mask < 256; ++mask) {
    for (int trial = 0; trial < 10; ++trial) {
      std::array<float, 8> values;
      for (int c = 0; c < 8; ++c) values[c] = ((mask >> c) & 1) ? -magnitude(rng) : magnitude(rng);
      const Mesh mesh = MeshSingleCube(values);
      ASSERT_EQ(static_cast<int>(mesh.faces.size()),
                MarchingCubesTriangleCount(static_cast<uint8_t>(mask)));

      // Identify which cube edge each vertex lies on: the two coordinates that are exactly 0 or 1.
      std::map<std::pair<int, int>, uint32_t> vertex_of_edge;
      for (uint32_t i = 0; i < mesh.vertices.size(); ++i) {
        const auto& v = mesh.vertices[i];
        int axis = -1, lower = 0;
        for (int k = 0; k < 3; ++k) {
          if (v[k] == 0.0f || v[k] == 1.0f) {
            lower |= (v[k] == 1.0f ? 1 : 0) << k;
          } else {
            ASSERT_EQ(axis, -1) << "vertex not on a cube edge";
            axis = k;
          }
        }
        ASSERT_NE(axis, -1);
        vertex_of_edge[{lower, axis}] = i;
      }

      // Close the surface with the inside part of each face, walked counter-clockwise from outside:
      // from a +-> - crossing over the inside corners to the next - -> + crossing.
      std::vector<Eigen::Vector3d> points;
      for (const auto& v : mesh.vertices) points.emplace_back(v[0], v[1], v[2]);
      for (int c = 0; c < 8; ++c) points.push_back(CornerPos(c));
      auto corner_id = [&](int c) { return static_cast<uint32_t>(mesh.vertices.size() + c); };
      std::vector<std::array<uint32_t, 3>> closed = mesh.faces;
      auto add_fan = [&](const std::vector<uint32_t>& poly) {
        for (size_t k = 1; k + 1 < poly.size(); ++k)
          closed.push_back({poly[0], poly[k], poly[k + 1]});
      };
      for (int axis = 0; axis < 3; ++axis) {
        for (int side = 0; side < 2; ++side) {
          const Eigen::Vector3d n = (side ? 1.0 : -1.0) * Eigen::Vector3d::Unit(axis);
          const Eigen::Vector3d t1 = Eigen::Vector3d::Unit((axis + 1) % 3);
          const Eigen::Vector3d t2 = n.cross(t1);
          const Eigen::Vector3d centre = Eigen::Vector3d::Constant(0.5) + 0.5 * n;
          std::vector<int> ring;
          for (int c = 0; c < 8; ++c) {
            if (((c >> axis) & 1) == side) ring.push_back(c);
          }
          std::sort(ring.begin(), ring.end(), [&](int a, int b) {
            const Eigen::Vector3d da = CornerPos(a) - centre, db = CornerPos(b) - centre;
            return std::atan2(da.dot(t2), da.dot(t1)) < std::atan2(db.dot(t2), db.dot(t1));
          });
          auto neg = [&](int k) { return values[ring[k % 4]] < 0.0f; };
          if (neg(0) && neg(1) && neg(2) && neg(3)) {
            add_fan(
                {corner_id(ring[0]), corner_id(ring[1]), corner_id(ring[2]), corner_id(ring[3])});
          }
          for (int k = 0; k < 4; ++k) {
            if (neg(k) || !neg(k + 1)) continue;
            std::vector<uint32_t> poly = {vertex_of_edge.at(EdgeOf(ring[k], ring[(k + 1) % 4]))};
            int j = k + 1;
            for (; neg(j); ++j) poly.push_back(corner_id(ring[j % 4]));
            poly.push_back(vertex_of_edge.at(EdgeOf(ring[(j - 1) % 4], ring[j % 4])));
            add_fan(poly);
          }
        }
      }
      ASSERT_TRUE(IsClosedAndOriented(closed)) << "mask " << mask;
      double volume = 0.0;
      for (const auto& f : closed)
        volume += points[f[0]].dot(points[f[1]].cross(points[f[2]])) / 6.0;
      if (mask != 0) {
        ASSERT_GT(volume, 0.0) << "mask " << mask;
      }
      ASSERT_LE(volume, 1.0 + 1e-6) << "mask " << mask;
    }
  }
}

// For a linear field the surface in a cube is planar and exact, so every triangle normal must be
// parallel to the gradient.
TEST(MarchingCubesTest, TriangleNormalsFollowTheGradientOfLinearFields) {
  std::mt19937 rng(11);
  std::normal_distribution<float> gauss;
  std::uniform_real_distribution<float> inside(0.1f, 0.9f);
  int checked = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    const Eigen::Vector3f grad = Eigen::Vector3f(gauss(rng), gauss(rng), gauss(rng)).normalized();
    const Eigen::Vector3f point(inside(rng), inside(rng), inside(rng));
    std::array<float, 8> values;
    for (int c = 0; c < 8; ++c) values[c] = grad.dot(CornerPos(c).cast<float>() - point);
    const Mesh mesh = MeshSingleCube(values);
    for (const auto& f : mesh.faces) {
      const Eigen::Vector3f n = TriangleNormal(mesh, f);
      if (n.norm() < 1e-4f) continue;
      ASSERT_GT(n.normalized().dot(grad), 0.999f);
      ++checked;
    }
  }
  EXPECT_GT(checked, 3000);
}

}  // namespace
}  // namespace rim
