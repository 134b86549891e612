// PCD writer. The reader is in pcd.cc.
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/io/file_util.h"
#include "rim/io/lzf.h"
#include "rim/io/pcd.h"

namespace rim::io {
namespace {

void AppendFloat(float v, std::string* out) {
  char b[4];
  std::memcpy(b, &v, 4);
  out->append(b, 4);
}

void AppendU32(uint32_t v, std::string* out) {
  char b[4];
  std::memcpy(b, &v, 4);
  out->append(b, 4);
}

}  // namespace

absl::Status WritePcd(const std::string& path, const PointCloud& cloud, PcdDataMode mode) {
  const size_t n = cloud.points.size();
  const bool has_intensity = !cloud.intensity.empty();
  if (has_intensity && cloud.intensity.size() != n) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": ", cloud.intensity.size(), " intensities for ", n, " points"));
  }
  const int nf = has_intensity ? 4 : 3;
  if (mode == PcdDataMode::kBinaryCompressed &&
      n > std::numeric_limits<uint32_t>::max() / (4 * nf)) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": too many points (", n, ") for binary_compressed PCD"));
  }
  const char* data_name = mode == PcdDataMode::kAscii    ? "ascii"
                          : mode == PcdDataMode::kBinary ? "binary"
                                                         : "binary_compressed";
  std::string out = absl::StrCat(
      "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n",
      has_intensity ? "FIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
                    : "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n",
      "WIDTH ", n, "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS ", n, "\nDATA ", data_name, "\n");
  auto value = [&](size_t i, int f) { return f < 3 ? cloud.points[i][f] : cloud.intensity[i]; };
  switch (mode) {
    case PcdDataMode::kAscii:
      for (size_t i = 0; i < n; ++i) {
        for (int f = 0; f < nf; ++f)
          absl::StrAppendFormat(&out, "%s%.9g", f ? " " : "", value(i, f));
        out.push_back('\n');
      }
      break;
    case PcdDataMode::kBinary:
      out.reserve(out.size() + n * 4 * nf);
      for (size_t i = 0; i < n; ++i) {
        for (int f = 0; f < nf; ++f) AppendFloat(value(i, f), &out);
      }
      break;
    case PcdDataMode::kBinaryCompressed: {
      std::string soa;
      soa.reserve(n * 4 * nf);
      for (int f = 0; f < nf; ++f) {
        for (size_t i = 0; i < n; ++i) AppendFloat(value(i, f), &soa);
      }
      const std::string packed = LzfCompress(soa);
      if (packed.size() > std::numeric_limits<uint32_t>::max()) {
        return absl::InvalidArgumentError(absl::StrCat(path, ": compressed data exceeds 4 GiB"));
      }
      AppendU32(static_cast<uint32_t>(packed.size()), &out);
      AppendU32(static_cast<uint32_t>(soa.size()), &out);
      out += packed;
      break;
    }
  }
  return WriteStringToFile(path, out);
}

}  // namespace rim::io
