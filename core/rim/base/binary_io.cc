#include "rim/base/binary_io.h"

#include <errno.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#if defined(__x86_64__)
#include <nmmintrin.h>
#endif

#include <array>
#include <atomic>
#include <cstring>
#include <filesystem>
#include <utility>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/status_macros.h"

namespace rim {
namespace {

constexpr char kMagic[4] = {'R', 'I', 'M', 'F'};
// magic + version + kind + payload size.
constexpr size_t kHeaderSize = 4 + 4 + 4 + 8;
constexpr size_t kTrailerSize = 4;

std::array<uint32_t, 256> MakeCrc32cTable() {
  std::array<uint32_t, 256> table{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ 0x82F63B78u : c >> 1;
    table[i] = c;
  }
  return table;
}

// Built once on first use; function-local statics are initialised thread-safely.
const std::array<uint32_t, 256>& Crc32cTable() {
  static const std::array<uint32_t, 256> table = MakeCrc32cTable();
  return table;
}

uint32_t LoadU32(const char* p) {
  uint32_t v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}

uint64_t LoadU64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}

// Kind tags are meant to be printable, but a corrupt file can hold anything. (The explicit
// conversion is needed where absl::string_view is not an alias of std::string_view.)
std::string Printable(std::string_view s) {
  return absl::CHexEscape(absl::string_view(s.data(), s.size()));
}

absl::Status CheckKind(std::string_view kind) {
  if (kind.size() != 4) {
    return absl::InvalidArgumentError(
        absl::StrCat("file kind tag must be 4 bytes, got \"", Printable(kind), "\""));
  }
  return absl::OkStatus();
}

// Closes an fd on every exit path, so error returns cannot leak descriptors.
class Fd {
 public:
  explicit Fd(int fd) : fd_(fd) {}
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  int get() const { return fd_; }
  // Close explicitly where the result matters: on some filesystems (NFS) write errors surface only
  // at close.
  int Close() {
    int r = ::close(fd_);
    fd_ = -1;
    return r;
  }

 private:
  int fd_;
};

absl::Status WriteAll(int fd, const char* p, size_t n, const std::string& path) {
  while (n > 0) {
    ssize_t w = ::write(fd, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, absl::StrCat("write to ", path));
    }
    p += w;
    n -= static_cast<size_t>(w);
  }
  return absl::OkStatus();
}

std::string DirName(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

absl::Status FsyncDir(const std::string& dir) {
  Fd fd(::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, absl::StrCat("open directory ", dir));
  if (::fsync(fd.get()) != 0) return absl::ErrnoToStatus(errno, absl::StrCat("fsync ", dir));
  return absl::OkStatus();
}

absl::Status WriteTmpFile(const std::string& tmp, const std::string& header,
                          std::string_view payload, const std::string& trailer) {
  // O_EXCL: the name is unique per process and call, so an existing file is a stale leftover from
  // a crashed process that happened to have our pid; never write through it.
  Fd fd(::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, absl::StrCat("create ", tmp));
  RIM_RETURN_IF_ERROR(WriteAll(fd.get(), header.data(), header.size(), tmp));
  RIM_RETURN_IF_ERROR(WriteAll(fd.get(), payload.data(), payload.size(), tmp));
  RIM_RETURN_IF_ERROR(WriteAll(fd.get(), trailer.data(), trailer.size(), tmp));
  // Without this the rename may reach the disk before the data, leaving an empty file after a
  // crash.
  if (::fsync(fd.get()) != 0) return absl::ErrnoToStatus(errno, absl::StrCat("fsync ", tmp));
  if (fd.Close() != 0) return absl::ErrnoToStatus(errno, absl::StrCat("close ", tmp));
  return absl::OkStatus();
}

absl::StatusOr<std::string> ReadWholeFile(const std::string& path) {
  Fd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, absl::StrCat("open ", path));
  struct stat st;
  if (::fstat(fd.get(), &st) != 0) return absl::ErrnoToStatus(errno, absl::StrCat("stat ", path));
  std::string out;
  if (st.st_size > 0) out.reserve(static_cast<size_t>(st.st_size));
  char buf[1 << 16];
  for (;;) {
    ssize_t r = ::read(fd.get(), buf, sizeof(buf));
    if (r < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, absl::StrCat("read ", path));
    }
    if (r == 0) break;
    out.append(buf, static_cast<size_t>(r));
  }
  return out;
}

}  // namespace

