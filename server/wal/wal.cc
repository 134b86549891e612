#include "server/wal/wal.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"
#include "rim/base/binary_io.h"
#include "rim/base/status_macros.h"
#include "server/wal/scan_record.h"
#include "server/wal/wal_record.h"

namespace rim::server {
namespace {

constexpr char kSegmentPrefix[] = "wal-";
constexpr char kSegmentSuffix[] = ".log";
constexpr size_t kIndexDigits = 20;  // Enough for any u64, so names sort like their indices.

std::string SegmentName(uint64_t first_index) {
  char digits[kIndexDigits + 1];
  std::snprintf(digits, sizeof(digits), "%020" PRIu64, first_index);
  return absl::StrCat(kSegmentPrefix, digits, kSegmentSuffix);
}

// Parses "wal-<20 digits>.log". Exactly 20 digits, so that one index has exactly one name.
bool ParseSegmentName(const std::string& name, uint64_t* first_index) {
  const size_t prefix = sizeof(kSegmentPrefix) - 1;
  const size_t suffix = sizeof(kSegmentSuffix) - 1;
  if (name.size() != prefix + kIndexDigits + suffix) return false;
  if (name.compare(0, prefix, kSegmentPrefix) != 0) return false;
  if (name.compare(prefix + kIndexDigits, suffix, kSegmentSuffix) != 0) return false;
  uint64_t v = 0;
  for (size_t i = prefix; i < prefix + kIndexDigits; ++i) {
    const char c = name[i];
    if (c < '0' || c > '9') return false;
    const uint64_t d = static_cast<uint64_t>(c - '0');
    if (v > (std::numeric_limits<uint64_t>::max() - d) / 10) return false;
    v = v * 10 + d;
  }
  *first_index = v;
  return true;
}

absl::Status ErrnoError(int err, const std::string& what) { return absl::ErrnoToStatus(err, what); }

absl::Status FsyncDir(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return ErrnoError(errno, absl::StrCat("open WAL directory ", dir));
  const int r = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (r != 0) return ErrnoError(err, absl::StrCat("fsync WAL directory ", dir));
  return absl::OkStatus();
}

absl::StatusOr<std::string> ReadWholeFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
  if (fd < 0) return ErrnoError(errno, absl::StrCat("open ", path));
  std::string out;
  struct stat st;
  if (::fstat(fd, &st) == 0 && st.st_size > 0) out.reserve(static_cast<size_t>(st.st_size));
  char buf[1 << 16];
  for (;;) {
    const ssize_t r = ::read(fd, buf, sizeof(buf));
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) {
      const int err = errno;
      ::close(fd);
      return ErrnoError(err, absl::StrCat("read ", path));
    }
    if (r == 0) break;
    out.append(buf, static_cast<size_t>(r));
  }
  ::close(fd);
  return out;
}

absl::Status PwriteAll(int fd, const std::string& bytes, int64_t offset, const std::string& path) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t w = ::pwrite(fd, bytes.data() + done, bytes.size() - done,
                               static_cast<off_t>(offset + static_cast<int64_t>(done)));
    if (w < 0 && errno == EINTR) continue;
    if (w < 0) return ErrnoError(errno, absl::StrCat("write WAL segment ", path));
    done += static_cast<size_t>(w);
  }
  return absl::OkStatus();
}

}  // namespace

WriteAheadLog::WriteAheadLog(std::string dir, const WalOptions& options)
    : dir_(std::move(dir)), options_(options) {}

WriteAheadLog::~WriteAheadLog() { CloseActive(); }

void WriteAheadLog::CloseActive() {
  // Every record was fdatasync'd before Append returned, so close has nothing left to report.
  if (active_fd_ >= 0) ::close(active_fd_);
  active_fd_ = -1;
}

