// Persistence primitives of the mapper: CRC-32C, little-endian byte (de)serialisation with
// bounds-checked reads, and checksummed container files written atomically.
//
// Everything on disk is little-endian. Bulk arrays are copied as raw memory, which is only
// correct on a little-endian host; that is the only kind of host we build for, and the
// static_assert below makes a port to anything else fail loudly instead of corrupting maps.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <initializer_list>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/base/status_macros.h"

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "rim/binary_io assumes a little-endian host"
#endif

namespace rim {

// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78). `crc` is the value returned by a previous
// call, so a checksum can be built incrementally: Crc32c(b, nb, Crc32c(a, na)) == Crc32c(a+b).
uint32_t Crc32c(const void* data, size_t size, uint32_t crc = 0);
// The same from a byte table, without SSE 4.2 (what Crc32c uses on CPUs without it); for tests.
uint32_t Crc32cPortable(const void* data, size_t size, uint32_t crc = 0);

// Little-endian serialisation into a growing byte buffer.
class ByteWriter {
 public:
  void U8(uint8_t v);
  void U32(uint32_t v);
  void U64(uint64_t v);
  void I32(int32_t v);
  void F32(float v);
  void F64(double v);
  void Bytes(const void* p, size_t n);
  // u64 length followed by the bytes.
  void String(const std::string& s);
  // u64 element count followed by the raw floats.
  void FloatArray(const float* p, size_t n);
  // u64 element count followed by the raw element bytes.
  template <typename T>
  void PodVector(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>, "PodVector needs a trivially copyable type");
    U64(v.size());
    Bytes(v.data(), v.size() * sizeof(T));
  }

  const std::string& data() const { return buf_; }
  size_t size() const { return buf_.size(); }
  // Makes room for `more` further bytes at once, so that a large payload written piecewise is
  // not copied again each time the buffer doubles.
  void Reserve(size_t more) { buf_.reserve(buf_.size() + more); }
  // Hands the buffer over and leaves the writer empty.
  std::string Release();

 private:
  std::string buf_;
};

// Bounds-checked little-endian reader over a borrowed buffer (which must outlive the reader).
// On overrun a read returns DataLossError naming the context (e.g. the file path), the byte
// offset and what was being read, and leaves the offset unchanged. Element counts are checked
// against the remaining bytes before anything is allocated, so a corrupt count cannot trigger a
// huge allocation.
class ByteReader {
 public:
  ByteReader(std::string_view data, std::string context);

  absl::Status U8(uint8_t* v);
  absl::Status U32(uint32_t* v);
  absl::Status U64(uint64_t* v);
  absl::Status I32(int32_t* v);
  absl::Status F32(float* v);
  absl::Status F64(double* v);
  absl::Status Bytes(void* p, size_t n);
  absl::Status String(std::string* s);
  absl::Status FloatArray(std::vector<float>* v);
  template <typename T>
  absl::Status PodVector(std::vector<T>* v) {
    static_assert(std::is_trivially_copyable_v<T>, "PodVector needs a trivially copyable type");
    size_t count = 0;
    RIM_RETURN_IF_ERROR(Count(sizeof(T), "pod vector", &count));
    std::vector<T> out(count);
    if (count > 0) std::memcpy(out.data(), data_.data() + offset_, count * sizeof(T));
    offset_ += count * sizeof(T);
    *v = std::move(out);
    return absl::OkStatus();
  }

  size_t remaining() const { return data_.size() - offset_; }
  size_t offset() const { return offset_; }
  // DataLoss if any bytes are left unread; catches writer/reader format drift.
  absl::Status ExpectEnd() const;

 private:
  // OK if `n` more bytes can be read, else the overrun error for reading `what`.
  absl::Status Need(size_t n, const char* what) const;
  // Reads a u64 element count and checks that count * elem_size bytes follow it. On failure the
  // offset is left where it was before the count.
  absl::Status Count(size_t elem_size, const char* what, size_t* count);
  // Copies `n` bytes after a successful Need().
  void Take(void* p, size_t n);

  std::string_view data_;
  std::string context_;
  size_t offset_ = 0;
};

// Container file layout, all little-endian:
//   "RIMF" | u32 format version | 4-char kind tag | u64 payload size | payload | u32 CRC-32C
// where the CRC covers every byte before it.
inline constexpr uint32_t kFileFormatVersion = 1;

// Writes a container file so that a crash at any point leaves either the old file or the new one:
// the bytes go to "<path>.tmp.<pid>.<counter>", which is fsynced, renamed over `path`, and then the
// directory is fsynced so the rename itself is durable. `kind` must be exactly 4 bytes.
absl::Status WriteFileAtomic(const std::string& path, std::string_view kind,
                             std::string_view payload);

// What identifies a file that rim wrote: device, inode, size and modification time. A later
// look that finds the same identity finds the same file, not rewritten since (a rewrite makes a
// new inode, as WriteFileAtomic does, or moves the modification time).
struct FileIdentity {
  uint64_t device = 0, inode = 0, size = 0;
  int64_t mtime_ns = 0;
  bool operator==(const FileIdentity& o) const {
    return device == o.device && inode == o.inode && size == o.size && mtime_ns == o.mtime_ns;
  }
};
// The identity of the regular file at `path` (not following a link); NotFound when it is missing,
// FailedPrecondition when it is not a regular file.
absl::StatusOr<FileIdentity> IdentifyFile(const std::string& path);

// Gives the file at `from` a second name `to` (a hard link), with WriteFileAtomic's guarantees:
// linked under a temporary name, renamed over `to`, and the directory fsynced. The file itself
// must already be durable (a file that WriteFileAtomic wrote is).
absl::Status LinkFileAtomic(const std::string& from, const std::string& to);

// Reads a container file and verifies magic, version, size, checksum and kind, returning the
// payload. NotFound for a missing file; DataLoss for truncated, corrupt or wrong-kind files. Every
// message names the path and the problem.
absl::StatusOr<std::string> ReadFileChecked(const std::string& path, std::string_view kind);
// The same for a file that may be of any of `kinds` (a newer format and the older ones that still
// load); the kind it has goes to *kind.
absl::StatusOr<std::string> ReadFileCheckedOneOf(const std::string& path,
                                                 std::initializer_list<std::string_view> kinds,
                                                 std::string* kind);

// Creates a directory and any missing parents, like `mkdir -p`. OK if it already exists.
absl::Status MakeDirs(const std::string& path);

// FAILED_PRECONDITION naming the path when `path` is a symbolic link; OK when it is anything
// else or does not exist. Data dirs are checked with these before rim reads or writes in them, so
// that a link planted in a data dir cannot make it read or overwrite files elsewhere.
absl::Status RefuseSymlink(const std::string& path);
// The same for `dir` and everything below it (the walk does not follow links).
absl::Status RefuseSymlinksUnder(const std::string& dir);

}  // namespace rim
