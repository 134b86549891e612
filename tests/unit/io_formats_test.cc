// Round trips and error messages of the single-file readers and writers in core/rim/io.
#include <stdlib.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "rim/io/depth.h"
#include "rim/io/file_util.h"
#include "rim/io/json.h"
#include "rim/io/kitti.h"
#include "rim/io/lzf.h"
#include "rim/io/pcd.h"
#include "rim/io/ply_points.h"
#include "rim/io/png_io.h"
#include "rim/io/pose_file.h"
#include "support/temp_dir.h"

namespace rim::io {
namespace {

using ::testing::HasSubstr;

std::string TempDir() { return rim::testing_support::MakeTempDir("rim_io_formats"); }

void WriteRaw(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string ReadRaw(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Random points plus values that a lossy text or type conversion would disturb.
PointCloud TestCloud(int n, bool with_intensity, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> coord(-80.0f, 80.0f);
  PointCloud cloud;
  for (int i = 0; i < n; ++i) {
    cloud.points.emplace_back(coord(rng), coord(rng), coord(rng));
    if (with_intensity) cloud.intensity.push_back(coord(rng) + 80.0f);
  }
  cloud.points[0] =
      Vec3f(-0.0f, std::numeric_limits<float>::denorm_min(), std::numeric_limits<float>::max());
  cloud.points[1] = Vec3f(0.1f, 1.0f / 3.0f, -std::numeric_limits<float>::epsilon());
  return cloud;
}

void ExpectBitExact(const PointCloud& a, const PointCloud& b) {
  ASSERT_EQ(a.points.size(), b.points.size());
  EXPECT_EQ(0, std::memcmp(a.points.data(), b.points.data(), a.points.size() * sizeof(Vec3f)));
  ASSERT_EQ(a.intensity.size(), b.intensity.size());
  if (a.intensity.empty()) return;
  EXPECT_EQ(0, std::memcmp(a.intensity.data(), b.intensity.data(), a.intensity.size() * 4));
}

TEST(IoFormatsTest, KittiBinRoundTripIsBitExact) {
  const std::string path = TempDir() + "/000000.bin";
  const PointCloud cloud = TestCloud(1000, true, 1);
  ASSERT_TRUE(WriteKittiBin(path, cloud).ok());
  EXPECT_EQ(ReadRaw(path).size(), 16000u);
  auto read = ReadKittiBin(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ExpectBitExact(cloud, *read);
}

TEST(IoFormatsTest, KittiBinWithoutIntensityWritesZeros) {
  const std::string path = TempDir() + "/a.bin";
  const PointCloud cloud = TestCloud(10, false, 2);
  ASSERT_TRUE(WriteKittiBin(path, cloud).ok());
  auto read = ReadKittiBin(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->intensity, std::vector<float>(10, 0.0f));
}

TEST(IoFormatsTest, TruncatedKittiBinNamesFile) {
  const std::string path = TempDir() + "/000007.bin";
  WriteRaw(path, std::string(16 * 5 + 7, '\0'));
  auto read = ReadKittiBin(path);
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("000007.bin"));
  EXPECT_THAT(read.status().message(), HasSubstr("not a multiple of 16"));
}

TEST(IoFormatsTest, PcdRoundTripIsBitExactInEveryMode) {
  const std::string dir = TempDir();
  for (bool with_intensity : {false, true}) {
    for (PcdDataMode mode :
         {PcdDataMode::kAscii, PcdDataMode::kBinary, PcdDataMode::kBinaryCompressed}) {
      SCOPED_TRACE(static_cast<int>(mode));
      const std::string path = dir + "/cloud.pcd";
      const PointCloud cloud = TestCloud(2000, with_intensity, 3);
      ASSERT_TRUE(WritePcd(path, cloud, mode).ok());
      auto read = ReadPcd(path);
      ASSERT_TRUE(read.ok()) << read.status();
      ExpectBitExact(cloud, *read);
    }
  }
}

TEST(IoFormatsTest, PcdReadsAnyFieldOrderTypesAndDropsNaN) {
  // Fields in an unusual order with an 8-byte x, padding and a 2-count field; NaN point dropped.
  const std::string path = TempDir() + "/odd.pcd";
  std::string header =
      "# comment\nVERSION .7\nFIELDS rgb z _ x y intensity\nSIZE 4 4 1 8 4 2\n"
      "TYPE U F U F F U\nCOUNT 1 1 2 1 1 1\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
      "POINTS 3\nDATA binary\n";
  std::string body;
  auto put = [&body](const void* p, size_t n) { body.append(static_cast<const char*>(p), n); };
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float zs[3] = {3.0f, nan, -1.5f};
  const double xs[3] = {1.25, 2.0, 0.1};
  const float ys[3] = {2.0f, 5.0f, 7.0f};
  const uint16_t is[3] = {100, 200, 300};
  for (int i = 0; i < 3; ++i) {
    const uint32_t rgb = 0xFFFFFF;
    const uint8_t pad[2] = {9, 9};
    put(&rgb, 4), put(&zs[i], 4), put(pad, 2), put(&xs[i], 8), put(&ys[i], 4), put(&is[i], 2);
  }
  WriteRaw(path, header + body);
  auto read = ReadPcd(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->points.size(), 2u);
  EXPECT_EQ(read->points[0], Vec3f(1.25f, 2.0f, 3.0f));
  EXPECT_EQ(read->points[1], Vec3f(static_cast<float>(0.1), 7.0f, -1.5f));
  EXPECT_EQ(read->intensity, std::vector<float>({100.0f, 300.0f}));

  // The same in ascii, with "nan" written out.
  WriteRaw(path,
           "VERSION 0.7\nFIELDS intensity y x z\nSIZE 4 4 4 4\nTYPE F F F F\nWIDTH 2\nHEIGHT 1\n"
           "POINTS 2\nDATA ascii\n7 nan 1 2\n\n8 0.5 0.25 -3\n");
  read = ReadPcd(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->points.size(), 1u);
  EXPECT_EQ(read->points[0], Vec3f(0.25f, 0.5f, -3.0f));
}

TEST(IoFormatsTest, PcdWithMorePointsThanDataFails) {
  const std::string dir = TempDir();
  for (PcdDataMode mode :
       {PcdDataMode::kAscii, PcdDataMode::kBinary, PcdDataMode::kBinaryCompressed}) {
    const std::string path = dir + "/short.pcd";
    ASSERT_TRUE(WritePcd(path, TestCloud(100, true, 4), mode).ok());
    std::string bytes = ReadRaw(path);
    const size_t at = bytes.find("POINTS 100");
    ASSERT_NE(at, std::string::npos);
    bytes.replace(at, 10, "POINTS 101");
    bytes.replace(bytes.find("WIDTH 100"), 9, "WIDTH 101");
    WriteRaw(path, bytes);
    auto read = ReadPcd(path);
    ASSERT_FALSE(read.ok());
    EXPECT_THAT(read.status().message(), HasSubstr("short.pcd"));
    EXPECT_THAT(read.status().message(), HasSubstr("101"));
  }
}

TEST(IoFormatsTest, PcdHeaderErrorsNameLine) {
  const std::string path = TempDir() + "/bad.pcd";
  WriteRaw(path,
           "VERSION 0.7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nDATA ascii\n");
  auto read = ReadPcd(path);
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("bad.pcd"));
  EXPECT_THAT(read.status().message(), HasSubstr("SIZE"));
  WriteRaw(path,
           "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 1\n"
           "POINTS 3\nDATA binary\n");
  read = ReadPcd(path);
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("WIDTH * HEIGHT"));
  WriteRaw(path,
           "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\n"
           "POINTS 1\nDATA ascii\n1 2\n");
  read = ReadPcd(path);
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("bad.pcd:9"));
}

TEST(IoFormatsTest, PlyRoundTripIsBitExact) {
  const std::string dir = TempDir();
  for (bool with_intensity : {false, true}) {
    for (PlyFormat format : {PlyFormat::kAscii, PlyFormat::kBinary}) {
      const std::string path = dir + "/frame.ply";
      const PointCloud cloud = TestCloud(1500, with_intensity, 5);
      ASSERT_TRUE(WritePlyPoints(path, cloud, format).ok());
      auto read = ReadPlyPoints(path);
      ASSERT_TRUE(read.ok()) << read.status();
      ExpectBitExact(cloud, *read);
    }
  }
}

TEST(IoFormatsTest, PlyReadsDoublesAnyOrderAndSkipsOtherElements) {
  const std::string path = TempDir() + "/d.ply";
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\ncomment made by hand\nelement camera 1\n"
      "property list uchar float params\nelement vertex 2\nproperty uchar r\n"
      "property double z\nproperty double y\nproperty double x\nproperty float intensity\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  auto put = [&bytes](const auto& v) {
    bytes.append(reinterpret_cast<const char*>(&v), sizeof(v));
  };
  put(uint8_t{2}), put(1.0f), put(2.0f);  // camera: a list of two floats
  put(uint8_t{7}), put(3.0), put(2.0), put(1.0), put(0.5f);
  put(uint8_t{7}), put(-3.0), put(-2.0), put(0.1), put(0.25f);
  put(uint8_t{3}), put(0), put(1), put(1);
  WriteRaw(path, bytes);
  auto read = ReadPlyPoints(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->points.size(), 2u);
  EXPECT_EQ(read->points[0], Vec3f(1, 2, 3));
  EXPECT_EQ(read->points[1], Vec3f(static_cast<float>(0.1), -2, -3));
  EXPECT_EQ(read->intensity, std::vector<float>({0.5f, 0.25f}));

