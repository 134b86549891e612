// rimctl query's file formats: query points in as CSV, answers out as CSV or NumPy .npy.
#pragma once

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "client/client.h"
#include "rim/base/types.h"

namespace rim::rimctl {

// Parses CSV points: x,y,z per line, separated by commas (spaces around values allowed). A first
// line that does not start with a number is a header and skipped; blank lines and lines starting
// with '#' are skipped; columns after the third are ignored, so a query's own output can be fed
// back in. InvalidArgument naming `source` and the line for anything else (too few columns, a value
// that is not a finite number), or for input without points.
absl::StatusOr<std::vector<Vec3f>> ParsePointsCsv(const std::string& text,
                                                  const std::string& source);

// The answer as CSV: header `x,y,z,sdf,observed` (plus `,gx,gy,gz` with gradients), observed as
// 0/1, one row per point in input order. Floats are written with 9 significant digits, so they
// read back bit-exact.
std::string FormatQueryCsv(const std::vector<Vec3f>& points, const QueryResult& result,
                           bool with_gradient);

// The same columns as a NumPy .npy file (format 1.0): little-endian float32, shape N x 5 (or
// N x 8 with gradients), C order.
std::string FormatQueryNpy(const std::vector<Vec3f>& points, const QueryResult& result,
                           bool with_gradient);

}  // namespace rim::rimctl
