#include "rim/io/png_io.h"

#include <png.h>

#include <csetjmp>
#include <cstdio>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/io/file_util.h"

namespace rim::io {
namespace {

// State shared with libpng's callbacks. The functions that call setjmp below hold no objects with
// destructors, so libpng's longjmp never skips a destructor.
struct PngContext {
  const unsigned char* data = nullptr;  // reading
  size_t size = 0;
  size_t pos = 0;
  std::string* out = nullptr;  // writing
  char message[256] = {0};
};

void OnError(png_structp png, png_const_charp msg) {
  auto* ctx = static_cast<PngContext*>(png_get_error_ptr(png));
  std::snprintf(ctx->message, sizeof(ctx->message), "%s", msg);
  png_longjmp(png, 1);
}

void OnWarning(png_structp, png_const_charp) {}

void ReadBytes(png_structp png, png_bytep dst, size_t n) {
  auto* ctx = static_cast<PngContext*>(png_get_io_ptr(png));
  if (n > ctx->size - ctx->pos) png_error(png, "unexpected end of file");
  std::memcpy(dst, ctx->data + ctx->pos, n);
  ctx->pos += n;
}

void WriteBytes(png_structp png, png_bytep src, size_t n) {
  auto* ctx = static_cast<PngContext*>(png_get_io_ptr(png));
  ctx->out->append(reinterpret_cast<const char*>(src), n);
}

void Flush(png_structp) {}

struct Ihdr {
  png_uint_32 width = 0, height = 0;
  int bit_depth = 0, color_type = 0, interlace = 0;
  size_t rowbytes = 0;
};

// Reads the header and sets up the 16-bit byte swap. Returns false on a libpng error.
bool ReadHeader(png_structp png, png_infop info, Ihdr* ihdr) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_read_info(png, info);
  png_get_IHDR(png, info, &ihdr->width, &ihdr->height, &ihdr->bit_depth, &ihdr->color_type,
               &ihdr->interlace, nullptr, nullptr);
  if (ihdr->bit_depth == 16) png_set_swap(png);  // PNG is big-endian; the host is little-endian
  png_read_update_info(png, info);
  ihdr->rowbytes = png_get_rowbytes(png, info);
  return true;
}

bool ReadRow(png_structp png, png_bytep row) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_read_row(png, row, nullptr);
  return true;
}

bool WriteImage(png_structp png, png_infop info, int width, int height, int color_type,
                int bit_depth, png_bytepp rows) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_IHDR(png, info, width, height, bit_depth, color_type, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  if (bit_depth == 16) png_set_swap(png);
  png_write_image(png, rows);
  png_write_end(png, nullptr);
  return true;
}

absl::StatusOr<std::string> Encode(int width, int height, int color_type, int bit_depth,
                                   int bytes_per_pixel, const void* pixels) {
  if (width <= 0 || height <= 0 || width > kMaxPngSide || height > kMaxPngSide) {
    return absl::InvalidArgumentError(
        absl::StrCat("PNG size ", width, "x", height, " is empty or too large"));
  }
  std::string out;
  PngContext ctx;
  ctx.out = &out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &ctx, OnError, OnWarning);
  if (png == nullptr) return absl::ResourceExhaustedError("png_create_write_struct failed");
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_write_struct(&png, nullptr);
    return absl::ResourceExhaustedError("png_create_info_struct failed");
  }
  png_set_write_fn(png, &ctx, WriteBytes, Flush);
  std::vector<png_bytep> rows(height);
  const size_t row_bytes = static_cast<size_t>(width) * bytes_per_pixel;
  for (int v = 0; v < height; ++v) {
    rows[v] = const_cast<png_bytep>(static_cast<const png_byte*>(pixels) + v * row_bytes);
  }
  const bool ok = WriteImage(png, info, width, height, color_type, bit_depth, rows.data());
  png_destroy_write_struct(&png, &info);
  if (!ok) return absl::InternalError(absl::StrCat("PNG encoding failed: ", ctx.message));
  return out;
}

