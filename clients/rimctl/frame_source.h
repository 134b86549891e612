// Where `rimctl stream` gets its scans: a dataset folder in any layout core/io detects, or the
// built-in synthetic city generated in memory ("sim:city").
#pragma once

#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "rim/base/scan.h"
#include "sim/city_frames.h"

namespace rim::rimctl {

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual size_t size() const = 0;
  // Frame `index` (< size()); errors name the file it came from.
  virtual absl::StatusOr<PosedScan> Read(size_t index) const = 0;
  // One line for the user, e.g. "KITTI dataset data/seq00 (120 frames)".
  virtual std::string Describe() const = 0;
};

// "sim:city" or "sim:city?key=value&key=value" (',' also separates) with keys frames, seed,
// step, columns, noise, walkers, threads (meaning as in rim_sim). InvalidArgument naming the key
// for an unknown key or a bad value.
absl::StatusOr<sim::CityFrameOptions> ParseSimCitySpec(const std::string& spec);

// A spec starting with "sim:" is a synthetic scene; anything else is a dataset folder. Errors name
// the path (NotFound for a folder that is missing or holds no known layout).
absl::StatusOr<std::unique_ptr<FrameSource>> OpenFrameSource(const std::string& spec);

}  // namespace rim::rimctl
