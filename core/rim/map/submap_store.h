// The global map (§3.3): sub-maps the size of the local box, keyed by integer index, each storing
// only the blocks (block_size³ voxels) that hold data. Thread-safe: the background saver writes
// while queries and the mesher read.
//
// A block is kept when any of its voxels was ever trained or observed. That is slightly more than
// "blocks with observed voxels": free-space voxels next to surfaces carry the positive SDF that
// queries and meshing need, and dropping them would make save/restore lossy.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/base/binary_io.h"
#include "rim/map/local_map.h"
#include "rim/map/map_geometry.h"

namespace rim {

enum class SubmapState { kActive = 0, kFrozen = 1, kOnDisk = 2 };

// How a serialised sub-map holds its features: the store's 8-bit rows (what rim writes), or
// float32 (files written before; they load, rounded to 8-bit rows as any write is).
enum class SubmapFormat { kRow8, kFloat32 };

struct SubmapStoreStats {
  int active = 0, frozen = 0, on_disk = 0;
  int64_t blocks = 0;
  int64_t host_bytes = 0;
};

class SubmapStore {
 public:
  SubmapStore(const MapGeometry& geometry, const SubmapConfig& config);

  // Stores the voxels of a slab that left the local map, replacing what was there (features
  // rounded to 8-bit rows, RoundRow8).
  void Write(const SlabBatch& batch);
  // Reads one voxel; false (and nothing written) when the store has no data there.
  bool Read(int level, const Int3& g, float* features, uint8_t* observed) const;

  // Where lattice point g of a level lives: its block, named by the world lattice index of the
  // block's minimum corner (unique per level), and its index inside the block.
  struct BlockAddress {
    Int3 origin;
    int index;
  };
  BlockAddress Address(int level, const Int3& g) const;
  int block_size() const { return config_.block_size; }
  int block_voxels() const { return config_.block_size * config_.block_size * config_.block_size; }

  // Features are stored as 8-bit rows with a shared power-of-two scale (rim/base/row8.h): the
  // global map is most of a long session's memory, and features that no longer train lose
  // nothing that the mesh metrics see (error under 0.8 % of a row's largest value; BENCHMARK.md).
  struct Block {
    std::vector<int8_t> features;   // block³ rows of Row8Bytes(D), index (x·B + y)·B + z
    std::vector<uint8_t> observed;  // block³, level 0 only
  };
  // The block holding lattice point g, shared and immutable: a later Write to it copies it
  // first, so a reader may keep using what it got without a lock. Null when the store has no
  // data there. Readers that visit many neighbouring points pay one lock and one lookup per
  // block instead of one per point, and copy nothing.
  std::shared_ptr<const Block> ReadBlock(int level, const Int3& g) const;

  // Read for a caller that visits many neighbouring voxels (a slab entering the local map): it
  // keeps up to kCachedBlocks blocks it visited per level, absent ones included, so the blocks
  // of a column of z runs, visited again by the runs of the next columns, cost one lock and one
  // lookup each. What it returns is a block as it was when first visited (ReadBlock's
  // snapshot). One reader per thread.
  class CachedReader {
   public:
    explicit CachedReader(const SubmapStore& store) : store_(store) {}
    bool Read(int level, const Int3& g, float* features, uint8_t* observed);
    // A run along z, as LocalMap::LoadRunFn asks: every voxel of a block the store holds gets
    // its features and flags = kHasData | its observed bits; voxels of absent blocks are left
    // as they are. One address computation, and one lookup if the block changes, per block the
    // run crosses, and the features of a block's piece of the run widened in one call.
    void ReadRun(int level, const Int3& g, int n, float* features, uint8_t* flags);

   private:
    // Twice the blocks a z run of the local map crosses for every preset (its height over the
    // block size, 8).
    static constexpr int kCachedBlocks = 16;
    struct Cached {
      bool valid = false;
      Int3 origin;
      std::shared_ptr<const Block> block;
    };
    // The cached block holding g (looked up or read), made the current one of its level.
    void Visit(int level, const Int3& g, const Int3& origin);

    const SubmapStore& store_;
    Cached cache_[kMaxLevels][kCachedBlocks];
    bool valid_[kMaxLevels] = {};
    Int3 origin_[kMaxLevels];
    const Block* block_[kMaxLevels] = {};
    // The last point read per level, its index in the block and the end (exclusive) of the
    // block's z range, which a sub-map border may cut short: the next z before that end is the
    // next index, with no address arithmetic (divisions).
    Int3 last_[kMaxLevels];
    int index_[kMaxLevels] = {}, z_end_[kMaxLevels] = {};
  };
  // Marks the stored finest voxels `cells` seen free instead of observed (moving things that
  // later rays passed through after the box had left them, train/transient.h): meshing and the
  // distance field then skip them. Voxels the store does not hold, or holds unobserved, are left
  // as they are. Returns the sub-maps that changed, sorted.
  std::vector<Int3> ClearObserved(const std::vector<Int3>& cells);
  // Finest-level lattice indices of observed voxels stored in a sub-map.
  std::vector<Int3> ObservedCells(const Int3& key) const;
  // A sub-map's finest-level blocks, each with the lattice index of its minimum corner: shared
  // and immutable, as ReadBlock's, so that a caller scans their flags after the lock is gone
  // (ObservedCells lists their observed voxels in this order). Empty for an unknown sub-map.
  std::vector<std::pair<Int3, std::shared_ptr<const Block>>> FinestBlocks(const Int3& key) const;

