#include "rim/mesh/mesher.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <optional>

#include "absl/strings/str_cat.h"
#include "rim/mesh/grid_encoder.h"
#include "rim/model/encoder.h"

namespace rim {

// One block's share of a tile: the mesh of the cells whose minimum corner lies in the block.
struct MeshBlockCache::Piece {
  // MeshChangeLog stamp taken before the block's map was read, when it was meshed or last found
  // within the tolerance of the values it was meshed from.
  uint64_t stamp = 0;
  std::vector<std::array<float, 3>> vertices;
  std::vector<std::array<uint32_t, 3>> faces;
  // Vertices on the block's faces, which cells of a neighbouring block can share, with their edges.
  std::vector<std::pair<uint32_t, GridEdge>> shared;
  // What the mesh was made from: a hash of the block's layout (BlockGrid::layout_hash: its observed
  // voxels, or coarse cells, which fix its grid points and their order) and the SDF at those
  // points. Empty values: not kept (tolerance 0).
  uint64_t voxels_hash = 0;
  std::vector<float> values;

  int64_t Bytes() const {
    return int64_t(sizeof(Piece) + vertices.capacity() * sizeof(vertices[0]) +
                   faces.capacity() * sizeof(faces[0]) + shared.capacity() * sizeof(shared[0]) +
                   values.capacity() * sizeof(values[0]));
  }
};

namespace {

using Piece = MeshBlockCache::Piece;
using mesh_internal::BlockScratch;
using mesh_internal::GridEncoder;
using mesh_internal::GridSpec;

// The share of a coarse cell's finest voxels that must be observed for the cell to be meshed.
constexpr double kCoarseShare = 0.25;

bool KeyLess(const Int3& a, const Int3& b) {
  return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
}

// Calls fn(g) for each observed finest voxel g of tile `key` (ObservedVoxels: the same voxels in
// the same order).
template <class Fn>
void VisitObservedVoxels(const MeshTileSource& src, const Int3& key, Fn&& fn) {
  const MapGeometry& geo = src.geometry;
  const Int3 cells = geo.cells(0);
  const Int3 tile_lo = key.cwiseProduct(cells), tile_hi = tile_lo + cells - Int3::Ones();
  const LocalMap& map = src.local_map;
  // The live map is authoritative for every lattice point of the box, lo..hi inclusive: a cell's
  // flags live at its minimum corner, and a point of the box's max face keeps in the live map
  // what it was given while it was inside the box (the store gets it only when it leaves). Taking
  // the cells at hi from the store dropped them from the mesh along the faces of the last box,
  // though queries reported them observed.
  const IntBox box = map.LatticeBox(0);
  // The store's blocks (ObservedCells' voxels in its order), their flags read without the store's
  // lock and a z run of eight at a time; a block wholly inside the box is skipped unread.
  using Word = uint64_t __attribute__((may_alias));
  constexpr uint64_t kObservedBytes = 0x0101010101010101ull * LocalMap::kObserved;
  static_assert(LocalMap::kObserved == 1, "one bit a byte: a set bit is a byte's flag");
  const int B = src.store.block_size();
  const size_t block_bytes = size_t(B) * B * B;
  for (const auto& [origin, block] : src.store.FinestBlocks(key)) {
    if (block->observed.size() != block_bytes) continue;
    if (map.placed() && box.Contains(origin) && box.Contains(origin + Int3::Constant(B - 1)))
      continue;
    const uint8_t* flags = block->observed.data();
    for (int x = 0; x < B; ++x)
      for (int y = 0; y < B; ++y) {
        const uint8_t* run = flags + (size_t(x) * B + y) * B;
        auto visit = [&](int z) {
          const Int3 g = origin + Int3(x, y, z);
          if (!map.placed() || !box.Contains(g)) fn(g);
        };
        if (B == 8) {
          uint64_t w;
          std::memcpy(&w, run, 8);
          for (w &= kObservedBytes; w != 0; w &= w - 1) visit(__builtin_ctzll(w) >> 3);
        } else {
          for (int z = 0; z < B; ++z)
            if (run[z] & LocalMap::kObserved) visit(z);
        }
      }
  }
  if (map.placed()) {
    const Int3 lo = box.lo.cwiseMax(tile_lo);
    const Int3 hi = box.hi.cwiseMin(tile_hi);
    const LocalMap::Level& grid = map.level(0);
    // Slots wrap per axis (LocalMap::Slot): a z run is contiguous in storage up to its wrap, so a
    // column is at most two runs. A run is read eight flags at a time, as most voxels of a box
    // are not observed (the 0.2 m watcher's meshing 2-3 % shorter, a distance refresh up to 6 %).
    // The loads are atomic, as flags_shared's (a frame's marking sets bits beside readers); the
    // voxels come in the same order.
    const Int3& dims = grid.dims;
    const uint8_t* flags = grid.flag_data();
    auto run = [&](int x, int y, int z0, int64_t first, int64_t count) {
      int64_t i = first;
      const int64_t end = first + count;
      auto one = [&](int64_t k) {
        if (__atomic_load_n(flags + k, __ATOMIC_RELAXED) & LocalMap::kObserved)
          fn(Int3(x, y, z0 + int(k - first)));
      };
      for (; i < end && (reinterpret_cast<uintptr_t>(flags + i) & 7) != 0; ++i) one(i);
      for (; i + 8 <= end; i += 8) {
        uint64_t w = __atomic_load_n(reinterpret_cast<const Word*>(flags + i), __ATOMIC_RELAXED) &
                     kObservedBytes;
        for (; w != 0; w &= w - 1) fn(Int3(x, y, z0 + int(i - first) + (__builtin_ctzll(w) >> 3)));
      }
      for (; i < end; ++i) one(i);
    };
    const int nz = hi.z() - lo.z() + 1;
    const int sz0 = PosMod(lo.z(), dims.z());
    const int first_run = std::min(nz, dims.z() - sz0);
    for (int x = lo.x(); x <= hi.x() && nz > 0; ++x)
      for (int y = lo.y(); y <= hi.y(); ++y) {
        const int64_t column = map.Slot(0, Int3(x, y, lo.z())) - sz0;
        run(x, y, lo.z(), column + sz0, first_run);
        if (first_run < nz) run(x, y, lo.z() + first_run, column, nz - first_run);
      }
  }
}

// A tile's observed voxels grouped by mesh block (blocks in key order, each block's voxels in key
// order). Above the leaf (s > 1 finest voxels a cell edge), each block's coarse cells instead:
// those holding at least kCoarseShare of their s³ finest voxels observed, in key order (a block
// with observed voxels and no such cell is listed, empty).
struct TileVoxels {
  std::vector<std::pair<Int3, std::vector<Int3>>> blocks;
};

// The coarse cells (s > 1) of a tile's observed voxels (mesh_internal::CountCoarseCells: the same
// lists as counting in hash maps and sorting, without either). At the finest level, 16³-voxel
// arrays cost a little more than grouping by hash.
TileVoxels CoarseTileCells(const MeshTileSource& src, const Int3& key, int s) {
  TileVoxels out;
  out.blocks = mesh_internal::CountCoarseCells(
      s, kCoarseShare, [&](const auto& fn) { VisitObservedVoxels(src, key, fn); });
  return out;
}

TileVoxels CollectTileVoxels(const MeshTileSource& src, const Int3& key, int s) {
  std::shared_lock lock(src.mutex);
  if (s > 1) return CoarseTileCells(src, key, s);
  TileVoxels out;
  absl::flat_hash_map<Int3, std::vector<Int3>, Int3Hash, Int3Equal> by_block;
  VisitObservedVoxels(src, key, [&by_block](const Int3& g) {
    by_block[FloorDiv(g, Int3::Constant(kMeshBlockVoxels))].push_back(g);
  });
  out.blocks.reserve(by_block.size());
  for (auto& [block, voxels] : by_block) {
    // Voxels in key order: a block's grid points come in an order fixed by its voxels alone, so
    // values kept from an earlier meshing line up with values evaluated now.
    std::sort(voxels.begin(), voxels.end(), KeyLess);
    out.blocks.emplace_back(block, std::move(voxels));
  }
  std::sort(out.blocks.begin(), out.blocks.end(),
            [](const auto& a, const auto& b) { return KeyLess(a.first, b.first); });
  return out;
}

uint64_t HashVoxels(const std::vector<Int3>& voxels) {
  uint64_t h = 0x9E3779B97F4A7C15ull ^ voxels.size();
  for (const Int3& g : voxels) {
    const uint64_t v = (uint64_t(uint32_t(g.x())) << 42) ^ (uint64_t(uint32_t(g.y())) << 21) ^
                       uint64_t(uint32_t(g.z()));
    h = (h ^ v) * 0x100000001B3ull;
    h ^= h >> 29;
  }
  return h;
}

// One block's mesh grid: the cells of its observed voxels at r cells per voxel edge (or the coarse
// cells of s finest voxels that hold observed ones), their grid points (dense-indexed in the
// scratch table while the grid lives) and the SDF at them.
class BlockGrid {
 public:
  // Evaluates the block's grid: `voxels` are its observed voxels, or above the leaf its coarse
  // cells (CollectTileVoxels). Caller holds the shared lock.
  BlockGrid(const MeshTileSource& src, GridSpec spec, const Int3& block,
            const std::vector<Int3>& voxels, FeatureReader& reader, BlockScratch& scratch)
      : n_(spec.CellsPerBlock() + 1),
        point0_(block * spec.CellsPerBlock()),
        scratch_(scratch),
        cells_(scratch.cells),
        points_(scratch.points) {
    cells_.clear();
    points_.clear();
    const int r = spec.r;
    const Int3 voxel0 = block * kMeshBlockVoxels;
    // Every grid point of an observed voxel's cells lies on that voxel (interior, face, edge or
    // corner), so it counts as observed: a point is observed when any voxel that shares it is.
    // Per grid point: -1 not a corner of the block's cells, else its index in `points_`. The
    // table is the call's, all -1 between blocks: the destructor resets the entries set here.
    std::vector<int32_t>& point_index = scratch.point_index;
    if (point_index.size() != size_t(n_) * n_ * n_) point_index.assign(size_t(n_) * n_ * n_, -1);
    if (spec.s > 1) {
      CoarseCells(voxels);
    } else {
      FineCells(r, voxel0, voxels);
      layout_hash_ = HashVoxels(voxels);
    }
    if (points_.empty()) return;
    const int F = src.geometry.encoding_dim();
    if (scratch.features.size() < points_.size() * F) scratch.features.resize(points_.size() * F);
    values_.resize(points_.size());
    GridEncoder encoder(src.geometry, spec, point0_, n_, src.local_map, reader, scratch);
    encoder.EncodeAll(points_, scratch.features.data());
    src.decoder.Forward(scratch.features.data(), int(points_.size()), values_.data());
  }
  ~BlockGrid() {
    for (const Int3& m : points_) scratch_.point_index[Local(m)] = -1;
  }
  BlockGrid(const BlockGrid&) = delete;
  BlockGrid& operator=(const BlockGrid&) = delete;

