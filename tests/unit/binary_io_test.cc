#include "rim/base/binary_io.h"

#include <dirent.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace rim {
namespace {

using ::testing::HasSubstr;

std::string ReadRaw(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void WriteRaw(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::vector<std::string> ListDir(const std::string& dir) {
  std::vector<std::string> names;
  DIR* d = opendir(dir.c_str());
  if (d == nullptr) return names;
  while (dirent* e = readdir(d)) {
    std::string name = e->d_name;
    if (name != "." && name != "..") names.push_back(name);
  }
  closedir(d);
  return names;
}

bool IsDir(const std::string& path) {
  struct stat st;
  return stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}

void RemoveTree(const std::string& path) {
  if (IsDir(path)) {
    for (const std::string& name : ListDir(path)) RemoveTree(path + "/" + name);
    rmdir(path.c_str());
  } else {
    unlink(path.c_str());
  }
}

class TempDirTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = ::testing::TempDir();
    if (tmpl.empty() || tmpl.back() != '/') tmpl += '/';
    tmpl += "binary_io_test.XXXXXX";
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr) << tmpl;
    dir_ = tmpl;
  }
  void TearDown() override {
    if (!dir_.empty()) RemoveTree(dir_);
  }
  std::string dir_;
};

// ---------------------------------------------------------------------------------------------

TEST(Crc32cTest, KnownCheckValue) {
  EXPECT_EQ(Crc32c("123456789", 9), 0xE3069283u);
  EXPECT_EQ(Crc32c("", 0), 0u);
}

// The hardware path (SSE 4.2, where the CPU has it) and the table agree for every length and
// alignment, chained or not.
TEST(Crc32cTest, HardwareAndTableAgree) {
  std::string s;
  for (int i = 0; i < 300; ++i) s.push_back(char(i * 131 + 7));
  EXPECT_EQ(Crc32cPortable("123456789", 9), 0xE3069283u);
  for (size_t start = 0; start < 9; ++start)
    for (size_t n = 0; start + n <= s.size(); n += 1 + n / 4) {
      const uint32_t seed = uint32_t(n * 2654435761u);
      ASSERT_EQ(Crc32c(s.data() + start, n), Crc32cPortable(s.data() + start, n))
          << start << " " << n;
      ASSERT_EQ(Crc32c(s.data() + start, n, seed), Crc32cPortable(s.data() + start, n, seed));
    }
}

TEST(Crc32cTest, IncrementalMatchesOneShot) {
  const std::string s = "The quick brown fox jumps over the lazy dog";
  const uint32_t whole = Crc32c(s.data(), s.size());
  for (size_t split = 0; split <= s.size(); ++split) {
    EXPECT_EQ(Crc32c(s.data() + split, s.size() - split, Crc32c(s.data(), split)), whole) << split;
  }
}

// ---------------------------------------------------------------------------------------------

struct Pod {
  int32_t a;
  float b;
  uint8_t c[8];
};

TEST(ByteIoTest, LittleEndianLayout) {
  ByteWriter w;
  w.U8(0xAB);
  w.U32(0x01020304u);
  w.U64(0x0102030405060708ull);
  w.I32(-2);
  w.F32(1.0f);
  const std::string expected(
      "\xAB"
      "\x04\x03\x02\x01"
      "\x08\x07\x06\x05\x04\x03\x02\x01"
      "\xFE\xFF\xFF\xFF"
      "\x00\x00\x80\x3F",
      1 + 4 + 8 + 4 + 4);
  EXPECT_EQ(w.data(), expected);
}

