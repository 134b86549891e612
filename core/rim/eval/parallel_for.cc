#include "rim/eval/parallel_for.h"

#include <algorithm>
#include <atomic>
#include <thread>
#include <vector>

namespace rim::eval {

void ParallelFor(int64_t n, int64_t block, int threads,
                 const std::function<void(int64_t begin, int64_t end)>& fn) {
  if (n <= 0) return;
  block = std::max<int64_t>(block, 1);
  const int64_t num_blocks = (n + block - 1) / block;
  std::atomic<int64_t> next{0};
  auto worker = [&] {
    for (int64_t b = next.fetch_add(1); b < num_blocks; b = next.fetch_add(1)) {
      fn(b * block, std::min(n, (b + 1) * block));
    }
  };
  const int64_t helpers = std::min<int64_t>(std::max(threads, 1), num_blocks) - 1;
  std::vector<std::thread> pool;
  pool.reserve(helpers);
  for (int64_t i = 0; i < helpers; ++i) pool.emplace_back(worker);
  worker();
  for (std::thread& t : pool) t.join();
}

}  // namespace rim::eval
