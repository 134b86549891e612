// Test helpers shared by the write-ahead log tests (tests/unit/server_wal*_test.cc): scans to
// log, bit-exact comparison, raw access to segment files, and a fixture with a fresh directory.
// Test-only: no library target compiles it.
#pragma once

#include <stdlib.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "rim/base/status_macros.h"
#include "server/wal/wal.h"

namespace rim::server::wal_testing {

struct Entry {
  uint64_t index = 0;
  uint64_t sequence = 0;
  PosedScan scan;
};

inline PosedScan MakeScan(uint32_t seed, int num_points, bool with_origins) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-50.f, 50.f);
  PosedScan scan;
  scan.timestamp_s = 1.7e9 + seed * 0.1;
  const Eigen::Vector3d axis = Eigen::Vector3d(u(rng), u(rng), u(rng) + 100.f).normalized();
  scan.T_world_sensor =
      Eigen::Translation3d(u(rng), u(rng), u(rng)) * Eigen::AngleAxisd(0.01 * seed + 0.3, axis);
  for (int i = 0; i < num_points; ++i) {
    scan.points_S.emplace_back(u(rng), u(rng), u(rng));
    if (with_origins) scan.origins_S.emplace_back(u(rng) * 1e-3f, u(rng) * 1e-3f, 0.f);
  }
  return scan;
}

// Bit-exact: replay must hand back exactly what was acknowledged.
inline void ExpectSameScan(const PosedScan& a, const PosedScan& b) {
  EXPECT_EQ(std::memcmp(&a.timestamp_s, &b.timestamp_s, sizeof(double)), 0);
  EXPECT_EQ(std::memcmp(a.T_world_sensor.matrix().data(), b.T_world_sensor.matrix().data(),
                        16 * sizeof(double)),
            0);
  ASSERT_EQ(a.points_S.size(), b.points_S.size());
  ASSERT_EQ(a.origins_S.size(), b.origins_S.size());
  if (!a.points_S.empty()) {
    EXPECT_EQ(std::memcmp(a.points_S.data(), b.points_S.data(), a.points_S.size() * 12), 0);
  }
  if (!a.origins_S.empty()) {
    EXPECT_EQ(std::memcmp(a.origins_S.data(), b.origins_S.data(), a.origins_S.size() * 12), 0);
  }
}

inline void ExpectSameEntries(const std::vector<Entry>& got, const std::vector<Entry>& want) {
  ASSERT_EQ(got.size(), want.size());
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].index, want[i].index) << i;
    EXPECT_EQ(got[i].sequence, want[i].sequence) << i;
    ExpectSameScan(got[i].scan, want[i].scan);
  }
}

inline absl::StatusOr<std::vector<Entry>> ReplayAll(const WriteAheadLog& wal, uint64_t from = 0) {
  std::vector<Entry> out;
  RIM_RETURN_IF_ERROR(wal.Replay(from, [&](uint64_t index, uint64_t seq, PosedScan scan) {
    out.push_back({index, seq, std::move(scan)});
    return absl::OkStatus();
  }));
  return out;
}

inline std::string ReadRaw(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

inline void WriteRaw(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Start offsets of the records in a segment, read from the framing documented in wal.h
// (16-byte header whose last u32 is the payload length, then payload and a 4-byte CRC).
inline std::vector<size_t> RecordOffsets(const std::string& bytes) {
  std::vector<size_t> offsets;
  for (size_t off = 0; off + 16 <= bytes.size();) {
    offsets.push_back(off);
    uint32_t length = 0;
    std::memcpy(&length, bytes.data() + off + 12, sizeof(length));
    off += 16 + length + 4;
  }
  return offsets;
}

inline std::vector<std::string> SegmentFiles(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("wal-", 0) == 0) names.push_back(name);
  }
  std::sort(names.begin(), names.end());
  return names;
}

inline int64_t DirBytes(const std::string& dir) {
  int64_t total = 0;
  for (const std::string& name : SegmentFiles(dir))
    total += std::filesystem::file_size(dir + "/" + name);
  return total;
}

class WalTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = ::testing::TempDir() + "/rim_wal_test_XXXXXX";
    ASSERT_NE(::mkdtemp(tmpl.data()), nullptr);
    root_ = tmpl;
    dir_ = root_ + "/session/wal";
  }
  void TearDown() override { std::filesystem::remove_all(root_); }

  // Appends scans index..index+count-1 and remembers them in `entries_`.
  void AppendRange(WriteAheadLog* wal, uint64_t first, int count, int points = 3) {
    for (int i = 0; i < count; ++i) {
      const uint64_t index = first + i;
      Entry e{index, 1000 + index * 7, MakeScan(index, points + index % 4, index % 3 == 0)};
      ASSERT_TRUE(wal->Append(e.index, e.sequence, e.scan).ok()) << index;
      entries_.push_back(std::move(e));
    }
  }

  std::vector<Entry> EntriesFrom(uint64_t from) const {
    std::vector<Entry> out;
    for (const Entry& e : entries_) {
      if (e.index >= from) out.push_back(e);
    }
    return out;
  }

  std::string root_;
  std::string dir_;
  std::vector<Entry> entries_;
};

}  // namespace rim::server::wal_testing