absl::StatusOr<std::unique_ptr<WriteAheadLog>> WriteAheadLog::Open(const std::string& dir,
                                                                   const WalOptions& options) {
  if (dir.empty()) return absl::InvalidArgumentError("WAL directory path is empty");
  if (options.segment_bytes <= 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("WAL segment_bytes must be positive, got ", options.segment_bytes));
  }
  struct stat st;
  if (::stat(dir.c_str(), &st) == 0 && !S_ISDIR(st.st_mode)) {
    return absl::FailedPreconditionError(
        absl::StrCat("WAL directory ", dir, " exists and is not a directory"));
  }
  RIM_RETURN_IF_ERROR(MakeDirs(dir));

  std::unique_ptr<WriteAheadLog> wal(new WriteAheadLog(dir, options));
  DIR* d = ::opendir(dir.c_str());
  if (d == nullptr) return ErrnoError(errno, absl::StrCat("list WAL directory ", dir));
  while (const dirent* e = ::readdir(d)) {
    Segment seg;
    // Other names (editor backups, operator notes) are not ours; leave them alone.
    if (!ParseSegmentName(e->d_name, &seg.first_index)) continue;
    seg.path = absl::StrCat(dir, "/", e->d_name);
    wal->segments_.push_back(std::move(seg));
  }
  ::closedir(d);
  std::sort(wal->segments_.begin(), wal->segments_.end(),
            [](const Segment& a, const Segment& b) { return a.first_index < b.first_index; });
  for (Segment& seg : wal->segments_) {
    if (::stat(seg.path.c_str(), &st) != 0) {
      return ErrnoError(errno, absl::StrCat("stat WAL segment ", seg.path));
    }
    seg.size = static_cast<int64_t>(st.st_size);
    wal->total_bytes_ += seg.size;
  }
  if (!wal->segments_.empty()) RIM_RETURN_IF_ERROR(wal->RecoverLastSegment());
  return wal;
}

absl::Status WriteAheadLog::RecoverLastSegment() {
  Segment& seg = segments_.back();
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadWholeFile(seg.path));
  RIM_ASSIGN_OR_RETURN(const WalSegmentExtent extent,
                       WalkWalSegment(seg.path, data, seg.first_index,
                                      /*allow_torn_tail=*/true, nullptr));
  const int fd = ::open(seg.path.c_str(), O_WRONLY | O_CLOEXEC | O_NOFOLLOW);
  if (fd < 0) return ErrnoError(errno, absl::StrCat("open WAL segment ", seg.path));
  active_fd_ = fd;
  if (extent.torn_tail) {
    // Cut the torn record off before appending, or the next record would follow garbage and
    // turn a harmless torn tail into corruption in the middle of the file.
    if (::ftruncate(fd, static_cast<off_t>(extent.valid_bytes)) != 0 || ::fdatasync(fd) != 0) {
      return ErrnoError(errno, absl::StrCat("cut torn tail off WAL segment ", seg.path));
    }
    torn_tail_bytes_ = static_cast<int64_t>(data.size() - extent.valid_bytes);
    total_bytes_ -= torn_tail_bytes_;
  }
  seg.size = static_cast<int64_t>(extent.valid_bytes);
  next_index_ = extent.next_index;
  return absl::OkStatus();
}

