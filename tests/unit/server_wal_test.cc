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

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "rim/status_macros.h"
#include "server/wal.h"

namespace rim::server {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

struct Entry {
  uint64_t index = 0;
  uint64_t sequence = 0;
  PosedScan scan;
};

PosedScan MakeScan(uint32_t seed, int num_points, bool with_origins) {
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
void ExpectSameScan(const PosedScan& a, const PosedScan& b) {
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

void ExpectSameEntries(const std::vector<Entry>& got, const std::vector<Entry>& want) {
  ASSERT_EQ(got.size(), want.size());
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].index, want[i].index) << i;
    EXPECT_EQ(got[i].sequence, want[i].sequence) << i;
    ExpectSameScan(got[i].scan, want[i].scan);
  }
}

absl::StatusOr<std::vector<Entry>> ReplayAll(const WriteAheadLog& wal, uint64_t from = 0) {
  std::vector<Entry> out;
  RIM_RETURN_IF_ERROR(wal.Replay(from, [&](uint64_t index, uint64_t seq, PosedScan scan) {
    out.push_back({index, seq, std::move(scan)});
    return absl::OkStatus();
  }));
  return out;
}

std::string ReadRaw(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void WriteRaw(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Start offsets of the records in a segment, read from the framing documented in wal.h
// (16-byte header whose last u32 is the payload length, then payload and a 4-byte CRC).
std::vector<size_t> RecordOffsets(const std::string& bytes) {
  std::vector<size_t> offsets;
  for (size_t off = 0; off + 16 <= bytes.size();) {
    offsets.push_back(off);
    uint32_t length = 0;
    std::memcpy(&length, bytes.data() + off + 12, sizeof(length));
    off += 16 + length + 4;
  }
  return offsets;
}

std::vector<std::string> SegmentFiles(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("wal-", 0) == 0) names.push_back(name);
  }
  std::sort(names.begin(), names.end());
  return names;
}

int64_t DirBytes(const std::string& dir) {
  int64_t total = 0;
  for (const std::string& name : SegmentFiles(dir)) total += fs::file_size(dir + "/" + name);
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
  void TearDown() override { fs::remove_all(root_); }

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

TEST_F(WalTest, AppendReplayRoundTripIsBitExact) {
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok()) << wal.status();
  EXPECT_EQ((*wal)->next_index(), 0u);
  AppendRange(wal->get(), 0, 12);
  // Edge cases: no points, and a large scan.
  Entry empty{12, 5, PosedScan{}};
  ASSERT_TRUE((*wal)->Append(12, 5, empty.scan).ok());
  entries_.push_back(empty);
  Entry big{13, 6, MakeScan(99, 20000, true)};
  ASSERT_TRUE((*wal)->Append(13, 6, big.scan).ok());
  entries_.push_back(big);
  EXPECT_EQ((*wal)->next_index(), 14u);
  EXPECT_EQ((*wal)->bytes(), DirBytes(dir_));

  auto got = ReplayAll(**wal);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, entries_);

  wal->reset();
  auto reopened = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(reopened.ok()) << reopened.status();
  EXPECT_EQ((*reopened)->torn_tail_bytes(), 0);
  got = ReplayAll(**reopened);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, entries_);
}

TEST_F(WalTest, ReplayFromMiddleIndexAcrossSegments) {
  WalOptions options;
  options.segment_bytes = 600;  // A few records per segment.
  auto wal = WriteAheadLog::Open(dir_, options);
  ASSERT_TRUE(wal.ok()) << wal.status();
  AppendRange(wal->get(), 0, 20);
  EXPECT_GT((*wal)->num_segments(), 3);
  for (uint64_t from : {0u, 1u, 7u, 13u, 19u, 20u, 1000u}) {
    auto got = ReplayAll(**wal, from);
    ASSERT_TRUE(got.ok()) << got.status();
    ExpectSameEntries(*got, EntriesFrom(from));
  }
}

TEST_F(WalTest, ReplayStopsAtCallbackError) {
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok());
  AppendRange(wal->get(), 0, 8);
  std::vector<uint64_t> seen;
  const absl::Status s = (*wal)->Replay(2, [&](uint64_t index, uint64_t, PosedScan) {
    seen.push_back(index);
    return index == 4 ? absl::ResourceExhaustedError("queue full") : absl::OkStatus();
  });
  EXPECT_EQ(s, absl::ResourceExhaustedError("queue full"));
  EXPECT_EQ(seen, (std::vector<uint64_t>{2, 3, 4}));
}