  const std::vector<float>& values() const { return values_; }
  // Names the cells meshed and the order of their grid points: the observed voxels' hash at the
  // fine grid, the meshed coarse cells' above the leaf (a voxel that changes no coarse cell leaves
  // the block's values comparable).
  uint64_t layout_hash() const { return layout_hash_; }

  // Marching cubes over the cells. `keep_values`: the piece keeps the values it is made from.
  std::shared_ptr<Piece> March(double step, bool keep_values) {
    auto piece = std::make_shared<Piece>();
    if (points_.empty()) return piece;
    DenseGridSamples samples;
    samples.step_m = float(step);
    samples.first = point0_;
    samples.n = n_;
    samples.index = scratch_.point_index.data();
    samples.values = values_.data();
    samples.count = values_.size();
    std::vector<GridEdge>& edges = scratch_.vertex_edges;
    Mesh mesh = MarchingCubes(cells_, samples, &edges, &scratch_.march);
    piece->vertices = std::move(mesh.vertices);
    piece->faces = std::move(mesh.faces);
    const int last = n_ - 1;
    for (size_t i = 0; i < edges.size(); ++i) {
      const Int3 m = edges[i].lower - point0_;
      bool on_face = false;
      for (int a = 0; a < 3; ++a)
        if (a != edges[i].axis && (m[a] == 0 || m[a] == last)) on_face = true;
      if (on_face) piece->shared.emplace_back(uint32_t(i), edges[i]);
    }
    if (keep_values) piece->values = std::move(values_);
    return piece;
  }

