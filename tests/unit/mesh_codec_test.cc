#include "proto/codec/mesh_codec.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace rim::codec {
namespace {

using ::testing::HasSubstr;

constexpr double kPi = 3.14159265358979323846;

// A closed UV ellipsoid (single-vertex poles), faces counter-clockwise seen from outside.
Mesh UvEllipsoid(const std::array<double, 3>& center, const std::array<double, 3>& radii, int rings,
                 int segments) {
  Mesh m;
  m.vertices.push_back({static_cast<float>(center[0]), static_cast<float>(center[1]),
                        static_cast<float>(center[2] + radii[2])});
  for (int r = 1; r < rings; ++r) {
    const double theta = kPi * r / rings;
    for (int s = 0; s < segments; ++s) {
      const double phi = 2 * kPi * s / segments;
      m.vertices.push_back(
          {static_cast<float>(center[0] + radii[0] * std::sin(theta) * std::cos(phi)),
           static_cast<float>(center[1] + radii[1] * std::sin(theta) * std::sin(phi)),
           static_cast<float>(center[2] + radii[2] * std::cos(theta))});
    }
  }
  m.vertices.push_back({static_cast<float>(center[0]), static_cast<float>(center[1]),
                        static_cast<float>(center[2] - radii[2])});
  const uint32_t south = static_cast<uint32_t>(m.vertices.size() - 1);
  auto ring_vertex = [&](int r, int s) {
    return static_cast<uint32_t>(1 + (r - 1) * segments + (s % segments));
  };
  for (int s = 0; s < segments; ++s) {
    m.faces.push_back({0, ring_vertex(1, s), ring_vertex(1, s + 1)});
    for (int r = 1; r + 1 < rings; ++r) {
      const uint32_t a = ring_vertex(r, s), b = ring_vertex(r + 1, s);
      const uint32_t c = ring_vertex(r + 1, s + 1), d = ring_vertex(r, s + 1);
      m.faces.push_back({a, b, c});
      m.faces.push_back({a, c, d});
    }
    m.faces.push_back({ring_vertex(rings - 1, s), south, ring_vertex(rings - 1, s + 1)});
  }
  return m;
}

double Dist(const std::array<float, 3>& a, const std::array<float, 3>& b) {
  const double dx = double{a[0]} - b[0], dy = double{a[1]} - b[1], dz = double{a[2]} - b[2];
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

// Rotates a face so its smallest index comes first, keeping the winding.
std::array<uint32_t, 3> Canonical(std::array<uint32_t, 3> f) {
  while (f[0] > f[1] || f[0] > f[2]) f = {f[1], f[2], f[0]};
  return f;
}

// Checks that `decoded` is `original` up to vertex order: each decoded vertex is within
// `max_error` of a distinct original vertex, and the faces map to the original faces with the
// same winding. Returns the largest vertex error.
// With `split_ok`, Draco may have duplicated vertices (it splits non-manifold ones), so the
// decoded vertices need only map onto the originals, not one to one.
double ExpectSameMesh(const Mesh& original, const Mesh& decoded, double max_error,
                      bool split_ok = false) {
  if (!split_ok) EXPECT_EQ(decoded.vertices.size(), original.vertices.size());
  EXPECT_EQ(decoded.faces.size(), original.faces.size());
  std::vector<uint32_t> to_original(decoded.vertices.size());
  std::vector<int> used(original.vertices.size(), 0);
  double worst = 0;
  for (size_t i = 0; i < decoded.vertices.size(); ++i) {
    double best = std::numeric_limits<double>::infinity();
    for (size_t j = 0; j < original.vertices.size(); ++j) {
      const double d = Dist(decoded.vertices[i], original.vertices[j]);
      if (d < best) {
        best = d;
        to_original[i] = static_cast<uint32_t>(j);
      }
    }
    worst = std::max(worst, best);
    ++used[to_original[i]];
  }
  EXPECT_LE(worst, max_error);
  if (split_ok) {
    EXPECT_EQ(std::count(used.begin(), used.end(), 0), 0) << "an original vertex is missing";
  } else {
    EXPECT_EQ(std::count(used.begin(), used.end(), 1), static_cast<long>(used.size()))
        << "decoded vertices do not map one to one onto the originals";
  }
  std::vector<std::array<uint32_t, 3>> want, got;
  for (const auto& f : original.faces) want.push_back(Canonical(f));
  for (const auto& f : decoded.faces) {
    got.push_back(Canonical({to_original[f[0]], to_original[f[1]], to_original[f[2]]}));
  }
  std::sort(want.begin(), want.end());
  std::sort(got.begin(), got.end());
  EXPECT_EQ(got, want);
  return worst;
}

TEST(PositionQuantizationBitsTest, MinimalBitsMeetingTheBound) {
  // The bound is on the distance in space: sqrt(3) half-steps.
  EXPECT_EQ(*PositionQuantizationBits(26.0, 0.001), 15);
  EXPECT_EQ(*PositionQuantizationBits(20.0, 0.001), 15);
  EXPECT_EQ(*PositionQuantizationBits(6.0, 0.001), 13);
  EXPECT_EQ(*PositionQuantizationBits(0.0, 0.001), 1);
  for (double range : {0.01, 1.0, 6.0, 20.0, 26.0, 100.0, 1234.5}) {
    for (double err : {1e-2, 1e-3, 1e-4}) {
      const int bits = *PositionQuantizationBits(range, err);
      auto error_at = [&](int b) { return std::sqrt(3.0) * range / (std::pow(2.0, b) - 1) / 2; };
      EXPECT_LE(error_at(bits), err) << range << " " << err;
      if (bits > 1) EXPECT_GT(error_at(bits - 1), err) << range << " " << err;
    }
  }
}

TEST(PositionQuantizationBitsTest, CapsAtThirtyBitsAndRefusesNonsense) {
  EXPECT_EQ(*PositionQuantizationBits(1e9, 1e-6), 30);
  EXPECT_FALSE(PositionQuantizationBits(-1, 0.001).ok());
  EXPECT_FALSE(PositionQuantizationBits(10, 0).ok());
  EXPECT_FALSE(PositionQuantizationBits(10, -1).ok());
  EXPECT_FALSE(PositionQuantizationBits(std::nan(""), 0.001).ok());
  EXPECT_FALSE(PositionQuantizationBits(10, std::numeric_limits<double>::infinity()).ok());
}

struct TileCase {
  std::array<double, 3> size;
};

void PrintTo(const TileCase& c, std::ostream* os) {
  *os << c.size[0] << " x " << c.size[1] << " x " << c.size[2] << " m";
}

class TileRoundTripTest : public ::testing::TestWithParam<TileCase> {};

TEST_P(TileRoundTripTest, EllipsoidFillingTheTileRoundTripsWithinOneMillimetre) {
  const std::array<double, 3> size = GetParam().size;
  // World coordinates away from the origin, as real tiles are.
  const std::array<double, 3> tile_min = {-130.0, 52.0, -2.0};
  const std::array<double, 3> tile_max = {tile_min[0] + size[0], tile_min[1] + size[1],
                                          tile_min[2] + size[2]};
  const std::array<double, 3> center = {(tile_min[0] + tile_max[0]) / 2,
                                        (tile_min[1] + tile_max[1]) / 2,
                                        (tile_min[2] + tile_max[2]) / 2};
  const Mesh mesh =
      UvEllipsoid(center, {size[0] / 2 - 0.05, size[1] / 2 - 0.05, size[2] / 2 - 0.05}, 40, 64);
  auto bytes = EncodeTileDraco(mesh, tile_min, tile_max);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  // Far below the 12 bytes per vertex and face of the raw mesh.
  EXPECT_LT(bytes->size(), (mesh.vertices.size() + mesh.faces.size()) * 12 / 4);
  auto decoded = DecodeTileDraco(*bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  const double worst = ExpectSameMesh(mesh, *decoded, 0.001);
  // The grid is no finer than needed: the error uses a fair part of the budget.
  EXPECT_GT(worst, 0.0002);
}

TEST_P(TileRoundTripTest, FasterCodersKeepTheBound) {
  const std::array<double, 3> size = GetParam().size;
  const std::array<double, 3> tile_min = {-130.0, 52.0, -2.0};
  const std::array<double, 3> tile_max = {tile_min[0] + size[0], tile_min[1] + size[1],
                                          tile_min[2] + size[2]};
  const Mesh mesh =
      UvEllipsoid({tile_min[0] + size[0] / 2, tile_min[1] + size[1] / 2, 1.0},
                  {size[0] / 2 - 0.05, size[1] / 2 - 0.05, size[2] / 2 - 0.05}, 40, 64);
  auto smallest = EncodeTileDraco(mesh, tile_min, tile_max, 0.004, DracoEffort::kSmallest);
  auto faster = EncodeTileDraco(mesh, tile_min, tile_max, 0.004, DracoEffort::kFaster);
  ASSERT_TRUE(smallest.ok() && faster.ok());
  // Other coders, so other bytes; the same mesh within the bound.
  EXPECT_NE(*smallest, *faster);
  auto decoded = DecodeTileDraco(*faster);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  ExpectSameMesh(mesh, *decoded, 0.004);
}

TEST(MeshCodecTest, TheServiceTakesTheFasterCodersFromFourTimesTheFinestCell) {
  EXPECT_EQ(TileEffort(0.05, 0.05), DracoEffort::kSmallest);
  EXPECT_EQ(TileEffort(0.1, 0.05), DracoEffort::kSmallest);
  EXPECT_EQ(TileEffort(0.2f, 0.05f), DracoEffort::kFaster);  // float levels, as the mapper's
  EXPECT_EQ(TileEffort(0.4, 0.05), DracoEffort::kFaster);
  EXPECT_EQ(TileEffort(0.2, 0.1), DracoEffort::kSmallest);
}

TEST_P(TileRoundTripTest, TighterBoundCostsBytesAndIsMet) {
  const std::array<double, 3> size = GetParam().size;
  const std::array<double, 3> tile_min = {10.0, 20.0, 0.0};
  const std::array<double, 3> tile_max = {10.0 + size[0], 20.0 + size[1], size[2]};
  const Mesh mesh = UvEllipsoid({10 + size[0] / 2, 20 + size[1] / 2, size[2] / 2},
                                {size[0] / 3, size[1] / 3, size[2] / 3}, 24, 32);
  auto coarse = EncodeTileDraco(mesh, tile_min, tile_max, 0.001);
  auto fine = EncodeTileDraco(mesh, tile_min, tile_max, 0.0001);
  ASSERT_TRUE(coarse.ok() && fine.ok());
  EXPECT_GT(fine->size(), coarse->size());
  auto decoded = DecodeTileDraco(*fine);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  ExpectSameMesh(mesh, *decoded, 0.0001);
}

INSTANTIATE_TEST_SUITE_P(TileSizes, TileRoundTripTest,
                         ::testing::Values(TileCase{{20, 20, 6}}, TileCase{{26, 26, 6}}),
                         [](const ::testing::TestParamInfo<TileCase>& info) {
                           const auto& s = info.param.size;
                           return "Tile" + std::to_string(static_cast<int>(s[0])) + "x" +
                                  std::to_string(static_cast<int>(s[1])) + "x" +
                                  std::to_string(static_cast<int>(s[2]));
                         });

TEST(MeshCodecTest, VerticesOutsideTheTileStayWithinTheBound) {
  // Marching cubes can put vertices on the far side of a tile face.
  const Mesh mesh = UvEllipsoid({0, 0, 0}, {3, 3, 3}, 16, 24);
  auto bytes = EncodeTileDraco(mesh, {-1, -1, -1}, {1, 1, 1});
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  auto decoded = DecodeTileDraco(*bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  ExpectSameMesh(mesh, *decoded, 0.001);
}

TEST(MeshCodecTest, EmptyMeshIsASmallValidPayload) {
  for (const Mesh& empty : {Mesh{}, Mesh{{{1.f, 2.f, 3.f}}, {}}}) {
    auto bytes = EncodeTileDraco(empty, {0, 0, 0}, {20, 20, 6});
    ASSERT_TRUE(bytes.ok()) << bytes.status();
    EXPECT_LT(bytes->size(), 64u);
    auto decoded = DecodeTileDraco(*bytes);
    ASSERT_TRUE(decoded.ok()) << decoded.status();
    EXPECT_TRUE(decoded->faces.empty());
    EXPECT_TRUE(decoded->vertices.empty());
  }
}

TEST(MeshCodecTest, DegenerateFacesAndUnusedVerticesAreDropped) {
  const Mesh sphere = UvEllipsoid({0, 0, 0}, {2, 2, 2}, 10, 12);
  Mesh mesh = sphere;
  mesh.faces.push_back({3, 3, 4});
  mesh.faces.push_back({5, 6, 5});
  mesh.vertices.push_back({0.5f, 0.5f, 0.5f});  // No face uses it.
  auto bytes = EncodeTileDraco(mesh, {-3, -3, -3}, {3, 3, 3});
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  auto decoded = DecodeTileDraco(*bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  ExpectSameMesh(sphere, *decoded, 0.001);

  // Nothing but degenerate faces: the empty payload, not an error.
  const Mesh only_degenerate{{{0, 0, 0}, {1, 0, 0}}, {{0, 0, 1}, {1, 1, 1}}};
  bytes = EncodeTileDraco(only_degenerate, {-3, -3, -3}, {3, 3, 3});
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  decoded = DecodeTileDraco(*bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  EXPECT_TRUE(decoded->faces.empty());
}

TEST(MeshCodecTest, NonManifoldMeshKeepsEveryFace) {
  // Three triangles on one edge, plus two fans touching at a single vertex: both non-manifold.
  Mesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0.5f, 1, 0}, {0.5f, -1, 0}, {0.5f, 0, 1},
                   {2, 2, 2}, {3, 2, 2}, {2, 3, 2},    {1, 1, 1},     {2, 1, 2}};
  mesh.faces = {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}, {5, 6, 7}, {5, 8, 9}};
  auto bytes = EncodeTileDraco(mesh, {0, 0, 0}, {4, 4, 4});
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  auto decoded = DecodeTileDraco(*bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  EXPECT_GE(decoded->vertices.size(), mesh.vertices.size());
  ExpectSameMesh(mesh, *decoded, 0.001, /*split_ok=*/true);
}

TEST(MeshCodecTest, InvalidInputsAreRefused) {
  const Mesh mesh = UvEllipsoid({0, 0, 0}, {1, 1, 1}, 8, 8);
  const std::array<double, 3> lo = {-2, -2, -2}, hi = {2, 2, 2};
  Mesh bad_index = mesh;
  bad_index.faces[3][1] = static_cast<uint32_t>(mesh.vertices.size());
  auto s = EncodeTileDraco(bad_index, lo, hi);
  EXPECT_EQ(s.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.status().message(), HasSubstr("out of range"));

  Mesh nan_vertex = mesh;
  nan_vertex.vertices[2][1] = std::nanf("");
  EXPECT_EQ(EncodeTileDraco(nan_vertex, lo, hi).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeTileDraco(mesh, hi, lo).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeTileDraco(mesh, {std::nan(""), 0, 0}, hi).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeTileDraco(mesh, lo, hi, 0).status().code(), absl::StatusCode::kInvalidArgument);
  // Below float32 resolution at these coordinates.
  EXPECT_EQ(EncodeTileDraco(mesh, {1e6, 1e6, 0}, {1e6 + 20, 1e6 + 20, 6}, 1e-4).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(MeshCodecTest, GarbageAndTruncationsDecodeToErrorsNeverCrash) {
  const Mesh mesh = UvEllipsoid({5, 5, 3}, {4, 4, 2}, 12, 16);
  auto bytes = EncodeTileDraco(mesh, {0, 0, 0}, {10, 10, 6});
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  EXPECT_EQ(DecodeTileDraco("").status().code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(DecodeTileDraco("not a draco payload").status().code(), absl::StatusCode::kDataLoss);
  for (size_t n = 0; n < bytes->size(); ++n) {
    auto decoded = DecodeTileDraco(std::string_view(*bytes).substr(0, n));
    EXPECT_FALSE(decoded.ok()) << "prefix of " << n << " of " << bytes->size() << " bytes";
  }
}

TEST(MeshCodecTest, RandomMutationsDecodeToErrorsOrValidMeshes) {
  const Mesh mesh = UvEllipsoid({5, 5, 3}, {4, 4, 2}, 12, 16);
  auto bytes = EncodeTileDraco(mesh, {0, 0, 0}, {10, 10, 6});
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  std::mt19937 rng(12345);
  int failures = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    std::string mutated = *bytes;
    const int changes = 1 + static_cast<int>(rng() % 4);
    for (int c = 0; c < changes; ++c) {
      mutated[rng() % mutated.size()] = static_cast<char>(rng());
    }
    auto decoded = DecodeTileDraco(mutated);
    if (!decoded.ok()) {
      EXPECT_EQ(decoded.status().code(), absl::StatusCode::kDataLoss);
      ++failures;
      continue;
    }
    // Draco has no checksum, so some mutations decode; what comes out must be a usable mesh.
    for (const auto& f : decoded->faces) {
      for (uint32_t i : f) ASSERT_LT(i, decoded->vertices.size());
    }
    for (const auto& v : decoded->vertices) {
      for (float c : v) ASSERT_TRUE(std::isfinite(c));
    }
  }
  EXPECT_GT(failures, 0);
}

}  // namespace
}  // namespace rim::codec
