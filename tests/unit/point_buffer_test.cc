// The historical point buffer (DESIGN.md §3.4 step 2): per-frame and total caps with random
// dropping, removal of points that left the box, filtering, and persistence including the random
// generator state.
#include "rim/train/point_buffer.h"

#include <algorithm>
#include <cstdint>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "rim/base/binary_io.h"
#include "rim/config/config.h"

namespace rim {
namespace {

// Point i of frame f is (f, i, 0.5); its origin is (f, i, -7), so that pairs can be checked.
std::vector<Vec3f> FramePoints(int f, int n) {
  std::vector<Vec3f> p;
  for (int i = 0; i < n; ++i) p.emplace_back(float(f), float(i), 0.5f);
  return p;
}
std::vector<Vec3f> FrameOrigins(int f, int n) {
  std::vector<Vec3f> o;
  for (int i = 0; i < n; ++i) o.emplace_back(float(f), float(i), -7.f);
  return o;
}
void AddTestFrame(PointBuffer* b, int f, int n) {
  b->AddFrame(FramePoints(f, n), FrameOrigins(f, n));
}

// Every point is one that was added, with its own origin, and none is duplicated.
void ExpectConsistent(const PointBuffer& b) {
  ASSERT_EQ(b.points().size(), b.origins().size());
  std::set<std::pair<float, float>> seen;
  for (size_t i = 0; i < b.size(); ++i) {
    const Vec3f& p = b.points()[i];
    const Vec3f& o = b.origins()[i];
    EXPECT_EQ(p.z(), 0.5f);
    EXPECT_EQ(o, Vec3f(p.x(), p.y(), -7.f)) << "point " << i << " lost its origin";
    EXPECT_TRUE(seen.insert({p.x(), p.y()}).second) << "duplicate point " << p.transpose();
  }
}

BufferConfig Caps(int max_points, int per_frame) {
  BufferConfig c;
  c.max_points = max_points;
  c.max_points_per_frame = per_frame;
  return c;
}

TEST(PointBufferTest, PerFrameCapKeepsARandomSubset) {
  PointBuffer b(Caps(1000000, 10), /*seed=*/1);
  AddTestFrame(&b, 0, 100);
  EXPECT_EQ(b.size(), 10u);
  ExpectConsistent(b);
  // Not simply the first ten.
  int beyond_first_ten = 0;
  for (const Vec3f& p : b.points()) beyond_first_ten += p.y() >= 10.f;
  EXPECT_GT(beyond_first_ten, 0);

  // Below the cap, the whole frame is kept.
  AddTestFrame(&b, 1, 7);
  EXPECT_EQ(b.size(), 17u);
  ExpectConsistent(b);

  // Uniform: over many frames each index is kept about equally often.
  PointBuffer u(Caps(1000000, 5), /*seed=*/2);
  for (int f = 0; f < 4000; ++f) AddTestFrame(&u, f, 20);
  ASSERT_EQ(u.size(), 20000u);
  std::vector<int> count(20, 0);
  for (const Vec3f& p : u.points()) ++count[int(p.y())];
  for (int i = 0; i < 20; ++i) EXPECT_NEAR(count[i], 1000, 150) << "index " << i;
}

TEST(PointBufferTest, TotalCapDropsRandomPoints) {
  PointBuffer b(Caps(100, 10), /*seed=*/3);
  for (int f = 0; f < 100; ++f) {
    AddTestFrame(&b, f, 10);
    EXPECT_EQ(b.size(), size_t(std::min(100, 10 * (f + 1))));
  }
  ExpectConsistent(b);
  // Random dropping, not first-in-first-out: some points older than the last ten frames survive.
  int old = 0;
  for (const Vec3f& p : b.points()) old += p.x() < 90.f;
  EXPECT_GT(old, 0);

  // A single frame larger than the total cap.
  PointBuffer c(Caps(5, 100), /*seed=*/4);
  AddTestFrame(&c, 0, 50);
  EXPECT_EQ(c.size(), 5u);
  ExpectConsistent(c);
}

// The newest frame's points (what training draws sampler.newest_share of its rays from) stay the
// last newest() points through the bound's drops, deferred rays joining and filters.
TEST(PointBufferTest, TheNewestFrameStaysAtTheEnd) {
  PointBuffer buffer(Caps(/*max_points=*/120, /*per_frame=*/1000), /*seed=*/5);
  auto frame = [](int n, float x) {
    std::vector<Vec3f> p;
    for (int i = 0; i < n; ++i) p.push_back(Vec3f(x, float(i), 0.f));
    return p;
  };
  const std::vector<Vec3f> zeros(200, Vec3f::Zero());
  buffer.AddFrame(frame(100, 1.f), {zeros.begin(), zeros.begin() + 100});
  EXPECT_EQ(buffer.newest(), 100u);
  buffer.AddFrame(frame(50, 2.f), {zeros.begin(), zeros.begin() + 50});  // 30 older points go
  ASSERT_EQ(buffer.size(), 120u);
  ASSERT_EQ(buffer.newest(), 50u);
  auto tail_xs = [&] {
    std::multiset<float> xs;
    for (size_t i = buffer.size() - buffer.newest(); i < buffer.size(); ++i)
      xs.insert(buffer.points()[i].x());
    return xs;
  };
  const std::vector<float> twos(50, 2.f), threes(10, 3.f);
  EXPECT_EQ(tail_xs(), std::multiset<float>(twos.begin(), twos.end()));
  buffer.AddPoints(frame(10, 3.f), {zeros.begin(), zeros.begin() + 10});  // deferred rays join
  ASSERT_EQ(buffer.newest(), 60u);
  std::multiset<float> want(twos.begin(), twos.end());
  want.insert(threes.begin(), threes.end());
  EXPECT_EQ(tail_xs(), want);
  size_t older_ones = 0;
  for (size_t i = 0; i < buffer.size() - buffer.newest(); ++i)
    older_ones += buffer.points()[i].x() == 1.f;
  EXPECT_EQ(older_ones, 60u);
  // A filter that drops every other point keeps the order, so the newest remain last.
  std::vector<bool> keep(buffer.size());
  for (size_t i = 0; i < keep.size(); ++i) keep[i] = i % 2 == 0;
  buffer.Filter(keep);
  EXPECT_EQ(buffer.size(), 60u);
  EXPECT_EQ(buffer.newest(), 30u);
  for (float x : tail_xs()) EXPECT_GE(x, 2.f);
  // A frame alone over the bound keeps what fits, all of it the newest.
  PointBuffer small(Caps(/*max_points=*/20, /*per_frame=*/1000), /*seed=*/6);
  small.AddFrame(frame(30, 1.f), {zeros.begin(), zeros.begin() + 30});
  EXPECT_EQ(small.size(), 20u);
  EXPECT_EQ(small.newest(), 20u);
}

TEST(PointBufferTest, RemoveOutsideIsHalfOpen) {
  PointBuffer b(Caps(1000, 1000), /*seed=*/5);
  // Frame f: points (f, i, 0.5) for i in [0, 10).
  for (int f = 0; f < 10; ++f) AddTestFrame(&b, f, 10);
  ASSERT_EQ(b.size(), 100u);
  b.RemoveOutside(Vec3d(2, 3, 0), Vec3d(5, 8, 1));
  // Kept: x in {2,3,4} (5 is on the max face: out), y in {3..7}.
  EXPECT_EQ(b.size(), 15u);
  ExpectConsistent(b);
  for (const Vec3f& p : b.points()) {
    EXPECT_GE(p.x(), 2.f);
    EXPECT_LT(p.x(), 5.f);
    EXPECT_GE(p.y(), 3.f);
    EXPECT_LT(p.y(), 8.f);
  }
  // z outside: everything goes.
  b.RemoveOutside(Vec3d(-10, -10, 1), Vec3d(10, 10, 2));
  EXPECT_EQ(b.size(), 0u);
  EXPECT_TRUE(b.origins().empty());
}

TEST(PointBufferTest, FilterKeepsOrderAndPairs) {
  PointBuffer b(Caps(1000, 1000), /*seed=*/6);
  AddTestFrame(&b, 0, 10);
  const std::vector<Vec3f> before = b.points();
  std::vector<bool> keep(10);
  for (int i = 0; i < 10; ++i) keep[i] = (i % 3) != 1;
  b.Filter(keep);
  std::vector<Vec3f> expected;
  for (int i = 0; i < 10; ++i)
    if (keep[i]) expected.push_back(before[i]);
  EXPECT_EQ(b.points(), expected);
  ExpectConsistent(b);
  b.Filter(std::vector<bool>(b.size(), true));
  EXPECT_EQ(b.points(), expected);
  b.Filter(std::vector<bool>(b.size(), false));
  EXPECT_EQ(b.size(), 0u);
}

// Remove drops exactly the listed points (the first, the last, neighbours, a lone one), moving the
// runs between them down with their origins, and counts the newest frame's that go.
TEST(PointBufferTest, RemoveDropsTheListedPointsAndKeepsTheRest) {
  PointBuffer b(Caps(1000, 1000), /*seed=*/7);
  AddTestFrame(&b, 0, 20);
  AddTestFrame(&b, 1, 10);  // the newest: indices 20-29
  ASSERT_EQ(b.newest(), 10u);
  const std::vector<Vec3f> before = b.points();
  const std::vector<uint32_t> drop = {0, 5, 6, 7, 19, 20, 25, 29};
  b.Remove(drop);
  std::vector<Vec3f> expected;
  for (uint32_t i = 0; i < before.size(); ++i)
    if (std::find(drop.begin(), drop.end(), i) == drop.end()) expected.push_back(before[i]);
  EXPECT_EQ(b.points(), expected);
  EXPECT_EQ(b.newest(), 7u);  // 20, 25 and 29 were the newest frame's
  ExpectConsistent(b);
  b.Remove({});
  EXPECT_EQ(b.points(), expected);
}

// The moving-things filter's per-point counts (passes()) move with their points through removal
// and the bound's random drops, new points start at 0, and a loaded buffer starts them over.
TEST(PointBufferTest, PassCountsMoveWithTheirPoints) {
  PointBuffer b(Caps(60, 1000), /*seed=*/3);
  AddTestFrame(&b, 0, 40);
  // Each count names its point: frame f, index i -> (f * 40 + i) % 251 + 1.
  auto tag = [](const Vec3f& p) { return uint8_t((int(p.x()) * 40 + int(p.y())) % 251 + 1); };
  auto tag_all = [&] {
    ASSERT_EQ(b.passes().size(), b.size());
    for (size_t i = 0; i < b.size(); ++i) b.passes()[i] = tag(b.points()[i]);
  };
  auto expect_tags = [&](const char* when) {
    ASSERT_EQ(b.passes().size(), b.size()) << when;
    for (size_t i = 0; i < b.size(); ++i)
      EXPECT_EQ(b.passes()[i], tag(b.points()[i])) << when << ", point " << i;
  };
  tag_all();
  b.Remove({1, 2, 17, 39});
  expect_tags("after Remove");
  AddTestFrame(&b, 1, 30);  // over the bound of 60: random older points go
  ASSERT_EQ(b.size(), 60u);
  for (size_t i = b.size() - b.newest(); i < b.size(); ++i) EXPECT_EQ(b.passes()[i], 0) << i;
  tag_all();
  b.RemoveOutside(Vec3d(-1, 5, 0), Vec3d(2, 100, 1));
  expect_tags("after RemoveOutside");
  b.AddPoints(FramePoints(2, 5), FrameOrigins(2, 5));
  for (size_t i = b.size() - 5; i < b.size(); ++i) EXPECT_EQ(b.passes()[i], 0) << i;
  ByteWriter w;
  b.Serialize(&w);
  const std::string bytes = w.Release();
  PointBuffer loaded(Caps(60, 1000), 9);
  ByteReader r(bytes, "buffer");
  ASSERT_TRUE(loaded.Deserialize(&r).ok());
  EXPECT_EQ(loaded.points(), b.points());
  ASSERT_EQ(loaded.passes().size(), loaded.size());
  for (uint8_t c : loaded.passes()) EXPECT_EQ(c, 0);
}

TEST(PointBufferTest, SerializeRoundTripIncludingRandomState) {
  PointBuffer a(Caps(50, 8), /*seed=*/77);
  for (int f = 0; f < 12; ++f) AddTestFrame(&a, f, 20);
  ByteWriter w;
  a.Serialize(&w);
  const std::string bytes = w.Release();

  PointBuffer b(Caps(50, 8), /*seed=*/12345);  // a different seed: the state must come from bytes
  ByteReader r(bytes, "buffer");
  absl::Status s = b.Deserialize(&r);
  ASSERT_TRUE(s.ok()) << s;
  EXPECT_TRUE(r.ExpectEnd().ok());
  EXPECT_EQ(a.points(), b.points());
  EXPECT_EQ(a.origins(), b.origins());

  // The same next frames give the same buffers: the random generator state travelled too.
  for (int f = 12; f < 20; ++f) {
    AddTestFrame(&a, f, 20);
    AddTestFrame(&b, f, 20);
    ASSERT_EQ(a.points(), b.points()) << "frame " << f;
    ASSERT_EQ(a.origins(), b.origins()) << "frame " << f;
  }
  ByteWriter w2, w3;
  a.Serialize(&w2);
  b.Serialize(&w3);
  EXPECT_EQ(w2.data(), w3.data());

  // An empty buffer round-trips as well.
  PointBuffer e(Caps(10, 10), 1), e2(Caps(10, 10), 2);
  ByteWriter we;
  e.Serialize(&we);
  const std::string ebytes = we.Release();
  ByteReader re(ebytes, "empty");
  ASSERT_TRUE(e2.Deserialize(&re).ok());
  EXPECT_EQ(e2.size(), 0u);
}

TEST(PointBufferTest, DeserializeRejectsCorruptBytesAndKeepsState) {
  PointBuffer a(Caps(50, 8), /*seed=*/77);
  for (int f = 0; f < 5; ++f) AddTestFrame(&a, f, 20);
  ByteWriter w;
  a.Serialize(&w);
  const std::string bytes = w.Release();

  PointBuffer b(Caps(50, 8), /*seed=*/1);
  AddTestFrame(&b, 100, 3);
  const std::vector<Vec3f> b_points = b.points();
  for (size_t n = 0; n < bytes.size(); n += (n < 64 ? 1 : 37)) {
    ByteReader r(std::string_view(bytes).substr(0, n), "truncated");
    EXPECT_FALSE(b.Deserialize(&r).ok()) << "length " << n;
    EXPECT_EQ(b.points(), b_points) << "a failed load changed the buffer (length " << n << ")";
  }
  // A garbled generator state is an error, not a silently different random stream.
  ByteWriter bad;
  bad.String("not a generator state");
  bad.FloatArray(nullptr, 0);
  bad.FloatArray(nullptr, 0);
  const std::string bad_bytes = bad.Release();
  ByteReader r(bad_bytes, "bad rng");
  EXPECT_FALSE(b.Deserialize(&r).ok());
  EXPECT_EQ(b.points(), b_points);
  // Point and origin arrays of different lengths.
  ByteWriter mismatch;
  std::ostringstream rng_state;
  rng_state << std::mt19937_64(5);
  mismatch.String(rng_state.str());
  const float three[3] = {1, 2, 3};
  mismatch.FloatArray(three, 3);
  mismatch.FloatArray(nullptr, 0);
  const std::string mm = mismatch.Release();
  ByteReader r2(mm, "mismatch");
  EXPECT_FALSE(b.Deserialize(&r2).ok());
  EXPECT_EQ(b.points(), b_points);
  // Control: the same generator state with matching arrays loads.
  ByteWriter good;
  good.String(rng_state.str());
  good.FloatArray(three, 3);
  good.FloatArray(three, 3);
  const std::string gb = good.Release();
  ByteReader r3(gb, "good");
  ASSERT_TRUE(b.Deserialize(&r3).ok());
  EXPECT_EQ(b.points(), std::vector<Vec3f>{Vec3f(1, 2, 3)});
}

}  // namespace
}  // namespace rim
