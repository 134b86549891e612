// Write-ahead log of the scans a session has accepted (DESIGN.md §5.3). A scan is acknowledged as
// accepted only once Append has returned, and Append returns only after the record is on disk, so
// after a crash (kill -9, power loss) the server reloads the last checkpoint and replays every
// record after it: no accepted scan is lost.
//
// On disk: a directory of segment files "wal-<first index, 20 digits>.log", each a sequence of
// records, all little-endian:
//   u32 magic "RWL1" | u64 accept index | u32 payload length | payload | u32 CRC-32C
// where the CRC covers the header and the payload, and the payload is a scan record
// (scan_record.h). Within a segment the indices are consecutive, starting at the index in its name;
// across segments they increase, with gaps allowed (see Append). A format change gets a new magic.
//
// Crash recovery. Records are only ever appended, each with one write followed by fdatasync, so a
// crash can damage at most the record being written, at the end of the last segment. Open treats a
// damaged record as such a torn tail only when no intact record follows it anywhere in the segment,
// and cuts it off; everything else that fails its checks (a damaged record followed by intact ones,
// or any damage in an earlier segment) is DataLoss naming the file and byte offset, because
// silently skipping it would drop scans that were acknowledged. The one ambiguity: damage (e.g. a
// disk bit flip) to the very last record of the log looks exactly like a torn write and is cut off.
//
// Not thread-safe: the session serialises calls (one writer per session).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/base/scan.h"

namespace rim::server {

struct WalOptions {
  // A new segment starts when the next record would push the current one past this size, so that
  // TruncateBefore can free space in whole files. A single larger record gets a segment alone.
  int64_t segment_bytes = int64_t{64} << 20;
};

class WriteAheadLog {
 public:
  using ReplayFn = std::function<absl::Status(uint64_t index, uint64_t sequence, PosedScan scan)>;

  // Opens (creating if needed) the log in `dir`, validates its last segment, cuts off a torn tail
  // record there (see above) and prepares to append after the last intact record.
  // FailedPrecondition if `dir` exists but is not a directory; DataLoss for damage that is not a
  // torn tail; an errno-based status for I/O failures.
  static absl::StatusOr<std::unique_ptr<WriteAheadLog>> Open(const std::string& dir,
                                                             const WalOptions& options = {});

  ~WriteAheadLog();
  WriteAheadLog(const WriteAheadLog&) = delete;
  WriteAheadLog& operator=(const WriteAheadLog&) = delete;

  // Appends one record and makes it durable (write + fdatasync) before returning. `index` must be
  // at least next_index(); a larger one (e.g. the first append after a checkpoint whose log was
  // lost) starts a new segment so that indices within a segment stay consecutive.
  // FailedPrecondition for an index below next_index(), InvalidArgument for a scan that cannot be
  // recorded, and the I/O error otherwise. After a failed write the partial record is cut off
  // again; after a failed fdatasync the kernel may have dropped the data, so every later Append
  // fails with that error until the log is reopened (which re-validates the file).
  absl::Status Append(uint64_t index, uint64_t sequence, const PosedScan& scan);

  // Calls `fn` for every record with index >= from_index, in index order, and stops at the first
  // error `fn` returns (returning it). DataLoss naming file and offset for a damaged record.
  absl::Status Replay(uint64_t from_index, const ReplayFn& fn) const;

  // After a checkpoint that covers every index below `index`: starts a new segment (so that the
  // current one can go at the next checkpoint) and deletes the segments whose records all lie
  // below `index`. A crash midway leaves a suffix of the segments, which replays correctly.
  absl::Status TruncateBefore(uint64_t index);

  // The smallest index Append accepts: one past the last record, or the first index of an empty
  // current segment, or 0 for a log that has never had a segment.
  uint64_t next_index() const { return next_index_; }
  // Bytes in all segment files.
  int64_t bytes() const { return total_bytes_; }
  // Bytes of a torn tail record that Open cut off (0 after a clean shutdown); worth logging.
  int64_t torn_tail_bytes() const { return torn_tail_bytes_; }
  int num_segments() const { return static_cast<int>(segments_.size()); }
  const std::string& dir() const { return dir_; }

 private:
  struct Segment {
    uint64_t first_index = 0;
    std::string path;
    int64_t size = 0;
  };

  WriteAheadLog(std::string dir, const WalOptions& options);

  absl::Status RecoverLastSegment();
  // Makes a new, empty segment named `first_index` the one Append writes to. A current segment
  // without records is deleted first, so only the last segment can ever be empty.
  absl::Status StartSegment(uint64_t first_index);
  void CloseActive();

  std::string dir_;
  WalOptions options_;
  std::vector<Segment> segments_;  // Ordered by first_index; the last one is appended to.
  int active_fd_ = -1;             // Open on segments_.back(), or -1 before the first segment.
  uint64_t next_index_ = 0;
  int64_t total_bytes_ = 0;
  int64_t torn_tail_bytes_ = 0;
  absl::Status broken_;  // Set after a failed fdatasync; see Append.
};

}  // namespace rim::server