 private:
  size_t Local(const Int3& m) const { return (size_t(m.x()) * n_ + m.y()) * n_ + m.z(); }

  // Adds grid point `m` (block-local) once.
  void AddPoint(const Int3& m) {
    int32_t& idx = scratch_.point_index[Local(m)];
    if (idx >= 0) return;
    idx = int32_t(points_.size());
    points_.push_back(m);
  }

  void FineCells(int r, const Int3& voxel0, const std::vector<Int3>& voxels) {
    std::vector<int32_t>& point_index = scratch_.point_index;
    cells_.reserve(voxels.size() * r * r * r);
    points_.reserve(voxels.size() * (r + 1) * (r + 1) * (r + 1) / 2);
    for (const Int3& g : voxels) {
      const Int3 c0 = (g - voxel0) * r;
      for (int i = 0; i < r; ++i)
        for (int j = 0; j < r; ++j)
          for (int k = 0; k < r; ++k) cells_.push_back(point0_ + c0 + Int3(i, j, k));
      // The voxel's (r + 1)³ grid points: the corners of its cells, in an order fixed by the
      // voxels (a point's value does not depend on its batch).
      for (int i = 0; i <= r; ++i)
        for (int j = 0; j <= r; ++j) {
          const size_t row = Local(c0 + Int3(i, j, 0));
          for (int k = 0; k <= r; ++k) {
            int32_t& idx = point_index[row + size_t(k)];
            if (idx >= 0) continue;
            idx = int32_t(points_.size());
            points_.push_back(c0 + Int3(i, j, k));
          }
        }
    }
  }

