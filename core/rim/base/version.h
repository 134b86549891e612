// Version strings reported by tools and the service.
#pragma once

#include <string>

namespace rim {

inline constexpr char kRimVersion[] = "0.1.0";
// The libtorch the core was built against (implemented in train_step.cc, which includes torch).
std::string TorchVersion();

}  // namespace rim
