#include "rim/io/mesh_io.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"

namespace rim {
namespace {

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

bool ParsePlyType(absl::string_view name, PlyType* type) {
  static constexpr std::pair<const char*, PlyType> kNames[] = {
      {"char", PlyType::kInt8},      {"int8", PlyType::kInt8},       {"uchar", PlyType::kUint8},
      {"uint8", PlyType::kUint8},    {"short", PlyType::kInt16},     {"int16", PlyType::kInt16},
      {"ushort", PlyType::kUint16},  {"uint16", PlyType::kUint16},   {"int", PlyType::kInt32},
      {"int32", PlyType::kInt32},    {"uint", PlyType::kUint32},     {"uint32", PlyType::kUint32},
      {"float", PlyType::kFloat32},  {"float32", PlyType::kFloat32}, {"double", PlyType::kFloat64},
      {"float64", PlyType::kFloat64}};
  for (const auto& [n, t] : kNames) {
    if (name == n) {
      *type = t;
      return true;
    }
  }
  return false;
}

int TypeSize(PlyType t) {
  switch (t) {
    case PlyType::kInt8:
    case PlyType::kUint8:
      return 1;
    case PlyType::kInt16:
    case PlyType::kUint16:
      return 2;
    case PlyType::kInt32:
    case PlyType::kUint32:
    case PlyType::kFloat32:
      return 4;
    case PlyType::kFloat64:
      return 8;
  }
  return 0;
}

bool IsIntegerType(PlyType t) { return t != PlyType::kFloat32 && t != PlyType::kFloat64; }

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;
  bool is_list = false;
  PlyType count_type = PlyType::kUint8;
};

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  std::vector<PlyProperty> properties;
};

struct PlyHeader {
  bool ascii = false;
  std::vector<PlyElement> elements;
  size_t data_offset = 0;
};

absl::StatusOr<PlyHeader> ParseHeader(const std::string& path, const std::string& data) {
  auto error = [&path](absl::string_view what) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": bad PLY header: ", what));
  };
  PlyHeader header;
  bool have_format = false;
  size_t pos = 0;
  for (int line_no = 0;; ++line_no) {
    const size_t eol = data.find('\n', pos);
    if (eol == std::string::npos) return error("missing end_header");
    absl::string_view line(data.data() + pos, eol - pos);
    pos = eol + 1;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (line_no == 0) {
      if (line != "ply") return error("file does not start with 'ply'");
      continue;
    }
    std::vector<absl::string_view> tok =
        absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "end_header") break;
    if (tok[0] == "format") {
      if (tok.size() < 2) return error("incomplete format line");
      if (tok[1] == "ascii") {
        header.ascii = true;
      } else if (tok[1] == "binary_little_endian") {
        header.ascii = false;
      } else if (tok[1] == "binary_big_endian") {
        return absl::UnimplementedError(
            absl::StrCat(path, ": binary_big_endian PLY is not supported"));
      } else {
        return error(absl::StrCat("unknown format '", tok[1], "'"));
      }
      have_format = true;
    } else if (tok[0] == "element") {
      PlyElement element;
      if (tok.size() != 3 || !absl::SimpleAtoi(tok[2], &element.count)) {
        return error(absl::StrCat("malformed line '", line, "'"));
      }
      element.name = std::string(tok[1]);
      header.elements.push_back(std::move(element));
    } else if (tok[0] == "property") {
      if (header.elements.empty()) return error("property before any element");
      PlyProperty prop;
      bool ok;
      if (tok.size() == 5 && tok[1] == "list") {
        prop.is_list = true;
        ok = ParsePlyType(tok[2], &prop.count_type) && IsIntegerType(prop.count_type) &&
             ParsePlyType(tok[3], &prop.type);
        prop.name = std::string(tok[4]);
      } else {
        ok = tok.size() == 3 && ParsePlyType(tok[1], &prop.type);
        prop.name = std::string(tok.size() > 2 ? tok[2] : "");
      }
      if (!ok) return error(absl::StrCat("malformed line '", line, "'"));
      header.elements.back().properties.push_back(std::move(prop));
    } else {
      return error(absl::StrCat("unknown keyword '", tok[0], "'"));
    }
  }
  if (!have_format) return error("missing format line");
  header.data_offset = pos;
  return header;
}

