// Mesh tiles on the client side: decoding a wire MeshTile (Draco) and stitching decoded tiles into
// one mesh.
//
// Neighbouring tiles (sub-maps) share their border vertices: the server meshes each sub-map with
// the vertices on its faces computed identically on both sides. Draco then quantises each tile on
// its own grid with at most 1 mm error per vertex, so a shared vertex arrives as two copies up to
// 2 mm apart. Welding with a 2 mm tolerance joins them, and the merged mesh has no seams.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "rim/base/mesh.h"
#include "rim/v1/rim.pb.h"

namespace rim {

struct DecodedTile {
  std::array<int32_t, 3> key = {0, 0, 0};  // sub-map index
  uint64_t version = 0;
  std::array<double, 3> bounds_min = {0, 0, 0};
  std::array<double, 3> bounds_max = {0, 0, 0};
  std::string draco;       // the payload as received
  Mesh mesh;               // decoded (empty for a tile whose surface went away)
  float resolution_m = 0;  // its level of detail (mesh cell size, metres)
};

// Decodes `tile`'s Draco payload. DataLoss naming the tile key and version when the payload is
// damaged. (The announced vertex/face counts are not checked against the decoded mesh: Draco drops
// degenerate faces and splits non-manifold vertices, so they may legitimately differ.)
absl::StatusOr<DecodedTile> DecodeTile(const rim::v1::MeshTile& tile);

// Merges vertices closer than tolerance_m (greedy: each vertex joins the first earlier kept vertex
// within the tolerance, else is kept), keeping first-occurrence order. Faces that collapse to a
// repeated index are dropped. A hash grid of tolerance_m cells keeps it linear in the vertex count.
// tolerance_m <= 0 merges only bit-identical positions.
Mesh WeldVertices(const Mesh& mesh, double tolerance_m);

// Concatenates the tiles' meshes and welds them with `tolerance_m` (2 mm covers two copies of a
// shared border vertex, each quantised within 1 mm).
Mesh MergeTiles(const std::vector<DecodedTile>& tiles, double tolerance_m = 0.002);

}  // namespace rim