#if defined(__x86_64__)
// The same CRC with SSE 4.2's crc32 instruction (Castagnoli polynomial, reflected, as the table),
// 8 bytes at a time: about 20x the table's speed. Write-ahead log records carry a whole scan
// (1.8 MB for a 64-beam frame) and checkpoints hundreds of MB; with the table alone a checkpoint
// held the trainer for about a second.
__attribute__((target("sse4.2"))) uint32_t Crc32cSse42(const unsigned char* p, size_t n,
                                                       uint32_t c) {
  uint64_t c64 = c;
  for (; n >= 8; n -= 8, p += 8) {
    uint64_t v;
    std::memcpy(&v, p, sizeof(v));
    c64 = _mm_crc32_u64(c64, v);
  }
  c = uint32_t(c64);
  for (; n > 0; --n, ++p) c = _mm_crc32_u8(c, *p);
  return c;
}
#endif

uint32_t Crc32cPortable(const void* data, size_t size, uint32_t crc) {
  const auto& table = Crc32cTable();
  const auto* p = static_cast<const unsigned char*>(data);
  // Pre- and post-inversion make the result chainable across calls.
  uint32_t c = ~crc;
  for (size_t i = 0; i < size; ++i) c = table[(c ^ p[i]) & 0xFFu] ^ (c >> 8);
  return ~c;
}

uint32_t Crc32c(const void* data, size_t size, uint32_t crc) {
#if defined(__x86_64__)
  static const bool sse42 = __builtin_cpu_supports("sse4.2");
  if (sse42) return ~Crc32cSse42(static_cast<const unsigned char*>(data), size, ~crc);
#endif
  return Crc32cPortable(data, size, crc);
}

// ---------------------------------------------------------------------------------------------
// ByteWriter

void ByteWriter::U8(uint8_t v) { buf_.push_back(static_cast<char>(v)); }
void ByteWriter::U32(uint32_t v) { Bytes(&v, sizeof(v)); }
void ByteWriter::U64(uint64_t v) { Bytes(&v, sizeof(v)); }
void ByteWriter::I32(int32_t v) { Bytes(&v, sizeof(v)); }
void ByteWriter::F32(float v) { Bytes(&v, sizeof(v)); }
void ByteWriter::F64(double v) { Bytes(&v, sizeof(v)); }

void ByteWriter::Bytes(const void* p, size_t n) {
  if (n > 0) buf_.append(static_cast<const char*>(p), n);
}

void ByteWriter::String(const std::string& s) {
  U64(s.size());
  Bytes(s.data(), s.size());
}

void ByteWriter::FloatArray(const float* p, size_t n) {
  U64(n);
  Bytes(p, n * sizeof(float));
}

std::string ByteWriter::Release() {
  std::string out = std::move(buf_);
  buf_.clear();
  return out;
}

// ---------------------------------------------------------------------------------------------
// ByteReader

ByteReader::ByteReader(std::string_view data, std::string context)
    : data_(data), context_(std::move(context)) {}

absl::Status ByteReader::Need(size_t n, const char* what) const {
  if (n <= remaining()) return absl::OkStatus();
  return absl::DataLossError(
      absl::StrFormat("%s: truncated at offset %u reading %s: need %u bytes, %u remain", context_,
                      offset_, what, n, remaining()));
}

void ByteReader::Take(void* p, size_t n) {
  if (n > 0) std::memcpy(p, data_.data() + offset_, n);
  offset_ += n;
}

