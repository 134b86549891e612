// PCD reader. The writer is in pcd_write.cc.
#include "rim/io/pcd.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "rim/base/status_macros.h"
#include "rim/io/file_util.h"
#include "rim/io/lzf.h"

namespace rim::io {
namespace {

constexpr size_t kMaxHeaderLines = 1000;
constexpr uint64_t kMaxFieldCount = 1 << 16;  // COUNT of one field

struct PcdField {
  std::string name;
  uint64_t size = 0;
  char type = 0;
  uint64_t count = 1;
  uint64_t offset = 0;  // within one point (binary) or as a multiple of POINTS (compressed)
};

struct PcdHeader {
  std::vector<PcdField> fields;
  uint64_t width = 0, height = 0, points = 0;
  bool have_points = false;
  PcdDataMode mode = PcdDataMode::kAscii;
  uint64_t point_step = 0;
  uint64_t tokens_per_point = 0;
  size_t data_offset = 0;
  int data_line = 0;  // line number of the DATA line
  int x = -1, y = -1, z = -1, intensity = -1;
};

absl::StatusOr<PcdHeader> ParseHeader(const std::string& data, const std::string& path) {
  PcdHeader h;
  std::vector<absl::string_view> sizes, types, counts;
  bool have_fields = false, have_width = false, have_height = false, have_data = false;
  size_t pos = 0;
  int line_no = 0;
  while (!have_data) {
    if (pos >= data.size() || line_no >= static_cast<int>(kMaxHeaderLines)) {
      return absl::InvalidArgumentError(absl::StrCat(path, ": bad PCD header: no DATA line"));
    }
    size_t eol = data.find('\n', pos);
    if (eol == std::string::npos) eol = data.size();
    absl::string_view line(data.data() + pos, eol - pos);
    pos = eol + 1;
    ++line_no;
    auto error = [&](absl::string_view what) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ":", line_no, ": bad PCD header: ", what));
    };
    std::vector<absl::string_view> tok =
        absl::StrSplit(line, absl::ByAnyChar(" \t\r"), absl::SkipEmpty());
    if (tok.empty() || tok[0][0] == '#') continue;
    const absl::string_view key = tok[0];
    tok.erase(tok.begin());
    auto one_uint = [&](uint64_t* v) -> absl::Status {
      if (tok.size() != 1 || !absl::SimpleAtoi(tok[0], v)) {
        return error(absl::StrCat(key, " needs one non-negative integer"));
      }
      return absl::OkStatus();
    };
    if (key == "VERSION") {
    } else if (key == "FIELDS" || key == "COLUMNS") {
      if (tok.empty()) return error("FIELDS lists no fields");
      for (absl::string_view name : tok) h.fields.push_back({std::string(name)});
      have_fields = true;
    } else if (key == "SIZE") {
      sizes = tok;
    } else if (key == "TYPE") {
      types = tok;
    } else if (key == "COUNT") {
      counts = tok;
    } else if (key == "WIDTH") {
      RIM_RETURN_IF_ERROR(one_uint(&h.width));
      have_width = true;
    } else if (key == "HEIGHT") {
      RIM_RETURN_IF_ERROR(one_uint(&h.height));
      have_height = true;
    } else if (key == "POINTS") {
      RIM_RETURN_IF_ERROR(one_uint(&h.points));
      h.have_points = true;
    } else if (key == "VIEWPOINT") {
      if (tok.size() != 7) return error("VIEWPOINT needs 7 numbers (tx ty tz qw qx qy qz)");
      for (absl::string_view t : tok) {
        double v;
        if (!absl::SimpleAtod(t, &v) || !std::isfinite(v)) return error("bad VIEWPOINT value");
      }
    } else if (key == "DATA") {
      if (tok.size() != 1) return error("DATA needs one of ascii, binary, binary_compressed");
      if (tok[0] == "ascii") {
        h.mode = PcdDataMode::kAscii;
      } else if (tok[0] == "binary") {
        h.mode = PcdDataMode::kBinary;
      } else if (tok[0] == "binary_compressed") {
        h.mode = PcdDataMode::kBinaryCompressed;
      } else {
        return error(absl::StrCat("unknown DATA type '", tok[0].substr(0, 40), "'"));
      }
      have_data = true;
      h.data_line = line_no;
    } else {
      return error(absl::StrCat("unknown keyword '", key.substr(0, 40), "'"));
    }
  }
  h.data_offset = std::min(pos, data.size());
  auto error = [&](absl::string_view what) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": bad PCD header: ", what));
  };
  if (!have_fields) return error("no FIELDS line");
  if (!have_width || !have_height) return error("missing WIDTH or HEIGHT");
  const size_t nf = h.fields.size();
  if (sizes.size() != nf || types.size() != nf || (!counts.empty() && counts.size() != nf)) {
    return error(absl::StrCat(nf, " FIELDS but ", sizes.size(), " SIZE, ", types.size(),
                              " TYPE and ", counts.size(), " COUNT entries"));
  }
  if (h.height != 0 && h.width > std::numeric_limits<uint64_t>::max() / h.height) {
    return error("WIDTH * HEIGHT overflows");
  }
  if (!h.have_points) h.points = h.width * h.height;
  if (h.points != h.width * h.height) {
    return error(
        absl::StrCat("POINTS ", h.points, " disagrees with WIDTH * HEIGHT = ", h.width * h.height));
  }
  for (size_t i = 0; i < nf; ++i) {
    PcdField& f = h.fields[i];
    if (!absl::SimpleAtoi(sizes[i], &f.size) ||
        (f.size != 1 && f.size != 2 && f.size != 4 && f.size != 8)) {
      return error(absl::StrCat("field '", f.name, "' has SIZE '", sizes[i].substr(0, 20),
                                "', expected 1, 2, 4 or 8"));
    }
    if (types[i].size() != 1 || (types[i][0] != 'F' && types[i][0] != 'I' && types[i][0] != 'U') ||
        (types[i][0] == 'F' && f.size < 4)) {
      return error(absl::StrCat("field '", f.name, "' has TYPE '", types[i].substr(0, 20),
                                "' with SIZE ", f.size));
    }
    f.type = types[i][0];
    if (!counts.empty() &&
        (!absl::SimpleAtoi(counts[i], &f.count) || f.count == 0 || f.count > kMaxFieldCount)) {
      return error(absl::StrCat("field '", f.name, "' has COUNT '", counts[i].substr(0, 20), "'"));
    }
    f.offset = h.point_step;
    h.point_step += f.size * f.count;
    h.tokens_per_point += f.count;
    int* slot = f.name == "x"           ? &h.x
                : f.name == "y"         ? &h.y
                : f.name == "z"         ? &h.z
                : f.name == "intensity" ? &h.intensity
                                        : nullptr;
    if (slot != nullptr && *slot < 0) *slot = static_cast<int>(i);
  }
  for (int idx : {h.x, h.y, h.z}) {
    if (idx < 0) return error("FIELDS must include x, y and z");
    const PcdField& f = h.fields[idx];
    if (f.type != 'F' || f.count != 1) {
      return error(absl::StrCat("field '", f.name, "' must be TYPE F with COUNT 1"));
    }
  }
  if (h.intensity >= 0 && h.fields[h.intensity].count != 1) h.intensity = -1;
  return h;
}

