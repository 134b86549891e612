#include "proto/codec/mesh_codec.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <utility>

#include "absl/strings/str_cat.h"
#include "draco/attributes/geometry_attribute.h"
#include "draco/attributes/point_attribute.h"
#include "draco/compression/config/compression_shared.h"
#include "draco/compression/decode.h"
#include "draco/compression/encode.h"
#include "draco/core/decoder_buffer.h"
#include "draco/core/encoder_buffer.h"
#include "draco/mesh/mesh.h"
#include "rim/base/status_macros.h"

namespace rim::codec {
namespace {

constexpr int kMaxQuantizationBits = 30;  // Draco rejects more.
constexpr double kSqrt3 = 1.7320508075688772;

// Draco's speed options trade compression for time (0 best, 10 fastest). Measured on a dense
// 26 x 26 x 6 m tile (24k vertices, 48k faces, 15 bits), one core: speed 5 (Draco's default,
// standard edgebreaker) 1.00 bytes/face in 9 ms; speed 4 (valence edgebreaker, parallelogram
// prediction) 0.76 bytes/face in 10 ms; speed 1 (constrained multi-parallelogram) 0.64 bytes/face
// in 20 ms. Speed 4 takes the large saving at no cost; tiles are re-encoded on every change.
// Speed 8 (standard edgebreaker, difference prediction) is DracoEffort::kFaster: on coarse tiles,
// whose vertices lie a cell apart, parallelogram prediction saves nothing (mesh_codec.h).
constexpr int kDracoSpeed = 4;
constexpr int kDracoFasterSpeed = 8;

bool Finite3(const std::array<double, 3>& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

}  // namespace

absl::StatusOr<int> PositionQuantizationBits(double range_m, double max_error_m) {
  if (!std::isfinite(range_m) || range_m < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("quantisation range ", range_m, " m is invalid"));
  }
  if (!std::isfinite(max_error_m) || max_error_m <= 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("max_error_m must be positive and finite, got ", max_error_m));
  }
  // Draco rounds each coordinate to the nearest step, so a vertex moves by up to half a step per
  // axis and by sqrt(3) half-steps in space; the bound is on the latter.
  int bits = 1;
  while (bits < kMaxQuantizationBits &&
         kSqrt3 * range_m / static_cast<double>((uint64_t{1} << bits) - 1) / 2 > max_error_m) {
    ++bits;
  }
  return bits;
}

namespace {

absl::Status ValidateTileInput(const Mesh& mesh, const std::array<double, 3>& tile_min,
                               const std::array<double, 3>& tile_max) {
  if (!Finite3(tile_min) || !Finite3(tile_max)) {
    return absl::InvalidArgumentError("tile bounds must be finite");
  }
  for (int a = 0; a < 3; ++a) {
    if (tile_min[a] > tile_max[a]) {
      return absl::InvalidArgumentError(absl::StrCat("tile_min[", a, "] = ", tile_min[a],
                                                     " exceeds tile_max[", a, "] = ", tile_max[a]));
    }
  }
  const size_t num_vertices = mesh.vertices.size();
  if (num_vertices > static_cast<size_t>(std::numeric_limits<int32_t>::max())) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile mesh has too many vertices: ", num_vertices));
  }
  for (const auto& v : mesh.vertices) {
    if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2])) {
      return absl::InvalidArgumentError("tile mesh has a non-finite vertex coordinate");
    }
  }
  for (const auto& f : mesh.faces) {
    for (uint32_t i : f) {
      if (i >= num_vertices) {
        return absl::InvalidArgumentError(absl::StrCat(
            "tile mesh face index ", i, " is out of range for ", num_vertices, " vertices"));
      }
    }
  }
  return absl::OkStatus();
}

struct QuantizationGrid {
  float origin[3];
  float range;
  int bits;
};