absl::Status WriteAheadLog::StartSegment(uint64_t first_index) {
  CloseActive();
  if (!segments_.empty() && segments_.back().size == 0) {
    if (::unlink(segments_.back().path.c_str()) != 0 && errno != ENOENT) {
      return ErrnoError(errno, absl::StrCat("delete empty WAL segment ", segments_.back().path));
    }
    segments_.pop_back();
  }
  Segment seg;
  seg.first_index = first_index;
  seg.path = absl::StrCat(dir_, "/", SegmentName(first_index));
  const int fd = ::open(seg.path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return ErrnoError(errno, absl::StrCat("create WAL segment ", seg.path));
  active_fd_ = fd;
  segments_.push_back(std::move(seg));
  // The new name must survive a crash, or records acknowledged in it would vanish with it.
  return FsyncDir(dir_);
}

absl::Status WriteAheadLog::Append(uint64_t index, uint64_t sequence, const PosedScan& scan) {
  if (!broken_.ok()) return broken_;
  if (index < next_index_) {
    return absl::FailedPreconditionError(absl::StrCat("WAL ", dir_, ": append index ", index,
                                                      " is below the next index ", next_index_));
  }
  if (index == std::numeric_limits<uint64_t>::max()) {
    return absl::InvalidArgumentError("WAL append index 2^64-1 is reserved");
  }
  RIM_RETURN_IF_ERROR(CheckScanRecordable(scan));
  std::string payload;
  EncodeScanRecord(sequence, scan, &payload);
  if (payload.size() > std::numeric_limits<uint32_t>::max()) {
    return absl::InvalidArgumentError(
        absl::StrCat("scan of ", payload.size(), " bytes is too large for one WAL record"));
  }
  std::string record;
  record.reserve(kWalHeaderBytes + payload.size() + kWalTrailerBytes);
  FrameWalRecord(index, payload, &record);

  const int64_t record_bytes = static_cast<int64_t>(record.size());
  const bool full = !segments_.empty() && segments_.back().size > 0 &&
                    segments_.back().size + record_bytes > options_.segment_bytes;
  if (active_fd_ < 0 || index != next_index_ || full) RIM_RETURN_IF_ERROR(StartSegment(index));

  Segment& seg = segments_.back();
  absl::Status s = PwriteAll(active_fd_, record, seg.size, seg.path);
  if (s.ok() && ::fdatasync(active_fd_) != 0) {
    s = ErrnoError(errno, absl::StrCat("fdatasync WAL segment ", seg.path));
    // After a failed fdatasync Linux may have dropped the dirty pages and report success on the
    // next call, so no later record could be trusted to be durable.
    broken_ = s;
  }
  if (!s.ok()) {
    // Remove the partial record so that a later append does not follow garbage.
    if (::ftruncate(active_fd_, static_cast<off_t>(seg.size)) != 0 && broken_.ok()) broken_ = s;
    return s;
  }
  seg.size += record_bytes;
  total_bytes_ += record_bytes;
  next_index_ = index + 1;
  return absl::OkStatus();
}

absl::Status WriteAheadLog::Replay(uint64_t from_index, const ReplayFn& fn) const {
  uint64_t expected_min = 0;  // Every index seen so far is below this.
  for (size_t i = 0; i < segments_.size(); ++i) {
    const Segment& seg = segments_[i];
    const bool last = i + 1 == segments_.size();
    if (!last && segments_[i + 1].first_index <= from_index) continue;  // All below from_index.
    if (seg.first_index < expected_min) {
      return absl::DataLossError(absl::StrCat("WAL segment ", seg.path, " starts at index ",
                                              seg.first_index, ", below the end ", expected_min,
                                              " of the segment before it"));
    }
    RIM_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(seg.path));
    // The last segment was validated by Open and since then only grown by Append; bytes past
    // what this process wrote are not acknowledged records.
    if (last && data.size() > static_cast<size_t>(seg.size)) data.resize(seg.size);
    auto visit = [&](const WalRecordView& rec) -> absl::Status {
      if (rec.index < from_index) return absl::OkStatus();
      uint64_t sequence = 0;
      PosedScan scan;
      RIM_RETURN_IF_ERROR(DecodeScanRecord(
          rec.payload, absl::StrCat("WAL segment ", seg.path, " record at offset ", rec.offset),
          &sequence, &scan));
      return fn(rec.index, sequence, std::move(scan));
    };
    RIM_ASSIGN_OR_RETURN(
        const WalSegmentExtent extent,
        WalkWalSegment(seg.path, data, seg.first_index, /*allow_torn_tail=*/false, visit));
    expected_min = extent.next_index;
  }
  return absl::OkStatus();
}

absl::Status WriteAheadLog::TruncateBefore(uint64_t index) {
  // Rotating first puts every record so far into closed segments, which the next checkpoint can
  // delete whole. An empty current segment is kept: it already holds the next index in its name.
  if (!segments_.empty() && segments_.back().size > 0) {
    RIM_RETURN_IF_ERROR(StartSegment(next_index_));
  }
  // Segment i holds indices below segments_[i + 1].first_index. Oldest first, so that a crash
  // midway leaves a contiguous suffix.
  size_t removed = 0;
  absl::Status s;
  while (removed + 1 < segments_.size() && segments_[removed + 1].first_index <= index) {
    const Segment& seg = segments_[removed];
    if (::unlink(seg.path.c_str()) != 0 && errno != ENOENT) {
      s = ErrnoError(errno, absl::StrCat("delete WAL segment ", seg.path));
      break;
    }
    total_bytes_ -= seg.size;
    ++removed;
  }
  segments_.erase(segments_.begin(), segments_.begin() + static_cast<std::ptrdiff_t>(removed));
  if (removed > 0) {
    absl::Status synced = FsyncDir(dir_);
    if (s.ok()) s = synced;
  }
  return s;
}

}  // namespace rim::server
