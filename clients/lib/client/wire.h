// Conversions between core types and the packed wire arrays of rim.v1 (little-endian float32
// triples in `bytes` fields, DESIGN.md §5.1).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "rim/base/scan.h"
#include "rim/base/types.h"
#include "rim/v1/rim.pb.h"

namespace rim {

// Packs xyz triples as the wire's float32 array (12 bytes per point).
std::string PackXyz(const std::vector<Vec3f>& points);
std::string PackXyz(const std::vector<std::array<float, 3>>& points);

// Unpacks a wire array of float32 values (4 bytes each) into `count` values. InvalidArgument
// naming `field` when the byte length is not 4 * count.
absl::StatusOr<std::vector<float>> UnpackFloats(const std::string& bytes, size_t count,
                                                const std::string& field);

// A wire Scan of `scan` for `robot_id`: the pose as translation plus unit quaternion (the rotation
// part of T_world_sensor, re-normalised so float drift in the caller's matrix never trips the
// server's unit-quaternion check), the packed points and, when present, the per-point origins.
rim::v1::Scan ScanToProto(const PosedScan& scan, const std::string& robot_id, uint64_t sequence);

// The inverse of ScanToProto for point scans, for tools and tests that read a Scan back.
// InvalidArgument naming the field for a depth scan, a length that is not a multiple of 12 or
// origins that are not one per point.
absl::StatusOr<PosedScan> ScanFromProto(const rim::v1::Scan& scan);

}  // namespace rim
