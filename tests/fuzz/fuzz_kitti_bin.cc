// KITTI velodyne .bin scans (rim::io::ParseKittiBin): float32 x, y, z, intensity records, followed
// by what Dataset::Read does with them (dropping non-finite points).
#include "fuzz_util.h"
#include "rim/io/kitti.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  auto cloud = rim::io::ParseKittiBin(rim::fuzz::AbslBytes(data, size), "fuzz.bin");
  RIM_FUZZ_CHECK(cloud.ok() == (size % 16 == 0));
  if (!cloud.ok()) return 0;
  RIM_FUZZ_CHECK(cloud->points.size() == size / 16 && cloud->intensity.size() == size / 16);
  const size_t dropped = rim::io::DropNonFinitePoints(&*cloud);
  RIM_FUZZ_CHECK(cloud->points.size() + dropped == size / 16);
  RIM_FUZZ_CHECK(cloud->intensity.size() == cloud->points.size());
  for (const auto& p : cloud->points) RIM_FUZZ_CHECK(p.allFinite());
  return 0;
}