  WriteRaw(path,
           "ply\nformat ascii 1.0\nelement vertex 2\nproperty float y\nproperty int x\n"
           "property float z\nend_header\n1.5 2 3\n-1 -2 -3\n");
  read = ReadPlyPoints(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->points.size(), 2u);
  EXPECT_EQ(read->points[0], Vec3f(2, 1.5f, 3));
  EXPECT_TRUE(read->intensity.empty());
}

TEST(IoFormatsTest, BadPlyHeaderNamesFile) {
  const std::string path = TempDir() + "/broken.ply";
  WriteRaw(path, "ply\nformat ascii 1.0\nelement vertex 2\nproperty flot x\nend_header\n");
  auto read = ReadPlyPoints(path);
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("broken.ply:4"));
  WriteRaw(path, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n2\n");
  read = ReadPlyPoints(path);
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("x, y, z"));
  WriteRaw(path,
           "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\n"
           "property float x\nproperty float y\nproperty float z\nend_header\n0123");
  read = ReadPlyPoints(path);
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("1000000000"));
}

TEST(IoFormatsTest, LzfRoundTripsAndRejectsBadStreams) {
  std::mt19937 rng(6);
  for (size_t size : {0, 1, 2, 3, 31, 32, 33, 1000, 100000}) {
    for (int kind = 0; kind < 3; ++kind) {
      std::string input(size, '\0');
      for (size_t i = 0; i < size; ++i) {
        input[i] = kind == 0 ? 0 : kind == 1 ? static_cast<char>(rng()) : "abcab"[i % 5];
      }
      const std::string packed = LzfCompress(input);
      if (kind == 0 && size >= 1000) EXPECT_LT(packed.size() * 50, size);
      EXPECT_LE(packed.size(), size + size / 32 + 1);
      auto unpacked = LzfDecompress(packed, size, "test");
      ASSERT_TRUE(unpacked.ok()) << unpacked.status();
      EXPECT_EQ(*unpacked, input);
    }
  }
  // A hand-made stream: literal "ab", then a back-reference of length 5 at distance 2.
  const std::string stream = std::string(
                                 "\x01"
                                 "ab",
                                 3) +
                             std::string("\x60\x01", 2);
  auto out = LzfDecompress(stream, 7, "hand");
  ASSERT_TRUE(out.ok()) << out.status();
  EXPECT_EQ(*out, "abababa");
  EXPECT_FALSE(LzfDecompress(stream, 8, "hand").ok());
  EXPECT_FALSE(LzfDecompress(std::string("\x20\x05", 2), 3, "hand").ok());  // before start
  EXPECT_FALSE(LzfDecompress(std::string("\x05"
                                         "ab",
                                         3),
                             6, "hand")
                   .ok());  // truncated
}