absl::StatusOr<QuantizationGrid> ChooseGrid(const Mesh& mesh, const std::array<double, 3>& tile_min,
                                            const std::array<double, 3>& tile_max,
                                            double max_error_m) {
  if (!std::isfinite(max_error_m) || max_error_m <= 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("max_error_m must be positive and finite, got ", max_error_m));
  }
  // The box is the tile, grown to any vertex outside it (marching cubes may place vertices on the
  // far side of a tile face), so that no vertex falls outside Draco's grid.
  std::array<double, 3> lo = tile_min, hi = tile_max;
  for (const auto& v : mesh.vertices) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], static_cast<double>(v[a]));
      hi[a] = std::max(hi[a], static_cast<double>(v[a]));
    }
  }
  // Draco works in float32: the origin is rounded down and the range up so that the box still
  // contains every vertex, and the error budget keeps a margin for float32 rounding of the
  // subtraction and the dequantisation at these coordinates.
  QuantizationGrid grid;
  double range = 0, max_abs = 0;
  for (int a = 0; a < 3; ++a) {
    grid.origin[a] = static_cast<float>(lo[a]);
    if (grid.origin[a] > lo[a]) grid.origin[a] = std::nextafter(grid.origin[a], -HUGE_VALF);
    range = std::max(range, hi[a] - static_cast<double>(grid.origin[a]));
    max_abs = std::max({max_abs, std::abs(lo[a]), std::abs(hi[a])});
  }
  const double float_margin = 4 * std::numeric_limits<float>::epsilon() * (max_abs + range);
  const double budget = max_error_m - float_margin;
  if (!(budget > 0)) {
    return absl::InvalidArgumentError(
        absl::StrCat("max_error_m ", max_error_m, " is below float32 resolution at coordinates of ",
                     max_abs, " m"));
  }
  // A zero range (a flat tile with one vertex) would divide by zero in Draco's quantiser; a
  // range of `budget` keeps one bit within the bound.
  grid.range = static_cast<float>(std::max(range, budget));
  if (grid.range < range) grid.range = std::nextafter(grid.range, HUGE_VALF);
  RIM_ASSIGN_OR_RETURN(grid.bits, PositionQuantizationBits(grid.range, budget));
  return grid;
}

// Copies the mesh into Draco's structure, leaving out faces with a repeated vertex index: they
// carry no surface and edgebreaker cannot represent them.
void ToDracoMesh(const Mesh& mesh, draco::Mesh* dm) {
  const auto num_vertices = static_cast<uint32_t>(mesh.vertices.size());
  dm->set_num_points(num_vertices);
  draco::GeometryAttribute position;
  position.Init(draco::GeometryAttribute::POSITION, nullptr, 3, draco::DT_FLOAT32, false,
                sizeof(float) * 3, 0);
  draco::PointAttribute* att =
      dm->attribute(dm->AddAttribute(position, /*identity_mapping=*/true, num_vertices));
  for (uint32_t i = 0; i < num_vertices; ++i) {
    att->SetAttributeValue(draco::AttributeValueIndex(i), mesh.vertices[i].data());
  }
  for (const auto& f : mesh.faces) {
    if (f[0] == f[1] || f[1] == f[2] || f[2] == f[0]) continue;
    dm->AddFace({draco::PointIndex(f[0]), draco::PointIndex(f[1]), draco::PointIndex(f[2])});
  }
}

absl::StatusOr<std::string> RunEncoder(draco::Encoder* encoder, const draco::Mesh& dm) {
  draco::EncoderBuffer buffer;
  const draco::Status s = encoder->EncodeMeshToBuffer(dm, &buffer);
  if (!s.ok()) {
    return absl::InternalError(absl::StrCat("Draco failed to encode a tile mesh of ",
                                            dm.num_points(), " vertices and ", dm.num_faces(),
                                            " faces: ", s.error_msg_string()));
  }
  return std::string(buffer.data(), buffer.size());
}

}  // namespace

