// Internal to the Mapper's sources (mapper*.cc): what more than one of them needs.
#pragma once

#include <chrono>

#include "rim/mapper.h"
#include "rim/train/sampler.h"

namespace rim {

// The last scan's rays that end outside the box (Preprocess fills them, training samples them).
struct Mapper::OutsideRaysHolder {
  OutsideRays rays;
};

namespace mapper_internal {

// Seconds on the steady clock, for stage timings.
inline double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace mapper_internal
}  // namespace rim
