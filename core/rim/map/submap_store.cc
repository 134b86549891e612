#include "rim/map/submap_store.h"

#include <dirent.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "rim/base/binary_io.h"
#include "rim/base/row8.h"
#include "rim/base/status_macros.h"

namespace rim {

std::string SubmapKeyName(const Int3& key) {
  return absl::StrCat(key.x(), "_", key.y(), "_", key.z());
}

SubmapStore::SubmapStore(const MapGeometry& geometry, const SubmapConfig& config)
    : geometry_(geometry), config_(config) {}

int64_t SubmapStore::BlockBytes(int level) const {
  const int64_t b3 = int64_t(config_.block_size) * config_.block_size * config_.block_size;
  return b3 * int64_t(Row8Bytes(geometry_.feature_dim())) + (level == 0 ? b3 : 0);
}

std::string SubmapStore::SpillPath(const Int3& key) const {
  return absl::StrCat(config_.spill_dir, "/submap_", SubmapKeyName(key), ".subm");
}

SubmapStore::Submap* SubmapStore::FindLocked(const Int3& key) const {
  auto it = submaps_.find(key);
  if (it == submaps_.end()) return nullptr;
  Submap& s = it->second;
  s.last_access = ++access_clock_;
  if (s.state == SubmapState::kOnDisk) {
    SubmapFormat format;
    auto bytes = ReadSubmapFile(SpillPath(key), &format);
    if (!bytes.ok()) {
      last_error_ = bytes.status();
      s.generation = ++generation_clock_;  // what it reads as (nothing) is not what was saved
      return &s;  // stays on disk; reads see no data and the error is reported
    }
    Int3 parsed_key;
    Submap parsed;
    absl::Status st = ParseSubmap(*bytes, SpillPath(key), format, &parsed_key, &parsed);
    if (!st.ok() || parsed_key != key) {
      last_error_ = st.ok() ? absl::DataLossError(SpillPath(key) + ": holds another sub-map") : st;
      s.generation = ++generation_clock_;
      return &s;
    }
    parsed.version = s.version;  // the version may have moved while it was on disk
    parsed.state = SubmapState::kFrozen;
    parsed.last_access = s.last_access;
    parsed.generation = s.generation;  // the same content, back from its spill file
    host_bytes_ += parsed.bytes;
    s = std::move(parsed);
    unlink(SpillPath(key).c_str());
    return &s;
  }
  return &s;
}

void SubmapStore::Write(const SlabBatch& batch) {
  const int D = geometry_.feature_dim();
  const int B = config_.block_size;
  const int l = batch.level;
  const Int3 cells = geometry_.cells(l);
  std::lock_guard<std::mutex> lock(mu_);
  Submap* cached_submap = nullptr;
  Int3 cached_key(INT32_MIN, 0, 0);
  const size_t n = batch.points.size();
  for (size_t i = 0; i < n;) {
    const Int3& g = batch.points[i];
    const Int3 key = geometry_.SubmapOfLattice(l, g);
    if (!cached_submap || key != cached_key) {
      cached_submap = FindLocked(key);
      if (!cached_submap) {
        cached_submap = &submaps_[key];
        cached_submap->last_access = ++access_clock_;
      } else if (cached_submap->state == SubmapState::kOnDisk) {
        // Its spill file could not be read back (last_error_ says why): that data is lost, and
        // the new voxels must stay visible rather than go into a sub-map nobody can read.
        cached_submap->state = SubmapState::kFrozen;
      }
      cached_submap->generation = ++generation_clock_;
      cached_key = key;
    }
    const Int3 local = g - key.cwiseProduct(cells);
    const Int3 block_key = FloorDiv(local, Int3::Constant(B));
    auto [it, inserted] = cached_submap->blocks[l].try_emplace(block_key);
    if (inserted) {
      it->second = std::make_shared<Block>();
      it->second->features.assign(size_t(B) * B * B * Row8Bytes(D), int8_t(0));
      if (l == 0) it->second->observed.assign(size_t(B) * B * B, 0);
      cached_submap->bytes += BlockBytes(l);
      host_bytes_ += BlockBytes(l);
    } else if (it->second.use_count() > 1) {
      // A reader holds this block (ReadBlock): it keeps its snapshot, the store gets a copy.
      it->second = std::make_shared<Block>(*it->second);
    }
    Block& block = *it->second;
    const Int3 in = local - block_key * B;
    const size_t idx = (size_t(in.x()) * B + in.y()) * B + in.z();
    // Slabs leave the box as z runs: the points that follow g along z in the same block (and
    // the same sub-map, whose border may cut a block short) are stored with this one, their
    // slots consecutive in the block as in the batch.
    const int room = std::min(B - in.z(), cells.z() - local.z());
    size_t len = 1;
    while (i + len < n && len < size_t(room) && batch.points[i + len].z() == g.z() + int(len) &&
           batch.points[i + len].x() == g.x() && batch.points[i + len].y() == g.y())
      ++len;
    EncodeRows8(&batch.features[i * D], len, D, &block.features[idx * Row8Bytes(D)]);
    if (l == 0)
      for (size_t k = 0; k < len && i + k < batch.observed.size(); ++k)
        block.observed[idx + k] = batch.observed[i + k];
    i += len;
  }
}

bool SubmapStore::Read(int level, const Int3& g, float* features, uint8_t* observed) const {
  const int D = geometry_.feature_dim();
  const int B = config_.block_size;
  const Int3 key = geometry_.SubmapOfLattice(level, g);
  std::lock_guard<std::mutex> lock(mu_);
  const Submap* s = FindLocked(key);
  if (!s || s->state == SubmapState::kOnDisk) return false;
  const Int3 local = g - key.cwiseProduct(geometry_.cells(level));
  const Int3 block_key = FloorDiv(local, Int3::Constant(B));
  auto it = s->blocks[level].find(block_key);
  if (it == s->blocks[level].end()) return false;
  const Int3 in = local - block_key * B;
  const size_t idx = (size_t(in.x()) * B + in.y()) * B + in.z();
  DecodeRows8(&it->second->features[idx * Row8Bytes(D)], 1, D, features);
  if (observed) *observed = level == 0 ? it->second->observed[idx] : 0;
  return true;
}

SubmapStore::BlockAddress SubmapStore::Address(int level, const Int3& g) const {
  const int B = config_.block_size;
  const Int3 key = geometry_.SubmapOfLattice(level, g);
  const Int3 sub_origin = key.cwiseProduct(geometry_.cells(level));
  const Int3 block_key = FloorDiv(Int3(g - sub_origin), Int3::Constant(B));
  const Int3 in = g - sub_origin - block_key * B;
  return {sub_origin + block_key * B, (in.x() * B + in.y()) * B + in.z()};
}

std::shared_ptr<const SubmapStore::Block> SubmapStore::ReadBlock(int level, const Int3& g) const {
  const int B = config_.block_size;
  const Int3 key = geometry_.SubmapOfLattice(level, g);
  std::lock_guard<std::mutex> lock(mu_);
  const Submap* s = FindLocked(key);
  if (!s || s->state == SubmapState::kOnDisk) return nullptr;
  const Int3 local = g - key.cwiseProduct(geometry_.cells(level));
  auto it = s->blocks[level].find(FloorDiv(local, Int3::Constant(B)));
  if (it == s->blocks[level].end()) return nullptr;
  return it->second;
}

void SubmapStore::CachedReader::Visit(int level, const Int3& g, const Int3& origin) {
  if (valid_[level] && origin_[level] == origin) return;
  // Direct-mapped by a hash of the block: the blocks of one column differ in z and land in
  // different entries.
  const uint32_t h = uint32_t(origin.x()) * 73856093u ^ uint32_t(origin.y()) * 19349663u ^
                     uint32_t(origin.z()) * 83492791u;
  Cached* slot = &cache_[level][(h >> 7) % kCachedBlocks];
  if (!slot->valid || slot->origin != origin) {
    slot->block = store_.ReadBlock(level, g);
    slot->origin = origin;
    slot->valid = true;
  }
  block_[level] = slot->block.get();
  origin_[level] = origin;
  valid_[level] = true;
}

bool SubmapStore::CachedReader::Read(int level, const Int3& g, float* features, uint8_t* observed) {
  const Int3& last = last_[level];
  if (valid_[level] && g.z() == last.z() + 1 && g.x() == last.x() && g.y() == last.y() &&
      g.z() < z_end_[level]) {
    ++index_[level];
  } else {
    const BlockAddress a = store_.Address(level, g);
    Visit(level, g, a.origin);
    index_[level] = a.index;
    const int cells_z = store_.geometry_.cells(level).z();
    const int submap_end_z = (store_.geometry_.SubmapOfLattice(level, g).z() + 1) * cells_z;
    z_end_[level] = std::min(a.origin.z() + store_.config_.block_size, submap_end_z);
  }
  last_[level] = g;
  const Block* b = block_[level];
  if (b == nullptr) return false;
  const size_t D = size_t(store_.geometry_.feature_dim()), index = size_t(index_[level]);
  DecodeRows8(&b->features[index * Row8Bytes(int(D))], 1, int(D), features);
  if (observed) *observed = level == 0 ? b->observed[index] : 0;
  return true;
}

void SubmapStore::CachedReader::ReadRun(int level, const Int3& g, int n, float* features,
                                        uint8_t* flags) {
  const size_t D = size_t(store_.geometry_.feature_dim());
  const int B = store_.config_.block_size;
  const Int3& cells = store_.geometry_.cells(level);
  // x and y of the address are the run's; z is stepped from block to block, and from sub-map to
  // sub-map where a border cuts a block short, without dividing again.
  int sub_origin[3], block[3], in[3];
  for (int a = 0; a < 3; ++a) {
    sub_origin[a] = FloorDiv(g[a], cells[a]) * cells[a];
    block[a] = (g[a] - sub_origin[a]) / B;  // non-negative
    in[a] = g[a] - sub_origin[a] - block[a] * B;
  }
  const int xy_index = (in[0] * B + in[1]) * B;
  for (int i = 0; i < n;) {
    const int z = g.z() + i;
    const int block_z0 = sub_origin[2] + block[2] * B;
    const int z_end = std::min(block_z0 + B, sub_origin[2] + cells.z());
    const int len = std::min(n - i, z_end - z);
    Visit(level, Int3(g.x(), g.y(), z),
          Int3(sub_origin[0] + block[0] * B, sub_origin[1] + block[1] * B, block_z0));
    if (const Block* b = block_[level]) {
      const size_t index = size_t(xy_index + z - block_z0);
      DecodeRows8(&b->features[index * Row8Bytes(int(D))], size_t(len), int(D),
                  features + size_t(i) * D);
      for (int k = 0; k < len; ++k)
        flags[i + k] = LocalMap::kHasData |
                       (level == 0 ? b->observed[index + k] & LocalMap::kObservedBits : 0);
    }
    i += len;
    if (z_end == sub_origin[2] + cells.z()) {
      sub_origin[2] += cells.z();
      block[2] = 0;
    } else {
      ++block[2];
    }
  }
  // Read's next-z shortcut refers to the voxel it read last, not to this run's block.
  z_end_[level] = std::numeric_limits<int>::min();
}

std::vector<Int3> SubmapStore::ClearObserved(const std::vector<Int3>& cells) {
  const int B = config_.block_size;
  const Int3 dims = geometry_.cells(0);
  std::vector<Int3> changed;
  std::lock_guard<std::mutex> lock(mu_);
  for (const Int3& g : cells) {
    const Int3 key = geometry_.SubmapOfLattice(0, g);
    Submap* sub = FindLocked(key);
    if (!sub) continue;
    const Int3 local = g - key.cwiseProduct(dims);
    const Int3 block_key = FloorDiv(local, Int3::Constant(B));
    auto it = sub->blocks[0].find(block_key);
    if (it == sub->blocks[0].end()) continue;
    const Int3 in = local - block_key * B;
    const size_t idx = (size_t(in.x()) * B + in.y()) * B + in.z();
    if (!(it->second->observed[idx] & LocalMap::kObserved)) continue;
    // A reader holds this block (ReadBlock): it keeps its snapshot, the store gets a copy.
    if (it->second.use_count() > 1) it->second = std::make_shared<Block>(*it->second);
    it->second->observed[idx] = LocalMap::kSeenFree;
    sub->generation = ++generation_clock_;
    changed.push_back(key);
  }
  std::sort(changed.begin(), changed.end(), [](const Int3& a, const Int3& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  });
  changed.erase(std::unique(changed.begin(), changed.end()), changed.end());
  return changed;
}

std::vector<std::pair<Int3, std::shared_ptr<const SubmapStore::Block>>> SubmapStore::FinestBlocks(
    const Int3& key) const {
  std::vector<std::pair<Int3, std::shared_ptr<const Block>>> out;
  std::lock_guard<std::mutex> lock(mu_);
  const Submap* s = FindLocked(key);
  if (!s) return out;
  const Int3 base = key.cwiseProduct(geometry_.cells(0));
  out.reserve(s->blocks[0].size());
  for (const auto& [block_key, block] : s->blocks[0])
    out.emplace_back(base + block_key * config_.block_size, block);
  return out;
}

std::vector<Int3> SubmapStore::ObservedCells(const Int3& key) const {
  const int B = config_.block_size;
  std::vector<Int3> out;
  for (const auto& [origin, block] : FinestBlocks(key))
    for (int x = 0; x < B; ++x)
      for (int y = 0; y < B; ++y)
        for (int z = 0; z < B; ++z) {
          if (block->observed[(size_t(x) * B + y) * B + z] & LocalMap::kObserved)
            out.push_back(origin + Int3(x, y, z));
        }
  return out;
}

void SubmapStore::SetVersion(const Int3& key, uint64_t version) {
  std::lock_guard<std::mutex> lock(mu_);
  auto [it, inserted] = submaps_.try_emplace(key);
  if (inserted) it->second.last_access = ++access_clock_;
  it->second.version = version;
}

void SubmapStore::SetAllVersions(uint64_t version) {
  std::lock_guard<std::mutex> lock(mu_);
  for (auto& [key, s] : submaps_) s.version = version;
}

std::vector<std::pair<Int3, uint64_t>> SubmapStore::Versions() const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<std::pair<Int3, uint64_t>> out;
  for (const auto& [key, s] : submaps_) out.emplace_back(key, s.version);
  return out;
}