TEST(ByteIoTest, RoundTripEveryType) {
  const std::vector<float> floats = {0.0f,
                                     -0.0f,
                                     1.5f,
                                     std::numeric_limits<float>::infinity(),
                                     std::numeric_limits<float>::denorm_min(),
                                     std::numeric_limits<float>::quiet_NaN()};
  std::vector<Pod> pods(3);
  for (int i = 0; i < 3; ++i) {
    pods[i].a = -i * 1000;
    pods[i].b = 0.25f * static_cast<float>(i);
    for (int k = 0; k < 8; ++k) pods[i].c[k] = static_cast<uint8_t>(i * 8 + k);
  }
  const std::string with_nul("a\0b\xff", 4);
  const char raw[3] = {'x', '\0', 'z'};

  ByteWriter w;
  w.U8(200);
  w.U32(0xDEADBEEFu);
  w.U64(0xFEDCBA9876543210ull);
  w.I32(std::numeric_limits<int32_t>::min());
  w.F32(-3.25f);
  w.F64(std::nextafter(1.0, 2.0));
  w.Bytes(raw, sizeof(raw));
  w.String(with_nul);
  w.String("");
  w.FloatArray(floats.data(), floats.size());
  w.FloatArray(nullptr, 0);
  w.PodVector(pods);
  w.PodVector(std::vector<uint16_t>{});
  const std::string bytes = w.data();

  ByteReader r(bytes, "mem");
  uint8_t u8;
  uint32_t u32;
  uint64_t u64;
  int32_t i32;
  float f32;
  double f64;
  char raw_in[3];
  std::string s1, s2 = "junk";
  std::vector<float> fa, fb = {1.0f};
  std::vector<Pod> pods_in;
  std::vector<uint16_t> empty = {7};
  ASSERT_TRUE(r.U8(&u8).ok());
  ASSERT_TRUE(r.U32(&u32).ok());
  ASSERT_TRUE(r.U64(&u64).ok());
  ASSERT_TRUE(r.I32(&i32).ok());
  ASSERT_TRUE(r.F32(&f32).ok());
  ASSERT_TRUE(r.F64(&f64).ok());
  ASSERT_TRUE(r.Bytes(raw_in, sizeof(raw_in)).ok());
  ASSERT_TRUE(r.String(&s1).ok());
  ASSERT_TRUE(r.String(&s2).ok());
  ASSERT_TRUE(r.FloatArray(&fa).ok());
  ASSERT_TRUE(r.FloatArray(&fb).ok());
  ASSERT_TRUE(r.PodVector(&pods_in).ok());
  ASSERT_TRUE(r.PodVector(&empty).ok());
  EXPECT_EQ(r.remaining(), 0u);
  EXPECT_EQ(r.offset(), bytes.size());
  EXPECT_TRUE(r.ExpectEnd().ok());

  EXPECT_EQ(u8, 200);
  EXPECT_EQ(u32, 0xDEADBEEFu);
  EXPECT_EQ(u64, 0xFEDCBA9876543210ull);
  EXPECT_EQ(i32, std::numeric_limits<int32_t>::min());
  EXPECT_EQ(f32, -3.25f);
  EXPECT_EQ(f64, std::nextafter(1.0, 2.0));
  EXPECT_EQ(std::memcmp(raw_in, raw, sizeof(raw)), 0);
  EXPECT_EQ(s1, with_nul);
  EXPECT_EQ(s2, "");
  // Byte-exact, so NaN payloads and the sign of zero survive.
  ASSERT_EQ(fa.size(), floats.size());
  EXPECT_EQ(std::memcmp(fa.data(), floats.data(), floats.size() * sizeof(float)), 0);
  EXPECT_TRUE(fb.empty());
  ASSERT_EQ(pods_in.size(), pods.size());
  EXPECT_EQ(std::memcmp(pods_in.data(), pods.data(), pods.size() * sizeof(Pod)), 0);
  EXPECT_TRUE(empty.empty());
}

TEST(ByteIoTest, ReleaseEmptiesWriter) {
  ByteWriter w;
  w.U32(5);
  const std::string out = w.Release();
  EXPECT_EQ(out.size(), 4u);
  EXPECT_TRUE(w.data().empty());
  w.U8(1);
  EXPECT_EQ(w.data().size(), 1u);
}

