// Write-ahead log crash recovery: torn tails are cut off, other damage is DataLoss.
#include <filesystem>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/wal/wal.h"
#include "support/wal_test_util.h"

namespace rim::server::wal_testing {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

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
    EXPECT_EQ((*wal)->bytes(), static_cast<int64_t>(last_start));
    auto got = ReplayAll(**wal);
    ASSERT_TRUE(got.ok()) << got.status();
    ExpectSameEntries(*got, complete);
    // The log keeps working after recovery, and the new record survives a reopen. Checked at
    // every header byte and then every 8th byte: each check costs two fdatasyncs.
    const size_t torn = cut - last_start;
    if (torn >= 16 && torn % 8 != 0 && cut + 1 != full.size()) continue;
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

}  // namespace
}  // namespace rim::server::wal_testing
