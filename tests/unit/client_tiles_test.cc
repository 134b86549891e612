// Client-side tile handling: Draco tiles decoded and welded back into one seamless mesh.
#include <cmath>
#include <map>
#include <utility>
#include <vector>

#include "client/tiles.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "proto/codec/mesh_codec.h"

namespace rim {
namespace {

using ::testing::HasSubstr;

constexpr int kColumns = 40;  // along x, split in two tiles at column 20
constexpr int kRows = 16;
constexpr double kX0 = 100.37, kY0 = -20.11;  // off the origin, so quantisation grids differ

// A wavy height field over [kX0, kX0 + 2] x [kY0, kY0 + 0.8], columns [c0, c1] only. Both tiles
// compute the shared column c = 20 from the same formula, as the server's mesher does.
Mesh HeightField(int c0, int c1) {
  Mesh m;
  for (int c = c0; c <= c1; ++c) {
    for (int r = 0; r <= kRows; ++r) {
      const double x = kX0 + 2.0 * c / kColumns, y = kY0 + 0.05 * r;
      m.vertices.push_back({float(x), float(y), float(0.3 + 0.1 * std::sin(3 * x + 2 * y))});
    }
  }
  const uint32_t stride = kRows + 1;
  for (int c = 0; c < c1 - c0; ++c) {
    for (int r = 0; r < kRows; ++r) {
      const uint32_t a = c * stride + r, b = a + stride;
      m.faces.push_back({a, b, b + 1});
      m.faces.push_back({a, b + 1, a + 1});
    }
  }
  return m;
}

DecodedTile EncodeAndDecode(const Mesh& mesh, int key_x, double x_min, double x_max) {
  auto draco = codec::EncodeTileDraco(mesh, {x_min, kY0 - 0.1, 0.0}, {x_max, kY0 + 0.9, 0.6});
  EXPECT_TRUE(draco.ok()) << draco.status();
  rim::v1::MeshTile tile;
  tile.set_key_x(key_x);
  tile.set_version(3);
  tile.set_draco(draco.value_or(""));
  tile.set_face_count(uint32_t(mesh.faces.size()));
  auto decoded = DecodeTile(tile);
  EXPECT_TRUE(decoded.ok()) << decoded.status();
  return decoded.ok() ? std::move(*decoded) : DecodedTile();
}

// Edges used by exactly one face: the mesh's open boundary (a seam adds the edges on both sides).
int BoundaryEdges(const Mesh& m) {
  std::map<std::pair<uint32_t, uint32_t>, int> uses;
  for (const auto& f : m.faces) {
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = f[k], b = f[(k + 1) % 3];
      ++uses[{std::min(a, b), std::max(a, b)}];
    }
  }
  int boundary = 0;
  for (const auto& [edge, n] : uses) boundary += n == 1;
  return boundary;
}

TEST(ClientTilesTest, NeighbouringTilesMergeWithoutSeams) {
  const DecodedTile left = EncodeAndDecode(HeightField(0, 20), 0, kX0, kX0 + 1.0);
  const DecodedTile right = EncodeAndDecode(HeightField(20, kColumns), 1, kX0 + 1.0, kX0 + 2.0);
  ASSERT_EQ(left.mesh.faces.size(), 2u * 20 * kRows);
  const Mesh merged = MergeTiles({left, right});
  EXPECT_EQ(merged.vertices.size(), size_t(kColumns + 1) * (kRows + 1));
  EXPECT_EQ(merged.faces.size(), 2u * kColumns * kRows);
  // One open rim around the whole field: no seam down the middle.
  EXPECT_EQ(BoundaryEdges(merged), 2 * (kColumns + kRows));

  // Without a tolerance the quantised copies of the shared column stay apart: the seam is real.
  const Mesh exact = MergeTiles({left, right}, 0.0);
  EXPECT_GT(exact.vertices.size(), merged.vertices.size());
  EXPECT_GT(BoundaryEdges(exact), 2 * (kColumns + kRows));
}

TEST(ClientTilesTest, WeldMergesWithinToleranceAcrossGridCells) {
  Mesh m;
  // 0.0019 and 0.0021 lie in different 2 mm cells but 0.2 mm apart; 0.0100 is 8 mm away.
  m.vertices = {{0.0019f, 0.f, 0.f}, {0.0021f, 0.f, 0.f}, {0.0100f, 0.f, 0.f}, {0.f, 1.f, 0.f}};
  m.faces = {{0, 2, 3}, {1, 2, 3}, {0, 1, 3}};
  const Mesh welded = WeldVertices(m, 0.002);
  ASSERT_EQ(welded.vertices.size(), 3u);
  EXPECT_EQ(welded.vertices[0][0], 0.0019f);  // first occurrence kept
  // Faces 0 and 1 became the same triangle (kept twice, as in the input); face 2 collapsed.
  ASSERT_EQ(welded.faces.size(), 2u);
  EXPECT_EQ(welded.faces[0], (std::array<uint32_t, 3>{0, 1, 2}));
  EXPECT_EQ(welded.faces[1], (std::array<uint32_t, 3>{0, 1, 2}));

  const Mesh tight = WeldVertices(m, 0.0001);
  EXPECT_EQ(tight.vertices.size(), 4u);
  EXPECT_EQ(tight.faces.size(), 3u);
}

TEST(ClientTilesTest, DamagedPayloadNamesTheTile) {
  rim::v1::MeshTile tile;
  tile.set_key_x(4);
  tile.set_key_y(-2);
  tile.set_key_z(0);
  tile.set_version(9);
  tile.set_draco("DRACO but not really a mesh");
  auto decoded = DecodeTile(tile);
  EXPECT_EQ(decoded.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(decoded.status().message(), HasSubstr("tile (4,-2,0) version 9"));
}

TEST(ClientTilesTest, DecodedTileKeepsMetadata) {
  DecodedTile t = EncodeAndDecode(HeightField(0, 20), 7, kX0, kX0 + 1.0);
  EXPECT_EQ(t.key, (std::array<int32_t, 3>{7, 0, 0}));
  EXPECT_EQ(t.version, 3u);
  EXPECT_FALSE(t.draco.empty());
  EXPECT_EQ(t.mesh.vertices.size(), 21u * (kRows + 1));
}

}  // namespace
}  // namespace rim
