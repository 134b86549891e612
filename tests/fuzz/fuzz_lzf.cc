// LZF, the codec of PCD's binary_compressed data (rim::io::LzfDecompress / LzfCompress). The first
// four bytes of the input are the expected output size (little-endian, as in a PCD file), the rest
// the compressed stream. The rest is also compressed and decompressed again, which must give it
// back exactly.
#include <string>

#include "fuzz_util.h"
#include "rim/io/lzf.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 4) return 0;
  uint32_t expected = 0;
  std::memcpy(&expected, data, 4);
  const absl::string_view stream = rim::fuzz::AbslBytes(data + 4, size - 4);
  auto out = rim::io::LzfDecompress(stream, expected, "fuzz.lzf");
  if (out.ok()) RIM_FUZZ_CHECK(out->size() == expected);
  // Claimed sizes beyond LZF's expansion are refused before anything is allocated.
  if (expected > stream.size() * rim::io::kLzfMaxExpansion) RIM_FUZZ_CHECK(!out.ok());

  const std::string packed = rim::io::LzfCompress(stream);
  RIM_FUZZ_CHECK(packed.size() <= stream.size() + stream.size() / 32 + 1);
  auto back = rim::io::LzfDecompress(packed, stream.size(), "roundtrip");
  RIM_FUZZ_CHECK(back.ok() && *back == stream);
  return 0;
}