TEST(IoFormatsTest, PngRoundTripAndFormatChecks) {
  const std::string dir = TempDir();
  std::vector<uint16_t> pixels(37 * 23);
  for (size_t i = 0; i < pixels.size(); ++i) pixels[i] = static_cast<uint16_t>(i * 2654435761u);
  ASSERT_TRUE(WritePng16(dir + "/d.png", 37, 23, pixels.data()).ok());
  auto image = ReadPng16(dir + "/d.png");
  ASSERT_TRUE(image.ok()) << image.status();
  EXPECT_EQ(image->width, 37);
  EXPECT_EQ(image->height, 23);
  EXPECT_EQ(image->pixels, pixels);

  std::vector<uint8_t> rgb(5 * 4 * 3, 200);
  ASSERT_TRUE(WritePngRgb8(dir + "/c.png", 5, 4, rgb.data()).ok());
  image = ReadPng16(dir + "/c.png");
  ASSERT_FALSE(image.ok());
  EXPECT_THAT(image.status().message(), HasSubstr("c.png"));
  EXPECT_THAT(image.status().message(), HasSubstr("16-bit grayscale"));

  const std::string bytes = ReadRaw(dir + "/d.png");
  WriteRaw(dir + "/t.png", bytes.substr(0, bytes.size() / 2));
  image = ReadPng16(dir + "/t.png");
  ASSERT_FALSE(image.ok());
  EXPECT_THAT(image.status().message(), HasSubstr("t.png"));
}

