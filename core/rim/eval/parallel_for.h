// A blocking parallel loop for the evaluation's large, independent per-point work.
#pragma once

#include <cstdint>
#include <functional>

namespace rim::eval {

// Calls fn(begin, end) on consecutive blocks of `block` items that cover [0, n), on `threads`
// threads (the caller's included). Blocks are handed out on demand, so uneven blocks balance.
void ParallelFor(int64_t n, int64_t block, int threads,
                 const std::function<void(int64_t begin, int64_t end)>& fn);

}  // namespace rim::eval
