// Validation and conversion of wire scans (rim.v1.Scan) into core PosedScans (DESIGN.md §5.2):
// every malformed field is INVALID_ARGUMENT naming it, a scan over the size limit is
// RESOURCE_EXHAUSTED, and nothing is converted until the whole scan checks out.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "rim/base/scan.h"
#include "rim/v1/rim.pb.h"

namespace rim::server {

// Converts `scan` (points or depth image) into a PosedScan in the sensor frame. Checks: a finite
// pose with a unit quaternion (within 1e-3), a finite timestamp, packed xyz arrays of a multiple of
// 12 bytes with finite values, origins empty or one per point, at most `max_points` points, a
// depth image whose size, encoding, intrinsics and scale agree, and last everything
// Mapper::ValidateScan checks (e.g. a translation within 1e6 m), so that training never refuses a
// scan accepted here.
absl::StatusOr<PosedScan> ConvertScan(const rim::v1::Scan& scan, size_t max_points);

// Unpacks packed little-endian float32 xyz triples from `bytes`; `field` names the field in
// errors. INVALID_ARGUMENT for a length that is not a multiple of 12, an empty array or a
// non-finite value; RESOURCE_EXHAUSTED for more than `max_points` points (`limit_flag` names the
// limit).
absl::StatusOr<std::vector<float>> UnpackXyz(const std::string& bytes, const std::string& field,
                                             size_t max_points, const std::string& limit_flag);

}  // namespace rim::server
