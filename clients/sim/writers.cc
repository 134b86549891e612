#include "sim/writers.h"

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/io/png_io.h"

namespace rim::sim {
namespace {

absl::Status WriteBytes(const std::string& path, const void* data, size_t size) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) {
    return absl::ErrnoToStatus(errno, absl::StrCat("cannot open ", path, " for writing"));
  }
  const bool wrote = size == 0 || std::fwrite(data, 1, size, f) == size;
  const int write_errno = errno;
  const bool closed = std::fclose(f) == 0;
  if (!wrote || !closed) {
    return absl::ErrnoToStatus(wrote ? errno : write_errno, absl::StrCat("cannot write ", path));
  }
  return absl::OkStatus();
}

// A row of a 3x4 or 4x4 matrix with enough digits to round-trip doubles closely.
std::string MatrixRow(const Eigen::Matrix4d& m, int row, int cols, const char* sep) {
  std::string s;
  for (int c = 0; c < cols; ++c) {
    absl::StrAppendFormat(&s, "%s%.12e", c == 0 ? "" : sep, m(row, c) + 0.0);  // no "-0"
  }
  return s;
}

bool IsDigits(const std::string& s, size_t pos, size_t n) {
  if (s.size() < pos + n) return false;
  for (size_t i = pos; i < pos + n; ++i) {
    if (!std::isdigit(static_cast<unsigned char>(s[i]))) return false;
  }
  return true;
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

absl::Status WriteTextFile(const std::string& path, const std::string& content) {
  return WriteBytes(path, content.data(), content.size());
}

absl::Status WriteKittiScan(const std::string& path, const std::vector<LidarPoint>& points) {
  static_assert(sizeof(LidarPoint) == 16, "LidarPoint must be 4 packed floats");
  return WriteBytes(path, points.data(), points.size() * sizeof(LidarPoint));
}

absl::Status WritePointCloudPly(const std::string& path,
                                const std::vector<std::array<float, 3>>& points) {
  static_assert(sizeof(std::array<float, 3>) == 12, "points must be 3 packed floats");
  std::string bytes =
      absl::StrCat("ply\nformat binary_little_endian 1.0\nelement vertex ", points.size(),
                   "\nproperty float x\nproperty float y\nproperty float z\nend_header\n");
  const size_t header = bytes.size();
  bytes.resize(header + points.size() * 12);
  if (!points.empty()) std::memcpy(&bytes[header], points.data(), points.size() * 12);
  return WriteBytes(path, bytes.data(), bytes.size());
}

absl::Status WriteKittiPoses(const std::string& path, const std::vector<Eigen::Isometry3d>& poses) {
  std::string s;
  for (const Eigen::Isometry3d& p : poses) {
    const Eigen::Matrix4d m = p.matrix();
    for (int r = 0; r < 3; ++r) absl::StrAppend(&s, r == 0 ? "" : " ", MatrixRow(m, r, 4, " "));
    s += '\n';
  }
  return WriteTextFile(path, s);
}

absl::Status WriteKittiCalib(const std::string& path) {
  // Projection matrices of KITTI odometry sequence 00, kept for tools that expect them. They
  // describe KITTI's cameras, not anything rim_sim renders.
  constexpr double f = 718.856, cx = 607.1928, cy = 185.2157, b = -386.1448;
  std::string s;
  const double tx[4] = {0.0, b, 45.38225, -337.2877};
  for (int i = 0; i < 4; ++i) {
    absl::StrAppendFormat(&s,
                          "P%d: %.12e 0.000000000000e+00 %.12e %.12e 0.000000000000e+00 %.12e "
                          "%.12e 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 "
                          "1.000000000000e+00 0.000000000000e+00\n",
                          i, f, cx, tx[i], f, cy);
  }
  s += "Tr: 1.000000000000e+00 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 "
       "0.000000000000e+00 1.000000000000e+00 0.000000000000e+00 0.000000000000e+00 "
       "0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00\n";
  return WriteTextFile(path, s);
}

absl::Status WriteKittiTimes(const std::string& path, int frames, double frame_rate_hz) {
  std::string s;
  for (int k = 0; k < frames; ++k) absl::StrAppendFormat(&s, "%e\n", k / frame_rate_hz);
  return WriteTextFile(path, s);
}

std::vector<uint16_t> DepthToMillimetres(const std::vector<float>& depth) {
  std::vector<uint16_t> mm(depth.size(), 0);
  for (size_t i = 0; i < depth.size(); ++i) {
    const double v = std::round(static_cast<double>(depth[i]) * 1000.0);
    if (std::isfinite(v) && v >= 1.0 && v < 65535.0) mm[i] = static_cast<uint16_t>(v);
  }
  return mm;
}

absl::Status WritePng16(const std::string& path, int width, int height,
                        const std::vector<uint16_t>& pixels) {
  if (width <= 0 || height <= 0 || pixels.size() != static_cast<size_t>(width) * height) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: image is %dx%d but has %d pixels", path,
                                                      width, height, pixels.size()));
  }
  return io::WritePng16(path, width, height, pixels.data());
}

