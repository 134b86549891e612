#include "fuzz_util.h"

#include <algorithm>
#include <fstream>

namespace rim::fuzz {

void WriteFileOrDie(const std::string& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) {
    fprintf(stderr, "fuzz harness: cannot write %s\n", path.c_str());
    abort();
  }
}

std::vector<Entry> SplitEntries(std::string_view input, size_t max_entries) {
  std::vector<Entry> entries;
  size_t at = 0;
  while (at < input.size() && entries.size() < max_entries) {
    Entry e;
    e.op = static_cast<uint8_t>(input[at++]);
    size_t length = 0;
    for (int i = 0; i < 2 && at < input.size(); ++i, ++at)
      length |= size_t(static_cast<uint8_t>(input[at])) << (8 * i);
    length = std::min(length, input.size() - at);
    e.bytes = input.substr(at, length);
    at += length;
    entries.push_back(e);
  }
  return entries;
}

void AppendEntry(uint8_t op, std::string_view bytes, std::string* out) {
  if (bytes.size() > 0xFFFF) {
    fprintf(stderr, "fuzz seed entry of %zu bytes is over 64 KiB\n", bytes.size());
    abort();
  }
  out->push_back(static_cast<char>(op));
  out->push_back(static_cast<char>(bytes.size() & 0xFF));
  out->push_back(static_cast<char>(bytes.size() >> 8));
  out->append(bytes);
}

}  // namespace rim::fuzz
