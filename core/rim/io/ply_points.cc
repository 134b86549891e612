#include "rim/io/ply_points.h"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "rim/base/status_macros.h"
#include "rim/io/file_util.h"

namespace rim::io {
namespace {

enum class Format { kAscii, kLittle, kBig };

// PLY scalar type: size in bytes and kind ('i' signed, 'u' unsigned, 'f' float).
struct ScalarType {
  int size = 0;
  char kind = 0;
};

bool ParseType(absl::string_view name, ScalarType* t) {
  static constexpr struct {
    const char* name;
    int size;
    char kind;
  } kTypes[] = {{"char", 1, 'i'},  {"int8", 1, 'i'},    {"uchar", 1, 'u'},  {"uint8", 1, 'u'},
                {"short", 2, 'i'}, {"int16", 2, 'i'},   {"ushort", 2, 'u'}, {"uint16", 2, 'u'},
                {"int", 4, 'i'},   {"int32", 4, 'i'},   {"uint", 4, 'u'},   {"uint32", 4, 'u'},
                {"float", 4, 'f'}, {"float32", 4, 'f'}, {"double", 8, 'f'}, {"float64", 8, 'f'}};
  for (const auto& k : kTypes) {
    if (name == k.name) {
      *t = {k.size, k.kind};
      return true;
    }
  }
  return false;
}

struct Property {
  std::string name;
  ScalarType type;
  bool is_list = false;
  ScalarType count_type;
};

struct Element {
  std::string name;
  uint64_t count = 0;
  std::vector<Property> props;
  bool has_list() const {
    for (const Property& p : props) {
      if (p.is_list) return true;
    }
    return false;
  }
  uint64_t fixed_stride() const {
    uint64_t s = 0;
    for (const Property& p : props) s += p.type.size;
    return s;
  }
};

struct Header {
  Format format = Format::kAscii;
  std::vector<Element> elements;
  size_t data_offset = 0;
};

absl::StatusOr<Header> ParseHeader(const std::string& data, const std::string& path) {
  Header h;
  bool have_format = false;
  size_t pos = 0;
  for (int line_no = 1;; ++line_no) {
    auto error = [&](absl::string_view what) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ":", line_no, ": bad PLY header: ", what));
    };
    const size_t eol = data.find('\n', pos);
    if (eol == std::string::npos || line_no > 10000) return error("no end_header line");
    absl::string_view line(data.data() + pos, eol - pos);
    pos = eol + 1;
    std::vector<absl::string_view> tok =
        absl::StrSplit(line, absl::ByAnyChar(" \t\r"), absl::SkipEmpty());
    if (line_no == 1) {
      if (tok.size() != 1 || tok[0] != "ply") return error("file does not start with 'ply'");
      continue;
    }
    if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "end_header") break;
    if (tok[0] == "format") {
      if (tok.size() != 3) return error("format line needs a format and a version");
      if (tok[1] == "ascii") {
        h.format = Format::kAscii;
      } else if (tok[1] == "binary_little_endian") {
        h.format = Format::kLittle;
      } else if (tok[1] == "binary_big_endian") {
        h.format = Format::kBig;
      } else {
        return error(absl::StrCat("unknown format '", tok[1].substr(0, 40), "'"));
      }
      have_format = true;
    } else if (tok[0] == "element") {
      Element e;
      if (tok.size() != 3 || !absl::SimpleAtoi(tok[2], &e.count)) {
        return error("element line needs a name and a non-negative count");
      }
      e.name = std::string(tok[1]);
      h.elements.push_back(std::move(e));
    } else if (tok[0] == "property") {
      if (h.elements.empty()) return error("property before any element");
      Property p;
      bool ok;
      if (tok.size() == 5 && tok[1] == "list") {
        p.is_list = true;
        ok = ParseType(tok[2], &p.count_type) && p.count_type.kind != 'f' &&
             ParseType(tok[3], &p.type);
        p.name = std::string(tok[4]);
      } else {
        ok = tok.size() == 3 && ParseType(tok[1], &p.type);
        if (ok) p.name = std::string(tok[2]);
      }
      if (!ok) return error(absl::StrCat("malformed property line '", line.substr(0, 80), "'"));
      h.elements.back().props.push_back(std::move(p));
    } else {
      return error(absl::StrCat("unknown keyword '", tok[0].substr(0, 40), "'"));
    }
  }
  if (!have_format) return absl::InvalidArgumentError(absl::StrCat(path, ": no format line"));
  h.data_offset = pos;
  return h;
}