TEST_F(WalTest, SegmentsRotateAtSizeLimit) {
  WalOptions options;
  options.segment_bytes = 1000;
  auto wal = WriteAheadLog::Open(dir_, options);
  ASSERT_TRUE(wal.ok());
  AppendRange(wal->get(), 0, 30);
  // One oversized record still gets written, alone in its segment.
  Entry big{30, 1, MakeScan(7, 500, false)};
  ASSERT_TRUE((*wal)->Append(30, 1, big.scan).ok());
  entries_.push_back(big);
  const std::vector<std::string> files = SegmentFiles(dir_);
  EXPECT_EQ(static_cast<int>(files.size()), (*wal)->num_segments());
  for (size_t i = 0; i + 1 < files.size(); ++i) {
    EXPECT_LE(fs::file_size(dir_ + "/" + files[i]), 1000u) << files[i];
    EXPECT_EQ(files[i].size(), std::string("wal-00000000000000000000.log").size());
  }
  EXPECT_EQ(files.back(), "wal-00000000000000000030.log");
  EXPECT_EQ((*wal)->bytes(), DirBytes(dir_));
  auto got = ReplayAll(**wal);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, entries_);
}

TEST_F(WalTest, CrashAtEveryByteOfTheLastRecordLosesOnlyThatRecord) {
  {
    auto wal = WriteAheadLog::Open(dir_);
    ASSERT_TRUE(wal.ok());
    AppendRange(wal->get(), 0, 3, /*points=*/1);
  }
  const std::string path = dir_ + "/" + SegmentFiles(dir_).at(0);
  const std::string full = ReadRaw(path);
  const std::vector<Entry> complete(entries_.begin(), entries_.end() - 1);
  const size_t last_start = RecordOffsets(full).at(2);

  const Entry next{2, 77, MakeScan(1234, 2, false)};
  for (size_t cut = last_start; cut < full.size(); ++cut) {
    SCOPED_TRACE(cut);
    WriteRaw(path, full.substr(0, cut));
    auto wal = WriteAheadLog::Open(dir_);
    ASSERT_TRUE(wal.ok()) << wal.status();
    EXPECT_EQ((*wal)->torn_tail_bytes(), static_cast<int64_t>(cut - last_start));
    EXPECT_EQ((*wal)->next_index(), 2u);
    EXPECT_EQ(fs::file_size(path), last_start);  // The torn bytes are gone from disk.
    auto got = ReplayAll(**wal);
    ASSERT_TRUE(got.ok()) << got.status();
    ExpectSameEntries(*got, complete);
    // The log keeps working after recovery, and the new record survives a reopen.
    ASSERT_TRUE((*wal)->Append(next.index, next.sequence, next.scan).ok());
    wal->reset();
    auto reopened = WriteAheadLog::Open(dir_);
    ASSERT_TRUE(reopened.ok()) << reopened.status();
    EXPECT_EQ((*reopened)->torn_tail_bytes(), 0);
    got = ReplayAll(**reopened);
    ASSERT_TRUE(got.ok()) << got.status();
    std::vector<Entry> want = complete;
    want.push_back(next);
    ExpectSameEntries(*got, want);
  }
}

TEST_F(WalTest, ZeroFilledTailIsTornNotCorrupt) {
  // Some filesystems extend the size before the data reaches disk, leaving zeros after a crash.
  {
    auto wal = WriteAheadLog::Open(dir_);
    ASSERT_TRUE(wal.ok());
    AppendRange(wal->get(), 0, 4);
  }
  const std::string path = dir_ + "/" + SegmentFiles(dir_).at(0);
  WriteRaw(path, ReadRaw(path) + std::string(4096, '\0'));
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok()) << wal.status();
  EXPECT_EQ((*wal)->torn_tail_bytes(), 4096);
  auto got = ReplayAll(**wal);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, entries_);
}

TEST_F(WalTest, FlippedByteInTheMiddleOfTheLastSegmentIsDataLoss) {
  {
    auto wal = WriteAheadLog::Open(dir_);
    ASSERT_TRUE(wal.ok());
    AppendRange(wal->get(), 0, 5, /*points=*/1);
  }
  const std::string path = dir_ + "/" + SegmentFiles(dir_).at(0);
  const std::string original = ReadRaw(path);
  // Every byte of the second record (header, payload and CRC): later records are intact, so no
  // damage there may pass for a torn tail.
  const std::vector<size_t> offsets = RecordOffsets(original);
  ASSERT_EQ(offsets.size(), 5u);
  const size_t record = offsets[1];
  for (size_t off = offsets[1]; off < offsets[2]; ++off) {
    SCOPED_TRACE(off);
    std::string damaged = original;
    damaged[off] = static_cast<char>(damaged[off] ^ 0x10);
    WriteRaw(path, damaged);
    auto wal = WriteAheadLog::Open(dir_);
    ASSERT_FALSE(wal.ok());
    EXPECT_EQ(wal.status().code(), absl::StatusCode::kDataLoss);
    EXPECT_THAT(wal.status().message(), HasSubstr(path));
    EXPECT_THAT(wal.status().message(), HasSubstr("offset " + std::to_string(record)));
  }
}

