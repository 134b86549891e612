// JSON documents (rim::io::ParseJson, nlohmann-json behind a Status API) and the Replica
// cam_params.json reader built on it.
#include "fuzz_util.h"
#include "rim/io/depth.h"
#include "rim/io/json.h"

namespace {

// Nesting depth of a parsed value; ParseJson promises at most kMaxJsonDepth.
int Depth(const nlohmann::json& v) {
  int d = 0;
  if (v.is_structured()) {
    for (const auto& item : v) d = std::max(d, Depth(item));
  }
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
