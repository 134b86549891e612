#include "server/wal/wal_record.h"

#include <cstring>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/binary_io.h"

namespace rim::server {
namespace {

template <typename T>
T LoadLe(std::string_view data, size_t offset) {
  T v;
  std::memcpy(&v, data.data() + offset, sizeof(T));
  return v;
}

// Parses the record at `offset`. On failure returns false with `problem` saying what is wrong.
bool ParseRecordAt(std::string_view data, size_t offset, WalRecordView* rec, std::string* problem) {
  const size_t left = data.size() - offset;
  if (left < kWalHeaderBytes) {
    *problem = absl::StrCat("record header cut short (", left, " of ", kWalHeaderBytes, " bytes)");
    return false;
  }
  const uint32_t magic = LoadLe<uint32_t>(data, offset);
  if (magic != kWalRecordMagic) {
    *problem = absl::StrFormat("bad record magic 0x%08x", magic);
    return false;
  }
  const uint64_t index = LoadLe<uint64_t>(data, offset + 4);
  const uint32_t length = LoadLe<uint32_t>(data, offset + 12);
  // Cannot overflow: offset and left are bounded by the buffer size, length by 2^32.
  const uint64_t record_bytes = uint64_t{kWalHeaderBytes} + length + kWalTrailerBytes;
  if (record_bytes > left) {
    *problem = absl::StrCat("record of ", record_bytes, " bytes runs past the end of the file (",
                            left, " bytes left)");
    return false;
  }
  const size_t crc_offset = offset + kWalHeaderBytes + length;
  const uint32_t stored = LoadLe<uint32_t>(data, crc_offset);
  const uint32_t computed = Crc32c(data.data() + offset, kWalHeaderBytes + length);
  if (stored != computed) {
    *problem =
        absl::StrFormat("checksum mismatch (stored 0x%08x, computed 0x%08x)", stored, computed);
    return false;
  }
  rec->index = index;
  rec->offset = offset;
  rec->payload = data.substr(offset + kWalHeaderBytes, length);
  return true;
}

// True if an intact record starts anywhere after `offset`. A crash can damage only the record
// being appended, which is the last thing in the file; an intact record after a damaged one
// therefore proves the damage is not a torn write. Runs only on the failure path.
bool IntactRecordAfter(std::string_view data, size_t offset) {
  char magic[4];
  std::memcpy(magic, &kWalRecordMagic, sizeof(magic));
  const std::string_view needle(magic, sizeof(magic));
  WalRecordView rec;
  std::string problem;
  for (size_t p = data.find(needle, offset + 1); p != std::string_view::npos;
       p = data.find(needle, p + 1)) {
    if (ParseRecordAt(data, p, &rec, &problem)) return true;
  }
  return false;
}

}  // namespace

void FrameWalRecord(uint64_t index, std::string_view payload, std::string* out) {
  ByteWriter w;
  w.U32(kWalRecordMagic);
  w.U64(index);
  w.U32(static_cast<uint32_t>(payload.size()));
  const size_t start = out->size();
  out->append(w.data());
  out->append(payload);
  ByteWriter crc;
  crc.U32(Crc32c(out->data() + start, out->size() - start));
  out->append(crc.data());
}

absl::StatusOr<WalSegmentExtent> WalkWalSegment(
    const std::string& path, std::string_view data, uint64_t first_index, bool allow_torn_tail,
    const std::function<absl::Status(const WalRecordView&)>& visit) {
  WalSegmentExtent extent;
  extent.next_index = first_index;
  size_t offset = 0;
  WalRecordView rec;
  std::string problem;
  while (offset < data.size()) {
    if (!ParseRecordAt(data, offset, &rec, &problem)) {
      if (allow_torn_tail && !IntactRecordAfter(data, offset)) {
        extent.torn_tail = true;
        break;
      }
      return absl::DataLossError(absl::StrCat("WAL segment ", path, ": ", problem, " at offset ",
                                              offset, " of ", data.size()));
    }
    if (rec.index != extent.next_index) {
      return absl::DataLossError(absl::StrCat("WAL segment ", path, ": record at offset ", offset,
                                              " has index ", rec.index, ", expected ",
                                              extent.next_index));
    }
    if (visit) {
      absl::Status s = visit(rec);
      if (!s.ok()) return s;
    }
    offset += kWalHeaderBytes + rec.payload.size() + kWalTrailerBytes;
    extent.next_index = rec.index + 1;
    ++extent.records;
  }
  extent.valid_bytes = offset;
  return extent;
}

}  // namespace rim::server