TEST_F(WalTest, FlippedByteInAnEarlierSegmentIsDataLossOnReplay) {
  WalOptions options;
  options.segment_bytes = 1;  // One record per segment.
  {
    auto wal = WriteAheadLog::Open(dir_, options);
    ASSERT_TRUE(wal.ok());
    AppendRange(wal->get(), 0, 5);
  }
  const std::vector<std::string> files = SegmentFiles(dir_);
  ASSERT_EQ(files.size(), 5u);
  const std::string path = dir_ + "/" + files[1];
  std::string bytes = ReadRaw(path);
  bytes[bytes.size() / 2] ^= 0x01;
  WriteRaw(path, bytes);

  auto wal = WriteAheadLog::Open(dir_, options);
  ASSERT_TRUE(wal.ok()) << wal.status();  // Only the last segment is checked at open.
  auto got = ReplayAll(**wal);
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(got.status().message(), HasSubstr(path));
  EXPECT_THAT(got.status().message(), HasSubstr("offset 0"));
  // Replay past the damaged segment still works.
  got = ReplayAll(**wal, 2);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, EntriesFrom(2));
}

TEST_F(WalTest, TruncatedEarlierSegmentIsDataLoss) {
  WalOptions options;
  options.segment_bytes = 1;
  {
    auto wal = WriteAheadLog::Open(dir_, options);
    ASSERT_TRUE(wal.ok());
    AppendRange(wal->get(), 0, 3);
  }
  const std::string path = dir_ + "/" + SegmentFiles(dir_).at(0);
  const std::string bytes = ReadRaw(path);
  WriteRaw(path, bytes.substr(0, bytes.size() - 1));
  auto wal = WriteAheadLog::Open(dir_, options);
  ASSERT_TRUE(wal.ok()) << wal.status();
  auto got = ReplayAll(**wal);
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(got.status().message(), HasSubstr(path));
}

TEST_F(WalTest, SegmentNamedAfterTheWrongIndexIsDataLoss) {
  {
    auto wal = WriteAheadLog::Open(dir_);
    ASSERT_TRUE(wal.ok());
    AppendRange(wal->get(), 0, 3);
  }
  const std::string renamed = dir_ + "/wal-00000000000000000007.log";
  fs::rename(dir_ + "/" + SegmentFiles(dir_).at(0), renamed);
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_FALSE(wal.ok());
  EXPECT_EQ(wal.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(wal.status().message(), HasSubstr(renamed));
  EXPECT_THAT(wal.status().message(), HasSubstr("expected 7"));
}

TEST_F(WalTest, TruncateBeforeRemovesOldSegmentsAndReplayStillWorks) {
  WalOptions options;
  options.segment_bytes = 700;
  auto wal = WriteAheadLog::Open(dir_, options);
  ASSERT_TRUE(wal.ok());
  AppendRange(wal->get(), 0, 30);
  const int64_t before = (*wal)->bytes();

  ASSERT_TRUE((*wal)->TruncateBefore(15).ok());
  EXPECT_LT((*wal)->bytes(), before);
  EXPECT_EQ((*wal)->bytes(), DirBytes(dir_));
  // Whatever is left starts at or below 15 (nothing needed was deleted) and every deleted
  // segment held only indices below 15.
  auto all = ReplayAll(**wal);
  ASSERT_TRUE(all.ok()) << all.status();
  ASSERT_FALSE(all->empty());
  EXPECT_GT(all->front().index, 0u);
  EXPECT_LE(all->front().index, 15u);
  ExpectSameEntries(*all, EntriesFrom(all->front().index));
  auto from15 = ReplayAll(**wal, 15);
  ASSERT_TRUE(from15.ok());
  ExpectSameEntries(*from15, EntriesFrom(15));

  // The checkpoint rotated to a fresh segment; appends continue there.
  EXPECT_EQ(SegmentFiles(dir_).back(), "wal-00000000000000000030.log");
  AppendRange(wal->get(), 30, 3);

  // A checkpoint covering everything leaves only the new, empty segment, whose name still
  // carries the next index across a restart.
  ASSERT_TRUE((*wal)->TruncateBefore(33).ok());
  EXPECT_EQ(SegmentFiles(dir_), (std::vector<std::string>{"wal-00000000000000000033.log"}));
  EXPECT_EQ((*wal)->bytes(), 0);
  wal->reset();
  auto reopened = WriteAheadLog::Open(dir_, options);
  ASSERT_TRUE(reopened.ok()) << reopened.status();
  EXPECT_EQ((*reopened)->next_index(), 33u);
  auto none = ReplayAll(**reopened);
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->empty());
  AppendRange(reopened->get(), 33, 2);
  auto got = ReplayAll(**reopened, 33);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, EntriesFrom(33));
}

