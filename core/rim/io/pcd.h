// PCD (Point Cloud Library) v0.7 point clouds: reading and writing.
//
// Reading understands the header keywords VERSION, FIELDS (or COLUMNS), SIZE, TYPE, COUNT,
// WIDTH, HEIGHT, VIEWPOINT, POINTS and DATA, with DATA ascii, binary (array of structures) or
// binary_compressed (u32 compressed size, u32 uncompressed size, LZF stream of the fields stored
// one after another, structure of arrays). Fields may come in any order: x, y, z must be F with
// SIZE 4 or 8 and COUNT 1; an `intensity` field of any numeric type is read if present; every
// other field is skipped. VIEWPOINT is parsed but not applied: points are returned as stored.
// Points with a NaN or infinite coordinate (PCD's "no return") are dropped. Header counts are
// checked against the file size before anything is allocated.
#pragma once

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/io/point_cloud.h"

namespace rim::io {

enum class PcdDataMode { kAscii, kBinary, kBinaryCompressed };

// Reads a PCD file; errors name the file and the header line or data position at fault.
absl::StatusOr<PointCloud> ReadPcd(const std::string& path);

// Parses PCD bytes already in memory; `path` is only used in messages.
absl::StatusOr<PointCloud> ParsePcd(const std::string& data, const std::string& path);

// Writes fields x y z (and intensity, if the cloud has intensities), float32, WIDTH = POINTS,
// HEIGHT 1, identity VIEWPOINT. ASCII uses 9 significant digits, which round-trips float32
// exactly.
absl::Status WritePcd(const std::string& path, const PointCloud& cloud, PcdDataMode mode);

}  // namespace rim::io