TEST(ByteIoTest, OverrunNamesContextOffsetAndWhat) {
  ByteWriter w;
  w.U32(1);
  w.U8(2);
  const std::string bytes = w.Release();
  ByteReader r(bytes, "/maps/a.rim");
  uint32_t u32;
  ASSERT_TRUE(r.U32(&u32).ok());
  uint64_t u64;
  absl::Status s = r.U64(&u64);
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_THAT(s.message(), HasSubstr("/maps/a.rim"));
  EXPECT_THAT(s.message(), HasSubstr("offset 4"));
  EXPECT_THAT(s.message(), HasSubstr("u64"));
  // A failed read consumes nothing, so the remaining byte is still there.
  EXPECT_EQ(r.offset(), 4u);
  uint8_t u8;
  ASSERT_TRUE(r.U8(&u8).ok());
  EXPECT_EQ(u8, 2);
  EXPECT_TRUE(absl::IsDataLoss(r.U8(&u8)));
  float f;
  EXPECT_TRUE(absl::IsDataLoss(r.F32(&f)));
  double d;
  EXPECT_TRUE(absl::IsDataLoss(r.F64(&d)));
  int32_t i;
  EXPECT_TRUE(absl::IsDataLoss(r.I32(&i)));
  char buf[2];
  EXPECT_TRUE(absl::IsDataLoss(r.Bytes(buf, 1)));
  EXPECT_TRUE(r.Bytes(buf, 0).ok());
}

TEST(ByteIoTest, EveryTruncationOfAStreamFails) {
  ByteWriter w;
  w.String("hello");
  const std::vector<float> f = {1, 2, 3};
  w.FloatArray(f.data(), f.size());
  w.PodVector(std::vector<int64_t>{4, 5});
  const std::string bytes = w.Release();
  for (size_t len = 0; len < bytes.size(); ++len) {
    ByteReader r(std::string_view(bytes).substr(0, len), "ctx");
    std::string s;
    std::vector<float> fv;
    std::vector<int64_t> iv;
    absl::Status st = r.String(&s);
    if (st.ok()) st = r.FloatArray(&fv);
    if (st.ok()) st = r.PodVector(&iv);
    EXPECT_TRUE(absl::IsDataLoss(st)) << len;
    EXPECT_THAT(st.message(), HasSubstr("ctx")) << len;
  }
}

TEST(ByteIoTest, HugeCorruptCountRejectedWithoutAllocating) {
  for (uint64_t count :
       {std::numeric_limits<uint64_t>::max(), uint64_t{1} << 62, uint64_t{1} << 40, uint64_t{5}}) {
    ByteWriter w;
    w.U64(count);
    w.U32(0);  // 4 bytes of "data": too few for any of the counts above.
    const std::string bytes = w.Release();
    {
      ByteReader r(bytes, "corrupt.bin");
      std::string s;
      absl::Status st = r.String(&s);
      EXPECT_TRUE(absl::IsDataLoss(st)) << st;
      EXPECT_THAT(st.message(), HasSubstr("corrupt.bin"));
      EXPECT_THAT(st.message(), HasSubstr("string"));
      EXPECT_EQ(r.offset(), 0u);
    }
    {
      ByteReader r(bytes, "corrupt.bin");
      std::vector<float> v;
      absl::Status st = r.FloatArray(&v);
      EXPECT_TRUE(absl::IsDataLoss(st)) << st;
      EXPECT_THAT(st.message(), HasSubstr("float array"));
      EXPECT_EQ(v.capacity(), 0u);
    }
    {
      ByteReader r(bytes, "corrupt.bin");
      std::vector<Pod> v;
      absl::Status st = r.PodVector(&v);
      EXPECT_TRUE(absl::IsDataLoss(st)) << st;
      EXPECT_EQ(v.capacity(), 0u);
    }
  }
}

TEST(ByteIoTest, ExpectEndReportsTrailingBytes) {
  const std::string bytes("\x01\x02\x03", 3);
  ByteReader r(bytes, "trail.bin");
  uint8_t u8;
  ASSERT_TRUE(r.U8(&u8).ok());
  absl::Status s = r.ExpectEnd();
  EXPECT_TRUE(absl::IsDataLoss(s));
  EXPECT_THAT(s.message(), HasSubstr("trail.bin"));
  EXPECT_THAT(s.message(), HasSubstr("2"));
}

// ---------------------------------------------------------------------------------------------

using FileTest = TempDirTest;

