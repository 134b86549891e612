// The small JSON parser (rim::io::ParseJson) and the Replica cam_params.json reader built on it.
#include "fuzz_util.h"
#include "rim/io/depth.h"
#include "rim/io/json_lite.h"

namespace {

// Nesting depth of a parsed value; the parser promises at most kMaxJsonDepth.
int Depth(const rim::io::JsonValue& v) {
  int d = 0;
  for (const auto& item : v.items) d = std::max(d, Depth(item));
  for (const auto& member : v.members) d = std::max(d, Depth(member.second));
  return d + 1;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const absl::string_view text = rim::fuzz::AbslBytes(data, size);
  auto json = rim::io::ParseJson(text, "fuzz.json");
  if (json.ok()) RIM_FUZZ_CHECK(Depth(*json) <= rim::io::kMaxJsonDepth + 1);
  auto cam = rim::io::ParseReplicaCamParams(text, "cam_params.json");
  if (cam.ok()) {
    const auto& K = cam->intrinsics;
    RIM_FUZZ_CHECK(K.width >= 1 && K.width <= rim::io::kMaxPngSide);
    RIM_FUZZ_CHECK(K.height >= 1 && K.height <= rim::io::kMaxPngSide);
    RIM_FUZZ_CHECK(K.fx > 0 && K.fy > 0 && cam->scale > 0);
  }
  return 0;
}