uint32_t Crc32(const std::string& bytes) {
  uint32_t crc = 0xFFFFFFFFu;
  for (unsigned char c : bytes) {
    crc ^= c;
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

void PutBigEndian32(uint32_t v, std::string* s, size_t at) {
  for (int i = 0; i < 4; ++i) (*s)[at + i] = static_cast<char>(v >> (24 - 8 * i));
}

TEST(IoFormatsTest, PngHeaderClaimingAHugeImageFailsWithoutAllocatingIt) {
  std::vector<uint16_t> pixels(4 * 3, 1000);
  auto png = EncodePng16(4, 3, pixels.data());
  ASSERT_TRUE(png.ok()) << png.status();
  // IHDR: length at 8, "IHDR" at 12, width at 16, height at 20, CRC over type+data at 29.
  for (uint32_t side : {10000u, 30000u, 2000000u}) {
    std::string bytes = *png;
    PutBigEndian32(side, &bytes, 16);
    PutBigEndian32(side, &bytes, 20);
    PutBigEndian32(Crc32(bytes.substr(12, 17)), &bytes, 29);
    auto image = DecodePng16(bytes, "huge.png");
    ASSERT_FALSE(image.ok());
    EXPECT_THAT(image.status().message(), HasSubstr("huge.png"));
  }
}

TEST(IoFormatsTest, PosesRoundTripAndValidation) {
  const std::string dir = TempDir();
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < 5; ++i) {
    Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
    p.linear() = Eigen::AngleAxisd(0.3 * i + 0.1, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
    p.translation() = Eigen::Vector3d(i, -2.5 * i, 1e-3 * i);
    poses.push_back(p);
  }
  ASSERT_TRUE(WritePosesFile(dir + "/poses.txt", poses).ok());
  auto read = ReadPoses3x4File(dir + "/poses.txt");
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_TRUE((*read)[i].matrix().isApprox(poses[i].matrix(), 1e-14));
  }

  const std::string ok_line = "1 0 0 0 0 1 0 0 0 0 1 0\n";
  WriteRaw(dir + "/nan.txt", ok_line + ok_line + "1 0 0 nan 0 1 0 0 0 0 1 0\n");
  read = ReadPoses3x4File(dir + "/nan.txt");
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("nan.txt:3"));
  WriteRaw(dir + "/inf.txt", ok_line + "1 0 0 0 0 1 0 0 0 0 1 -inf\n");
  read = ReadPoses3x4File(dir + "/inf.txt");
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("inf.txt:2"));
  WriteRaw(dir + "/scaled.txt", ok_line + "\n2 0 0 0 0 2 0 0 0 0 2 0\n");
  read = ReadPoses3x4File(dir + "/scaled.txt");
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("scaled.txt:3"));
  EXPECT_THAT(read.status().message(), HasSubstr("not rigid"));
  WriteRaw(dir + "/mirror.txt", "-1 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_FALSE(ReadPoses3x4File(dir + "/mirror.txt").ok());
  WriteRaw(dir + "/short.txt", "1 0 0 0 0 1 0 0 0 0 1\n");
  read = ReadPoses3x4File(dir + "/short.txt");
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(read.status().message(), HasSubstr("short.txt:1: expected 12 numbers"));
  // Rounded rotations (KITTI prints ~7 digits) are accepted and made exactly orthonormal.
  WriteRaw(dir + "/rounded.txt",
           "0.9999970 0.0014000 0.0019590 1 -0.0013980 0.9999990 "
           "-0.0009210 2 -0.0019600 0.0009190 0.9999980 3\n");
  read = ReadPoses3x4File(dir + "/rounded.txt");
  ASSERT_TRUE(read.ok()) << read.status();
  const Eigen::Matrix3d R = (*read)[0].linear();
  EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 1e-14);
}