TEST_F(FileTest, RoundTrip) {
  const std::string path = dir_ + "/conf.rim";
  const std::string payload("config\0payload\xff", 15);
  ASSERT_TRUE(WriteFileAtomic(path, "CONF", payload).ok());
  absl::StatusOr<std::string> got = ReadFileChecked(path, "CONF");
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(*got, payload);
  // 4 magic + 4 version + 4 kind + 8 size + payload + 4 crc.
  EXPECT_EQ(ReadRaw(path).size(), 24 + payload.size());
  EXPECT_EQ(ReadRaw(path).substr(0, 4), "RIMF");

  // Empty payloads are legal, and an overwrite replaces the old contents.
  ASSERT_TRUE(WriteFileAtomic(path, "CONF", "").ok());
  got = ReadFileChecked(path, "CONF");
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(*got, "");
}

TEST_F(FileTest, NoTmpFilesLeftBehind) {
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(WriteFileAtomic(dir_ + "/a.rim", "SUBM", std::string(100 * i, 'x')).ok());
  }
  ASSERT_TRUE(WriteFileAtomic(dir_ + "/b.rim", "SUBM", "b").ok());
  std::vector<std::string> names = ListDir(dir_);
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"a.rim", "b.rim"}));
}

TEST_F(FileTest, FailedWriteLeavesOldFileAndNoTmp) {
  // The target is an existing non-empty directory, so the rename must fail after the tmp file
  // was fully written.
  const std::string path = dir_ + "/occupied";
  ASSERT_TRUE(MakeDirs(path + "/child").ok());
  absl::Status s = WriteFileAtomic(path, "CONF", "data");
  EXPECT_FALSE(s.ok());
  EXPECT_THAT(s.message(), HasSubstr(path));
  EXPECT_EQ(ListDir(dir_), std::vector<std::string>{"occupied"});
}

TEST_F(FileTest, WriteIntoMissingDirectoryFails) {
  absl::Status s = WriteFileAtomic(dir_ + "/nope/x.rim", "CONF", "data");
  EXPECT_TRUE(absl::IsNotFound(s)) << s;
  EXPECT_THAT(s.message(), HasSubstr(dir_ + "/nope/x.rim"));
}

TEST_F(FileTest, BadKindArgumentRejected) {
  EXPECT_TRUE(absl::IsInvalidArgument(WriteFileAtomic(dir_ + "/k.rim", "CON", "x")));
  EXPECT_TRUE(absl::IsInvalidArgument(WriteFileAtomic(dir_ + "/k.rim", "CONFX", "x")));
  EXPECT_TRUE(ListDir(dir_).empty());
  ASSERT_TRUE(WriteFileAtomic(dir_ + "/k.rim", "CONF", "x").ok());
  EXPECT_TRUE(absl::IsInvalidArgument(ReadFileChecked(dir_ + "/k.rim", "").status()));
}

TEST_F(FileTest, EverySingleByteFlipDetected) {
  const std::string path = dir_ + "/flip.rim";
  ASSERT_TRUE(WriteFileAtomic(path, "SUBM", "small payload!").ok());
  const std::string good = ReadRaw(path);
  ASSERT_TRUE(ReadFileChecked(path, "SUBM").ok());
  for (size_t i = 0; i < good.size(); ++i) {
    for (uint8_t mask : {0x01, 0x80, 0xFF}) {
      std::string bad = good;
      bad[i] = static_cast<char>(bad[i] ^ mask);
      WriteRaw(path, bad);
      absl::StatusOr<std::string> got = ReadFileChecked(path, "SUBM");
      ASSERT_FALSE(got.ok()) << "offset " << i << " mask " << int{mask};
      EXPECT_TRUE(absl::IsDataLoss(got.status())) << got.status();
      EXPECT_THAT(got.status().message(), HasSubstr(path));
    }
  }
  // Payload and checksum corruption are named as such.
  std::string bad = good;
  bad[22] ^= 1;
  WriteRaw(path, bad);
  EXPECT_THAT(ReadFileChecked(path, "SUBM").status().message(), HasSubstr("checksum mismatch"));
}