// Reads scalars from the PLY body in either encoding, converting them to double (exact for every
// PLY scalar type).
class BodyReader {
 public:
  BodyReader(const std::string& data, size_t offset, bool ascii)
      : p_(data.data() + offset), end_(data.data() + data.size()), ascii_(ascii) {}

  bool Read(PlyType type, double* out) {
    return ascii_ ? ReadAscii(type, out) : ReadBinary(type, out);
  }

 private:
  bool ReadBinary(PlyType type, double* out) {
    const int size = TypeSize(type);
    if (end_ - p_ < size) return false;
    // Assemble little-endian bytes explicitly so the result does not depend on host byte order.
    uint64_t bits = 0;
    for (int i = 0; i < size; ++i)
      bits |= static_cast<uint64_t>(static_cast<uint8_t>(p_[i])) << (8 * i);
    p_ += size;
    switch (type) {
      case PlyType::kInt8:
        *out = static_cast<int8_t>(bits);
        return true;
      case PlyType::kUint8:
        *out = static_cast<uint8_t>(bits);
        return true;
      case PlyType::kInt16:
        *out = static_cast<int16_t>(bits);
        return true;
      case PlyType::kUint16:
        *out = static_cast<uint16_t>(bits);
        return true;
      case PlyType::kInt32:
        *out = static_cast<int32_t>(bits);
        return true;
      case PlyType::kUint32:
        *out = static_cast<uint32_t>(bits);
        return true;
      case PlyType::kFloat32: {
        const uint32_t b32 = static_cast<uint32_t>(bits);
        float f;
        std::memcpy(&f, &b32, sizeof(f));
        *out = f;
        return true;
      }
      case PlyType::kFloat64:
        std::memcpy(out, &bits, sizeof(*out));
        return true;
    }
    return false;
  }

  bool ReadAscii(PlyType type, double* out) {
    auto is_space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; };
    while (p_ < end_ && is_space(*p_)) ++p_;
    const char* token_end = p_;
    while (token_end < end_ && !is_space(*token_end)) ++token_end;
    if (token_end == p_) return false;
    // The token is followed by whitespace or the string's terminating NUL, so strto* stops there.
    char* parsed_end = nullptr;
    // strtof for float properties avoids double rounding through a double.
    *out = type == PlyType::kFloat32 ? std::strtof(p_, &parsed_end) : std::strtod(p_, &parsed_end);
    const bool ok = parsed_end == token_end;
    p_ = token_end;
    return ok;
  }

  const char* p_;
  const char* end_;
  bool ascii_;
};

void AppendLE32(uint32_t v, std::string* out) {
  for (int i = 0; i < 4; ++i) out->push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}

}  // namespace

