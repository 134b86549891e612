// Start-up warm-up (DESIGN.md §5.1: health reports SERVING only after it): trains a throwaway
// map on a few frames of a built-in scene, then queries and meshes it, so that libtorch's kernels,
// thread pools and allocators are ready before the first robot connects.
#pragma once

#include "absl/status/statusor.h"

namespace rim::server {

// Runs the warm-up; returns the seconds it took. `frames` 0 does nothing.
absl::StatusOr<double> WarmUp(int frames);

}  // namespace rim::server
