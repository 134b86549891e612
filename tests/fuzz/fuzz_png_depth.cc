// 16-bit depth PNGs (rim::io::DecodePng16 through libpng) and their back-projection to points, as
// the 7-Scenes and Replica readers do: any chunk layout, bit depth, colour type or image size.
#include <string>

#include "fuzz_util.h"
#include "rim/io/depth.h"
#include "rim/io/png_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(rim::fuzz::Bytes(data, size));
  auto image = rim::io::DecodePng16(bytes, "fuzz.png");
  if (!image.ok()) return 0;
  RIM_FUZZ_CHECK(image->width > 0 && image->height > 0);
  RIM_FUZZ_CHECK(image->width <= rim::io::kMaxPngSide && image->height <= rim::io::kMaxPngSide);
  RIM_FUZZ_CHECK(image->pixels.size() == size_t(image->width) * size_t(image->height));
  // Both encodings the readers use: 7-Scenes (mm, 65535 invalid) and Replica (scale, 0 invalid).
  for (const rim::io::DepthEncoding encoding :
       {rim::io::DepthEncoding{1000.0, true}, rim::io::DepthEncoding{6553.5, false}}) {
    const auto points =
        rim::io::BackProjectDepth(*image, rim::io::kSevenScenesDefaultIntrinsics, encoding);
    RIM_FUZZ_CHECK(points.size() <= image->pixels.size());
    for (const auto& p : points) RIM_FUZZ_CHECK(p.allFinite() && p.z() > 0);
  }
  return 0;
}