absl::Status WriteMeshPly(const std::string& path, const Mesh& mesh) {
  const size_t nv = mesh.vertices.size();
  if (nv > static_cast<size_t>(std::numeric_limits<int32_t>::max())) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": too many vertices for PLY int indices"));
  }
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    for (uint32_t idx : mesh.faces[f]) {
      if (idx >= nv) {
        return absl::InvalidArgumentError(
            absl::StrCat(path, ": face ", f, " refers to vertex ", idx, " but the mesh has ", nv));
      }
    }
  }
  std::string out =
      absl::StrCat("ply\nformat binary_little_endian 1.0\nelement vertex ", nv,
                   "\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face ",
                   mesh.faces.size(), "\nproperty list uchar int vertex_indices\nend_header\n");
  out.reserve(out.size() + nv * 12 + mesh.faces.size() * 13);
  for (const auto& v : mesh.vertices) {
    for (float c : v) {
      uint32_t bits;
      std::memcpy(&bits, &c, sizeof(bits));
      AppendLE32(bits, &out);
    }
  }
  for (const auto& f : mesh.faces) {
    out.push_back(3);
    for (uint32_t idx : f) AppendLE32(idx, &out);
  }
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) {
    return absl::UnavailableError(
        absl::StrCat(path, ": cannot open for writing: ", std::strerror(errno)));
  }
  const size_t written = std::fwrite(out.data(), 1, out.size(), file);
  const int close_result = std::fclose(file);
  if (written != out.size() || close_result != 0) {
    return absl::DataLossError(absl::StrCat(path, ": write failed: ", std::strerror(errno)));
  }
  return absl::OkStatus();
}

absl::StatusOr<Mesh> ReadMeshPly(const std::string& path) {
  std::string data;
  {
    std::FILE* file = std::fopen(path.c_str(), "rb");
    if (file == nullptr) {
      const int err = errno;
      const std::string what = absl::StrCat(path, ": cannot open: ", std::strerror(err));
      return err == ENOENT ? absl::NotFoundError(what) : absl::UnavailableError(what);
    }
    char buf[1 << 16];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof(buf), file)) > 0) data.append(buf, n);
    const bool read_error = std::ferror(file) != 0;
    std::fclose(file);
    if (read_error) return absl::DataLossError(absl::StrCat(path, ": read error"));
  }
  auto header_or = ParseHeader(path, data);
  if (!header_or.ok()) return header_or.status();
  const PlyHeader& header = *header_or;

  // Locate what we need; everything else is read and dropped.
  const PlyElement* vertex_element = nullptr;
  int xyz_prop[3] = {-1, -1, -1};
  int index_prop = -1;
  for (const PlyElement& element : header.elements) {
    for (size_t p = 0; p < element.properties.size(); ++p) {
      const PlyProperty& prop = element.properties[p];
      if (element.name == "vertex" && !prop.is_list) {
        vertex_element = &element;
        for (int axis = 0; axis < 3; ++axis) {
          if (prop.name == std::string(1, static_cast<char>('x' + axis)))
            xyz_prop[axis] = static_cast<int>(p);
        }
      }
      if (element.name == "face" && prop.is_list &&
          (prop.name == "vertex_indices" || prop.name == "vertex_index")) {
        if (!IsIntegerType(prop.type)) {
          return absl::InvalidArgumentError(
              absl::StrCat(path, ": face indices must have an integer type"));
        }
        index_prop = static_cast<int>(p);
      }
    }
  }
  if (vertex_element == nullptr || xyz_prop[0] < 0 || xyz_prop[1] < 0 || xyz_prop[2] < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": no vertex element with x, y, z properties"));
  }
  const uint64_t num_vertices = vertex_element->count;
  if (num_vertices > std::numeric_limits<uint32_t>::max()) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": too many vertices (", num_vertices, ")"));
  }

  Mesh mesh;
  // Counts come from the header; cap the reservation so a corrupt count cannot exhaust memory.
  mesh.vertices.reserve(std::min<uint64_t>(num_vertices, data.size()));
  BodyReader reader(data, header.data_offset, header.ascii);
  std::vector<uint32_t> polygon;
  for (const PlyElement& element : header.elements) {
    const bool is_vertex = &element == vertex_element;
    const bool is_face = element.name == "face";
    for (uint64_t item = 0; item < element.count; ++item) {
      auto truncated = [&]() {
        return absl::DataLossError(absl::StrCat(path, ": truncated or malformed data in element '",
                                                element.name, "' item ", item, " of ",
                                                element.count));
      };
      std::array<float, 3> position = {0.0f, 0.0f, 0.0f};
      for (size_t p = 0; p < element.properties.size(); ++p) {
        const PlyProperty& prop = element.properties[p];
        double value;
        if (!prop.is_list) {
          if (!reader.Read(prop.type, &value)) return truncated();
          for (int axis = 0; axis < 3; ++axis) {
            if (is_vertex && static_cast<int>(p) == xyz_prop[axis])
              position[axis] = static_cast<float>(value);
          }
          continue;
        }
        double count;
        if (!reader.Read(prop.count_type, &count)) return truncated();
        if (!(count >= 0.0) || count != std::floor(count) || count > 1e9) {
          return absl::InvalidArgumentError(absl::StrCat(path, ": invalid list length ", count,
                                                         " in element '", element.name, "'"));
        }
        const bool collect = is_face && static_cast<int>(p) == index_prop;
        polygon.clear();
        for (uint64_t k = 0; k < static_cast<uint64_t>(count); ++k) {
          if (!reader.Read(prop.type, &value)) return truncated();
          if (!collect) continue;
          if (!(value >= 0.0) || value >= static_cast<double>(num_vertices) ||
              value != std::floor(value)) {
            return absl::OutOfRangeError(absl::StrCat(path, ": face ", item, " refers to vertex ",
                                                      value, " but the file has ", num_vertices,
                                                      " vertices"));
          }
          polygon.push_back(static_cast<uint32_t>(value));
        }
        for (size_t k = 1; k + 1 < polygon.size(); ++k) {
          mesh.faces.push_back({polygon[0], polygon[k], polygon[k + 1]});
        }
      }
      if (is_vertex) mesh.vertices.push_back(position);
    }
  }
  return mesh;
}

