// The main of a fuzz target outside a RIM_FUZZ build: runs LLVMFuzzerTestOneInput once on every
// file of the directories (or files) given, so that the seeds and every crash input ever found
// replay as ordinary regression tests with any compiler. Arguments starting with '-' (libFuzzer
// flags) are ignored, so the same command lines work for both kinds of binary.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "fuzz_util.h"

namespace {

namespace fs = std::filesystem;

std::string ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<fs::path> files;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (!arg.empty() && arg[0] == '-') continue;
    std::error_code ec;
    if (fs::is_directory(arg, ec)) {
      for (const auto& e : fs::directory_iterator(arg, ec))
        if (e.is_regular_file()) files.push_back(e.path());
    } else if (fs::is_regular_file(arg, ec)) {
      files.push_back(arg);
    } else {
      fprintf(stderr, "%s: no such file or directory\n", arg.c_str());
      return 2;
    }
  }
  // An empty corpus would pass without testing anything: most likely a wrong path.
  if (files.empty()) {
    fprintf(stderr, "usage: %s CORPUS_DIR_OR_FILE...: no inputs found\n", argv[0]);
    return 2;
  }
  std::sort(files.begin(), files.end());
  const auto start = std::chrono::steady_clock::now();
  for (const fs::path& f : files) {
    const std::string bytes = ReadAll(f);
    fprintf(stderr, "replay %s (%zu bytes)\n", f.c_str(), bytes.size());
    LLVMFuzzerTestOneInput(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  fprintf(stderr, "replayed %zu inputs in %.2f s without a crash\n", files.size(), s);
  return 0;
}