TEST_F(FileTest, EveryTruncationDetected) {
  const std::string path = dir_ + "/trunc.rim";
  ASSERT_TRUE(WriteFileAtomic(path, "SUBM", "0123456789").ok());
  const std::string good = ReadRaw(path);
  for (size_t len = 0; len < good.size(); ++len) {
    WriteRaw(path, good.substr(0, len));
    absl::StatusOr<std::string> got = ReadFileChecked(path, "SUBM");
    ASSERT_FALSE(got.ok()) << len;
    EXPECT_TRUE(absl::IsDataLoss(got.status())) << got.status();
    EXPECT_THAT(got.status().message(), HasSubstr(path));
    EXPECT_THAT(got.status().message(), HasSubstr("truncated"));
  }
  WriteRaw(path, good.substr(0, good.size() - 3));
  EXPECT_THAT(ReadFileChecked(path, "SUBM").status().message(),
              HasSubstr("truncated: expected 34 bytes, found 31"));
  // Appended garbage is corruption too.
  WriteRaw(path, good + "x");
  EXPECT_TRUE(absl::IsDataLoss(ReadFileChecked(path, "SUBM").status()));
}

TEST_F(FileTest, WrongKindDetected) {
  const std::string path = dir_ + "/sub.rim";
  ASSERT_TRUE(WriteFileAtomic(path, "SUBM", "x").ok());
  absl::Status s = ReadFileChecked(path, "CONF").status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_THAT(s.message(), HasSubstr(path));
  EXPECT_THAT(s.message(), HasSubstr("kind is SUBM, expected CONF"));
}

TEST_F(FileTest, MissingFileIsNotFound) {
  const std::string path = dir_ + "/missing.rim";
  absl::Status s = ReadFileChecked(path, "CONF").status();
  EXPECT_TRUE(absl::IsNotFound(s)) << s;
  EXPECT_THAT(s.message(), HasSubstr(path));
}

TEST_F(FileTest, HugeSizeFieldIsTruncationNotAllocation) {
  const std::string path = dir_ + "/huge.rim";
  ASSERT_TRUE(WriteFileAtomic(path, "CONF", "abc").ok());
  std::string bad = ReadRaw(path);
  std::memset(&bad[12], 0xFF, 8);
  WriteRaw(path, bad);
  absl::Status s = ReadFileChecked(path, "CONF").status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_THAT(s.message(), HasSubstr("truncated"));
}

TEST_F(FileTest, MakeDirsNested) {
  const std::string deep = dir_ + "/a/b//c/d/";
  ASSERT_TRUE(MakeDirs(deep).ok());
  EXPECT_TRUE(IsDir(dir_ + "/a/b/c/d"));
  // Idempotent.
  EXPECT_TRUE(MakeDirs(dir_ + "/a/b/c/d").ok());
  EXPECT_TRUE(MakeDirs(dir_).ok());
  // Files can then be written there.
  ASSERT_TRUE(WriteFileAtomic(dir_ + "/a/b/c/d/f.rim", "CONF", "z").ok());
  EXPECT_TRUE(ReadFileChecked(dir_ + "/a/b/c/d/f.rim", "CONF").ok());
}

TEST_F(FileTest, MakeDirsThroughFileFails) {
  WriteRaw(dir_ + "/file", "not a dir");
  absl::Status s = MakeDirs(dir_ + "/file/sub");
  EXPECT_FALSE(s.ok());
  EXPECT_THAT(s.message(), HasSubstr(dir_ + "/file/sub"));
  EXPECT_TRUE(absl::IsInvalidArgument(MakeDirs("")));
}

TEST_F(FileTest, MakeDirsRelativePath) {
  char old_cwd[4096];
  ASSERT_NE(getcwd(old_cwd, sizeof(old_cwd)), nullptr);
  ASSERT_EQ(chdir(dir_.c_str()), 0);
  absl::Status s = MakeDirs("rel/x");
  EXPECT_EQ(chdir(old_cwd), 0);
  ASSERT_TRUE(s.ok()) << s;
  EXPECT_TRUE(IsDir(dir_ + "/rel/x"));
}

}  // namespace
}  // namespace rim