TEST(IoFormatsTest, KittiPoseConversionMatchesHandComputation) {
  const std::string dir = TempDir();
  // Tr: the usual KITTI axes swap (LiDAR x forward, y left, z up -> camera z forward, x right,
  // y down) plus an offset.
  Eigen::Isometry3d tr = Eigen::Isometry3d::Identity();
  tr.linear() << 0, -1, 0, 0, 0, -1, 1, 0, 0;
  tr.translation() = Eigen::Vector3d(0.1, -0.2, 0.3);
  ASSERT_TRUE(WriteCalibFile(dir + "/calib.txt", tr).ok());
  auto read_tr = ReadCalibFile(dir + "/calib.txt");
  ASSERT_TRUE(read_tr.ok()) << read_tr.status();
  EXPECT_TRUE(read_tr->matrix().isApprox(tr.matrix(), 1e-15));

  // Camera moved 2 m forward along its z axis, no rotation.
  Eigen::Isometry3d cam = Eigen::Isometry3d::Identity();
  cam.translation() = Eigen::Vector3d(0, 0, 2);
  const auto lidar = CameraToLidarPoses({cam}, *read_tr);
  // By hand: Tr^-1 P Tr = [I | R^T t_P] with R = Tr's rotation, so the LiDAR moved 2 m along
  // its own x axis (camera z is LiDAR x).
  EXPECT_TRUE(lidar[0].linear().isApprox(Eigen::Matrix3d::Identity(), 1e-15));
  EXPECT_TRUE(lidar[0].translation().isApprox(Eigen::Vector3d(2, 0, 0), 1e-15));

  // A rotated camera: 90 degrees about camera y (down) is -90 degrees about LiDAR z (up).
  cam.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).matrix();
  const auto rotated = CameraToLidarPoses({cam}, *read_tr);
  const Eigen::Matrix3d expected_R =
      Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitZ()).matrix();
  EXPECT_TRUE(rotated[0].linear().isApprox(expected_R, 1e-12));
  const Eigen::Matrix4d full = tr.inverse().matrix() * cam.matrix() * tr.matrix();
  EXPECT_TRUE(rotated[0].matrix().isApprox(full, 1e-12));

  WriteRaw(dir + "/no_tr.txt", "P0: 1 0 0 0 0 1 0 0 0 0 1 0\n");
  auto missing = ReadCalibFile(dir + "/no_tr.txt");
  ASSERT_FALSE(missing.ok());
  EXPECT_THAT(missing.status().message(), HasSubstr("no_tr.txt"));
}