// Reads scalars from the body in any of the three encodings.
class Body {
 public:
  Body(const std::string& data, size_t offset, Format format)
      : p_(data.data() + offset), end_(data.data() + data.size()), format_(format) {}

  size_t remaining() const { return static_cast<size_t>(end_ - p_); }
  void Skip(uint64_t n) { p_ += n; }  // caller checked n <= remaining()

  bool Read(ScalarType t, double* out) {
    if (format_ == Format::kAscii) return ReadAscii(t, out);
    if (remaining() < static_cast<size_t>(t.size)) return false;
    *out = Load(p_, t, format_ == Format::kBig);
    p_ += t.size;
    return true;
  }

  static double Load(const char* p, ScalarType t, bool big_endian) {
    uint64_t bits = 0;
    for (int i = 0; i < t.size; ++i) {
      const int byte = big_endian ? t.size - 1 - i : i;
      bits |= static_cast<uint64_t>(static_cast<uint8_t>(p[byte])) << (8 * i);
    }
    if (t.kind == 'f') {
      if (t.size == 4) {
        const uint32_t b = static_cast<uint32_t>(bits);
        float f;
        std::memcpy(&f, &b, 4);
        return f;
      }
      double d;
      std::memcpy(&d, &bits, 8);
      return d;
    }
    if (t.kind == 'u') return static_cast<double>(bits);
    const int shift = 64 - 8 * t.size;
    return static_cast<double>(static_cast<int64_t>(bits << shift) >> shift);
  }

 private:
  bool ReadAscii(ScalarType t, double* out) {
    auto is_space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; };
    while (p_ < end_ && is_space(*p_)) ++p_;
    const char* token_end = p_;
    while (token_end < end_ && !is_space(*token_end)) ++token_end;
    if (token_end == p_) return false;
    const absl::string_view token(p_, token_end - p_);
    p_ = token_end;
    if (t.kind == 'f' && t.size == 4) {  // parse float32 directly: no double rounding
      float f;
      if (!absl::SimpleAtof(token, &f)) return false;
      *out = f;
      return true;
    }
    return absl::SimpleAtod(token, out);
  }

  const char* p_;
  const char* end_;
  Format format_;
};

}  // namespace

