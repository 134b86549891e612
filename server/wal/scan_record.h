// Byte encoding of one accepted scan, as the write-ahead log stores it (DESIGN.md §5.3).
//
// Layout, all little-endian (rim/base/binary_io.h):
//   u64 client sequence | f64 timestamp_s | 16 x f64 T_world_sensor (4x4, column-major) |
//   u64 point count n | n x (f32 x, y, z) | u64 origin count m | m x (f32 x, y, z)
// The pose is stored as the full matrix rather than translation + quaternion so that a replayed
// scan is bit-identical to the accepted one: a quaternion round trip changes the last bits of the
// rotation, and replay must train on exactly what was acknowledged.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "rim/base/scan.h"

namespace rim::server {

// InvalidArgument if origins_S is neither empty nor one per point: such a scan could be written
// but not read back, so it is refused before it reaches the log.
absl::Status CheckScanRecordable(const PosedScan& scan);

// Appends the encoding of (sequence, scan) to `out`. Call CheckScanRecordable first.
void EncodeScanRecord(uint64_t sequence, const PosedScan& scan, std::string* out);

// Decodes a payload written by EncodeScanRecord. DataLoss naming `context` (e.g. "file at offset")
// for truncated, inconsistent or trailing bytes; counts are checked against the remaining bytes
// before anything is allocated, so corrupt bytes cannot cause a huge allocation.
absl::Status DecodeScanRecord(std::string_view bytes, const std::string& context,
                              uint64_t* sequence, PosedScan* scan);

}  // namespace rim::server