absl::StatusOr<Png16> ReadPng16(const std::string& path) {
  absl::StatusOr<io::Image16> image = io::ReadPng16(path);
  if (!image.ok()) return image.status();
  Png16 out;
  out.width = image->width;
  out.height = image->height;
  out.pixels = std::move(image->pixels);
  return out;
}

absl::Status WritePoseMatrix(const std::string& path, const Eigen::Isometry3d& pose) {
  const Eigen::Matrix4d m = pose.matrix();
  std::string s;
  for (int r = 0; r < 4; ++r) absl::StrAppend(&s, MatrixRow(m, r, 4, "\t"), "\n");
  return WriteTextFile(path, s);
}

absl::Status WriteIntrinsics(const std::string& path, const PinholeCamera& camera) {
  return WriteTextFile(path, absl::StrFormat("%.6f\t0\t%.6f\n0\t%.6f\t%.6f\n0\t0\t1\n", camera.fx,
                                             camera.cx, camera.fy, camera.cy));
}

absl::Status RemovePreviousOutput(const std::string& dir) {
  namespace fs = std::filesystem;
  auto remove_matching = [](const fs::path& folder, auto&& matches) -> absl::Status {
    std::error_code ec;
    if (!fs::is_directory(folder, ec)) return absl::OkStatus();
    std::vector<fs::path> doomed;
    for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
      if (!it->is_regular_file(ec)) continue;
      if (matches(it->path().filename().string())) doomed.push_back(it->path());
    }
    if (ec) return absl::ErrnoToStatus(ec.value(), absl::StrCat("cannot list ", folder.string()));
    for (const fs::path& p : doomed) {
      if (!fs::remove(p, ec) && ec) {
        return absl::ErrnoToStatus(ec.value(), absl::StrCat("cannot remove ", p.string()));
      }
    }
    return absl::OkStatus();
  };
  const fs::path velodyne = fs::path(dir) / "velodyne";
  absl::Status s = remove_matching(velodyne, [](const std::string& n) {
    return n.size() == 10 && IsDigits(n, 0, 6) && EndsWith(n, ".bin");
  });
  if (!s.ok()) return s;
  std::error_code ec;
  if (fs::is_directory(velodyne, ec) && fs::is_empty(velodyne, ec)) fs::remove(velodyne, ec);
  return remove_matching(fs::path(dir), [](const std::string& n) {
    for (const char* fixed :
         {"poses.txt", "calib.txt", "times.txt", "camera-intrinsics.txt", "gt.ply",
          "gt_observed.ply", "gt_moving_last.ply", "scene.json", "README.txt"}) {
      if (n == fixed) return true;
    }
    if (n.rfind("frame-", 0) != 0 || !IsDigits(n, 6, 6)) return false;
    const std::string rest = n.substr(12);
    return rest == ".depth.png" || rest == ".pose.txt" || rest == ".color.png";
  });
}

}  // namespace rim::sim