absl::Status ByteReader::Count(size_t elem_size, const char* what, size_t* count) {
  RIM_RETURN_IF_ERROR(Need(sizeof(uint64_t), what));
  uint64_t n = LoadU64(data_.data() + offset_);
  const size_t avail = remaining() - sizeof(uint64_t);
  // Divide rather than multiply so a corrupt count cannot overflow past the check.
  if (n > avail / elem_size) {
    return absl::DataLossError(absl::StrFormat(
        "%s: corrupt count at offset %u reading %s: %u elements of %u bytes, only %u bytes remain",
        context_, offset_, what, n, elem_size, avail));
  }
  offset_ += sizeof(uint64_t);
  *count = static_cast<size_t>(n);
  return absl::OkStatus();
}

absl::Status ByteReader::U8(uint8_t* v) {
  RIM_RETURN_IF_ERROR(Need(sizeof(*v), "u8"));
  Take(v, sizeof(*v));
  return absl::OkStatus();
}

absl::Status ByteReader::U32(uint32_t* v) {
  RIM_RETURN_IF_ERROR(Need(sizeof(*v), "u32"));
  Take(v, sizeof(*v));
  return absl::OkStatus();
}

absl::Status ByteReader::U64(uint64_t* v) {
  RIM_RETURN_IF_ERROR(Need(sizeof(*v), "u64"));
  Take(v, sizeof(*v));
  return absl::OkStatus();
}

absl::Status ByteReader::I32(int32_t* v) {
  RIM_RETURN_IF_ERROR(Need(sizeof(*v), "i32"));
  Take(v, sizeof(*v));
  return absl::OkStatus();
}

absl::Status ByteReader::F32(float* v) {
  RIM_RETURN_IF_ERROR(Need(sizeof(*v), "f32"));
  Take(v, sizeof(*v));
  return absl::OkStatus();
}

absl::Status ByteReader::F64(double* v) {
  RIM_RETURN_IF_ERROR(Need(sizeof(*v), "f64"));
  Take(v, sizeof(*v));
  return absl::OkStatus();
}

absl::Status ByteReader::Bytes(void* p, size_t n) {
  RIM_RETURN_IF_ERROR(Need(n, "bytes"));
  Take(p, n);
  return absl::OkStatus();
}

absl::Status ByteReader::String(std::string* s) {
  size_t n = 0;
  RIM_RETURN_IF_ERROR(Count(1, "string", &n));
  s->assign(data_.data() + offset_, n);
  offset_ += n;
  return absl::OkStatus();
}

absl::Status ByteReader::FloatArray(std::vector<float>* v) {
  size_t n = 0;
  RIM_RETURN_IF_ERROR(Count(sizeof(float), "float array", &n));
  v->resize(n);
  Take(v->data(), n * sizeof(float));
  return absl::OkStatus();
}

absl::Status ByteReader::ExpectEnd() const {
  if (remaining() == 0) return absl::OkStatus();
  return absl::DataLossError(absl::StrFormat("%s: %u unexpected trailing bytes at offset %u",
                                             context_, remaining(), offset_));
}

// ---------------------------------------------------------------------------------------------
// Container files

absl::Status WriteFileAtomic(const std::string& path, std::string_view kind,
                             std::string_view payload) {
  RIM_RETURN_IF_ERROR(CheckKind(kind));
  ByteWriter header;
  header.Bytes(kMagic, sizeof(kMagic));
  header.U32(kFileFormatVersion);
  header.Bytes(kind.data(), kind.size());
  header.U64(payload.size());
  uint32_t crc = Crc32c(header.data().data(), header.data().size());
  crc = Crc32c(payload.data(), payload.size(), crc);
  ByteWriter trailer;
  trailer.U32(crc);

  // The counter keeps concurrent writers in one process (e.g. two threads saving the same file)
  // off each other's tmp files; the pid does the same across processes.
  static std::atomic<uint64_t> counter{0};
  const std::string tmp =
      absl::StrCat(path, ".tmp.", static_cast<int64_t>(::getpid()), ".", counter.fetch_add(1));

  absl::Status s = WriteTmpFile(tmp, header.data(), payload, trailer.data());
  if (s.ok() && ::rename(tmp.c_str(), path.c_str()) != 0) {
    s = absl::ErrnoToStatus(errno, absl::StrCat("rename ", tmp, " to ", path));
  }
  if (!s.ok()) {
    ::unlink(tmp.c_str());
    return s;
  }
  // Makes the rename durable; until then a crash could bring back the old file, which is allowed,
  // but the caller would wrongly believe the new one is safe.
  return FsyncDir(DirName(path));
}