TEST_F(WalTest, TruncateBeforeOnAnEmptyLogIsANoOp) {
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok());
  ASSERT_TRUE((*wal)->TruncateBefore(10).ok());
  EXPECT_TRUE(SegmentFiles(dir_).empty());
  AppendRange(wal->get(), 0, 2);
  auto got = ReplayAll(**wal);
  ASSERT_TRUE(got.ok());
  ExpectSameEntries(*got, entries_);
}

TEST_F(WalTest, ReopenContinuesIndices) {
  {
    auto wal = WriteAheadLog::Open(dir_);
    ASSERT_TRUE(wal.ok());
    AppendRange(wal->get(), 0, 10);
  }
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok()) << wal.status();
  EXPECT_EQ((*wal)->next_index(), 10u);
  EXPECT_EQ((*wal)->bytes(), DirBytes(dir_));
  const absl::Status stale = (*wal)->Append(5, 0, MakeScan(1, 1, false));
  EXPECT_EQ(stale.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(stale.message(), HasSubstr("below the next index 10"));
  AppendRange(wal->get(), 10, 2);
  auto got = ReplayAll(**wal);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, entries_);
}

TEST_F(WalTest, IndexGapStartsANewSegment) {
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok());
  AppendRange(wal->get(), 0, 3);
  AppendRange(wal->get(), 100, 2);  // E.g. the first append after restoring a checkpoint.
  EXPECT_EQ(SegmentFiles(dir_), (std::vector<std::string>{"wal-00000000000000000000.log",
                                                          "wal-00000000000000000100.log"}));
  wal->reset();
  auto reopened = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(reopened.ok()) << reopened.status();
  EXPECT_EQ((*reopened)->next_index(), 102u);
  auto got = ReplayAll(**reopened);
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameEntries(*got, entries_);
  got = ReplayAll(**reopened, 50);
  ASSERT_TRUE(got.ok());
  ExpectSameEntries(*got, EntriesFrom(50));
}

TEST_F(WalTest, UnrecordableScanChangesNothing) {
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok());
  AppendRange(wal->get(), 0, 2);
  PosedScan bad = MakeScan(3, 4, false);
  bad.origins_S.resize(2);  // Neither none nor one per point.
  const int64_t bytes = (*wal)->bytes();
  const absl::Status s = (*wal)->Append(2, 0, bad);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("2 origins for 4 points"));
  EXPECT_EQ((*wal)->bytes(), bytes);
  EXPECT_EQ((*wal)->next_index(), 2u);
  EXPECT_EQ(DirBytes(dir_), bytes);
}

TEST_F(WalTest, OpenOnAFileIsAClearError) {
  const std::string file = root_ + "/not_a_dir";
  WriteRaw(file, "x");
  auto wal = WriteAheadLog::Open(file);
  ASSERT_FALSE(wal.ok());
  EXPECT_EQ(wal.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(wal.status().message(), HasSubstr(file));
  EXPECT_THAT(wal.status().message(), HasSubstr("not a directory"));
  // A file further up the path is refused too.
  auto below = WriteAheadLog::Open(file + "/wal");
  ASSERT_FALSE(below.ok());
  EXPECT_THAT(below.status().message(), HasSubstr("not a directory"));
}

TEST_F(WalTest, BadOptionsAreRefused) {
  EXPECT_EQ(WriteAheadLog::Open("").status().code(), absl::StatusCode::kInvalidArgument);
  WalOptions options;
  options.segment_bytes = 0;
  EXPECT_EQ(WriteAheadLog::Open(dir_, options).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_F(WalTest, UnrelatedFilesAreIgnored) {
  fs::create_directories(dir_);
  WriteRaw(dir_ + "/README", "notes");
  WriteRaw(dir_ + "/wal-123.log", "not a segment name: too few digits");
  auto wal = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(wal.ok()) << wal.status();
  AppendRange(wal->get(), 0, 2);
  wal->reset();
  auto reopened = WriteAheadLog::Open(dir_);
  ASSERT_TRUE(reopened.ok()) << reopened.status();
  auto got = ReplayAll(**reopened);
  ASSERT_TRUE(got.ok());
  ExpectSameEntries(*got, entries_);
  EXPECT_TRUE(fs::exists(dir_ + "/README"));
}

}  // namespace
}  // namespace rim::server
