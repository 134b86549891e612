// Scratch directories for tests that are removed when the test process exits, so that repeated
// runs (and CI) do not fill /tmp.
#pragma once

#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <mutex>
#include <string>
#include <vector>

namespace rim::testing_support {

class TempDirRegistry {
 public:
  static TempDirRegistry& Get() {
    static TempDirRegistry registry;
    return registry;
  }
  void Add(const std::string& dir) {
    std::lock_guard<std::mutex> lock(mu_);
    dirs_.push_back(dir);
  }
  ~TempDirRegistry() {
    if (std::getenv("RIM_KEEP_TEST_DIRS")) return;
    std::error_code ec;
    for (const std::string& d : dirs_) std::filesystem::remove_all(d, ec);
  }

 private:
  std::mutex mu_;
  std::vector<std::string> dirs_;
};

// A new empty directory under the test temp dir, named prefix_XXXXXX; removed at exit unless
// RIM_KEEP_TEST_DIRS is set.
inline std::string MakeTempDir(const std::string& prefix) {
  std::string tmpl = ::testing::TempDir() + "/" + prefix + "_XXXXXX";
  const char* dir = mkdtemp(tmpl.data());
  if (dir == nullptr) {
    ADD_FAILURE() << "mkdtemp failed for " << tmpl;
    return ::testing::TempDir();
  }
  TempDirRegistry::Get().Add(dir);
  return dir;
}

}  // namespace rim::testing_support
