#include "client/tiles.h"

#include <cmath>
#include <unordered_map>
#include <utility>

#include "absl/strings/str_cat.h"
#include "proto/codec/mesh_codec.h"
#include "rim/io/mesh_io.h"

namespace rim {
namespace {

struct CellHash {
  size_t operator()(const std::array<int64_t, 3>& c) const {
    uint64_t h = static_cast<uint64_t>(c[0]) * 0x9E3779B97F4A7C15ull;
    h ^= static_cast<uint64_t>(c[1]) * 0xC2B2AE3D27D4EB4Full;
    h ^= static_cast<uint64_t>(c[2]) * 0x165667B19E3779F9ull;
    return static_cast<size_t>(h ^ (h >> 29));
  }
};

}  // namespace

absl::StatusOr<DecodedTile> DecodeTile(const rim::v1::MeshTile& tile) {
  DecodedTile out;
  out.key = {tile.key_x(), tile.key_y(), tile.key_z()};
  out.version = tile.version();
  out.resolution_m = tile.resolution_m();
  out.bounds_min = {tile.bounds().min().x(), tile.bounds().min().y(), tile.bounds().min().z()};
  out.bounds_max = {tile.bounds().max().x(), tile.bounds().max().y(), tile.bounds().max().z()};
  out.draco = tile.draco();
  const std::string name =
      absl::StrCat("tile (", tile.key_x(), ",", tile.key_y(), ",", tile.key_z(), ")");
  auto mesh = codec::DecodeTileDraco(out.draco);
  if (!mesh.ok()) {
    return absl::DataLossError(
        absl::StrCat(name, " version ", tile.version(), ": ", mesh.status().message()));
  }
  out.mesh = std::move(*mesh);
  return out;
}

Mesh WeldVertices(const Mesh& mesh, double tolerance_m) {
  if (!(tolerance_m > 0)) return WeldIdenticalVertices(mesh);
  const double tol2 = tolerance_m * tolerance_m;
  auto cell_of = [&](const std::array<float, 3>& v) {
    return std::array<int64_t, 3>{static_cast<int64_t>(std::floor(v[0] / tolerance_m)),
                                  static_cast<int64_t>(std::floor(v[1] / tolerance_m)),
                                  static_cast<int64_t>(std::floor(v[2] / tolerance_m))};
  };
  // Kept vertices by cell. A vertex within the tolerance of a kept one lies in the same or an
  // adjacent cell, so 27 cells are searched.
  std::unordered_map<std::array<int64_t, 3>, std::vector<uint32_t>, CellHash> grid;
  grid.reserve(mesh.vertices.size());
  Mesh out;
  std::vector<uint32_t> remap(mesh.vertices.size());
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    const auto& v = mesh.vertices[i];
    const auto c = cell_of(v);
    int64_t found = -1;
    for (int dx = -1; dx <= 1 && found < 0; ++dx) {
      for (int dy = -1; dy <= 1 && found < 0; ++dy) {
        for (int dz = -1; dz <= 1 && found < 0; ++dz) {
          auto it = grid.find({c[0] + dx, c[1] + dy, c[2] + dz});
          if (it == grid.end()) continue;
          for (uint32_t k : it->second) {
            const auto& w = out.vertices[k];
            const double ex = double(v[0]) - w[0], ey = double(v[1]) - w[1],
                         ez = double(v[2]) - w[2];
            if (ex * ex + ey * ey + ez * ez <= tol2) {
              found = k;
              break;
            }
          }
        }
      }
    }
    if (found < 0) {
      found = static_cast<int64_t>(out.vertices.size());
      out.vertices.push_back(v);
      grid[c].push_back(static_cast<uint32_t>(found));
    }
    remap[i] = static_cast<uint32_t>(found);
  }
  AppendRemappedFaces(mesh, remap, &out);
  return out;
}

Mesh MergeTiles(const std::vector<DecodedTile>& tiles, double tolerance_m) {
  Mesh all;
  for (const DecodedTile& tile : tiles) AppendMesh(tile.mesh, &all);
  return WeldVertices(all, tolerance_m);
}

}  // namespace rim