TEST(IoFormatsTest, DepthBackProjectionOfAPlane) {
  // A plane z = 2 - 0.5 x seen by a 64x48 camera; depth stored in mm.
  const CameraIntrinsics K{60.0, 62.0, 31.5, 23.5, 64, 48};
  Image16 depth;
  depth.width = 64;
  depth.height = 48;
  for (int v = 0; v < 48; ++v) {
    for (int u = 0; u < 64; ++u) {
      // Ray (a, b, 1) hits z = 2 - 0.5 a z  =>  z = 2 / (1 + 0.5 a).
      const double a = (u - K.cx) / K.fx;
      depth.pixels.push_back(static_cast<uint16_t>(std::lround(2000.0 / (1 + 0.5 * a))));
    }
  }
  depth.pixels[0] = 0;       // invalid
  depth.pixels[1] = 0xFFFF;  // invalid in 7-Scenes
  auto points = BackProjectDepth(depth, K, {1000.0, true});
  ASSERT_EQ(points.size(), 64u * 48 - 2);
  for (const Vec3f& p : points) EXPECT_NEAR(p.z() + 0.5 * p.x(), 2.0, 1e-3);
  // Pixel (2, 0) is the first point: x = (2 - cx) z / fx, y = (0 - cy) z / fy.
  const double z = depth.pixels[2] / 1000.0;
  EXPECT_NEAR(points[0].x(), (2 - K.cx) * z / K.fx, 1e-6);
  EXPECT_NEAR(points[0].y(), (0 - K.cy) * z / K.fy, 1e-6);
  // With 65535 valid (Replica), only the zero is skipped, and the scale applies.
  auto replica = BackProjectDepth(depth, K, {6553.5, false});
  ASSERT_EQ(replica.size(), 64u * 48 - 1);
  EXPECT_NEAR(replica[0].z(), 65535 / 6553.5, 1e-5);
}

TEST(IoFormatsTest, IntrinsicsAndCamParamsFiles) {
  const std::string dir = TempDir();
  WriteRaw(dir + "/K.txt", "585\t0\t320\n0 586 240.5\n0 0 1\n");
  auto K = ReadIntrinsicsMatrixFile(dir + "/K.txt");
  ASSERT_TRUE(K.ok()) << K.status();
  EXPECT_EQ(K->fx, 585);
  EXPECT_EQ(K->fy, 586);
  EXPECT_EQ(K->cy, 240.5);
  WriteRaw(dir + "/K8.txt", "585 0 320\n0 586 240\n0 0\n");
  K = ReadIntrinsicsMatrixFile(dir + "/K8.txt");
  ASSERT_FALSE(K.ok());
  EXPECT_THAT(K.status().message(), HasSubstr("K8.txt"));

  WriteRaw(dir + "/cam.json",
           "{\"camera\": {\"w\": 1200, \"h\": 680, \"fx\": 600.0, \"fy\": 600.0, \"cx\": 599.5,"
           " \"cy\": 339.5, \"scale\": 6553.5}, \"note\": [1, \"x\\u00e9\", null, true]}");
  auto cam = ReadReplicaCamParams(dir + "/cam.json");
  ASSERT_TRUE(cam.ok()) << cam.status();
  EXPECT_EQ(cam->intrinsics.width, 1200);
  EXPECT_EQ(cam->intrinsics.cy, 339.5);
  EXPECT_EQ(cam->scale, 6553.5);
  WriteRaw(dir + "/flat.json", "{\"w\": 8, \"h\": 6, \"fx\": 5, \"fy\": 5, \"cx\": 4, \"cy\": 3}");
  cam = ReadReplicaCamParams(dir + "/flat.json");
  ASSERT_FALSE(cam.ok());
  EXPECT_THAT(cam.status().message(), HasSubstr("flat.json"));
  EXPECT_THAT(cam.status().message(), HasSubstr("'scale'"));
  WriteRaw(dir + "/broken.json", "{\n\"camera\": {\"w\": 1200,,}}");
  cam = ReadReplicaCamParams(dir + "/broken.json");
  ASSERT_FALSE(cam.ok());
  EXPECT_THAT(cam.status().message(), HasSubstr("broken.json:2"));
}

