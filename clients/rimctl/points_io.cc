#include "rimctl/points_io.h"

#include <cmath>
#include <cstring>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"

namespace rim::rimctl {
namespace {

// The row of one point: x, y, z, sdf, observed (0/1) and, when asked, the gradient.
std::vector<float> Row(const std::vector<Vec3f>& points, const QueryResult& result, size_t i,
                       bool with_gradient) {
  std::vector<float> row = {points[i].x(), points[i].y(), points[i].z(), result.sdf[i],
                            result.observed[i] ? 1.f : 0.f};
  if (with_gradient) {
    for (int k = 0; k < 3; ++k) row.push_back(result.gradient[3 * i + k]);
  }
  return row;
}

}  // namespace

absl::StatusOr<std::vector<Vec3f>> ParsePointsCsv(const std::string& text,
                                                  const std::string& source) {
  std::vector<Vec3f> points;
  size_t line_number = 0;
  bool seen_content = false;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    ++line_number;
    line = absl::StripAsciiWhitespace(line);
    if (line.empty() || line[0] == '#') continue;
    const std::vector<absl::string_view> cells = absl::StrSplit(line, ',');
    float xyz[3];
    bool numeric = cells.size() >= 3;
    for (size_t k = 0; numeric && k < 3; ++k) {
      numeric = absl::SimpleAtof(absl::StripAsciiWhitespace(cells[k]), &xyz[k]);
    }
    // A header is a first line that does not start with a number ("x,y,z"); a first line like
    // "1,2" is a broken data row and an error.
    float ignored = 0;
    const bool header =
        !seen_content && !absl::SimpleAtof(absl::StripAsciiWhitespace(cells[0]), &ignored);
    seen_content = true;
    if (header) continue;
    if (!numeric) {
      return absl::InvalidArgumentError(absl::StrCat(
          source, ":", line_number, ": expected x,y,z (three numbers), got '", line, "'"));
    }
    if (!std::isfinite(xyz[0]) || !std::isfinite(xyz[1]) || !std::isfinite(xyz[2])) {
      return absl::InvalidArgumentError(
          absl::StrCat(source, ":", line_number, ": point '", line, "' is not finite"));
    }
    points.emplace_back(xyz[0], xyz[1], xyz[2]);
  }
  if (points.empty()) {
    return absl::InvalidArgumentError(absl::StrCat(source, ": no points (expected x,y,z lines)"));
  }
  return points;
}

std::string FormatQueryCsv(const std::vector<Vec3f>& points, const QueryResult& result,
                           bool with_gradient) {
  std::string out = with_gradient ? "x,y,z,sdf,observed,gx,gy,gz\n" : "x,y,z,sdf,observed\n";
  for (size_t i = 0; i < points.size(); ++i) {
    const std::vector<float> row = Row(points, result, i, with_gradient);
    for (size_t k = 0; k < row.size(); ++k) {
      if (k > 0) out += ',';
      if (k == 4) {
        out += result.observed[i] ? '1' : '0';
      } else {
        absl::StrAppendFormat(&out, "%.9g", row[k]);
      }
    }
    out += '\n';
  }
  return out;
}

std::string FormatQueryNpy(const std::vector<Vec3f>& points, const QueryResult& result,
                           bool with_gradient) {
  const int columns = with_gradient ? 8 : 5;
  std::string header = absl::StrFormat(
      "{'descr': '<f4', 'fortran_order': False, 'shape': (%d, %d), }", points.size(), columns);
  // Magic (6) + version (2) + header length (2) + header, padded with spaces and ended by a
  // newline so that the data starts on a 64-byte boundary, as NumPy writes it.
  const size_t unpadded = 10 + header.size() + 1;
  header.append((64 - unpadded % 64) % 64, ' ');
  header += '\n';
  std::string out = "\x93NUMPY";
  out += '\x01';
  out += '\x00';
  out += static_cast<char>(header.size() & 0xff);
  out += static_cast<char>(header.size() >> 8);
  out += header;
  const size_t data_begin = out.size();
  out.resize(data_begin + points.size() * columns * 4);
  for (size_t i = 0; i < points.size(); ++i) {
    const std::vector<float> row = Row(points, result, i, with_gradient);
    std::memcpy(&out[data_begin + i * columns * 4], row.data(), columns * 4);
  }
  return out;
}

}  // namespace rim::rimctl
