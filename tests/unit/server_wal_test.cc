// Write-ahead log: appending, replay, rotation, checkpoint truncation and reopening.
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
}  // namespace rim::server::wal_testing
