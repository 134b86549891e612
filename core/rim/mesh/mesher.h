// Mesh tiles (§3.6): marching cubes over one sub-map's observed voxels on a world-aligned grid.
#pragma once

#include <shared_mutex>

#include "absl/status/statusor.h"
#include "rim/base/mesh.h"
#include "rim/map/local_map.h"
#include "rim/map/submap_store.h"
#include "rim/model/decoder.h"

namespace rim {

struct MeshTileSource {
  const MapGeometry& geometry;
  const LocalMap& local_map;
  const SubmapStore& store;
  const Decoder& decoder;
  std::shared_mutex& mutex;  // shared while reading the map, released between chunks
};

// Finest-level voxels (minimum-corner lattice index) owned by sub-map `key` that were observed:
// from the live local map inside the box, from the store elsewhere. Caller holds the shared lock.
std::vector<Int3> ObservedVoxels(const MeshTileSource& src, const Int3& key);

// Meshes the tile of sub-map `key` at `resolution_m` (which divides the leaf size).
// - Only observed finest voxels are visited (sparse), and a mesh cell is meshed only when all its
//   grid points lie in observed voxels.
// - The tile owns the mesh cells whose minimum corner lies in its sub-map; cells on its upper
//   border read features across the border, so neighbouring tiles compute bit-identical vertices
//   on their shared faces (no seams, no gaps).
// - The SDF is evaluated in chunks, each under the shared lock, so that meshing a large tile
//   never holds training up for more than one chunk.
absl::StatusOr<Mesh> ExtractTile(const MeshTileSource& src, float resolution_m, const Int3& key);

}  // namespace rim