  // Coarse cells of s finest voxels per edge, in key order: a cell is meshed when at least
  // kCoarseShare of its finest voxels are observed (CoarseTileCells counts them), so that a coarse
  // tile covers what the fine one does without reaching far into voxels no ray constrained.
  void CoarseCells(const std::vector<Int3>& cells) {
    layout_hash_ = HashVoxels(cells);
    cells_.reserve(cells.size());
    for (const Int3& c : cells) {
      cells_.push_back(c);
      const Int3 c0 = c - point0_;
      for (int i = 0; i <= 1; ++i)
        for (int j = 0; j <= 1; ++j)
          for (int k = 0; k <= 1; ++k) AddPoint(c0 + Int3(i, j, k));
    }
  }

  const int n_;  // grid points per block edge
  uint64_t layout_hash_ = 0;
  const Int3 point0_;
  BlockScratch& scratch_;
  std::vector<Int3>& cells_;   // scratch_.cells
  std::vector<Int3>& points_;  // scratch_.points
  std::vector<float> values_;
};

// Whether every value is within `tolerance` of the one kept.
bool WithinTolerance(const std::vector<float>& kept, const std::vector<float>& now,
                     float tolerance) {
  if (kept.size() != now.size()) return false;
  // No early exit: the loop vectorises, and most blocks pass.
  float worst = 0.f;
  for (size_t i = 0; i < now.size(); ++i) worst = std::max(worst, std::abs(now[i] - kept[i]));
  return worst <= tolerance;
}

// Joins block pieces into one indexed mesh, welding the vertices that lie on a shared grid edge.
Mesh Weld(const std::vector<std::shared_ptr<const Piece>>& pieces) {
  Mesh out;
  size_t nv = 0, nf = 0, ns = 0;
  for (const auto& p : pieces) {
    nv += p->vertices.size();
    nf += p->faces.size();
    ns += p->shared.size();
  }
  out.vertices.reserve(nv);
  out.faces.reserve(nf);
  absl::flat_hash_map<GridEdge, uint32_t, GridEdgeHash> welded;
  welded.reserve(ns);  // an upper bound: each shared edge is there once or twice
  std::vector<uint32_t> remap;
  for (const auto& p : pieces) {
    constexpr uint32_t kUnset = ~0u;
    remap.assign(p->vertices.size(), kUnset);
    for (const auto& [i, edge] : p->shared) {
      auto [it, inserted] = welded.try_emplace(edge, uint32_t(out.vertices.size()));
      if (inserted) out.vertices.push_back(p->vertices[i]);
      remap[i] = it->second;
    }
    for (size_t i = 0; i < p->vertices.size(); ++i) {
      if (remap[i] != kUnset) continue;
      remap[i] = uint32_t(out.vertices.size());
      out.vertices.push_back(p->vertices[i]);
    }
    for (const auto& f : p->faces) out.faces.push_back({remap[f[0]], remap[f[1]], remap[f[2]]});
  }
  return out;
}

absl::StatusOr<GridSpec> MeshGridSpec(const MapGeometry& geo, float resolution_m) {
  auto spec = MeshGridOf(geo, resolution_m);
  if (!spec.ok()) return spec.status();
  return GridSpec{spec->first, spec->second};
}

// Meshes a tile from its blocks. A block whose piece in `cached` is still current (no change in
// `log` since the piece's stamp reaches it) is reused; one that a change reaches is evaluated
// again and reused when its values are within `tolerance` of those it was meshed from (and its
// voxels are the same); the others are meshed now. `changed` (with `cached`): whether the tile's
// mesh differs from the one its cached pieces made.
absl::StatusOr<Mesh> MeshTileBlocks(
    const MeshTileSource& src, float resolution_m, float tolerance, const Int3& key,
    const MeshChangeLog* log,
    absl::flat_hash_map<Int3, std::shared_ptr<Piece>, Int3Hash, Int3Equal>* cached,
    MeshUpdateStats* stats, bool* changed) {
  const MapGeometry& geo = src.geometry;
  auto spec = MeshGridSpec(geo, resolution_m);
  if (!spec.ok()) return spec.status();
  const double step = geo.leaf_m() * spec->s / spec->r;
  const uint64_t stamp = log ? log->Stamp() : 0;
  const TileVoxels voxels = CollectTileVoxels(src, key, spec->s);
  // A feature row of level l at lattice point p reaches grid points within 2^l finest voxels of
  // p, and an observed flag reaches one voxel: a block depends on the changes within this reach.
  const int reach = (1 << (geo.levels() - 1)) + 1;
  const bool keep_values = cached && log && tolerance > 0.f;

  std::vector<std::shared_ptr<const Piece>> pieces;
  pieces.reserve(voxels.blocks.size());
  BlockScratch scratch;
  // One reader for the tile's blocks while the box stays where it was: the store blocks it keeps
  // were read after `stamp`, like everything else the blocks are made from, so a change they miss
  // is in the log for the next update. A slide between two blocks (each reads the live map under
  // its own lock) moves slabs from the box to the store, which the kept blocks predate: the next
  // block then starts a reader of its own, as every block did before.
  std::optional<FeatureReader> reader;
  IntBox reader_box{Int3::Zero(), Int3::Zero()};
  absl::flat_hash_map<Int3, std::shared_ptr<Piece>, Int3Hash, Int3Equal> next;
  MeshUpdateStats s;
  s.blocks = int(voxels.blocks.size());
  for (const auto& [block, block_voxels] : voxels.blocks) {
    std::shared_ptr<Piece> old;
    if (cached && log) {
      auto it = cached->find(block);
      const Int3 lo = block * kMeshBlockVoxels;
      const IntBox region{lo - Int3::Constant(reach),
                          lo + Int3::Constant(kMeshBlockVoxels + reach)};
      if (it != cached->end()) {
        if (!log->ChangedSince(it->second->stamp, region)) {
          pieces.push_back(it->second);
          next.emplace(block, it->second);
          continue;
        }
        old = it->second;
      }
    }
    std::shared_lock lock(src.mutex);
    const IntBox box =
        src.local_map.placed() ? src.local_map.LatticeBox(0) : IntBox{Int3::Zero(), Int3::Zero()};
    if (!reader || !(box.lo == reader_box.lo && box.hi == reader_box.hi)) {
      reader.emplace(src.local_map, src.store);
      reader_box = box;
    }
    BlockGrid grid(src, *spec, block, block_voxels, *reader, scratch);
    lock.unlock();
    const uint64_t hash = keep_values ? grid.layout_hash() : 0;
    if (old && !old->values.empty() && old->voxels_hash == hash) {
      ++s.blocks_checked;
      if (WithinTolerance(old->values, grid.values(), tolerance)) {
        // Not visibly changed: the mesh stays, measured against the values it was made from.
        ++s.blocks_skipped;
        old->stamp = stamp;
        pieces.push_back(old);
        next.emplace(block, std::move(old));
        continue;
      }
    }
    std::shared_ptr<Piece> piece = grid.March(step, keep_values);
    piece->stamp = stamp;
    piece->voxels_hash = hash;
    ++s.blocks_remeshed;
    if (stats) s.remeshed.push_back(block);
    pieces.push_back(piece);
    if (cached) next.emplace(block, std::move(piece));
  }
  if (cached) {
    if (changed) *changed = s.blocks_remeshed > 0 || next.size() != cached->size();
    *cached = std::move(next);
  }
  if (stats) *stats = std::move(s);
  return Weld(pieces);
}

}  // namespace

absl::StatusOr<std::pair<int, int>> MeshGridOf(const MapGeometry& geo, float resolution_m) {
  const auto bad = [&](const char* why) {
    return absl::InvalidArgumentError(absl::StrCat("mesh resolution_m ", resolution_m, " m ", why,
                                                   " (leaf ", geo.leaf_m(), " m)"));
  };
  if (!(resolution_m > 0.f) || !std::isfinite(resolution_m)) return bad("must be > 0");
  if (resolution_m <= geo.leaf_m() + 1e-6) {
    const int r = int(std::lround(geo.leaf_m() / resolution_m));
    if (r < 1 || r > kMeshBlockVoxels || std::abs(r * double(resolution_m) - geo.leaf_m()) > 1e-6)
      return bad("does not divide the leaf size");
    return std::make_pair(r, 1);
  }
  const int s = int(std::lround(resolution_m / geo.leaf_m()));
  // A coarse cell must not straddle a mesh block or a sub-map: s divides both.
  const Int3 cells = geo.cells(0);
  if (std::abs(s * geo.leaf_m() - double(resolution_m)) > 1e-6 || kMeshBlockVoxels % s != 0 ||
      cells.x() % s != 0 || cells.y() % s != 0 || cells.z() % s != 0)
    return bad(
        "is neither a divisor of the leaf size nor the leaf times a power of two up to 16 "
        "that divides the sub-map");
  return std::make_pair(1, s);
}

std::vector<Int3> ObservedVoxels(const MeshTileSource& src, const Int3& key) {
  std::vector<Int3> out;
  VisitObservedVoxels(src, key, [&out](const Int3& g) { out.push_back(g); });
  return out;
}

absl::StatusOr<Mesh> ExtractTile(const MeshTileSource& src, float resolution_m, const Int3& key) {
  return MeshTileBlocks(src, resolution_m, 0.f, key, nullptr, nullptr, nullptr, nullptr);
}

uint64_t MeshChangeLog::Stamp() const {
  std::lock_guard<std::mutex> lock(mu_);
  return stamp_;
}

void MeshChangeLog::Record(const std::vector<IntBox>& regions, bool all) {
  std::lock_guard<std::mutex> lock(mu_);
  ++stamp_;
  if (all) {
    // Everything changed: older entries can no longer decide anything.
    entries_.clear();
    floor_ = stamp_;
    return;
  }
  for (const IntBox& b : regions) entries_.push_back({stamp_, b, false});
  if (entries_.size() > kMaxEntries) {
    const size_t drop = entries_.size() - kMaxEntries / 2;
    floor_ = entries_[drop - 1].stamp;
    entries_.erase(entries_.begin(), entries_.begin() + drop);
  }
}

bool MeshChangeLog::ChangedSince(uint64_t stamp, const IntBox& region) const {
  std::lock_guard<std::mutex> lock(mu_);
  if (stamp < floor_) return true;
  for (auto it = entries_.rbegin(); it != entries_.rend() && it->stamp > stamp; ++it) {
    const IntBox& b = it->region;
    if ((b.lo.array() <= region.hi.array()).all() && (region.lo.array() <= b.hi.array()).all())
      return true;
  }
  return false;
}

absl::StatusOr<Mesh> MeshBlockCache::Update(const MeshTileSource& src, float resolution_m,
                                            float tolerance_m, const Int3& key,
                                            const MeshChangeLog& log, bool keep,
                                            MeshUpdateStats* stats) {
  std::shared_ptr<Tile> tile;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto& slot = tiles_[key];
    if (!slot) slot = std::make_shared<Tile>();
    tile = slot;
  }
  std::lock_guard<std::mutex> tile_lock(tile->mu);
  MeshUpdateStats s;
  bool changed = true;
  auto mesh =
      MeshTileBlocks(src, resolution_m, tolerance_m, key, &log, &tile->pieces, &s, &changed);
  std::lock_guard<std::mutex> lock(mu_);
  if (mesh.ok()) {
    totals_.blocks += s.blocks;
    totals_.blocks_remeshed += s.blocks_remeshed;
    totals_.blocks_checked += s.blocks_checked;
    totals_.blocks_skipped += s.blocks_skipped;
  }
  if (changed || tile->generation == 0) tile->generation = ++generations_;
  s.generation = tile->generation;
  if (stats) *stats = std::move(s);
  if (!mesh.ok() || !keep) {
    tile->pieces.clear();
    tile->bytes = 0;
    auto it = tiles_.find(key);
    if (it != tiles_.end() && it->second == tile) tiles_.erase(it);
    return mesh;
  }
  int64_t bytes = 0;
  for (const auto& [block, piece] : tile->pieces) bytes += piece->Bytes();
  tile->bytes = bytes;
  return mesh;
}

MeshCacheTotals MeshBlockCache::Totals() const {
  std::lock_guard<std::mutex> lock(mu_);
  return totals_;
}

int64_t MeshBlockCache::MemoryBytes() const {
  std::lock_guard<std::mutex> lock(mu_);
  int64_t bytes = 0;
  for (const auto& [key, tile] : tiles_) bytes += tile->bytes;
  return bytes;
}

}  // namespace rim