// The value of a binary field at `p` as a double (exact for F4 and integers up to 2^53).
double LoadValue(const char* p, const PcdField& f) {
  switch (f.type) {
    case 'F':
      if (f.size == 4) {
        float v;
        std::memcpy(&v, p, 4);
        return v;
      } else {
        double v;
        std::memcpy(&v, p, 8);
        return v;
      }
    case 'I': {
      int64_t v = 0;
      std::memcpy(&v, p, f.size);  // little-endian: low bytes first
      const int shift = 64 - 8 * static_cast<int>(f.size);
      return static_cast<double>(static_cast<int64_t>(static_cast<uint64_t>(v) << shift) >> shift);
    }
    default: {
      uint64_t v = 0;
      std::memcpy(&v, p, f.size);
      return static_cast<double>(v);
    }
  }
}

float LoadCoord(const char* p, const PcdField& f) {
  if (f.size == 4) {
    float v;
    std::memcpy(&v, p, 4);
    return v;
  }
  return static_cast<float>(LoadValue(p, f));
}

// Fills `cloud` from binary data; `field_base(f)` gives the byte position of field f of point 0
// and `stride(f)` the distance between consecutive points.
template <typename Base, typename Stride>
void ReadBinaryPoints(const char* data, const PcdHeader& h, Base field_base, Stride stride,
                      PointCloud* cloud) {
  const PcdField &fx = h.fields[h.x], &fy = h.fields[h.y], &fz = h.fields[h.z];
  const char *bx = data + field_base(fx), *by = data + field_base(fy), *bz = data + field_base(fz);
  const uint64_t sx = stride(fx), sy = stride(fy), sz = stride(fz);
  cloud->points.resize(h.points);
  for (uint64_t i = 0; i < h.points; ++i) {
    cloud->points[i] =
        Vec3f(LoadCoord(bx + i * sx, fx), LoadCoord(by + i * sy, fy), LoadCoord(bz + i * sz, fz));
  }
  if (h.intensity >= 0) {
    const PcdField& fi = h.fields[h.intensity];
    const char* bi = data + field_base(fi);
    const uint64_t si = stride(fi);
    cloud->intensity.resize(h.points);
    for (uint64_t i = 0; i < h.points; ++i) {
      cloud->intensity[i] = static_cast<float>(LoadValue(bi + i * si, fi));
    }
  }
}