absl::StatusOr<PointCloud> ParsePlyPoints(const std::string& data, const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const Header h, ParseHeader(data, path));
  size_t vertex = h.elements.size();
  int prop_of[4] = {-1, -1, -1, -1};  // x, y, z, intensity
  for (size_t e = 0; e < h.elements.size() && vertex == h.elements.size(); ++e) {
    if (h.elements[e].name != "vertex") continue;
    vertex = e;
    const auto& props = h.elements[e].props;
    for (size_t p = 0; p < props.size(); ++p) {
      if (props[p].is_list) continue;
      const char* names[4] = {"x", "y", "z", "intensity"};
      for (int k = 0; k < 4; ++k) {
        if (props[p].name == names[k] && prop_of[k] < 0) prop_of[k] = static_cast<int>(p);
      }
    }
  }
  if (vertex == h.elements.size() || prop_of[0] < 0 || prop_of[1] < 0 || prop_of[2] < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": bad PLY header: no vertex element with x, y, z properties"));
  }

  Body body(data, h.data_offset, h.format);
  PointCloud cloud;
  // Only elements up to and including the vertex element need reading.
  for (size_t e = 0; e <= vertex; ++e) {
    const Element& el = h.elements[e];
    const bool is_vertex = e == vertex;
    auto truncated = [&](uint64_t item) {
      return absl::DataLossError(absl::StrCat(path, ": truncated or malformed data in element '",
                                              el.name, "' item ", item, " of ", el.count));
    };
    if (el.props.empty()) continue;  // items of no properties take no bytes
    const uint64_t stride = el.fixed_stride();
    if (h.format != Format::kAscii && !el.has_list()) {
      // Fixed-size items: check the whole element fits before touching it.
      if (el.count > body.remaining() / stride) {
        return absl::DataLossError(absl::StrCat(path, ": element '", el.name, "' declares ",
                                                el.count, " items of ", stride, " bytes but only ",
                                                body.remaining(), " bytes remain"));
      }
      if (!is_vertex) {
        body.Skip(el.count * stride);
        continue;
      }
    }
    if (is_vertex) {
      // Every item takes at least one byte: the reservation is bounded by the file size.
      const uint64_t cap = std::min<uint64_t>(el.count, body.remaining());
      cloud.points.reserve(cap);
      if (prop_of[3] >= 0) cloud.intensity.reserve(cap);
    }
    for (uint64_t item = 0; item < el.count; ++item) {
      double v[4] = {0, 0, 0, 0};
      for (size_t p = 0; p < el.props.size(); ++p) {
        const Property& prop = el.props[p];
        double value;
        if (!prop.is_list) {
          if (!body.Read(prop.type, &value)) return truncated(item);
          for (int k = 0; k < 4; ++k) {
            if (is_vertex && prop_of[k] == static_cast<int>(p)) v[k] = value;
          }
          continue;
        }
        double count;
        if (!body.Read(prop.count_type, &count)) return truncated(item);
        if (!(count >= 0) || count > static_cast<double>(body.remaining())) {
          return truncated(item);
        }
        const uint64_t n = static_cast<uint64_t>(count);
        if (h.format != Format::kAscii) {
          if (n > body.remaining() / prop.type.size) return truncated(item);
          body.Skip(n * prop.type.size);
        } else {
          for (uint64_t k = 0; k < n; ++k) {
            if (!body.Read(prop.type, &value)) return truncated(item);
          }
        }
      }
      if (is_vertex) {
        cloud.points.emplace_back(static_cast<float>(v[0]), static_cast<float>(v[1]),
                                  static_cast<float>(v[2]));
        if (prop_of[3] >= 0) cloud.intensity.push_back(static_cast<float>(v[3]));
      }
    }
  }
  return cloud;
}

absl::StatusOr<PointCloud> ReadPlyPoints(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string data, ReadFileToString(path));
  return ParsePlyPoints(data, path);
}

absl::Status WritePlyPoints(const std::string& path, const PointCloud& cloud, PlyFormat format) {
  const size_t n = cloud.points.size();
  const bool has_intensity = !cloud.intensity.empty();
  if (has_intensity && cloud.intensity.size() != n) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": ", cloud.intensity.size(), " intensities for ", n, " points"));
  }
  const int nf = has_intensity ? 4 : 3;
  std::string out = absl::StrCat(
      "ply\nformat ", format == PlyFormat::kAscii ? "ascii" : "binary_little_endian",
      " 1.0\nelement vertex ", n, "\nproperty float x\nproperty float y\nproperty float z\n",
      has_intensity ? "property float intensity\n" : "", "end_header\n");
  auto value = [&](size_t i, int f) { return f < 3 ? cloud.points[i][f] : cloud.intensity[i]; };
  if (format == PlyFormat::kAscii) {
    for (size_t i = 0; i < n; ++i) {
      for (int f = 0; f < nf; ++f) absl::StrAppendFormat(&out, "%s%.9g", f ? " " : "", value(i, f));
      out.push_back('\n');
    }
  } else {
    out.reserve(out.size() + n * 4 * nf);
    for (size_t i = 0; i < n; ++i) {
      for (int f = 0; f < nf; ++f) {
        const float v = value(i, f);
        char b[4];
        std::memcpy(b, &v, 4);
        out.append(b, 4);
      }
    }
  }
  return WriteStringToFile(path, out);
}

}  // namespace rim::io