absl::StatusOr<FileIdentity> IdentifyFile(const std::string& path) {
  struct stat st;
  if (::lstat(path.c_str(), &st) != 0)
    return absl::ErrnoToStatus(errno, absl::StrCat("stat ", path));
  if (!S_ISREG(st.st_mode))
    return absl::FailedPreconditionError(absl::StrCat(path, " is not a regular file"));
  FileIdentity id;
  id.device = uint64_t(st.st_dev);
  id.inode = uint64_t(st.st_ino);
  id.size = uint64_t(st.st_size);
  id.mtime_ns = int64_t(st.st_mtim.tv_sec) * 1000000000 + int64_t(st.st_mtim.tv_nsec);
  return id;
}

absl::Status LinkFileAtomic(const std::string& from, const std::string& to) {
  static std::atomic<uint64_t> counter{0};
  const std::string tmp =
      absl::StrCat(to, ".link.", static_cast<int64_t>(::getpid()), ".", counter.fetch_add(1));
  if (::link(from.c_str(), tmp.c_str()) != 0)
    return absl::ErrnoToStatus(errno, absl::StrCat("link ", from, " to ", tmp));
  if (::rename(tmp.c_str(), to.c_str()) != 0) {
    const absl::Status s = absl::ErrnoToStatus(errno, absl::StrCat("rename ", tmp, " to ", to));
    ::unlink(tmp.c_str());
    return s;
  }
  return FsyncDir(DirName(to));
}

namespace {
// ReadFileChecked up to the kind, which goes to *kind_out.
absl::StatusOr<std::string> ReadContainer(const std::string& path, std::string* kind_out) {
  RIM_ASSIGN_OR_RETURN(std::string file, ReadWholeFile(path));

  // Check order: layout first (magic, version, sizes) so offsets can be trusted, then the checksum
  // so that a corrupt kind byte is reported as corruption, then the kind.
  const size_t min_size = kHeaderSize + kTrailerSize;
  if (file.size() < min_size) {
    return absl::DataLossError(absl::StrFormat(
        "%s: truncated: expected at least %u bytes, found %u", path, min_size, file.size()));
  }
  if (std::memcmp(file.data(), kMagic, sizeof(kMagic)) != 0) {
    return absl::DataLossError(absl::StrCat(path, ": bad magic \"",
                                            Printable(std::string_view(file.data(), 4)),
                                            "\", expected \"RIMF\""));
  }
  const uint32_t version = LoadU32(file.data() + 4);
  if (version != kFileFormatVersion) {
    return absl::DataLossError(absl::StrFormat("%s: unsupported format version %u, expected %u",
                                               path, version, kFileFormatVersion));
  }
  const std::string_view file_kind(file.data() + 8, 4);
  const uint64_t payload_size = LoadU64(file.data() + 12);
  const uint64_t max_payload = file.size() - min_size;
  if (payload_size > max_payload) {
    // Do the arithmetic in the "found" domain so a huge corrupt size cannot overflow the message.
    return absl::DataLossError(absl::StrFormat(
        "%s: truncated: expected %u bytes, found %u", path,
        payload_size > UINT64_MAX - min_size ? UINT64_MAX : payload_size + min_size, file.size()));
  }
  if (payload_size < max_payload) {
    return absl::DataLossError(absl::StrFormat("%s: trailing data: expected %u bytes, found %u",
                                               path, payload_size + min_size, file.size()));
  }
  const size_t crc_offset = kHeaderSize + static_cast<size_t>(payload_size);
  const uint32_t stored_crc = LoadU32(file.data() + crc_offset);
  const uint32_t actual_crc = Crc32c(file.data(), crc_offset);
  if (stored_crc != actual_crc) {
    return absl::DataLossError(absl::StrFormat(
        "%s: checksum mismatch: stored 0x%08x, computed 0x%08x", path, stored_crc, actual_crc));
  }
  kind_out->assign(file_kind);
  file.resize(crc_offset);
  file.erase(0, kHeaderSize);
  return file;
}
}  // namespace

