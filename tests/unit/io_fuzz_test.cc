// Fuzz-style robustness of every parser in core/rim/io: every truncated prefix of a small valid
// file and a few thousand random mutations of it must give OK or an error, never a crash, a hang
// or a huge allocation. Deterministic (fixed seeds), well under a few seconds in total.
#include <stdlib.h>

#include <chrono>
#include <fstream>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "gtest/gtest.h"
#include "rim/io/depth.h"
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

std::string TempDir() { return rim::testing_support::MakeTempDir("rim_io_fuzz"); }

void WriteRaw(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string ReadRaw(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// One random edit: overwrite bytes, insert digits (inflating header counts), delete or duplicate
// a range, or replace a byte with a structural character.
std::string Mutate(const std::string& input, std::mt19937* rng) {
  std::string s = input;
  auto pos = [&](size_t n) { return n == 0 ? size_t{0} : (*rng)() % n; };
  const int edits = 1 + (*rng)() % 3;
  for (int e = 0; e < edits; ++e) {
    switch ((*rng)() % 6) {
      case 0:
        if (!s.empty()) s[pos(s.size())] = static_cast<char>((*rng)());
        break;
      case 1:
        s.insert(pos(s.size() + 1), std::string(1 + (*rng)() % 12, '0' + (*rng)() % 10));
        break;
      case 2:
        if (!s.empty()) {
          const size_t at = pos(s.size());
          s.erase(at, 1 + pos(std::min<size_t>(64, s.size() - at)));
        }
        break;
      case 3:
        if (!s.empty()) {
          const size_t at = pos(s.size());
          const size_t len = 1 + pos(std::min<size_t>(64, s.size() - at));
          s.insert(pos(s.size() + 1), s.substr(at, len));
        }
        break;
      case 4:
        if (!s.empty()) s[pos(s.size())] = " \n\t-.e9"[(*rng)() % 7];
        break;
      default:
        if (!s.empty()) s[pos(s.size())] ^= static_cast<char>(1 << ((*rng)() % 8));
        break;
    }
  }
  return s;
}

// Runs `parse` on every prefix (all of them for files up to `max_prefixes` bytes, evenly spaced
// otherwise) and on `mutations` random mutations. Returns how many inputs parsed OK.
int Fuzz(const std::string& valid, int mutations, uint32_t seed,
         const std::function<absl::Status(const std::string&)>& parse, size_t max_prefixes = 4096) {
  int ok = 0;
  const absl::Status full = parse(valid);
  EXPECT_TRUE(full.ok()) << full;
  const size_t step = std::max<size_t>(1, valid.size() / max_prefixes);
  for (size_t len = 0; len < valid.size(); len += step) ok += parse(valid.substr(0, len)).ok();
  std::mt19937 rng(seed);
  for (int i = 0; i < mutations; ++i) ok += parse(Mutate(valid, &rng)).ok();
  return ok;
}

// A parser that only reads files: each input is written to `path` first.
std::function<absl::Status(const std::string&)> ViaFile(
    const std::string& path, std::function<absl::Status(const std::string&)> read) {
  return [path, read](const std::string& bytes) {
    WriteRaw(path, bytes);
    return read(path);
  };
}

PointCloud SmallCloud() {
  PointCloud cloud;
  for (int i = 0; i < 12; ++i) {
    cloud.points.emplace_back(0.37f * i, -1.5f * i, 100.0f / (i + 1));
    cloud.intensity.push_back(static_cast<float>(i % 3));
  }
  return cloud;
}

TEST(IoFuzzTest, Pcd) {
  const std::string dir = TempDir();
  for (PcdDataMode mode :
       {PcdDataMode::kAscii, PcdDataMode::kBinary, PcdDataMode::kBinaryCompressed}) {
    ASSERT_TRUE(WritePcd(dir + "/a.pcd", SmallCloud(), mode).ok());
    const std::string valid = ReadRaw(dir + "/a.pcd");
    Fuzz(valid, 3000, 11 + static_cast<int>(mode),
         [](const std::string& b) { return ParsePcd(b, "fuzz.pcd").status(); });
  }
}

TEST(IoFuzzTest, Ply) {
  const std::string dir = TempDir();
  for (PlyFormat format : {PlyFormat::kAscii, PlyFormat::kBinary}) {
    ASSERT_TRUE(WritePlyPoints(dir + "/a.ply", SmallCloud(), format).ok());
    std::string valid = ReadRaw(dir + "/a.ply");
    Fuzz(valid, 3000, 21 + static_cast<int>(format),
         [](const std::string& b) { return ParsePlyPoints(b, "fuzz.ply").status(); });
  }
  // Lists and an element before the vertex element, so list lengths get mutated too.
  std::string valid =
      "ply\nformat binary_little_endian 1.0\nelement camera 2\nproperty list uchar float p\n"
      "element vertex 3\nproperty double x\nproperty float y\nproperty int z\n"
      "property list int uchar extra\nend_header\n";
  auto put = [&valid](const auto& v) {
    valid.append(reinterpret_cast<const char*>(&v), sizeof(v));
  };
  put(uint8_t{1}), put(1.0f), put(uint8_t{0});
  for (int i = 0; i < 3; ++i)
    put(0.5 * i), put(1.5f), put(i), put(2), put(uint8_t{1}), put(uint8_t{2});
  Fuzz(valid, 3000, 23,
       [](const std::string& b) { return ParsePlyPoints(b, "fuzz.ply").status(); });
}

TEST(IoFuzzTest, Lzf) {
  std::string input;
  for (int i = 0; i < 600; ++i) input += static_cast<char>("abcabd\0\0\0xy"[i % 12] + i / 100);
  const std::string packed = LzfCompress(input);
  Fuzz(packed, 4000, 31,
       [&](const std::string& b) { return LzfDecompress(b, input.size(), "fuzz").status(); });
  // Huge claimed sizes are refused before allocating.
  EXPECT_FALSE(LzfDecompress(packed, size_t{1} << 40, "fuzz").ok());
}

TEST(IoFuzzTest, Png) {
  std::vector<uint16_t> pixels(9 * 7);
  for (size_t i = 0; i < pixels.size(); ++i) pixels[i] = static_cast<uint16_t>(i * 977);
  auto valid = EncodePng16(9, 7, pixels.data());
  ASSERT_TRUE(valid.ok()) << valid.status();
  Fuzz(*valid, 3000, 41, [](const std::string& b) { return DecodePng16(b, "fuzz.png").status(); });
}

TEST(IoFuzzTest, Json) {
  const std::string valid =
      "{\"camera\": {\"w\": 1200, \"h\": 680, \"fx\": 600.0, \"fy\": 600.0, \"cx\": 599.5,"
      " \"cy\": 339.5, \"scale\": 6553.5}, \"x\": [1, -2e3, true, false, null, \"a\\n\\u00e9\"]}";
  Fuzz(valid, 3000, 51, [](const std::string& b) { return ParseJson(b, "fuzz.json").status(); });
  // Deep nesting is refused, not recursed into.
  EXPECT_FALSE(ParseJson(std::string(100000, '['), "deep.json").ok());
}

TEST(IoFuzzTest, TextFiles) {
  const std::string dir = TempDir();
  std::vector<Eigen::Isometry3d> poses(4, Eigen::Isometry3d::Identity());
  for (int i = 0; i < 4; ++i) {
    poses[i].linear() = Eigen::AngleAxisd(0.4 * i, Eigen::Vector3d::UnitZ()).matrix();
    poses[i].translation() = Eigen::Vector3d(i, 2 * i, 0.5);
  }
  ASSERT_TRUE(WritePosesFile(dir + "/poses.txt", poses).ok());
  Fuzz(ReadRaw(dir + "/poses.txt"), 600, 61,
       ViaFile(dir + "/p.txt", [](const std::string& p) { return ReadPoses3x4File(p).status(); }),
       400);
  ASSERT_TRUE(WriteCalibFile(dir + "/calib.txt", poses[1]).ok());
  Fuzz(ReadRaw(dir + "/calib.txt"), 400, 62,
       ViaFile(dir + "/c.txt", [](const std::string& p) { return ReadCalibFile(p).status(); }),
       400);
  Fuzz("0.6 0 0.8 1\n0 1 0 2\n-0.8 0 0.6 3\n0 0 0 1\n", 400, 63,
       ViaFile(dir + "/f.txt", [](const std::string& p) { return ReadPose4x4File(p).status(); }));
  Fuzz("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n0 -1 0 1 1 0 0 2 0 0 1 3 0 0 0 1\n", 400, 64,
       ViaFile(dir + "/t.txt",
               [](const std::string& p) { return ReadPoses4x4LinesFile(p).status(); }));
  Fuzz("585 0 320\n0 585 240\n0 0 1\n", 400, 65, ViaFile(dir + "/k.txt", [](const std::string& p) {
         return ReadIntrinsicsMatrixFile(p).status();
       }));
  Fuzz("1630577758.569490\n1630577759.068947\n", 400, 66,
       ViaFile(dir + "/times.txt", [](const std::string& p) { return ReadTimesFile(p).status(); }));
  Fuzz("{\"w\": 8, \"h\": 6, \"fx\": 5, \"fy\": 5, \"cx\": 4, \"cy\": 3, \"scale\": 1000}", 400, 67,
       ViaFile(dir + "/cam.json",
               [](const std::string& p) { return ReadReplicaCamParams(p).status(); }));
  ASSERT_TRUE(WriteKittiBin(dir + "/s.bin", SmallCloud()).ok());
  Fuzz(ReadRaw(dir + "/s.bin"), 200, 68,
       ViaFile(dir + "/k.bin", [](const std::string& p) { return ReadKittiBin(p).status(); }));
}

}  // namespace
}  // namespace rim::io
