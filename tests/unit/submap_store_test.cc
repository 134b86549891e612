// The global map of sparse sub-maps (DESIGN.md §3.3): serialisation round trips, sparse block
// accounting, freeze/activate with spilling to disk, corrupt input, and concurrent use through the
// background slab saver.
#include "rim/map/submap_store.h"

#include <stdlib.h>
#include <sys/stat.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "gtest/gtest.h"
#include "rim/base/binary_io.h"
#include "rim/base/row8.h"
#include "rim/config/config.h"
#include "rim/map/map_geometry.h"
#include "rim/map/slab_saver.h"

namespace rim {
namespace {

// One row of features as the store keeps it (rim/base/row8.h).
std::vector<int8_t> Row8(const std::vector<float>& v) {
  std::vector<int8_t> q(Row8Bytes(int(v.size())));
  EncodeRows8(v.data(), 1, int(v.size()), q.data());
  return q;
}

// What a row reads back as from the store.
std::vector<float> Rounded(std::vector<float> v) {
  RoundRow8(v.data(), int(v.size()));
  return v;
}

namespace fs = std::filesystem;

MapperConfig SmallConfig() {
  MapperConfig c = *MakePreset("maicity");
  // Sub-maps of 4 m × 4 m × 2.4 m (a 3.6 m × 3.6 m × 2 m box asked, one coarse voxel of 0.4 m
  // more per axis: map_geometry.h): level 0 has 40×40×24 cells, i.e. 5×5×3 blocks of 8³.
  absl::Status s = ApplyOverrides(
      {"grid.half_extent_x_m=1.8", "grid.half_extent_y_m=1.8", "grid.z_min_m=-1", "grid.z_max_m=1"},
      &c);
  EXPECT_TRUE(s.ok()) << s;
  return c;
}

std::string MakeTempDir(const std::string& name) {
  std::string tmpl = ::testing::TempDir();
  if (tmpl.empty() || tmpl.back() != '/') tmpl += '/';
  tmpl += name + ".XXXXXX";
  EXPECT_NE(mkdtemp(tmpl.data()), nullptr) << tmpl;
  return tmpl;
}

class TempDir {
 public:
  explicit TempDir(const std::string& name) : path_(MakeTempDir(name)) {}
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

std::string ReadRaw(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}
void WriteRaw(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

// (level, x, y, z) → expected features and observed byte.
using VoxelKey = std::tuple<int, int, int, int>;
struct Expected {
  std::vector<float> features;
  uint8_t observed = 0;
};
using Reference = std::map<VoxelKey, Expected>;

// Writes `n` random voxels of level `l` around world lattice point `center`, one batch.
void WriteRandomVoxels(SubmapStore* store, Reference* ref, std::mt19937_64* rng, int l,
                       const Int3& center, int radius, int n, int D) {
  SlabBatch batch;
  batch.level = l;
  std::uniform_int_distribution<int> off(-radius, radius);
  std::uniform_real_distribution<float> value(-3.f, 3.f);
  std::set<VoxelKey> in_batch;
  for (int i = 0; i < n; ++i) {
    const Int3 g = center + Int3(off(*rng), off(*rng), off(*rng));
    if (!in_batch.insert({l, g.x(), g.y(), g.z()}).second) continue;
    batch.points.push_back(g);
    Expected e;
    for (int d = 0; d < D; ++d) {
      const float v = value(*rng);
      batch.features.push_back(v);
      e.features.push_back(v);
    }
    // The store keeps 8-bit rows: it reads back the written row rounded (RoundRow8).
    e.features = Rounded(e.features);
    e.observed = l == 0 ? uint8_t((*rng)() % 2) : 0;
    if (l == 0) batch.observed.push_back(e.observed);
    (*ref)[{l, g.x(), g.y(), g.z()}] = e;
  }
  store->Write(batch);
}

// Every reference voxel reads back bit-identically.
void ExpectMatches(const SubmapStore& store, const Reference& ref, int D) {
  std::vector<float> f(D);
  int64_t bad = 0;
  for (const auto& [key, e] : ref) {
    const auto [l, x, y, z] = key;
    uint8_t obs = 0xAA;
    if (!store.Read(l, Int3(x, y, z), f.data(), &obs)) {
      if (++bad <= 5)
        ADD_FAILURE() << "missing voxel level " << l << " (" << x << "," << y << "," << z << ")";
      continue;
    }
    if (std::memcmp(f.data(), e.features.data(), sizeof(float) * D) != 0 || obs != e.observed) {
      if (++bad <= 5)
        ADD_FAILURE() << "wrong voxel level " << l << " (" << x << "," << y << "," << z << ")";
    }
  }
  EXPECT_EQ(bad, 0);
}

std::set<std::array<int, 3>> KeySet(const SubmapStore& store) {
  std::set<std::array<int, 3>> out;
  for (const Int3& k : store.Keys()) out.insert({k.x(), k.y(), k.z()});
  return out;
}

class SubmapStoreTest : public ::testing::Test {
 protected:
  SubmapStoreTest() : config_(SmallConfig()), geometry_(config_.grid) {}

  // Random data in a few sub-maps on every level, including negative sub-map indices.
  void Fill(SubmapStore* store, Reference* ref, uint64_t seed = 5) {
    std::mt19937_64 rng(seed);
    const int D = geometry_.feature_dim();
    for (const Int3& key : {Int3(0, 0, 0), Int3(-1, 0, 0), Int3(2, -3, 1), Int3(0, 1, -1)}) {
      for (int l = 0; l < geometry_.levels(); ++l) {
        const Int3 center = key.cwiseProduct(geometry_.cells(l)) + geometry_.cells(l) / 2;
        WriteRandomVoxels(store, ref, &rng, l, center, geometry_.cells(l).minCoeff() / 2 - 1, 300,
                          D);
      }
    }
  }

  MapperConfig config_;
  MapGeometry geometry_;
};

TEST_F(SubmapStoreTest, SerializeDeserializeIsByteIdentical) {
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  Fill(&store, &ref);
  store.SetVersion(Int3(2, -3, 1), 77);
  ExpectMatches(store, ref, geometry_.feature_dim());
  ASSERT_EQ(store.Keys().size(), 4u);

  SubmapStore copy(geometry_, config_.submap);
  for (const Int3& key : store.Keys()) {
    auto bytes = store.SerializeSubmap(key);
    ASSERT_TRUE(bytes.ok()) << bytes.status();
    ASSERT_TRUE(copy.DeserializeSubmap(*bytes, "test").ok());
    auto again = copy.SerializeSubmap(key);
    ASSERT_TRUE(again.ok()) << again.status();
    EXPECT_EQ(*bytes, *again) << "sub-map " << SubmapKeyName(key);
    // Serialising twice gives the same bytes (block order does not depend on hash order).
    EXPECT_EQ(*bytes, *store.SerializeSubmap(key));
  }
  ExpectMatches(copy, ref, geometry_.feature_dim());
  EXPECT_EQ(KeySet(copy), KeySet(store));
  EXPECT_EQ(copy.Stats().blocks, store.Stats().blocks);
  EXPECT_EQ(copy.Stats().host_bytes, store.Stats().host_bytes);
  auto versions = copy.Versions();
  std::map<std::array<int, 3>, uint64_t> vmap;
  for (const auto& [k, v] : versions) vmap[{k.x(), k.y(), k.z()}] = v;
  EXPECT_EQ(vmap[(std::array<int, 3>{2, -3, 1})], 77u);

  // Observed cells survive too.
  for (const Int3& key : store.Keys()) {
    auto a = store.ObservedCells(key), b = copy.ObservedCells(key);
    auto less = [](const Int3& p, const Int3& q) {
      return std::lexicographical_compare(p.data(), p.data() + 3, q.data(), q.data() + 3);
    };
    std::sort(a.begin(), a.end(), less);
    std::sort(b.begin(), b.end(), less);
    EXPECT_EQ(a, b);
  }

  // Deserialize replaces a sub-map: its earlier content is gone.
  SubmapStore other(geometry_, config_.submap);
  Reference other_ref;
  Fill(&other, &other_ref, /*seed=*/99);
  auto bytes = store.SerializeSubmap(Int3(0, 0, 0));
  ASSERT_TRUE(bytes.ok());
  ASSERT_TRUE(other.DeserializeSubmap(*bytes, "test").ok());
  EXPECT_EQ(*other.SerializeSubmap(Int3(0, 0, 0)), *bytes);

  EXPECT_FALSE(store.SerializeSubmap(Int3(50, 50, 50)).ok());
}

TEST_F(SubmapStoreTest, SaveToLoadFromRoundTrip) {
  TempDir dir("submap_store_save");
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  Fill(&store, &ref);
  ASSERT_TRUE(store.SaveTo(dir.path() + "/maps").ok());

  SubmapStore loaded(geometry_, config_.submap);
  absl::Status s = loaded.LoadFrom(dir.path() + "/maps");
  ASSERT_TRUE(s.ok()) << s;
  EXPECT_EQ(KeySet(loaded), KeySet(store));
  for (const Int3& key : store.Keys())
    EXPECT_EQ(*loaded.SerializeSubmap(key), *store.SerializeSubmap(key));
  ExpectMatches(loaded, ref, geometry_.feature_dim());

  // Saving a store with fewer sub-maps into the same directory removes the stale files.
  SubmapStore small(geometry_, config_.submap);
  Reference small_ref;
  std::mt19937_64 rng(3);
  WriteRandomVoxels(&small, &small_ref, &rng, 0, Int3(5, 5, 5), 3, 20, geometry_.feature_dim());
  ASSERT_TRUE(small.SaveTo(dir.path() + "/maps").ok());
  SubmapStore reloaded(geometry_, config_.submap);
  ASSERT_TRUE(reloaded.LoadFrom(dir.path() + "/maps").ok());
  EXPECT_EQ(KeySet(reloaded), KeySet(small));

  SubmapStore missing(geometry_, config_.submap);
  EXPECT_FALSE(missing.LoadFrom(dir.path() + "/does_not_exist").ok());
}

// A save links the file of a sub-map unchanged since the store last saved or loaded it (one
// inode, two names) and writes the others: a checkpoint costs what changed, not the whole map.
TEST_F(SubmapStoreTest, SaveLinksTheFilesOfUnchangedSubmapsAndWritesTheRest) {
  TempDir dir("submap_store_links");
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  Fill(&store, &ref);
  auto file = [&](const std::string& sub, const Int3& key) {
    return dir.path() + "/" + sub + "/submap_" + SubmapKeyName(key) + ".subm";
  };
  auto inode = [](const std::string& path) {
    struct stat st {};
    EXPECT_EQ(::lstat(path.c_str(), &st), 0) << path;
    return st.st_ino;
  };
  ASSERT_TRUE(store.SaveTo(dir.path() + "/a").ok());
  ASSERT_TRUE(store.SaveTo(dir.path() + "/b").ok());
  const std::vector<Int3> keys = store.Keys();
  ASSERT_EQ(keys.size(), 4u);
  for (const Int3& key : keys) EXPECT_EQ(inode(file("a", key)), inode(file("b", key)));

  // New voxels in one sub-map, a new version for another, a file rewritten in place for a third:
  // those three are written, the fourth is linked.
  const Int3 touched(0, 0, 0), bumped(-1, 0, 0), tampered(2, -3, 1), kept(0, 1, -1);
  std::mt19937_64 rng(11);
  WriteRandomVoxels(&store, &ref, &rng, 0, geometry_.cells(0) / 2, 2, 5, geometry_.feature_dim());
  store.SetVersion(bumped, 77);
  {
    std::ofstream out(file("b", tampered), std::ios::binary | std::ios::trunc);  // same inode
    out << "not the sub-map that was saved";
  }
  ASSERT_TRUE(store.SaveTo(dir.path() + "/c").ok());
  EXPECT_NE(inode(file("c", touched)), inode(file("b", touched)));
  EXPECT_NE(inode(file("c", bumped)), inode(file("b", bumped)));
  EXPECT_NE(inode(file("c", tampered)), inode(file("b", tampered)));
  EXPECT_EQ(inode(file("c", kept)), inode(file("b", kept)));

  // What the save left loads to the store as it is; and a save after that load links the files
  // it loaded.
  SubmapStore loaded(geometry_, config_.submap);
  absl::Status s = loaded.LoadFrom(dir.path() + "/c");
  ASSERT_TRUE(s.ok()) << s;
  EXPECT_EQ(KeySet(loaded), KeySet(store));
  for (const Int3& key : keys)
    EXPECT_EQ(*loaded.SerializeSubmap(key), *store.SerializeSubmap(key)) << SubmapKeyName(key);
  ExpectMatches(loaded, ref, geometry_.feature_dim());
  ASSERT_TRUE(loaded.SaveTo(dir.path() + "/d").ok());
  for (const Int3& key : keys) EXPECT_EQ(inode(file("d", key)), inode(file("c", key)));
}

// ReadBlock hands out the store's block without a copy; every voxel of it matches Read, and a
// later Write to it leaves the reader's snapshot alone (copy on write) while the store moves on.
TEST_F(SubmapStoreTest, CachedReaderReadsWhatReadReads) {
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  Fill(&store, &ref);
  const int D = geometry_.feature_dim();
  // Walks as a slab enters the local map (z runs across block and sub-map borders, stored and
  // absent blocks), then the same points in a random order, each through one reader.
  for (const bool shuffled : {false, true}) {
    SubmapStore::CachedReader reader(store);
    std::mt19937_64 rng(9);
    int64_t found = 0, absent = 0;
    for (int l = 0; l < geometry_.levels(); ++l) {
      const Int3 c = geometry_.cells(l);
      const Int3 lo = -c / 2, hi = Int3(c.x() / 2, c.y() / 2, c.z() + c.z() / 2);
      std::vector<Int3> points;
      for (int x = lo.x(); x < hi.x(); x += 3)
        for (int y = lo.y(); y < hi.y(); y += 2)
          for (int z = lo.z(); z < hi.z(); ++z) points.push_back(Int3(x, y, z));
      if (shuffled) std::shuffle(points.begin(), points.end(), rng);
      for (const Int3& g : points) {
        std::vector<float> want(D, -9.f), got(D, -9.f);
        uint8_t want_obs = 7, got_obs = 7;
        const bool want_ok = store.Read(l, g, want.data(), &want_obs);
        ASSERT_EQ(reader.Read(l, g, got.data(), &got_obs), want_ok)
            << "level " << l << " " << g.transpose();
        ASSERT_EQ(got, want) << "level " << l << " " << g.transpose();
        ASSERT_EQ(got_obs, want_obs) << "level " << l << " " << g.transpose();
        (want_ok ? found : absent)++;
      }
    }
    EXPECT_GT(found, 1000) << "the walk must cover stored blocks";
    EXPECT_GT(absent, 1000) << "and places with nothing stored";
  }
}

TEST_F(SubmapStoreTest, CachedReaderRunsReadWhatReadReads) {
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  Fill(&store, &ref);
  const int D = geometry_.feature_dim();
  std::mt19937_64 rng(5);
  SubmapStore::CachedReader reader(store);
  int64_t found = 0, absent = 0;
  for (int l = 0; l < geometry_.levels(); ++l) {
    const Int3 c = geometry_.cells(l);
    std::uniform_int_distribution<int> xy(-c.x() / 2, c.x() / 2), z(-c.z(), 2 * c.z());
    std::uniform_int_distribution<int> length(1, 2 * c.z());
    // Runs of every length from every start: across block and sub-map borders, in stored and
    // absent blocks, with single reads mixed in (the reader's two paths share its cache).
    for (int i = 0; i < 400; ++i) {
      const Int3 g(xy(rng), xy(rng), z(rng));
      const int n = length(rng);
      std::vector<float> got(size_t(n) * D, -9.f);
      std::vector<uint8_t> flags(n, 0xee);
      reader.ReadRun(l, g, n, got.data(), flags.data());
      for (int k = 0; k < n; ++k) {
        const Int3 p(g.x(), g.y(), g.z() + k);
        std::vector<float> want(D, -9.f);
        uint8_t obs = 0;
        const bool ok = store.Read(l, p, want.data(), &obs);
        const std::vector<float> run_f(got.begin() + size_t(k) * D,
                                       got.begin() + size_t(k + 1) * D);
        if (ok) {
          ASSERT_EQ(flags[k], LocalMap::kHasData | (obs & LocalMap::kObservedBits))
              << "level " << l << " " << p.transpose();
          ASSERT_EQ(run_f, want) << "level " << l << " " << p.transpose();
          ++found;
        } else {
          ASSERT_EQ(flags[k], 0xee) << "untouched where nothing is stored: " << p.transpose();
          ASSERT_EQ(run_f, std::vector<float>(D, -9.f)) << p.transpose();
          ++absent;
        }
      }
      if (i % 3 == 0) {
        std::vector<float> want(D), single(D);
        uint8_t want_obs = 7, got_obs = 7;
        const bool ok = store.Read(l, g, want.data(), &want_obs);
        ASSERT_EQ(reader.Read(l, g, single.data(), &got_obs), ok);
        if (ok) ASSERT_EQ(single, want);
        // The next z through Read's shortcut, right after a run moved the reader elsewhere.
        const Int3 next(g.x(), g.y(), g.z() + 1);
        const bool next_ok = store.Read(l, next, want.data(), &want_obs);
        ASSERT_EQ(reader.Read(l, next, single.data(), &got_obs), next_ok);
        if (next_ok) ASSERT_EQ(single, want) << next.transpose();
      }
    }
  }
  EXPECT_GT(found, 1000) << "the runs must cover stored blocks";
  EXPECT_GT(absent, 1000) << "and places with nothing stored";
}

// A slab batch is stored a z run at a time; the result must be the store that voxel-by-voxel
// writes make: runs across block and sub-map borders, runs broken by a gap or a new column, and
// points written twice (the later wins), compared byte for byte through the serialised sub-maps.
TEST_F(SubmapStoreTest, BatchWrittenByRunsEqualsVoxelByVoxelWrites) {
  SubmapStore runs(geometry_, config_.submap), single(geometry_, config_.submap);
  const int D = geometry_.feature_dim();
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<float> value(-2.f, 2.f);
  for (int l = 0; l < geometry_.levels(); ++l) {
    const Int3 c = geometry_.cells(l);
    std::uniform_int_distribution<int> xy(-c.x(), c.x()), z(-c.z(), 2 * c.z());
    std::uniform_int_distribution<int> length(1, 2 * c.z());
    SlabBatch batch;
    batch.level = l;
    for (int r = 0; r < 60; ++r) {
      const Int3 g(xy(rng), xy(rng), z(rng));
      const int n = length(rng);
      for (int k = 0; k < n; ++k) {
        if (k > 0 && rng() % 17 == 0) continue;  // a gap breaks the run
        batch.points.emplace_back(g.x(), g.y(), g.z() + k);
      }
      if (r % 10 == 0) batch.points.push_back(batch.points[batch.points.size() / 2]);  // again
      // z goes on, but in the next column: a new run.
      const Int3 last = batch.points.back();
      if (r % 3 == 0) batch.points.emplace_back(last.x() + 1, last.y(), last.z() + 1);
      if (r % 3 == 1) batch.points.emplace_back(last.x(), last.y() + 1, last.z() + 1);
    }
    for (size_t i = 0; i < batch.points.size(); ++i) {
      for (int d = 0; d < D; ++d) batch.features.push_back(value(rng));
      if (l == 0) batch.observed.push_back(uint8_t(rng() % 8) & LocalMap::kObservedBits);
    }
    runs.Write(batch);
    for (size_t i = 0; i < batch.points.size(); ++i) {
      SlabBatch one;
      one.level = l;
      one.points = {batch.points[i]};
      one.features.assign(batch.features.begin() + i * D, batch.features.begin() + (i + 1) * D);
      if (l == 0) one.observed = {batch.observed[i]};
      single.Write(one);
    }
  }
  ASSERT_EQ(KeySet(runs), KeySet(single));
  ASSERT_GT(runs.Keys().size(), 4u);
  for (const Int3& key : runs.Keys()) {
    auto a = runs.SerializeSubmap(key), b = single.SerializeSubmap(key);
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_EQ(*a, *b) << "sub-map " << SubmapKeyName(key);
  }
  EXPECT_EQ(runs.Stats().blocks, single.Stats().blocks);
}

TEST_F(SubmapStoreTest, ReadBlockSharesBlocksAndCopiesOnWrite) {
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  Fill(&store, &ref);
  const int D = geometry_.feature_dim();
  std::vector<float> f(D);
  int checked = 0;
  for (const auto& [key, e] : ref) {
    const auto [l, x, y, z] = key;
    const Int3 g(x, y, z);
    auto block = store.ReadBlock(l, g);
    ASSERT_NE(block, nullptr);
    const SubmapStore::BlockAddress a = store.Address(l, g);
    ASSERT_EQ(std::memcmp(&block->features[size_t(a.index) * Row8Bytes(D)], Row8(e.features).data(),
                          Row8Bytes(D)),
              0);
    if (l == 0) {
      ASSERT_EQ(block->observed[size_t(a.index)], e.observed);
    }
    // The block's origin is a block corner that holds g.
    for (int k = 0; k < 3; ++k) {
      ASSERT_LE(a.origin[k], g[k]);
      ASSERT_LT(g[k], a.origin[k] + config_.submap.block_size);
    }
    ++checked;
  }
  EXPECT_EQ(size_t(checked), ref.size());
  EXPECT_EQ(store.ReadBlock(0, Int3(100000, 0, 0)), nullptr);

  // Copy on write.
  const auto& [key, e] = *ref.begin();
  const auto [l, x, y, z] = key;
  auto held = store.ReadBlock(l, Int3(x, y, z));
  const int index = store.Address(l, Int3(x, y, z)).index;
  SlabBatch batch;
  batch.level = l;
  batch.points.push_back(Int3(x, y, z));
  batch.features.assign(D, 42.f);
  if (l == 0) batch.observed.push_back(1);
  store.Write(batch);
  EXPECT_EQ(std::memcmp(&held->features[size_t(index) * Row8Bytes(D)], Row8(e.features).data(),
                        Row8Bytes(D)),
            0);
  ASSERT_TRUE(store.Read(l, Int3(x, y, z), f.data(), nullptr));
  EXPECT_EQ(f, std::vector<float>(D, 42.f));
  EXPECT_NE(store.ReadBlock(l, Int3(x, y, z)).get(), held.get());
}

TEST_F(SubmapStoreTest, SparseStorageCountsBlocks) {
  const int B = config_.submap.block_size;
  const int D = geometry_.feature_dim();
  const int64_t b3 = int64_t(B) * B * B;
  // 8-bit feature rows (D values and an exponent), and observed bytes at level 0.
  const int64_t level0_bytes = b3 * (D + 1) + b3;
  const int64_t upper_bytes = b3 * (D + 1);
  SubmapStore store(geometry_, config_.submap);
  EXPECT_EQ(store.Stats().blocks, 0);
  EXPECT_EQ(store.Stats().host_bytes, 0);

  // k voxels in k distinct blocks of level 0, spread over two sub-maps.
  const int k = 7;
  std::vector<Int3> firsts;
  for (int i = 0; i < k; ++i)
    firsts.push_back(Int3(B * i, B * (i % 3), -B * (i % 2)) + Int3(1, 2, 3));
  SlabBatch b0;
  b0.level = 0;
  for (const Int3& g : firsts) {
    b0.points.push_back(g);
    b0.features.insert(b0.features.end(), D, 1.5f);
    b0.observed.push_back(1);
  }
  store.Write(b0);
  EXPECT_EQ(store.Stats().blocks, k);
  EXPECT_EQ(store.Stats().host_bytes, k * level0_bytes);

  // The same k blocks on levels 1 and 2.
  for (int l = 1; l < geometry_.levels(); ++l) {
    SlabBatch b;
    b.level = l;
    for (int i = 0; i < k; ++i) {
      b.points.push_back(Int3(B * i, 0, 0) + Int3(0, 1, 1));
      b.features.insert(b.features.end(), D, 0.5f);
    }
    store.Write(b);
  }
  EXPECT_EQ(store.Stats().blocks, int64_t(k) * geometry_.levels());
  const int64_t expected_bytes =
      k * level0_bytes + int64_t(k) * (geometry_.levels() - 1) * upper_bytes;
  EXPECT_EQ(store.Stats().host_bytes, expected_bytes);

  // More voxels in the same blocks add no memory.
  SlabBatch more;
  more.level = 0;
  for (const Int3& g : firsts) {
    for (int j = 0; j < 5; ++j) {
      // Stay inside the block of g: offsets within [0, B).
      const Int3 base = Int3(FloorDiv(g.x(), B), FloorDiv(g.y(), B), FloorDiv(g.z(), B)) * B;
      more.points.push_back(base + Int3(j, (j * 3) % B, (j * 5) % B));
      more.features.insert(more.features.end(), D, float(j));
      more.observed.push_back(0);
    }
  }
  store.Write(more);
  EXPECT_EQ(store.Stats().blocks, int64_t(k) * geometry_.levels());
  EXPECT_EQ(store.Stats().host_bytes, expected_bytes);

  // A voxel never written, inside a stored block, reads as zero; one outside any block is absent.
  std::vector<float> f(D, -1.f);
  uint8_t obs = 7;
  const Int3 base0 =
      Int3(FloorDiv(firsts[0].x(), B), FloorDiv(firsts[0].y(), B), FloorDiv(firsts[0].z(), B)) * B;
  ASSERT_TRUE(store.Read(0, base0 + Int3(B - 1, B - 1, B - 1), f.data(), &obs));
  EXPECT_EQ(f, std::vector<float>(D, 0.f));
  EXPECT_EQ(obs, 0);
  std::fill(f.begin(), f.end(), -1.f);
  EXPECT_FALSE(store.Read(0, Int3(1000, 1000, 1000), f.data(), &obs));
  EXPECT_EQ(f, std::vector<float>(D, -1.f)) << "a failed read must write nothing";
  ASSERT_TRUE(store.Read(0, firsts[2], f.data(), &obs));
  EXPECT_EQ(f, std::vector<float>(D, 1.5f));
  EXPECT_EQ(obs, 1);
}

TEST_F(SubmapStoreTest, FreezeSpillAndReload) {
  TempDir dir("submap_store_spill");
  SubmapConfig sc = config_.submap;
  sc.active_radius_submaps = 1.5f;
  sc.spill_dir = dir.path() + "/spill";
  sc.host_budget_bytes = 1;  // everything frozen must go to disk
  SubmapStore store(geometry_, sc);
  Reference ref;
  Fill(&store, &ref);  // sub-maps (0,0,0), (-1,0,0), (2,-3,1), (0,1,-1)
  const int D = geometry_.feature_dim();

  // Without a budget breach nothing spills; here first check the freeze alone.
  {
    SubmapConfig no_spill = sc;
    no_spill.host_budget_bytes = 0;
    SubmapStore s2(geometry_, no_spill);
    Reference r2;
    Fill(&s2, &r2);
    ASSERT_TRUE(s2.UpdateActivity(Int3(10, 10, 10)).ok());
    EXPECT_EQ(s2.Stats().frozen, 4);
    EXPECT_EQ(s2.Stats().active, 0);
    EXPECT_EQ(s2.Stats().on_disk, 0);
    ExpectMatches(s2, r2, D);
  }

  const SubmapStoreStats before = store.Stats();
  EXPECT_EQ(before.active, 4);
  ASSERT_GT(before.host_bytes, 0);

  // Robot in sub-map (0,0,0): (-1,0,0) and (0,1,-1) are within 1.5, (2,-3,1) is not.
  absl::Status s = store.UpdateActivity(Int3(0, 0, 0));
  ASSERT_TRUE(s.ok()) << s;
  SubmapStoreStats st = store.Stats();
  EXPECT_EQ(st.active, 3);
  EXPECT_EQ(st.frozen, 0);
  EXPECT_EQ(st.on_disk, 1);
  EXPECT_LT(st.host_bytes, before.host_bytes);
  EXPECT_TRUE(fs::exists(sc.spill_dir + "/submap_2_-3_1.subm"));

  // Robot far away: everything is frozen, and then spilled.
  ASSERT_TRUE(store.UpdateActivity(Int3(100, 0, 0)).ok());
  st = store.Stats();
  EXPECT_EQ(st.active, 0);
  EXPECT_EQ(st.on_disk, 4);
  EXPECT_EQ(st.host_bytes, 0);
  EXPECT_EQ(st.blocks, 0);

  // Reads reload the spilled sub-maps with identical data.
  ExpectMatches(store, ref, D);
  st = store.Stats();
  EXPECT_EQ(st.on_disk, 0);
  EXPECT_EQ(st.frozen, 4);
  EXPECT_EQ(st.host_bytes, before.host_bytes);
  EXPECT_EQ(st.blocks, before.blocks);
  EXPECT_TRUE(store.last_error().ok()) << store.last_error();

  // Spill again and revisit: the robot's sub-map is re-activated.
  ASSERT_TRUE(store.UpdateActivity(Int3(100, 0, 0)).ok());
  EXPECT_EQ(store.Stats().on_disk, 4);
  ASSERT_TRUE(store.UpdateActivity(Int3(2, -3, 1)).ok());
  st = store.Stats();
  EXPECT_EQ(st.active, 1);
  EXPECT_EQ(st.on_disk, 3);
  ExpectMatches(store, ref, D);

  // Serialising a spilled sub-map gives the same bytes as before it was spilled.
  SubmapStore fresh(geometry_, config_.submap);
  Reference fresh_ref;
  Fill(&fresh, &fresh_ref);
  ASSERT_TRUE(store.UpdateActivity(Int3(100, 0, 0)).ok());
  for (const Int3& key : fresh.Keys())
    EXPECT_EQ(*store.SerializeSubmap(key), *fresh.SerializeSubmap(key));
}

TEST_F(SubmapStoreTest, CorruptSpillFileGivesErrorNotCrash) {
  TempDir dir("submap_store_corrupt");
  SubmapConfig sc = config_.submap;
  sc.spill_dir = dir.path();
  sc.host_budget_bytes = 1;
  SubmapStore store(geometry_, sc);
  Reference ref;
  Fill(&store, &ref);
  ASSERT_TRUE(store.UpdateActivity(Int3(100, 0, 0)).ok());
  ASSERT_EQ(store.Stats().on_disk, 4);

  const std::string path = dir.path() + "/submap_2_-3_1.subm";
  std::string bytes = ReadRaw(path);
  ASSERT_GT(bytes.size(), 100u);
  bytes[bytes.size() / 2] ^= 0x40;
  WriteRaw(path, bytes);

  // A voxel of the corrupted sub-map: the read fails cleanly and the error is reported.
  auto it = std::find_if(ref.begin(), ref.end(), [&](const auto& kv) {
    const auto [l, x, y, z] = kv.first;
    return geometry_.SubmapOfLattice(l, Int3(x, y, z)) == Int3(2, -3, 1);
  });
  ASSERT_NE(it, ref.end());
  const auto [l, x, y, z] = it->first;
  std::vector<float> f(geometry_.feature_dim(), -1.f);
  uint8_t obs = 0;
  EXPECT_FALSE(store.Read(l, Int3(x, y, z), f.data(), &obs));
  EXPECT_FALSE(store.last_error().ok());
  EXPECT_NE(std::string(store.last_error().message()).find("submap_2_-3_1"), std::string::npos)
      << store.last_error();
  // Reading again does not crash either.
  EXPECT_FALSE(store.Read(l, Int3(x, y, z), f.data(), &obs));

  // The other sub-maps are unaffected.
  Reference others;
  for (const auto& kv : ref) {
    const auto [l2, x2, y2, z2] = kv.first;
    if (geometry_.SubmapOfLattice(l2, Int3(x2, y2, z2)) != Int3(2, -3, 1)) others.insert(kv);
  }
  ExpectMatches(store, others, geometry_.feature_dim());

  // A sub-map whose data cannot be loaded must not be serialised (or saved) as if it were empty.
  auto ser = store.SerializeSubmap(Int3(2, -3, 1));
  EXPECT_FALSE(ser.ok()) << "SerializeSubmap returned " << (ser.ok() ? ser->size() : 0)
                         << " bytes for a sub-map whose spill file is corrupt";
  TempDir save_dir("submap_store_corrupt_save");
  EXPECT_FALSE(store.SaveTo(save_dir.path()).ok())
      << "SaveTo succeeded although one sub-map could not be read back from its spill file";

  // Missing spill file: also an error, no crash.
  ASSERT_TRUE(store.UpdateActivity(Int3(100, 0, 0)).ok());
  ASSERT_TRUE(fs::exists(dir.path() + "/submap_0_0_0.subm"));
  std::error_code ec;
  fs::remove(dir.path() + "/submap_0_0_0.subm", ec);
  EXPECT_FALSE(store.Read(0, Int3(20, 20, 12), f.data(), &obs));
}

TEST_F(SubmapStoreTest, FailedReloadOnRevisitKeepsTheSpilledData) {
  TempDir dir("submap_store_revisit");
  SubmapConfig sc = config_.submap;
  sc.spill_dir = dir.path();
  sc.host_budget_bytes = 1;
  SubmapStore store(geometry_, sc);
  Reference ref;
  Fill(&store, &ref);
  ASSERT_TRUE(store.UpdateActivity(Int3(100, 0, 0)).ok());
  ASSERT_EQ(store.Stats().on_disk, 4);

  // The spill file of (2,-3,1) is briefly unreadable while the robot comes back to it.
  const std::string path = dir.path() + "/submap_2_-3_1.subm";
  const std::string moved = dir.path() + "/elsewhere";
  fs::rename(path, moved);
  (void)store.UpdateActivity(Int3(2, -3, 1));
  EXPECT_FALSE(store.last_error().ok());
  fs::rename(moved, path);

  // The sub-map must not have been declared active (and empty) while its data is on disk: once
  // the file is readable again, its data comes back.
  ASSERT_TRUE(store.UpdateActivity(Int3(2, -3, 1)).ok());
  ExpectMatches(store, ref, geometry_.feature_dim());
}

// The float32 payload that checkpoints held before the 8-bit format, made from an 8-bit one by
// widening each block's rows.
std::string WidenedPayload(const std::string& row8, int levels, int D, size_t b3) {
  ByteReader r(row8, "row8");
  ByteWriter w;
  int32_t v32;
  uint64_t v64;
  auto copy_i32 = [&] {
    EXPECT_TRUE(r.I32(&v32).ok());
    w.I32(v32);
  };
  for (int i = 0; i < 3; ++i) copy_i32();  // key
  EXPECT_TRUE(r.U64(&v64).ok());
  w.U64(v64);                              // version
  for (int i = 0; i < 3; ++i) copy_i32();  // levels, dim, block
  for (int l = 0; l < levels; ++l) {
    uint64_t n = 0;
    EXPECT_TRUE(r.U64(&n).ok());
    w.U64(n);
    for (uint64_t b = 0; b < n; ++b) {
      for (int i = 0; i < 3; ++i) copy_i32();  // block key
      std::vector<int8_t> rows;
      std::vector<uint8_t> observed;
      EXPECT_TRUE(r.PodVector(&rows).ok());
      EXPECT_TRUE(r.PodVector(&observed).ok());
      EXPECT_EQ(rows.size(), b3 * Row8Bytes(D));
      std::vector<float> wide(b3 * size_t(D));
      DecodeRows8(rows.data(), b3, D, wide.data());
      w.FloatArray(wide.data(), wide.size());
      w.PodVector(observed);
    }
  }
  EXPECT_TRUE(r.ExpectEnd().ok());
  return w.Release();
}

// Sub-maps are written as 8-bit rows (a quarter of the float32 bytes); float32 files of older
// checkpoints and spills load to the same store, and an 8-bit row that would decode to -inf
// (-128 at the top exponent) loads as finite values.
TEST_F(SubmapStoreTest, WritesEightBitRowsAndLoadsOlderFloatFiles) {
  TempDir dir("submap_store_formats");
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  Fill(&store, &ref);
  const int D = geometry_.feature_dim();
  const size_t b3 =
      size_t(config_.submap.block_size) * config_.submap.block_size * config_.submap.block_size;
  ASSERT_TRUE(fs::create_directories(dir.path() + "/old"));
  size_t row8_bytes = 0, float_bytes = 0;
  for (const Int3& key : store.Keys()) {
    const std::string row8 = *store.SerializeSubmap(key);
    const std::string wide = WidenedPayload(row8, geometry_.levels(), D, b3);
    row8_bytes += row8.size();
    float_bytes += wide.size();
    ASSERT_TRUE(WriteFileAtomic(dir.path() + "/old/submap_" + SubmapKeyName(key) + ".subm",
                                kSubmapFloatFileKind, wide)
                    .ok());
  }
  EXPECT_LT(row8_bytes * 3, float_bytes);
  SubmapStore old(geometry_, config_.submap);
  absl::Status s = old.LoadFrom(dir.path() + "/old");
  ASSERT_TRUE(s.ok()) << s;
  // The same values (unwritten rows of zeros may carry another exponent).
  for (const Int3& key : store.Keys())
    EXPECT_TRUE(WidenedPayload(*old.SerializeSubmap(key), geometry_.levels(), D, b3) ==
                WidenedPayload(*store.SerializeSubmap(key), geometry_.levels(), D, b3))
        << SubmapKeyName(key);
  ExpectMatches(old, ref, D);

  // What SaveTo writes is of the 8-bit kind.
  ASSERT_TRUE(store.SaveTo(dir.path() + "/new").ok());
  for (const Int3& key : store.Keys()) {
    const std::string path = dir.path() + "/new/submap_" + SubmapKeyName(key) + ".subm";
    EXPECT_TRUE(ReadFileChecked(path, kSubmapFileKind).ok()) << path;
  }

  // A row of -128s with the top exponent.
  SubmapStore one(geometry_, config_.submap);
  std::mt19937_64 rng(2);
  Reference one_ref;
  WriteRandomVoxels(&one, &one_ref, &rng, 0, Int3(4, 4, 4), 0, 1, D);
  std::string bytes = *one.SerializeSubmap(Int3(0, 0, 0));
  // The first block's rows follow the header (key, version, levels, dim, block: 32 bytes), the
  // level's block count, the block key and the rows' length.
  const size_t rows_at = 32 + 8 + 12 + 8;
  for (size_t row = 0; row < b3; ++row) {
    bytes[rows_at + row * Row8Bytes(D)] = char(127);
    for (int k = 0; k < D; ++k) bytes[rows_at + row * Row8Bytes(D) + 1 + k] = char(-128);
  }
  SubmapStore odd(geometry_, config_.submap);
  s = odd.DeserializeSubmap(bytes, "odd rows");
  ASSERT_TRUE(s.ok()) << s;
  std::vector<float> f(D);
  uint8_t observed = 0;
  ASSERT_TRUE(odd.Read(0, Int3(0, 0, 0), f.data(), &observed));
  for (float v : f) EXPECT_TRUE(std::isfinite(v)) << v;
  EXPECT_EQ(*odd.SerializeSubmap(Int3(0, 0, 0)), [&] {
    // Deserialising what it now holds changes nothing.
    SubmapStore again(geometry_, config_.submap);
    EXPECT_TRUE(again.DeserializeSubmap(*odd.SerializeSubmap(Int3(0, 0, 0)), "again").ok());
    return *again.SerializeSubmap(Int3(0, 0, 0));
  }());
}

TEST_F(SubmapStoreTest, DeserializeRejectsCorruptBytes) {
  // A small sub-map: two blocks on level 1 and one on level 0.
  SubmapStore store(geometry_, config_.submap);
  Reference ref;
  std::mt19937_64 rng(11);
  WriteRandomVoxels(&store, &ref, &rng, 0, Int3(4, 4, 4), 2, 10, geometry_.feature_dim());
  WriteRandomVoxels(&store, &ref, &rng, 1, Int3(4, 4, 4), 3, 10, geometry_.feature_dim());
  auto good = store.SerializeSubmap(Int3(0, 0, 0));
  ASSERT_TRUE(good.ok());
  const std::string& bytes = *good;
  ASSERT_GT(bytes.size(), 1000u);

  SubmapStore target(geometry_, config_.submap);
  // Truncations: every length in the header region and a stride through the rest.
  std::vector<size_t> lengths;
  for (size_t n = 0; n < 256 && n < bytes.size(); ++n) lengths.push_back(n);
  for (size_t n = 256; n < bytes.size(); n += 61) lengths.push_back(n);
  for (size_t n = bytes.size() > 16 ? bytes.size() - 16 : 0; n < bytes.size(); ++n)
    lengths.push_back(n);
  for (size_t n : lengths) {
    absl::Status s = target.DeserializeSubmap(bytes.substr(0, n), "truncated");
    EXPECT_FALSE(s.ok()) << "length " << n;
    if (!s.ok()) {
      EXPECT_NE(std::string(s.message()).find("truncated"), std::string::npos) << s;
    }
  }
  // Trailing garbage.
  EXPECT_FALSE(target.DeserializeSubmap(bytes + "x", "extra").ok());
  // Random bytes.
  std::mt19937_64 r(17);
  for (int i = 0; i < 2000; ++i) {
    std::string junk(r() % 300, '\0');
    for (char& c : junk) c = char(r());
    EXPECT_FALSE(target.DeserializeSubmap(junk, "junk").ok());
  }
  // Random bytes behind a valid header: a huge block count must not allocate or crash.
  for (int i = 0; i < 500; ++i) {
    std::string junk = bytes.substr(0, 36);
    junk.resize(36 + r() % 200);
    for (size_t j = 36; j < junk.size(); ++j) junk[j] = char(r());
    EXPECT_FALSE(target.DeserializeSubmap(junk, "junk").ok());
  }
  // Single flipped bytes anywhere: never a crash (payload floats may legitimately change).
  for (int i = 0; i < 500; ++i) {
    std::string m = bytes;
    m[r() % m.size()] ^= char(1 << (r() % 8));
    (void)target.DeserializeSubmap(m, "flipped");
  }
  // Nothing failed half-way into the store.
  SubmapStore empty(geometry_, config_.submap);
  EXPECT_FALSE(empty.DeserializeSubmap(bytes.substr(0, bytes.size() - 1), "t").ok());
  EXPECT_TRUE(empty.Keys().empty());
  EXPECT_EQ(empty.Stats().host_bytes, 0);

  // A layout that does not match the config is rejected.
  SubmapConfig other = config_.submap;
  other.block_size = 4;
  SubmapStore mismatched(geometry_, other);
  absl::Status s = mismatched.DeserializeSubmap(bytes, "layout");
  EXPECT_FALSE(s.ok());
  EXPECT_NE(std::string(s.message()).find("block"), std::string::npos) << s;
}

TEST_F(SubmapStoreTest, BackgroundSaverWithConcurrentReaders) {
  SubmapStore store(geometry_, config_.submap);
  const int D = geometry_.feature_dim();
  // Last write wins per voxel; the saver writes batches in submission order.
  std::map<VoxelKey, float> ref;
  std::atomic<bool> done{false};
  std::atomic<int64_t> torn{0}, reads_ok{0};

  std::thread reader([&] {
    std::mt19937_64 rng(2);
    std::vector<float> f(D);
    while (!done.load()) {
      const int l = int(rng() % 3);
      const Int3 g(int(rng() % 64) - 32, int(rng() % 16), int(rng() % 8));
      uint8_t obs;
      if (store.Read(l, g, f.data(), &obs)) {
        ++reads_ok;
        // Every batch writes D equal values per voxel; a torn read would mix them.
        for (int d = 1; d < D; ++d)
          if (f[d] != f[0]) ++torn;
      }
      if (rng() % 64 == 0) {
        (void)store.Stats();
        (void)store.Versions();
        (void)store.ObservedCells(Int3(0, 0, 0));
      }
    }
  });

  {
    SlabSaver saver(&store, /*background=*/true);
    std::mt19937_64 rng(1);
    for (int b = 0; b < 3000; ++b) {
      SlabBatch batch;
      batch.level = int(rng() % 3);
      std::set<std::array<int, 3>> seen;
      for (int i = 0; i < 8; ++i) {
        const Int3 g(int(rng() % 64) - 32, int(rng() % 16), int(rng() % 8));
        if (!seen.insert({g.x(), g.y(), g.z()}).second) continue;
        const float v = float(b * 8 + i + 1);
        batch.points.push_back(g);
        batch.features.insert(batch.features.end(), D, v);
        if (batch.level == 0) batch.observed.push_back(uint8_t(v) & 1);
        ref[{batch.level, g.x(), g.y(), g.z()}] = v;
      }
      saver.Submit(std::move(batch));
      if (b % 500 == 0) store.SetVersion(Int3(0, 0, 0), uint64_t(b));
    }
    saver.Flush();
    EXPECT_EQ(saver.pending(), 0u);
    // Everything submitted before Flush is in the store.
    std::vector<float> f(D);
    int64_t bad = 0;
    for (const auto& [key, v] : ref) {
      const auto [l, x, y, z] = key;
      uint8_t obs = 0;
      if (!store.Read(l, Int3(x, y, z), f.data(), &obs) || f != Rounded(std::vector<float>(D, v)) ||
          (l == 0 && obs != (uint8_t(v) & 1)))
        ++bad;
    }
    EXPECT_EQ(bad, 0);
  }
  done = true;
  reader.join();
  EXPECT_EQ(torn.load(), 0);
  EXPECT_GT(reads_ok.load(), 0);
}

TEST_F(SubmapStoreTest, SynchronousSaverWritesImmediately) {
  SubmapStore store(geometry_, config_.submap);
  SlabSaver saver(&store, /*background=*/false);
  SlabBatch b;
  b.level = 2;
  b.points.push_back(Int3(-1, -1, -1));
  b.features.assign(geometry_.feature_dim(), 4.f);
  saver.Submit(std::move(b));
  EXPECT_EQ(saver.pending(), 0u);
  std::vector<float> f(geometry_.feature_dim());
  uint8_t obs = 9;
  ASSERT_TRUE(store.Read(2, Int3(-1, -1, -1), f.data(), &obs));
  EXPECT_EQ(f[0], 4.f);
  EXPECT_EQ(obs, 0);
  EXPECT_EQ(store.Keys().size(), 1u);
  EXPECT_EQ(store.Keys()[0], Int3(-1, -1, -1));
}

}  // namespace
}  // namespace rim