absl::Status WriteEncoded(const std::string& path, absl::StatusOr<std::string> encoded) {
  if (!encoded.ok()) {
    return absl::Status(encoded.status().code(),
                        absl::StrCat(path, ": ", encoded.status().message()));
  }
  return WriteStringToFile(path, *encoded);
}

}  // namespace

absl::StatusOr<Image16> DecodePng16(const std::string& bytes, const std::string& path) {
  if (bytes.size() < 8 || png_sig_cmp(reinterpret_cast<png_const_bytep>(bytes.data()), 0, 8)) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": not a PNG file (bad signature)"));
  }
  PngContext ctx;
  ctx.data = reinterpret_cast<const unsigned char*>(bytes.data());
  ctx.size = bytes.size();
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &ctx, OnError, OnWarning);
  if (png == nullptr) return absl::ResourceExhaustedError("png_create_read_struct failed");
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    return absl::ResourceExhaustedError("png_create_info_struct failed");
  }
  // Release libpng's state on every return path.
  struct Cleanup {
    png_structp* png;
    png_infop* info;
    ~Cleanup() { png_destroy_read_struct(png, info, nullptr); }
  } cleanup{&png, &info};
  png_set_read_fn(png, &ctx, ReadBytes);
  png_set_user_limits(png, kMaxPngSide, kMaxPngSide);
  png_set_chunk_malloc_max(png, 8 << 20);
  auto libpng_error = [&]() {
    return absl::DataLossError(absl::StrCat(path, ": corrupt or truncated PNG: ", ctx.message));
  };

  Ihdr ihdr;
  if (!ReadHeader(png, info, &ihdr)) return libpng_error();
  if (ihdr.bit_depth != 16 || ihdr.color_type != PNG_COLOR_TYPE_GRAY) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": expected a 16-bit grayscale PNG, found bit depth ", ihdr.bit_depth,
        " and colour type ", ihdr.color_type, " (0 gray, 2 RGB, 3 palette, 4 gray+alpha, 6 RGBA)"));
  }
  if (ihdr.interlace != PNG_INTERLACE_NONE) {
    return absl::UnimplementedError(absl::StrCat(path, ": interlaced PNG is not supported"));
  }
  const uint64_t total = uint64_t{ihdr.width} * ihdr.height * 2;
  if (total > kMaxPngBytes || ihdr.rowbytes != size_t{ihdr.width} * 2) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": PNG of ", ihdr.width, "x", ihdr.height,
                                                   " is larger than the limit of ",
                                                   kMaxPngBytes >> 20, " MiB decoded"));
  }
  Image16 image;
  image.width = static_cast<int>(ihdr.width);
  image.height = static_cast<int>(ihdr.height);
  // Grow row by row, so that a header claiming a huge image in a short file fails before
  // allocating it all.
  std::vector<uint16_t> row(ihdr.width);
  for (png_uint_32 v = 0; v < ihdr.height; ++v) {
    if (!ReadRow(png, reinterpret_cast<png_bytep>(row.data()))) return libpng_error();
    image.pixels.insert(image.pixels.end(), row.begin(), row.end());
  }
  return image;
}

absl::StatusOr<Image16> ReadPng16(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(const std::string bytes, ReadFileToString(path, kMaxPngBytes));
  return DecodePng16(bytes, path);
}

absl::StatusOr<std::string> EncodePng16(int width, int height, const uint16_t* pixels) {
  return Encode(width, height, PNG_COLOR_TYPE_GRAY, 16, 2, pixels);
}

absl::Status WritePng16(const std::string& path, int width, int height, const uint16_t* pixels) {
  return WriteEncoded(path, EncodePng16(width, height, pixels));
}

absl::Status WritePngRgb8(const std::string& path, int width, int height, const uint8_t* rgb) {
  return WriteEncoded(path, Encode(width, height, PNG_COLOR_TYPE_RGB, 8, 3, rgb));
}

}  // namespace rim::io