absl::StatusOr<std::string> ReadFileChecked(const std::string& path, std::string_view kind) {
  RIM_RETURN_IF_ERROR(CheckKind(kind));
  std::string found;
  RIM_ASSIGN_OR_RETURN(std::string payload, ReadContainer(path, &found));
  if (found != kind) {
    return absl::DataLossError(
        absl::StrCat(path, ": kind is ", Printable(found), ", expected ", Printable(kind)));
  }
  return payload;
}

absl::StatusOr<std::string> ReadFileCheckedOneOf(const std::string& path,
                                                 std::initializer_list<std::string_view> kinds,
                                                 std::string* kind) {
  std::string expected;
  for (std::string_view k : kinds) {
    RIM_RETURN_IF_ERROR(CheckKind(k));
    absl::StrAppend(&expected, expected.empty() ? "" : " or ", Printable(k));
  }
  RIM_ASSIGN_OR_RETURN(std::string payload, ReadContainer(path, kind));
  for (std::string_view k : kinds)
    if (*kind == k) return payload;
  return absl::DataLossError(
      absl::StrCat(path, ": kind is ", Printable(*kind), ", expected ", expected));
}

absl::Status MakeDirs(const std::string& path) {
  if (path.empty()) return absl::InvalidArgumentError("MakeDirs: empty path");
  // Create each prefix in turn; EEXIST is fine as long as it is a directory, which also covers a
  // concurrent creator winning the race.
  size_t pos = 0;
  while (pos != std::string::npos) {
    pos = path.find('/', pos + 1);
    const std::string prefix = path.substr(0, pos);
    if (prefix.empty() || prefix.back() == '/') continue;  // "//" or a trailing slash.
    if (::mkdir(prefix.c_str(), 0755) == 0) continue;
    const int err = errno;
    struct stat st;
    if (err == EEXIST && ::stat(prefix.c_str(), &st) == 0) {
      if (S_ISDIR(st.st_mode)) continue;
      return absl::FailedPreconditionError(
          absl::StrCat("MakeDirs ", path, ": ", prefix, " exists and is not a directory"));
    }
    return absl::ErrnoToStatus(err, absl::StrCat("MakeDirs ", path, ": mkdir ", prefix));
  }
  return absl::OkStatus();
}

absl::Status RefuseSymlink(const std::string& path) {
  struct stat st;
  if (::lstat(path.c_str(), &st) != 0 || !S_ISLNK(st.st_mode)) return absl::OkStatus();
  return absl::FailedPreconditionError(
      absl::StrCat(path, " is a symbolic link; rim does not follow links in its data dir"));
}

absl::Status RefuseSymlinksUnder(const std::string& dir) {
  RIM_RETURN_IF_ERROR(RefuseSymlink(dir));
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) return absl::OkStatus();
  // recursive_directory_iterator does not descend into linked directories by default; a link
  // is reported as an entry and refused here.
  for (auto it = std::filesystem::recursive_directory_iterator(dir, ec);
       !ec && it != std::filesystem::recursive_directory_iterator(); it.increment(ec)) {
    if (it->is_symlink(ec)) RIM_RETURN_IF_ERROR(RefuseSymlink(it->path().string()));
  }
  if (ec) return absl::InternalError(absl::StrCat("listing ", dir, ": ", ec.message()));
  return absl::OkStatus();
}

}  // namespace rim