TEST(IoFormatsTest, NaturalOrder) {
  EXPECT_TRUE(NaturalLess("frame2", "frame10"));
  EXPECT_FALSE(NaturalLess("frame10", "frame2"));
  EXPECT_TRUE(NaturalLess("000009.bin", "000010.bin"));
  EXPECT_TRUE(NaturalLess("a", "b"));
  EXPECT_FALSE(NaturalLess("a", "a"));
}

// --- JSON written (DumpJson, JsonNumber)
// -----------------------------------------------------------

TEST(JsonWriterTest, EscapesEveryControlCharacter) {
  // A path may hold any byte but NUL: quotes, backslashes, tabs, newlines, \x01, \x1f, DEL.
  std::string path = "/tmp/a\"b\\c\td\ne\rf";
  for (int c = 1; c < 0x20; ++c) path += char(c);
  path += "\x7f/g";
  const nlohmann::ordered_json value = {{"path", path}, {"list", {path, 1}}};
  for (int inline_depth : {0, 1, 2}) {
    const std::string text = DumpJson(value, inline_depth);
    for (char c : text) EXPECT_FALSE(static_cast<unsigned char>(c) < 0x20 && c != '\n') << text;
    absl::StatusOr<nlohmann::json> back = ParseJson(text, "dump.json");
    ASSERT_TRUE(back.ok()) << back.status() << "\n" << text;
    EXPECT_EQ((*back)["path"], path);
    EXPECT_EQ((*back)["list"][0], path);
  }
  // Bytes that are not UTF-8 become U+FFFD rather than an exception or invalid output.
  const std::string text = DumpJson({{"path", std::string("/tmp/\xff\xfe")}});
  EXPECT_TRUE(ParseJson(text, "dump.json").ok()) << text;
}

TEST(JsonWriterTest, Layout) {
  const nlohmann::ordered_json value = {{"b", 1},
                                        {"a", {{"x", 0.5}, {"y", nullptr}}},
                                        {"series", {1.5, 2.0, 3.25}},
                                        {"empty", nlohmann::ordered_json::object()},
                                        {"rows", {{{"k", 1}}, {{"k", 2}}}}};
  EXPECT_EQ(DumpJson(value),
            "{\n  \"b\": 1,\n  \"a\": {\"x\": 0.5, \"y\": null},\n  \"series\": [1.5, 2.0, 3.25],\n"
            "  \"empty\": {},\n  \"rows\": [{\"k\": 1}, {\"k\": 2}]\n}\n");
  EXPECT_EQ(DumpJson(value, 2),
            "{\n  \"b\": 1,\n  \"a\": {\n    \"x\": 0.5,\n    \"y\": null\n  },\n"
            "  \"series\": [1.5, 2.0, 3.25],\n  \"empty\": {},\n"
            "  \"rows\": [\n    {\"k\": 1},\n    {\"k\": 2}\n  ]\n}\n");
  EXPECT_EQ(DumpJson(nlohmann::ordered_json::array()), "[]\n");
  EXPECT_EQ(DumpJson(3), "3\n");
}

TEST(JsonWriterTest, NumbersRoundedOrNull) {
  EXPECT_EQ(JsonNumber(100.0, 3).dump(), "100.0");
  EXPECT_EQ(JsonNumber(2.999999, 4).dump(), "3.0");
  EXPECT_EQ(JsonNumber(0.123456789, 4).dump(), "0.1235");
  EXPECT_EQ(JsonNumber(-1.00049, 3).dump(), "-1.0");
  EXPECT_EQ(JsonNumber(12345.678, 1).dump(), "12345.7");
  EXPECT_EQ(JsonNumber(1e300, 4).dump(), "1e+300");
  EXPECT_TRUE(JsonNumber(std::nan(""), 3).is_null());
  EXPECT_TRUE(JsonNumber(std::numeric_limits<double>::infinity(), 3).is_null());
  EXPECT_TRUE(JsonNumber(-std::numeric_limits<double>::infinity(), 3).is_null());
}

}  // namespace
}  // namespace rim::io