absl::StatusOr<std::string> EncodeTileDraco(const Mesh& mesh, const std::array<double, 3>& tile_min,
                                            const std::array<double, 3>& tile_max,
                                            double max_error_m, DracoEffort effort) {
  RIM_RETURN_IF_ERROR(ValidateTileInput(mesh, tile_min, tile_max));
  RIM_ASSIGN_OR_RETURN(const QuantizationGrid grid,
                       ChooseGrid(mesh, tile_min, tile_max, max_error_m));
  draco::Mesh dm;
  ToDracoMesh(mesh, &dm);
  draco::Encoder encoder;
  const int speed = effort == DracoEffort::kFaster ? kDracoFasterSpeed : kDracoSpeed;
  encoder.SetSpeedOptions(speed, speed);
  if (dm.num_faces() == 0) {
    // Edgebreaker refuses a mesh without triangles; the sequential coder writes a valid empty
    // mesh that any Draco decoder reads. Without faces every vertex is unreferenced: none is kept.
    draco::Mesh empty;
    ToDracoMesh(Mesh{}, &empty);
    encoder.SetEncodingMethod(draco::MESH_SEQUENTIAL_ENCODING);
    return RunEncoder(&encoder, empty);
  }
  encoder.SetAttributeExplicitQuantization(draco::GeometryAttribute::POSITION, grid.bits, 3,
                                           grid.origin, grid.range);
  encoder.SetEncodingMethod(draco::MESH_EDGEBREAKER_ENCODING);
  return RunEncoder(&encoder, dm);
}

absl::StatusOr<Mesh> DecodeTileDraco(std::string_view bytes) {
  draco::DecoderBuffer buffer;
  buffer.Init(bytes.data(), bytes.size());
  draco::Decoder decoder;
  auto decoded = decoder.DecodeMeshFromBuffer(&buffer);
  if (!decoded.ok()) {
    return absl::DataLossError(
        absl::StrCat("mesh tile of ", bytes.size(),
                     " bytes is not a valid Draco mesh: ", decoded.status().error_msg_string()));
  }
  const std::unique_ptr<draco::Mesh> dm = std::move(decoded).value();
  Mesh out;
  const size_t num_points = dm->num_points();
  const size_t num_faces = dm->num_faces();
  if (num_points == 0 && num_faces == 0) return out;
  const draco::PointAttribute* att = dm->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (att == nullptr || att->num_components() != 3) {
    return absl::DataLossError("Draco mesh tile has no 3D position attribute");
  }
  // The checks below guard against payloads that Draco accepts but that describe an inconsistent
  // mesh; indexing with their values unchecked would read out of bounds.
  if (!att->is_mapping_identity() && att->indices_map_size() < num_points) {
    return absl::DataLossError("Draco mesh tile maps fewer points than it has");
  }
  out.vertices.resize(num_points);
  for (size_t i = 0; i < num_points; ++i) {
    const draco::AttributeValueIndex avi =
        att->mapped_index(draco::PointIndex(static_cast<uint32_t>(i)));
    if (avi.value() >= att->size() || !att->ConvertValue<float, 3>(avi, out.vertices[i].data())) {
      return absl::DataLossError(absl::StrCat("Draco mesh tile position ", i, " is unreadable"));
    }
    for (float c : out.vertices[i]) {
      if (!std::isfinite(c)) {
        return absl::DataLossError(absl::StrCat("Draco mesh tile position ", i, " is not finite"));
      }
    }
  }
  out.faces.resize(num_faces);
  for (size_t f = 0; f < num_faces; ++f) {
    const draco::Mesh::Face& face = dm->face(draco::FaceIndex(static_cast<uint32_t>(f)));
    for (int c = 0; c < 3; ++c) {
      if (face[c].value() >= num_points) {
        return absl::DataLossError(absl::StrCat("Draco mesh tile face ", f, " has point index ",
                                                face[c].value(), " of ", num_points));
      }
      out.faces[f][c] = face[c].value();
    }
  }
  return out;
}

}  // namespace rim::codec
