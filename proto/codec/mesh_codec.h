// Draco encoding of mesh tiles for GetMeshTiles / WatchMeshTiles (DESIGN.md §5.1).
//
// Positions are quantised on a grid fixed by the tile, not by the vertices: the box is the tile's
// bounds (grown to any vertex outside them) and the bit count is the smallest that keeps the
// quantisation error below max_error_m for that box. Successive versions of a tile therefore use
// the same grid (while their vertices stay inside the tile), so unchanged surface does not jitter
// between versions, and the error bound holds whatever part of the tile the surface covers. No
// normals are sent: clients recompute them from the faces, which costs less than the bits.
//
// Draco's edgebreaker reorders vertices and faces; winding is kept. Faces with a repeated vertex
// index and vertices no face uses are dropped. Draco duplicates non-manifold vertices, so such a
// mesh decodes with more vertices at the same positions. A Draco payload has no checksum: the
// transport protects it; the decoder only guarantees that damaged bytes never crash and never
// yield an out-of-range index.
#pragma once

#include <array>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "rim/base/mesh.h"

namespace rim::codec {

// The smallest number of position quantisation bits b with sqrt(3) * range_m / (2^b - 1) / 2 <=
// max_error_m. Draco's quantiser divides a box of side range_m into 2^b - 1 steps per axis and
// rounds each coordinate to the nearest step, so a vertex moves by at most half a step per axis,
// sqrt(3) half-steps in space; max_error_m bounds that distance. For a 1 mm bound: 20 m and 26 m
// tiles need 15 bits, 6 m 13 bits. Capped at Draco's maximum of 30 bits, which meets 1 mm for
// boxes up to about 1200 km. InvalidArgument unless range_m >= 0 and max_error_m > 0, both finite.
absl::StatusOr<int> PositionQuantizationBits(double range_m, double max_error_m);

// Encodes `mesh` as an indexed Draco mesh (edgebreaker, positions only) so that every decoded
// vertex lies within max_error_m of its original. The bound includes a margin for float32
// rounding at the tile's coordinates; InvalidArgument when that margin alone exceeds max_error_m.
// InvalidArgument also for an invalid tile box, non-finite vertices, or face indices out of range.
// A mesh without faces (or with only degenerate ones) encodes to a small valid payload (22 bytes)
// that decodes to an empty mesh, so that "this tile is now empty" travels like any other version.
//
// `effort` picks Draco's coders: kSmallest (speed 4: valence edgebreaker, parallelogram
// prediction) for the fewest bytes, kFaster (speed 8: standard edgebreaker, difference
// prediction) for less time. On watched city tiles (docs/perf-log.md, "The 0.2 m watcher through
// the server"): at 0.2 m cells both give the same bytes and kFaster takes 10-18 % less time; at
// 0.1 m it is 8-13 % faster for 5 % more bytes, at 5 cm 16-19 % faster for 15 % more.
enum class DracoEffort { kSmallest, kFaster };
// The effort the service gives a tile meshed at `cell_m` cells when its finest level is
// `finest_m`: kFaster from four times the finest cell up, where it costs no bytes; kSmallest below.
inline DracoEffort TileEffort(double cell_m, double finest_m) {
  return cell_m >= 4 * finest_m * (1 - 1e-6) ? DracoEffort::kFaster : DracoEffort::kSmallest;
}
absl::StatusOr<std::string> EncodeTileDraco(const Mesh& mesh, const std::array<double, 3>& tile_min,
                                            const std::array<double, 3>& tile_max,
                                            double max_error_m = 0.001,
                                            DracoEffort effort = DracoEffort::kSmallest);

// Decodes a payload of EncodeTileDraco (or any Draco triangle mesh with 3D positions). DataLoss
// for bytes that are not such a mesh, including truncated or corrupted payloads and decoded
// meshes with out-of-range indices or non-finite positions.
absl::StatusOr<Mesh> DecodeTileDraco(std::string_view bytes);

}  // namespace rim::codec
