// PNG reading and writing through libpng: 16-bit grayscale depth images in, 16-bit grayscale and
// 8-bit RGB images out. libpng's longjmp error handling is confined to png_io.cc; callers only
// see absl::Status.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace rim::io {

struct Image16 {
  int width = 0;
  int height = 0;
  std::vector<uint16_t> pixels;  // row-major, width * height

  uint16_t at(int u, int v) const { return pixels[static_cast<size_t>(v) * width + u]; }
};

// Largest image ReadPng16 accepts, per side (libpng user limit) and in total bytes.
inline constexpr int kMaxPngSide = 1 << 15;
inline constexpr uint64_t kMaxPngBytes = uint64_t{1} << 28;  // 256 MiB decoded

// Reads a non-interlaced 16-bit grayscale PNG. Other bit depths and colour types are rejected
// (naming what the file holds), as are interlaced images. Errors name `path`.
absl::StatusOr<Image16> ReadPng16(const std::string& path);

// Decodes PNG bytes already in memory; `path` is only used in messages.
absl::StatusOr<Image16> DecodePng16(const std::string& bytes, const std::string& path);

// Encodes a 16-bit grayscale image (row-major, width * height values).
absl::StatusOr<std::string> EncodePng16(int width, int height, const uint16_t* pixels);
absl::Status WritePng16(const std::string& path, int width, int height, const uint16_t* pixels);

// Writes an 8-bit RGB image (row-major, width * height * 3 bytes).
absl::Status WritePngRgb8(const std::string& path, int width, int height, const uint8_t* rgb);

}  // namespace rim::io
