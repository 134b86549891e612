// PLY point clouds (the per-frame files of the MaiCity layout): reading and writing.
//
// Reading accepts format ascii, binary_little_endian and binary_big_endian. The `vertex` element
// gives the points: x, y, z are found by name and may have any PLY scalar type (float, double or
// integer); an `intensity` property is read if present; every other property and element
// (faces, ...) is skipped. Counts in the header are checked against the file size before
// anything is allocated. Points are returned as stored, non-finite ones included.
#pragma once

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/io/point_cloud.h"

namespace rim::io {

enum class PlyFormat { kAscii, kBinary /* binary_little_endian */ };

absl::StatusOr<PointCloud> ReadPlyPoints(const std::string& path);

// Parses PLY bytes already in memory; `path` is only used in messages.
absl::StatusOr<PointCloud> ParsePlyPoints(const std::string& data, const std::string& path);

// Writes a `vertex` element with float x, y, z (and float intensity if the cloud has them).
// ASCII uses 9 significant digits, which round-trips float32 exactly.
absl::Status WritePlyPoints(const std::string& path, const PointCloud& cloud, PlyFormat format);

}  // namespace rim::io
