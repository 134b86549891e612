#include "rim/io/mesh_io.h"

#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

namespace rim {
namespace {

std::string TempPath(const std::string& name) {
  return ::testing::TempDir() + "/rim_mesh_io_" + name;
}

void WriteFile(const std::string& path, const std::string& contents) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << contents;
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

Mesh RandomMesh(int num_vertices, int num_faces, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> coord(-100.0f, 100.0f);
  std::uniform_int_distribution<uint32_t> index(0, num_vertices - 1);
  Mesh mesh;
  for (int i = 0; i < num_vertices; ++i)
    mesh.vertices.push_back({coord(rng), coord(rng), coord(rng)});
  // Values that a text round trip or a sloppy conversion would disturb.
  mesh.vertices[0] = {-0.0f, std::numeric_limits<float>::denorm_min(),
                      std::numeric_limits<float>::max()};
  mesh.vertices[1] = {0.1f, 1.0f / 3.0f, -std::numeric_limits<float>::epsilon()};
  for (int i = 0; i < num_faces; ++i) mesh.faces.push_back({index(rng), index(rng), index(rng)});
  return mesh;
}

TEST(MeshIoTest, BinaryRoundTripIsBitExact) {
  const Mesh mesh = RandomMesh(500, 900, 1);
  const std::string path = TempPath("roundtrip.ply");
  ASSERT_TRUE(WriteMeshPly(path, mesh).ok());
  const auto read = ReadMeshPly(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->vertices.size(), mesh.vertices.size());
  EXPECT_EQ(0, std::memcmp(read->vertices.data(), mesh.vertices.data(), mesh.vertices.size() * 12));
  EXPECT_EQ(read->faces, mesh.faces);

  const std::string bytes = ReadFile(path);
  EXPECT_EQ(bytes.rfind("ply\nformat binary_little_endian 1.0\n", 0), 0u);
  const size_t header_end = bytes.find("end_header\n") + std::strlen("end_header\n");
  EXPECT_EQ(bytes.size() - header_end, 500u * 12 + 900u * 13);
}

TEST(MeshIoTest, EmptyMeshRoundTrips) {
  const std::string path = TempPath("empty.ply");
  ASSERT_TRUE(WriteMeshPly(path, Mesh()).ok());
  const auto read = ReadMeshPly(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_TRUE(read->vertices.empty());
  EXPECT_TRUE(read->faces.empty());
}

TEST(MeshIoTest, ReadsAsciiWithShuffledAndExtraProperties) {
  const std::string path = TempPath("ascii.ply");
  WriteFile(path,
            "ply\r\n"
            "format ascii 1.0\r\n"
            "comment properties deliberately out of order\r\n"
            "element vertex 5\r\n"
            "property uchar red\r\n"
            "property float z\r\n"
            "property double confidence\r\n"
            "property float x\r\n"
            "property list uchar int neighbours\r\n"
            "property short y\r\n"
            "element face 3\r\n"
            "property int flags\r\n"
            "property list uchar uint vertex_indices\r\n"
            "element edge 1\r\n"
            "property int vertex1\r\n"
            "property int vertex2\r\n"
            "end_header\r\n"
            "255 0.5 0.25 1.5 2 7 8 -3\r\n"
            "0 1e-3 1 2.25 0 4\r\n"
            "1 -7 0.5 0.1 3 1 2 3 5\n"
            "2 0 0 0 0 0\n"
            "3 1 0 1 1 9 9\n"
            "0 3 0 1 2\n"
            "1 4 1 2 3 4\n"
            "2 3 4 3 2\n"
            "0 1\n");
  const auto read = ReadMeshPly(path);
  ASSERT_TRUE(read.ok()) << read.status();
  const std::vector<std::array<float, 3>> expected_vertices = {{1.5f, -3.0f, 0.5f},
                                                               {2.25f, 4.0f, 1e-3f},
                                                               {0.1f, 5.0f, -7.0f},
                                                               {0.0f, 0.0f, 0.0f},
                                                               {1.0f, 9.0f, 1.0f}};
  EXPECT_EQ(read->vertices, expected_vertices);
  const std::vector<std::array<uint32_t, 3>> expected_faces = {
      {0, 1, 2}, {1, 2, 3}, {1, 3, 4}, {4, 3, 2}};
  EXPECT_EQ(read->faces, expected_faces);
}

void AppendLE(uint64_t v, int bytes, std::string* out) {
  for (int i = 0; i < bytes; ++i) out->push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}

TEST(MeshIoTest, ReadsBinaryWithOtherTypes) {
  std::string data =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\n"
      "property ushort quality\nproperty double y\nproperty double z\n"
      "element face 1\nproperty list int int vertex_indices\nproperty float weight\nend_header\n";
  const double coords[3][3] = {{0.5, 1.0, -2.0}, {3.0, 0.25, 7.0}, {-1.0, 0.0, 8.5}};
  for (const auto& c : coords) {
    uint64_t bits;
    std::memcpy(&bits, &c[0], 8);
    AppendLE(bits, 8, &data);
    AppendLE(0xBEEF, 2, &data);
    std::memcpy(&bits, &c[1], 8);
    AppendLE(bits, 8, &data);
    std::memcpy(&bits, &c[2], 8);
    AppendLE(bits, 8, &data);
  }
  AppendLE(3, 4, &data);
  for (uint32_t i : {2u, 0u, 1u}) AppendLE(i, 4, &data);
  AppendLE(0x3F800000, 4, &data);
  const std::string path = TempPath("binary_types.ply");
  WriteFile(path, data);
  const auto read = ReadMeshPly(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->vertices.size(), 3u);
  EXPECT_EQ(read->vertices[1], (std::array<float, 3>{3.0f, 0.25f, 7.0f}));
  ASSERT_EQ(read->faces.size(), 1u);
  EXPECT_EQ(read->faces[0], (std::array<uint32_t, 3>{2, 0, 1}));
}

TEST(MeshIoTest, TruncatedBinaryFileIsAnErrorNamingTheFile) {
  const std::string path = TempPath("truncated.ply");
  ASSERT_TRUE(WriteMeshPly(path, RandomMesh(20, 30, 2)).ok());
  std::string bytes = ReadFile(path);
  bytes.resize(bytes.size() - 5);
  WriteFile(path, bytes);
  const auto read = ReadMeshPly(path);
  ASSERT_FALSE(read.ok());
  EXPECT_NE(read.status().message().find(path), std::string::npos) << read.status();
  EXPECT_NE(read.status().message().find("truncated"), std::string::npos) << read.status();
}

TEST(MeshIoTest, TruncatedAsciiFileIsAnError) {
  const std::string path = TempPath("truncated_ascii.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n3 0 1\n");
  const auto read = ReadMeshPly(path);
  ASSERT_FALSE(read.ok());
  EXPECT_NE(read.status().message().find(path), std::string::npos) << read.status();
}

TEST(MeshIoTest, OutOfRangeIndexIsAnErrorNamingTheFile) {
  const std::string path = TempPath("bad_index.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n");
  const auto read = ReadMeshPly(path);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_NE(read.status().message().find(path), std::string::npos) << read.status();

  Mesh bad;
  bad.vertices = {{0, 0, 0}};
  bad.faces = {{0, 0, 1}};
  const absl::Status write = WriteMeshPly(TempPath("bad_write.ply"), bad);
  EXPECT_FALSE(write.ok());
}

TEST(MeshIoTest, MissingFileAndBadHeaderAreErrorsNamingTheFile) {
  const std::string missing = TempPath("does_not_exist.ply");
  const auto read = ReadMeshPly(missing);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(read.status().message().find(missing), std::string::npos);

  const std::string bad = TempPath("bad_header.ply");
  for (const std::string& contents :
       {std::string("not a ply\n"), std::string("ply\nformat ascii 1.0\nelement vertex 1\n"),
        std::string("ply\nformat ascii 1.0\nproperty float x\nend_header\n"),
        std::string(
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n")}) {
    WriteFile(bad, contents);
    const auto r = ReadMeshPly(bad);
    ASSERT_FALSE(r.ok()) << contents;
    EXPECT_NE(r.status().message().find(bad), std::string::npos) << r.status();
  }
}

TEST(MeshIoTest, AppendMeshOffsetsIndices) {
  Mesh a, b;
  a.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  a.faces = {{0, 1, 2}};
  b.vertices = {{5, 5, 5}, {6, 5, 5}, {5, 6, 5}, {5, 5, 6}};
  b.faces = {{0, 1, 2}, {0, 2, 3}};
  AppendMesh(b, &a);
  ASSERT_EQ(a.vertices.size(), 7u);
  EXPECT_EQ(a.vertices[3], (std::array<float, 3>{5, 5, 5}));
  const std::vector<std::array<uint32_t, 3>> expected = {{0, 1, 2}, {3, 4, 5}, {3, 5, 6}};
  EXPECT_EQ(a.faces, expected);
}

TEST(MeshIoTest, WeldMergesOnlyIdenticalPositions) {
  Mesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0},     {0, 1, 0},
                {1, 0, 0}, {-0.0f, 0, 0}, {std::nextafter(1.0f, 2.0f), 0, 0}};
  m.faces = {{0, 1, 2}, {3, 2, 5}, {4, 3, 0}};
  const Mesh w = WeldIdenticalVertices(m);
  ASSERT_EQ(w.vertices.size(), 4u);  // 3 merges into 1, -0 into +0; the nextafter value stays.
  EXPECT_EQ(w.vertices[3][0], std::nextafter(1.0f, 2.0f));
  // The last face collapses to (0, 1, 0) and is dropped.
  const std::vector<std::array<uint32_t, 3>> expected = {{0, 1, 2}, {1, 2, 3}};
  EXPECT_EQ(w.faces, expected);
}

}  // namespace
}  // namespace rim
