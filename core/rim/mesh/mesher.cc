#include "rim/mesh/mesher.h"

#include <cmath>
#include <mutex>

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/strings/str_cat.h"
#include "rim/mesh/marching_cubes.h"
#include "rim/model/encoder.h"

namespace rim {
namespace {
constexpr size_t kChunkPoints = 32768;
}  // namespace

std::vector<Int3> ObservedVoxels(const MeshTileSource& src, const Int3& key) {
  const MapGeometry& geo = src.geometry;
  const Int3 cells = geo.cells(0);
  const Int3 tile_lo = key.cwiseProduct(cells), tile_hi = tile_lo + cells - Int3::Ones();
  std::vector<Int3> out;
  const LocalMap& map = src.local_map;
  // The live map is authoritative for every lattice point of the box, lo..hi inclusive: a cell's
  // flags live at its minimum corner, and a point of the box's max face keeps in the live map
  // what it was given while it was inside the box (the store gets it only when it leaves). Taking
  // the cells at hi from the store dropped them from the mesh along the faces of the last box,
  // though queries reported them observed.
  const IntBox box = map.LatticeBox(0);
  for (const Int3& g : src.store.ObservedCells(key))
    if (!map.placed() || !box.Contains(g)) out.push_back(g);
  if (map.placed()) {
    const Int3 lo = box.lo.cwiseMax(tile_lo);
    const Int3 hi = box.hi.cwiseMin(tile_hi);
    const LocalMap::Level& grid = map.level(0);
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) {
          const Int3 g(x, y, z);
          if (grid.flags(map.Slot(0, g)) & LocalMap::kObserved) out.push_back(g);
        }
  }
  return out;
}

absl::StatusOr<Mesh> ExtractTile(const MeshTileSource& src, float resolution_m, const Int3& key) {
  const MapGeometry& geo = src.geometry;
  const int r = int(std::lround(geo.leaf_m() / resolution_m));
  if (r < 1 || std::abs(r * double(resolution_m) - geo.leaf_m()) > 1e-6)
    return absl::InvalidArgumentError(
        absl::StrCat("mesh resolution ", resolution_m, " m does not divide the leaf size"));
  const double step = geo.leaf_m() / r;

  std::vector<Int3> cells;
  absl::flat_hash_set<Int3, Int3Hash, Int3Equal> observed_voxels;
  {
    std::shared_lock<std::shared_mutex> lock(src.mutex);
    for (const Int3& g : ObservedVoxels(src, key)) {
      observed_voxels.insert(g);
      for (int i = 0; i < r; ++i)
        for (int j = 0; j < r; ++j)
          for (int k = 0; k < r; ++k) cells.push_back(g * r + Int3(i, j, k));
    }
  }
  if (cells.empty()) return Mesh{};

  // Grid points of the cells, and whether each lies in an observed voxel. A point on a voxel face
  // belongs to every voxel that shares it; it counts as observed if any of them is, so that
  // meshes of neighbouring observed voxels join up.
  absl::flat_hash_map<Int3, float, Int3Hash, Int3Equal> values;
  std::vector<Int3> points;
  {
    absl::flat_hash_set<Int3, Int3Hash, Int3Equal> seen;
    std::shared_lock<std::shared_mutex> lock(src.mutex);
    FeatureReader reader(src.local_map, src.store);
    auto observed = [&](const Int3& m) {
      Int3 lo, hi;
      for (int a = 0; a < 3; ++a) {
        hi[a] = FloorDiv(m[a], r);
        lo[a] = (m[a] % r == 0) ? hi[a] - 1 : hi[a];
      }
      for (int x = lo.x(); x <= hi.x(); ++x)
        for (int y = lo.y(); y <= hi.y(); ++y)
          for (int z = lo.z(); z <= hi.z(); ++z) {
            const Int3 v(x, y, z);
            if (observed_voxels.count(v) || (reader.ObservedBits(v) & LocalMap::kObserved))
              return true;
          }
      return false;
    };
    for (const Int3& c : cells)
      for (int corner = 0; corner < 8; ++corner) {
        const Int3 m = c + Int3(corner >> 2 & 1, corner >> 1 & 1, corner & 1);
        if (seen.insert(m).second && observed(m)) points.push_back(m);
      }
  }

  const int F = geo.encoding_dim();
  std::vector<float> features, sdf;
  for (size_t begin = 0; begin < points.size(); begin += kChunkPoints) {
    const size_t n = std::min(kChunkPoints, points.size() - begin);
    features.resize(n * F);
    sdf.resize(n);
    std::shared_lock<std::shared_mutex> lock(src.mutex);
    FeatureReader reader(src.local_map, src.store);
    for (size_t i = 0; i < n; ++i) {
      const Int3& m = points[begin + i];
      reader.Encode(m.cast<double>() * step, &features[i * F], nullptr);
    }
    src.decoder.Forward(features.data(), int(n), sdf.data());
    for (size_t i = 0; i < n; ++i) values.emplace(points[begin + i], sdf[i]);
  }

  GridSamples samples;
  samples.step_m = float(step);
  samples.origin_m = Eigen::Vector3f::Zero();
  samples.lookup = [&values](const Int3& g, float* value) {
    auto it = values.find(g);
    if (it == values.end()) return false;
    *value = it->second;
    return true;
  };
  return MarchingCubes(cells, samples);
}

}  // namespace rim
