// PCD point clouds (rim::io::ParsePcd): ascii, binary and binary_compressed (LZF) data, any header.
#include <cmath>
#include <string>

#include "fuzz_util.h"
#include "rim/io/pcd.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(rim::fuzz::Bytes(data, size));
  auto cloud = rim::io::ParsePcd(bytes, "fuzz.pcd");
  if (!cloud.ok()) return 0;
  // pcd.h: intensities are absent or one per point, and points with a non-finite coordinate are
  // dropped while reading.
  RIM_FUZZ_CHECK(cloud->intensity.empty() || cloud->intensity.size() == cloud->points.size());
  for (const auto& p : cloud->points) RIM_FUZZ_CHECK(p.allFinite());
  return 0;
}