  // Per-sub-map versions (the map version of its last change); creates the entry if needed.
  void SetVersion(const Int3& key, uint64_t version);
  void SetAllVersions(uint64_t version);
  std::vector<std::pair<Int3, uint64_t>> Versions() const;

  // Freeze/activate policy: sub-maps within config.active_radius_submaps of the robot's sub-map
  // are active, the rest frozen; then, while host memory exceeds the budget, the least recently
  // used frozen sub-maps spill to disk. A spilled sub-map reloads when it is read again.
  absl::Status UpdateActivity(const Int3& robot_submap);
  SubmapStoreStats Stats() const;
  std::vector<Int3> Keys() const;

  // Whole-store persistence: one checksummed file per sub-map under `dir`. A sub-map unchanged
  // since a file that this store saved or loaded (same content and version, and the file still
  // the one it was: IdentifyFile) gets that file hard-linked in rather than written again, so
  // that a checkpoint's cost follows what changed since the last one, not the size of the map.
  // Where the link cannot be made (another file system) the sub-map is written.
  absl::Status SaveTo(const std::string& dir) const;
  absl::Status LoadFrom(const std::string& dir);
  // One sub-map as bytes (8-bit rows) and back (also used for spilling). Deserialize replaces the
  // sub-map; it reads float32 bytes too, from files written before the 8-bit format.
  absl::StatusOr<std::string> SerializeSubmap(const Int3& key) const;
  absl::Status DeserializeSubmap(const std::string& bytes, const std::string& context,
                                 SubmapFormat format = SubmapFormat::kRow8);

  // Sticky error of a failed reload of a spilled sub-map (reads then see no data).
  absl::Status last_error() const;

 private:
  struct Submap {
    // Shared with readers that hold them (ReadBlock): written in place only while unshared.
    std::unordered_map<Int3, std::shared_ptr<Block>, Int3Hash, Int3Equal> blocks[kMaxLevels];
    uint64_t version = 0;
    SubmapState state = SubmapState::kActive;
    uint64_t last_access = 0;
    int64_t bytes = 0;
    // Stamp of its last content change, from generation_clock_: equal stamps, equal content.
    uint64_t generation = 0;
  };
  // A file that holds a sub-map as it was at `generation` with `version`.
  struct SavedFile {
    uint64_t generation = 0, version = 0;
    std::string path;
    FileIdentity identity;
  };

  // Caller holds mu_. Reloads a spilled sub-map; returns null if the key is unknown.
  Submap* FindLocked(const Int3& key) const;
  absl::Status ParseSubmap(const std::string& bytes, const std::string& context,
                           SubmapFormat format, Int3* key, Submap* out) const;
  void SerializeLocked(const Int3& key, const Submap& s, std::string* out) const;
  // SerializeSubmap, with the stamp and version of what it serialised.
  absl::Status SerializeStamped(const Int3& key, std::string* out, SavedFile* stamp) const;
  // DeserializeSubmap, saying which sub-map it replaced and the stamp and version it now has.
  absl::Status Install(const std::string& bytes, const std::string& context, SubmapFormat format,
                       Int3* key, SavedFile* stamp);
  // SaveTo for one sub-map: link the file saved_ names when it still holds the sub-map as it is,
  // else write it. Records the file in saved_.
  absl::Status SaveOne(const Int3& key, const std::string& path) const;
  std::string SpillPath(const Int3& key) const;
  int64_t BlockBytes(int level) const;

  MapGeometry geometry_;
  SubmapConfig config_;
  mutable std::mutex mu_;
  mutable std::unordered_map<Int3, Submap, Int3Hash, Int3Equal> submaps_;
  mutable uint64_t access_clock_ = 0;
  mutable int64_t host_bytes_ = 0;
  mutable absl::Status last_error_;
  mutable uint64_t generation_clock_ = 0;
  // Per sub-map, the last file that SaveTo wrote or linked, or LoadFrom read.
  mutable std::unordered_map<Int3, SavedFile, Int3Hash, Int3Equal> saved_;
};

// The file kinds of a serialised sub-map (spilled, or saved in a checkpoint): 8-bit rows, what
// rim writes; float32, what it wrote before and still reads.
inline constexpr char kSubmapFileKind[] = "SUB8";
inline constexpr char kSubmapFloatFileKind[] = "SUBM";
// Reads a sub-map file of either kind, saying which format its payload has.
absl::StatusOr<std::string> ReadSubmapFile(const std::string& path, SubmapFormat* format);

std::string SubmapKeyName(const Int3& key);

}  // namespace rim
