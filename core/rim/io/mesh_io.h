// PLY reading and writing for rim::Mesh, plus helpers for stitching per-tile meshes together.
#pragma once

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/base/mesh.h"

namespace rim {

// Writes a binary_little_endian PLY: vertex element with float x y z, face element with
// `property list uchar int vertex_indices`. Fails (naming the file) if it cannot be written or if
// a face index is out of range.
absl::Status WriteMeshPly(const std::string& path, const Mesh& mesh);

// Reads an ascii or binary_little_endian PLY mesh. Vertex properties may come in any order and of
// any PLY scalar type; x, y, z are found by name and everything else (including other elements) is
// skipped. Faces come from the `vertex_indices` (or `vertex_index`) list of the face element with
// integer count and index types; triangles are kept and larger polygons are split into fans
// (a quad becomes two triangles); polygons with fewer than 3 corners are dropped. Every error
// message starts with the file name and says what is wrong.
absl::StatusOr<Mesh> ReadMeshPly(const std::string& path);

// Appends src to *dst, offsetting src's face indices by the vertices already in *dst.
void AppendMesh(const Mesh& src, Mesh* dst);

// Appends `mesh`'s faces to *out with every index i replaced by remap[i], dropping faces that
// collapse (two equal indices): the last step of any vertex weld.
void AppendRemappedFaces(const Mesh& mesh, const std::vector<uint32_t>& remap, Mesh* out);

// Merges vertices whose positions are bit-identical (with -0 and +0 treated as equal), keeping
// first-occurrence order, e.g. to merge per-tile meshes whose borders share vertices. Faces that
// collapse (two equal indices after merging) are dropped.
Mesh WeldIdenticalVertices(const Mesh& mesh);

}  // namespace rim
