#include "rim/io/depth.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/io/file_util.h"
#include "rim/io/json.h"

namespace rim::io {

std::vector<Vec3f> BackProjectDepth(const Image16& depth, const CameraIntrinsics& K,
                                    const DepthEncoding& encoding) {
  std::vector<Vec3f> points;
  points.reserve(depth.pixels.size());
  const double inv_units = 1.0 / encoding.units_per_metre;
  for (int v = 0; v < depth.height; ++v) {
    for (int u = 0; u < depth.width; ++u) {
      const uint16_t d = depth.at(u, v);
      if (d == 0 || (encoding.max_is_invalid && d == 0xFFFF)) continue;
      const double z = d * inv_units;
      points.emplace_back(static_cast<float>((u - K.cx) * z / K.fx),
                          static_cast<float>((v - K.cy) * z / K.fy), static_cast<float>(z));
    }
  }
  return points;
}

absl::StatusOr<CameraIntrinsics> ReadIntrinsicsMatrixFile(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path, 1 << 20));
  return ParseIntrinsicsMatrix(data, path);
}

absl::StatusOr<CameraIntrinsics> ParseIntrinsicsMatrix(absl::string_view data,
                                                       const std::string& path) {
  std::vector<double> k;
  for (const TextLine& line : SplitLines(data, '#')) {
    RIM_ASSIGN_OR_RETURN(std::vector<double> row, ParseNumbers(line.text, path, line.number));
    k.insert(k.end(), row.begin(), row.end());
    if (k.size() > 9) break;
  }
  if (k.size() != 9) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": expected 9 numbers (3x3 intrinsics matrix K), found ", k.size()));
  }
  for (double x : k) {
    if (!std::isfinite(x)) {
      return absl::InvalidArgumentError(absl::StrCat(path, ": intrinsics value is not finite"));
    }
  }
  if (k[1] != 0 || k[3] != 0 || k[6] != 0 || k[7] != 0 || k[8] != 1) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": intrinsics must be [fx 0 cx; 0 fy cy; 0 0 1] (no skew), found [", k[0], " ", k[1],
        " ", k[2], "; ", k[3], " ", k[4], " ", k[5], "; ", k[6], " ", k[7], " ", k[8], "]"));
  }
  if (!(k[0] > 0) || !(k[4] > 0)) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": focal lengths must be positive (fx ", k[0], ", fy ", k[4], ")"));
  }
  CameraIntrinsics K;
  K.fx = k[0];
  K.fy = k[4];
  K.cx = k[2];
  K.cy = k[5];
  return K;
}

absl::StatusOr<ReplicaCamera> ReadReplicaCamParams(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path, 1 << 20));
  return ParseReplicaCamParams(data, path);
}

absl::StatusOr<ReplicaCamera> ParseReplicaCamParams(absl::string_view data,
                                                    const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const nlohmann::json root, ParseJson(data, path));
  if (!root.is_object()) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": expected a JSON object"));
  }
  const auto camera = root.find("camera");
  const bool has_camera = camera != root.end();
  const nlohmann::json& obj = has_camera && camera->is_object() ? *camera : root;
  auto get = [&](const char* key, double* out) -> absl::Status {
    const auto v = obj.find(key);
    if (v == obj.end() || !v->is_number() || !std::isfinite(v->get<double>())) {
      return absl::InvalidArgumentError(absl::StrCat(
          path, ": missing number '", key, "' (need w, h, fx, fy, cx, cy, scale",
          has_camera ? " in \"camera\")" : " in a \"camera\" object or at the top level)"));
    }
    *out = v->get<double>();
    return absl::OkStatus();
  };
  double w = 0, h = 0;
  ReplicaCamera cam;
  CameraIntrinsics& K = cam.intrinsics;
  RIM_RETURN_IF_ERROR(get("w", &w));
  RIM_RETURN_IF_ERROR(get("h", &h));
  RIM_RETURN_IF_ERROR(get("fx", &K.fx));
  RIM_RETURN_IF_ERROR(get("fy", &K.fy));
  RIM_RETURN_IF_ERROR(get("cx", &K.cx));
  RIM_RETURN_IF_ERROR(get("cy", &K.cy));
  RIM_RETURN_IF_ERROR(get("scale", &cam.scale));
  if (!(w >= 1 && w <= kMaxPngSide && w == std::floor(w)) ||
      !(h >= 1 && h <= kMaxPngSide && h == std::floor(h))) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": image size w ", w, ", h ", h, " is not a positive integer size"));
  }
  K.width = static_cast<int>(w);
  K.height = static_cast<int>(h);
  if (!(K.fx > 0) || !(K.fy > 0)) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": focal lengths must be positive (fx ", K.fx, ", fy ", K.fy, ")"));
  }
  if (!(cam.scale > 0)) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": depth 'scale' must be positive, found ", cam.scale));
  }
  return cam;
}

}  // namespace rim::io
