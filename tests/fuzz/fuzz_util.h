// Helpers shared by the fuzz targets (docs/security.md, "Fuzzing"): checks that abort so the fuzzer
// records the input, scratch directories, and the small record format that targets taking several
// files (a checkpoint, a write-ahead log) read their input in.
#pragma once

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "absl/strings/string_view.h"

// libFuzzer's entry point, which each target defines; replay_main.cc calls it too.
extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

// An invariant the code under test promises. A violation aborts, which libFuzzer reports as a crash
// and saves the input for, like a sanitizer error.
#define RIM_FUZZ_CHECK(cond)                                                            \
  do {                                                                                  \
    if (!(cond)) {                                                                      \
      fprintf(stderr, "%s:%d: fuzz invariant failed: %s\n", __FILE__, __LINE__, #cond); \
      abort();                                                                          \
    }                                                                                   \
  } while (0)

namespace rim::fuzz {

inline std::string_view Bytes(const uint8_t* data, size_t size) {
  return std::string_view(reinterpret_cast<const char*>(data), size);
}

// The same bytes for rim's io functions, which take absl::string_view (not an alias of
// std::string_view in every absl build).
inline absl::string_view AbslBytes(const uint8_t* data, size_t size) {
  return absl::string_view(reinterpret_cast<const char*>(data), size);
}

// A directory for one fuzz process, removed when the process exits normally. It lives on /dev/shm
// when that is writable: the targets that go through the write-ahead log and checkpoints fsync on
// every input, which is free on tmpfs and slow on a disk. RIM_FUZZ_TMPDIR overrides the location.
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& prefix) {
    std::string base = "/tmp";
    if (const char* env = getenv("RIM_FUZZ_TMPDIR")) {
      base = env;
    } else if (access("/dev/shm", W_OK) == 0) {
      base = "/dev/shm";
    }
    std::string tmpl = base + "/" + prefix + "_XXXXXX";
    if (mkdtemp(tmpl.data()) == nullptr) {
      perror(("mkdtemp " + tmpl).c_str());
      abort();
    }
    path_ = tmpl;
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// Writes `bytes` to `path` (created or truncated); aborts on failure, which is the harness's
// environment failing, not the code under test.
void WriteFileOrDie(const std::string& path, std::string_view bytes);

// Fuzz inputs that describe several files or records are a sequence of entries:
//   u8 op | u16 length (little-endian) | `length` bytes
// A length past the end of the input takes what is left, so every byte string is a valid input and
// the fuzzer's mutations never fall off a framing cliff. At most `max_entries` are returned.
struct Entry {
  uint8_t op = 0;
  std::string_view bytes;
};
std::vector<Entry> SplitEntries(std::string_view input, size_t max_entries);

// The inverse, for writing seeds: appends one entry to `out`. `bytes` must be under 64 KiB.
void AppendEntry(uint8_t op, std::string_view bytes, std::string* out);

}  // namespace rim::fuzz
