#include "server/warmup.h"

#include <chrono>
#include <cmath>
#include <vector>

#include "rim/base/status_macros.h"
#include "rim/config/config.h"
#include "rim/mapper.h"

namespace rim::server {
namespace {

// A sensor 1.5 m above a floor, facing a wall 3 m ahead: returns on a polar grid of the floor and
// a regular grid of the wall, in the sensor frame.
PosedScan Scene(double x) {
  PosedScan scan;
  scan.T_world_sensor = Eigen::Isometry3d::Identity();
  scan.T_world_sensor.translation() = Vec3d(x, 0, 0);
  for (int r = 1; r <= 20; ++r)
    for (int a = 0; a < 90; ++a) {
      const float rho = 0.15f * r, phi = float(a) * 6.2831853f / 90.f;
      scan.points_S.emplace_back(rho * std::cos(phi), rho * std::sin(phi), -1.5f);
    }
  for (int i = -20; i <= 20; ++i)
    for (int j = 0; j < 20; ++j)
      scan.points_S.emplace_back(float(3.0 - x), 0.1f * i, -1.5f + 0.1f * j);
  return scan;
}

}  // namespace

absl::StatusOr<double> WarmUp(int frames) {
  const auto start = std::chrono::steady_clock::now();
  if (frames <= 0) return 0.0;
  RIM_ASSIGN_OR_RETURN(MapperConfig config, MakePreset("maicity"));
  RIM_RETURN_IF_ERROR(ApplyOverrides({"grid.half_extent_x_m=4", "grid.half_extent_y_m=4",
                                      "grid.z_min_m=-2", "grid.z_max_m=2", "train.iterations=10"},
                                     &config));
  RIM_ASSIGN_OR_RETURN(std::unique_ptr<Mapper> mapper, Mapper::Create(config));
  for (int f = 0; f < frames; ++f) RIM_RETURN_IF_ERROR(mapper->IntegrateScan(Scene(0.2 * f)));
  std::vector<float> xyz;
  for (int i = 0; i < 1000; ++i) xyz.insert(xyz.end(), {0.003f * i, 0.f, -1.4f});
  QueryResult q;
  RIM_RETURN_IF_ERROR(mapper->QuerySdf(xyz.data(), xyz.size() / 3, /*want_gradient=*/true, &q));
  for (const TileInfo& t : mapper->ListTiles(0))
    RIM_RETURN_IF_ERROR(mapper->ExtractMeshTile(t.key).status());
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace rim::server