std::vector<Int3> SubmapStore::Keys() const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<Int3> out;
  for (const auto& [key, s] : submaps_) out.push_back(key);
  return out;
}

absl::Status SubmapStore::UpdateActivity(const Int3& robot_submap) {
  std::lock_guard<std::mutex> lock(mu_);
  for (auto& [key, s] : submaps_) {
    const float dist = (key - robot_submap).cast<float>().norm();
    if (dist <= config_.active_radius_submaps) {
      if (s.state == SubmapState::kOnDisk) {
        FindLocked(key);  // revisit re-activates
        // A failed reload (last_error_ says why) leaves the data on disk: retry on a later update
        // rather than declaring an empty sub-map active and losing what the spill file holds.
        if (s.state == SubmapState::kOnDisk) continue;
      }
      s.state = SubmapState::kActive;
    } else if (s.state == SubmapState::kActive) {
      s.state = SubmapState::kFrozen;
    }
  }
  if (config_.host_budget_bytes <= 0 || config_.spill_dir.empty()) return absl::OkStatus();
  if (host_bytes_ <= config_.host_budget_bytes) return absl::OkStatus();
  std::vector<std::pair<uint64_t, Int3>> frozen;
  for (const auto& [key, s] : submaps_)
    if (s.state == SubmapState::kFrozen && s.bytes > 0) frozen.emplace_back(s.last_access, key);
  std::sort(frozen.begin(), frozen.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  RIM_RETURN_IF_ERROR(MakeDirs(config_.spill_dir));
  for (const auto& [access, key] : frozen) {
    if (host_bytes_ <= config_.host_budget_bytes) break;
    Submap& s = submaps_[key];
    std::string bytes;
    SerializeLocked(key, s, &bytes);
    RIM_RETURN_IF_ERROR(WriteFileAtomic(SpillPath(key), kSubmapFileKind, bytes));
    for (auto& level : s.blocks) level.clear();
    host_bytes_ -= s.bytes;
    s.bytes = 0;
    s.state = SubmapState::kOnDisk;
  }
  return absl::OkStatus();
}

SubmapStoreStats SubmapStore::Stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  SubmapStoreStats st;
  for (const auto& [key, s] : submaps_) {
    if (s.state == SubmapState::kActive) ++st.active;
    if (s.state == SubmapState::kFrozen) ++st.frozen;
    if (s.state == SubmapState::kOnDisk) ++st.on_disk;
    for (const auto& level : s.blocks) st.blocks += int64_t(level.size());
  }
  st.host_bytes = host_bytes_;
  return st;
}

absl::Status SubmapStore::last_error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return last_error_;
}

}  // namespace rim