void AppendMesh(const Mesh& src, Mesh* dst) {
  const uint32_t offset = static_cast<uint32_t>(dst->vertices.size());
  dst->vertices.insert(dst->vertices.end(), src.vertices.begin(), src.vertices.end());
  dst->faces.reserve(dst->faces.size() + src.faces.size());
  for (const auto& f : src.faces)
    dst->faces.push_back({f[0] + offset, f[1] + offset, f[2] + offset});
}

Mesh WeldIdenticalVertices(const Mesh& mesh) {
  struct KeyHash {
    size_t operator()(const std::array<uint32_t, 3>& k) const {
      uint64_t h = k[0] * 0x9E3779B97F4A7C15ull;
      h ^= k[1] * 0xC2B2AE3D27D4EB4Full;
      h ^= k[2] * 0x165667B19E3779F9ull;
      return static_cast<size_t>(h ^ (h >> 29));
    }
  };
  std::unordered_map<std::array<uint32_t, 3>, uint32_t, KeyHash> index_of;
  index_of.reserve(mesh.vertices.size());
  std::vector<uint32_t> remap(mesh.vertices.size());
  Mesh out;
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    std::array<uint32_t, 3> key;
    for (int c = 0; c < 3; ++c) {
      // -0 and +0 are the same position, so both get the key of +0.
      const float v = mesh.vertices[i][c] == 0.0f ? 0.0f : mesh.vertices[i][c];
      std::memcpy(&key[c], &v, sizeof(v));
    }
    auto [it, inserted] = index_of.try_emplace(key, static_cast<uint32_t>(out.vertices.size()));
    if (inserted) out.vertices.push_back(mesh.vertices[i]);
    remap[i] = it->second;
  }
  AppendRemappedFaces(mesh, remap, &out);
  return out;
}

void AppendRemappedFaces(const Mesh& mesh, const std::vector<uint32_t>& remap, Mesh* out) {
  out->faces.reserve(out->faces.size() + mesh.faces.size());
  for (const auto& f : mesh.faces) {
    const std::array<uint32_t, 3> g = {remap[f[0]], remap[f[1]], remap[f[2]]};
    if (g[0] == g[1] || g[1] == g[2] || g[0] == g[2]) continue;
    out->faces.push_back(g);
  }
}

}  // namespace rim
