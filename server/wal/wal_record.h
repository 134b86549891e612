// Record framing of the write-ahead log (layout and recovery rules in wal.h), and the walk over a
// segment's bytes that checks every record and tells a torn tail from corruption.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace rim::server {

inline constexpr uint32_t kWalRecordMagic = 0x314C5752;  // "RWL1" as little-endian bytes.
inline constexpr size_t kWalHeaderBytes = 16;            // magic u32, index u64, length u32.
inline constexpr size_t kWalTrailerBytes = 4;            // CRC-32C of header and payload.

// Appends the framed record (header, payload, CRC) to `out`. The payload must be shorter than
// 4 GiB (its length is a u32); the caller checks.
void FrameWalRecord(uint64_t index, std::string_view payload, std::string* out);

struct WalRecordView {
  uint64_t index = 0;
  size_t offset = 0;  // Of the record's header within the segment.
  std::string_view payload;
};

struct WalSegmentExtent {
  size_t valid_bytes = 0;   // Length of the run of intact records from the start.
  uint64_t next_index = 0;  // One past the last intact record; the segment's first index if none.
  size_t records = 0;
  bool torn_tail = false;  // The bytes after valid_bytes are a torn record (allow_torn_tail only).
};

// Checks the records of segment `path` (contents `data`, named after `first_index`): framing,
// CRC, and indices consecutive from `first_index`; calls `visit` (if set) for each intact record,
// stopping at the first error it returns. When a record fails its checks and `allow_torn_tail` is
// set (the last segment) and no intact record starts anywhere after it, the walk ends there with
// torn_tail set. Any other failure is DataLoss naming the path, the offset and the problem.
absl::StatusOr<WalSegmentExtent> WalkWalSegment(
    const std::string& path, std::string_view data, uint64_t first_index, bool allow_torn_tail,
    const std::function<absl::Status(const WalRecordView&)>& visit);

}  // namespace rim::server