absl::Status ReadAsciiPoints(const std::string& data, const PcdHeader& h, const std::string& path,
                             PointCloud* cloud) {
  // Each value takes at least two characters (digit and separator): a cheap bound on POINTS.
  const uint64_t body = data.size() - h.data_offset;
  if (h.points > body / (2 * h.tokens_per_point) + 1) {
    return absl::DataLossError(absl::StrCat(path, ": POINTS ", h.points, " cannot fit in the ",
                                            body, " bytes of ascii data after the header"));
  }
  // Token index of each wanted field within a point's line.
  uint64_t token_of[4] = {0, 0, 0, 0};
  const int wanted[4] = {h.x, h.y, h.z, h.intensity};
  for (int k = 0; k < 4; ++k) {
    if (wanted[k] < 0) continue;
    uint64_t t = 0;
    for (int i = 0; i < wanted[k]; ++i) t += h.fields[i].count;
    token_of[k] = t;
  }
  cloud->points.reserve(h.points);
  if (h.intensity >= 0) cloud->intensity.reserve(h.points);
  size_t pos = h.data_offset;
  int line_no = h.data_line;
  std::vector<absl::string_view> tok;
  for (uint64_t i = 0; i < h.points;) {
    if (pos >= data.size()) {
      return absl::DataLossError(absl::StrCat(path, ": POINTS ", h.points,
                                              " but the ascii data ends after ", i, " points"));
    }
    size_t eol = data.find('\n', pos);
    if (eol == std::string::npos) eol = data.size();
    absl::string_view line(data.data() + pos, eol - pos);
    pos = eol + 1;
    ++line_no;
    tok = absl::StrSplit(line, absl::ByAnyChar(" \t\r"), absl::SkipEmpty());
    if (tok.empty()) continue;
    if (tok.size() != h.tokens_per_point) {
      return absl::DataLossError(absl::StrCat(path, ":", line_no, ": expected ", h.tokens_per_point,
                                              " values, found ", tok.size()));
    }
    float v[4] = {0, 0, 0, 0};
    for (int k = 0; k < 4; ++k) {
      if (wanted[k] < 0) continue;
      const absl::string_view t = tok[token_of[k]];
      bool ok;
      if (h.fields[wanted[k]].type == 'F' && h.fields[wanted[k]].size == 4) {
        ok = absl::SimpleAtof(t, &v[k]);
      } else {
        double d;
        ok = absl::SimpleAtod(t, &d);
        v[k] = static_cast<float>(d);
      }
      if (!ok) {
        return absl::DataLossError(absl::StrCat(path, ":", line_no, ": field '",
                                                h.fields[wanted[k]].name, "' value '",
                                                t.substr(0, 40), "' is not a number"));
      }
    }
    cloud->points.emplace_back(v[0], v[1], v[2]);
    if (h.intensity >= 0) cloud->intensity.push_back(v[3]);
    ++i;
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<PointCloud> ParsePcd(const std::string& data, const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const PcdHeader h, ParseHeader(data, path));
  PointCloud cloud;
  const uint64_t body = data.size() - h.data_offset;
  if (h.mode == PcdDataMode::kAscii) {
    RIM_RETURN_IF_ERROR(ReadAsciiPoints(data, h, path, &cloud));
  } else if (h.mode == PcdDataMode::kBinary) {
    if (h.point_step != 0 && h.points > body / h.point_step) {
      return absl::DataLossError(absl::StrCat(path, ": POINTS ", h.points, " of ", h.point_step,
                                              " bytes need more than the ", body,
                                              " bytes of binary data after the header"));
    }
    ReadBinaryPoints(
        data.data() + h.data_offset, h, [](const PcdField& f) { return f.offset; },
        [&h](const PcdField&) { return h.point_step; }, &cloud);
  } else {
    if (body < 8) {
      return absl::DataLossError(
          absl::StrCat(path, ": binary_compressed data is missing its 8-byte size header"));
    }
    uint32_t compressed = 0, uncompressed = 0;
    std::memcpy(&compressed, data.data() + h.data_offset, 4);
    std::memcpy(&uncompressed, data.data() + h.data_offset + 4, 4);
    if (compressed > body - 8) {
      return absl::DataLossError(absl::StrCat(path, ": compressed size ", compressed,
                                              " is more than the ", body - 8,
                                              " bytes after the header"));
    }
    if (h.point_step != 0 && h.points > std::numeric_limits<uint32_t>::max() / h.point_step) {
      return absl::DataLossError(absl::StrCat(path, ": POINTS ", h.points, " too large"));
    }
    if (uint64_t{uncompressed} != h.points * h.point_step) {
      return absl::DataLossError(absl::StrCat(path, ": uncompressed size ", uncompressed,
                                              " disagrees with POINTS ", h.points, " * ",
                                              h.point_step, " bytes per point"));
    }
    RIM_ASSIGN_OR_RETURN(
        const std::string raw,
        LzfDecompress(absl::string_view(data.data() + h.data_offset + 8, compressed), uncompressed,
                      path));
    ReadBinaryPoints(
        raw.data(), h, [&h](const PcdField& f) { return f.offset * h.points; },
        [](const PcdField& f) { return f.size * f.count; }, &cloud);
  }
  DropNonFinitePoints(&cloud);
  return cloud;
}

absl::StatusOr<PointCloud> ReadPcd(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path));
  return ParsePcd(data, path);
}

}  // namespace rim::io
