// PLY point clouds (rim::io::ParsePlyPoints): ascii and binary of either endianness, any elements,
// properties, types and list properties before or after the vertices.
#include <string>

#include "fuzz_util.h"
#include "rim/io/ply_points.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(rim::fuzz::Bytes(data, size));
  auto cloud = rim::io::ParsePlyPoints(bytes, "fuzz.ply");
  if (!cloud.ok()) return 0;
  RIM_FUZZ_CHECK(cloud->intensity.empty() || cloud->intensity.size() == cloud->points.size());
  // Every vertex takes at least one byte of the file, so a header cannot conjure up more points.
  RIM_FUZZ_CHECK(cloud->points.size() <= size);
  return 0;
}
