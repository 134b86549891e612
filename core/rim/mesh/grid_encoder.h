// The mesh grid's encoding (mesh/mesher.cc's internals, in a header of their own to keep the
// mesher short): the grid of a resolution, the buffers a meshing call reuses from block to block,
// and the trilinear encoding of a block's grid points from the map's lattice rows.
#pragma once

#if defined(__x86_64__)
#include <immintrin.h>
#define RIM_MESH_AVX2 1
#endif

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "rim/base/types.h"
#include "rim/map/local_map.h"
#include "rim/map/map_geometry.h"
#include "rim/mesh/mesher.h"
#include "rim/model/encoder.h"

namespace rim::mesh_internal {

// The mesh grid of a resolution: `r` cells per finest voxel edge (a resolution that divides the
// leaf), or one cell per `s` finest voxels (a coarser level: a multiple of the leaf). One of the
// two is 1. Grid points are numbered in steps of leaf·s/r from the world origin.
struct GridSpec {
  int r = 1, s = 1;
  int CellsPerBlock() const { return kMeshBlockVoxels * r / s; }
};

// A coarse level's cells of s finest voxels an edge (s divides kMeshBlockVoxels), from observed
// voxels: `visit(fn)` calls fn(g) once for each observed voxel g, in any order. Returns per mesh
// block holding any of them (blocks in key order) the cells holding at least need = ⌈share · s³⌉
// of them, in key order (possibly none). The counts live in a dense array per block (at most 8³
// cells), read out in order: no hash per voxel and no sort, where hashing each voxel's block and
// then its cell, and sorting each block's voxels, was over a quarter of meshing a 0.2 m tile.
template <class Visit>
std::vector<std::pair<Int3, std::vector<Int3>>> CountCoarseCells(int s, double share,
                                                                 Visit&& visit) {
  const int per = kMeshBlockVoxels / s;  // cells a block edge
  const size_t cells = size_t(per) * per * per;
  const int need = std::max(1, int(std::ceil(share * s * s * s)));
  absl::flat_hash_map<Int3, uint32_t, Int3Hash, Int3Equal> index;  // block -> its counts
  std::vector<std::pair<Int3, std::vector<uint16_t>>> counts;
  Int3 last(0, 0, 0);
  uint16_t* at = nullptr;  // the last voxel's block's counts: a z run stays in one block
  visit([&](const Int3& g) {
    const Int3 b = FloorDiv(g, Int3::Constant(kMeshBlockVoxels));
    if (at == nullptr || b != last) {
      auto [it, inserted] = index.try_emplace(b, uint32_t(counts.size()));
      if (inserted) counts.emplace_back(b, std::vector<uint16_t>(cells, 0));
      at = counts[it->second].second.data();
      last = b;
    }
    const Int3 c = (g - b * kMeshBlockVoxels) / s;  // in [0, per) on each axis
    ++at[(size_t(c.x()) * per + c.y()) * per + c.z()];
  });
  auto key_less = [](const Int3& a, const Int3& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  };
  std::sort(counts.begin(), counts.end(),
            [&](const auto& a, const auto& b) { return key_less(a.first, b.first); });
  std::vector<std::pair<Int3, std::vector<Int3>>> out;
  out.reserve(counts.size());
  for (const auto& [b, n] : counts) {
    std::vector<Int3> kept;
    const Int3 c0 = b * per;
    for (int x = 0; x < per; ++x)
      for (int y = 0; y < per; ++y)
        for (int z = 0; z < per; ++z)
          if (n[(size_t(x) * per + y) * per + z] >= need) kept.push_back(c0 + Int3(x, y, z));
    out.emplace_back(b, std::move(kept));
  }
  return out;
}

// GridEncoder's per-block tables of one level (see its Level), kept in BlockScratch so that a block
// reuses the last one's storage.
struct EncoderLevelTables {
  struct Axis {
    size_t offset;  // the lattice cell's index part along this axis
    float w[2];     // weights of the cell's lower and upper side: 1 − f and f
    // w of each corner c = 4·cx + 2·cy + cz: w[cx] on the x axis, w[cy] on y, w[cz] on z.
    alignas(32) float lanes[8];
  };
  std::vector<float> rows;  // the lattice rows, written before read
  std::vector<uint8_t> have;
  std::vector<Axis> axis[3];
  std::vector<int> lattice[3];
  std::vector<int64_t> slot_part[3];
  std::vector<uint8_t> in_box[3];
};

// Buffers reused from block to block by one meshing call: nothing of a block's dense size is
// allocated or cleared per block, and nothing of its sparse size either once a larger block came.
struct BlockScratch {
  EncoderLevelTables levels[kMaxLevels];  // GridEncoder's
  std::vector<int32_t> point_index;       // BlockGrid's point table, all -1 between blocks
  std::vector<float> features;
  std::vector<Int3> cells, points;  // BlockGrid's
  MarchScratch march;
  std::vector<GridEdge> vertex_edges;  // BlockGrid::March's
};

// The trilinear encoding (model/encoder.h) at the mesh grid points of one block. A grid point m
// lies at m·s / (r·2^l) in level-l voxels, so its cell and weights are exact: the integer quotient
// and the remainder over a power of two times r. Each lattice row is fetched once per block (on
// first use) instead of once per point and corner; a level on which every grid point is a lattice
// point (a coarse grid) reads its rows straight from the map. The result is a function of the
// point alone, so blocks and tiles that share a point compute the same bits for it.
class GridEncoder {
 public:
  // `map` is the live map that `reader` reads first.
  GridEncoder(const MapGeometry& geo, GridSpec spec, const Int3& point0, int n, const LocalMap& map,
              FeatureReader& reader, BlockScratch& scratch)
      : L_(geo.levels()), D_(geo.feature_dim()), reader_(reader) {
    const int mult = spec.s;
    for (int l = 0; l < L_; ++l) {
      Level& lv = levels_[l];
      lv.scale = spec.r << l;
      // A coarse grid whose spacing is a multiple of the level's voxel puts every point on a
      // lattice point: its encoding is that row (weight 1, the other corners 0), read straight
      // from the map. Each such row serves one point, so the block's row cache would only copy.
      lv.aligned = mult % lv.scale == 0;
      if (lv.aligned) {
        // Per axis, also where the lattice index lies in the live map's storage and whether it
        // lies in its box: a point's row in the box is found without LocalMap::Slot's modulos,
        // and can be asked for ahead of its point (FeatureReader::Get's rows, the same pointers).
        const IntBox box = map.placed() ? map.LatticeBox(l) : IntBox{Int3::Ones(), Int3::Zero()};
        const Int3& d = map.level(l).dims;
        const int64_t stride[3] = {int64_t(d.y()) * d.z(), int64_t(d.z()), 1};
        EncoderLevelTables& t = scratch.levels[l];
        for (int a = 0; a < 3; ++a) {
          t.lattice[a].resize(size_t(n));
          t.slot_part[a].resize(size_t(n));
          t.in_box[a].resize(size_t(n));
          for (int k = 0; k < n; ++k) {
            const int g = (point0[a] + k) * (mult / lv.scale);
            t.lattice[a][size_t(k)] = g;
            t.in_box[a][size_t(k)] = g >= box.lo[a] && g <= box.hi[a];
            t.slot_part[a][size_t(k)] = d[a] > 0 ? PosMod(g, d[a]) * stride[a] : 0;
          }
          lv.lattice[a] = t.lattice[a].data();
          lv.slot_part[a] = t.slot_part[a].data();
          lv.in_box[a] = t.in_box[a].data();
        }
        lv.features = map.placed() ? map.level(l).features(0) : nullptr;
        any_aligned_ = true;
        continue;
      }
      lv.lo = FloorDiv(Int3(point0 * mult), Int3::Constant(lv.scale));
      const Int3 hi =
          FloorDiv(Int3((point0 + Int3::Constant(n - 1)) * mult), Int3::Constant(lv.scale)) +
          Int3::Ones();
      lv.dims = hi - lv.lo + Int3::Ones();
      const size_t count = size_t(lv.dims.x()) * lv.dims.y() * lv.dims.z();
      // Rows are written before they are read (`have`): the buffer is reused from block to
      // block without clearing.
      EncoderLevelTables& t = scratch.levels[l];
      if (t.rows.size() < count * D_) t.rows.resize(count * D_);
      lv.rows = t.rows.data();
      t.have.assign(count, 0);
      lv.have = t.have.data();
      // Per axis and block-local coordinate: the lattice cell (from lo), as a row-index stride
      // multiple, and the weights of its two sides, computed once per block instead of per point
      // (the same arithmetic, so the same bits).
      const size_t stride[3] = {size_t(lv.dims.y()) * lv.dims.z(), size_t(lv.dims.z()), 1};
      const float inv = 1.f / float(lv.scale);
      for (int a = 0; a < 3; ++a) {
        t.axis[a].resize(size_t(n));
        lv.axis[a] = t.axis[a].data();
        for (int k = 0; k < n; ++k) {
          const int m = (point0[a] + k) * mult;
          const int base = FloorDiv(m, lv.scale);
          const float f = float(m - base * lv.scale) * inv;
          Axis& e = t.axis[a][size_t(k)];
          e.offset = size_t(base - lv.lo[a]) * stride[a];
          e.w[0] = 1.f - f;
          e.w[1] = f;
          for (int c = 0; c < 8; ++c) e.lanes[c] = e.w[c >> (2 - a) & 1];
        }
      }
      lv.corner_offset[0] = 0;
      for (int c = 1; c < 8; ++c)
        lv.corner_offset[c] =
            (c >> 2 & 1) * stride[0] + (c >> 1 & 1) * stride[1] + (c & 1) * stride[2];
    }
  }

  // Features (L·D floats per point) at the block-local grid points.
  void EncodeAll(const std::vector<Int3>& points, float* out) {
#ifdef RIM_MESH_AVX2
    static const bool avx2 = __builtin_cpu_supports("avx2");
    if (D_ == 8 && avx2) return EncodeAvx2(points, out);
#endif
    if (D_ == 8)
      EncodeAll<8>(points, out);
    else
      EncodeAll<0>(points, out);
  }

 private:
  using Axis = EncoderLevelTables::Axis;
  struct Level {
    int scale = 1;  // r·2^l: the level's voxel edge in 1/r finest voxels
    Int3 lo = Int3::Zero(), dims = Int3::Zero();
    float* rows = nullptr;  // count·D floats of BlockScratch's rows of the level
    uint8_t* have = nullptr;
    const Axis* axis[3] = {};    // per axis and block-local coordinate
    size_t corner_offset[8];     // row-index offset of corner (cx, cy, cz) = c from the cell
    bool aligned = false;        // every grid point on a lattice point: no row cache
    const int* lattice[3] = {};  // aligned: per axis and block-local coordinate, the lattice index
    // aligned: per axis and block-local coordinate, its part of the live map's slot and whether it
    // lies in the box; the live map's rows from slot 0 (null: no box)
    const int64_t* slot_part[3] = {};
    const uint8_t* in_box[3] = {};
    const float* features = nullptr;
  };

#ifdef RIM_MESH_AVX2
  // EncodeAll<8> with the eight corner weights in one register: the same products in the same
  // order ((tx·ty)·tz per lane), then the corners of nonzero weight in ascending order from a
  // bit mask, so the sums are the same as the generic loop's.
  __attribute__((target("avx2"))) void EncodeAvx2(const std::vector<Int3>& points, float* out) {
    alignas(32) float w[8];
    for (size_t i = 0; i < points.size(); ++i) {
      const Int3& m = points[i];
      if (any_aligned_ && i + kPrefetchPoints < points.size())
        PrefetchAligned(points[i + kPrefetchPoints]);
      for (int l = 0; l < L_; ++l, out += 8) {
        Level& lv = levels_[l];
        if (lv.aligned) {
          // 0 + 1·row, as the corner sum below makes it (−0 becomes +0).
          _mm256_storeu_ps(
              out, _mm256_add_ps(_mm256_setzero_ps(), _mm256_loadu_ps(LatticeRow(l, lv, m))));
          continue;
        }
        const Axis& ax = lv.axis[0][size_t(m.x())];
        const Axis& ay = lv.axis[1][size_t(m.y())];
        const Axis& az = lv.axis[2][size_t(m.z())];
        const size_t cell = ax.offset + ay.offset + az.offset;
        const __m256 wc =
            _mm256_mul_ps(_mm256_mul_ps(_mm256_load_ps(ax.lanes), _mm256_load_ps(ay.lanes)),
                          _mm256_load_ps(az.lanes));
        _mm256_store_ps(w, wc);
        unsigned mask =
            unsigned(_mm256_movemask_ps(_mm256_cmp_ps(wc, _mm256_setzero_ps(), _CMP_NEQ_UQ)));
        __m256 o = _mm256_setzero_ps();
        while (mask != 0) {
          const int c = __builtin_ctz(mask);
          mask &= mask - 1;
          const float* row = Row(lv, cell + lv.corner_offset[c]);
          o = _mm256_add_ps(o, _mm256_mul_ps(_mm256_set1_ps(w[c]), _mm256_loadu_ps(row)));
        }
        _mm256_storeu_ps(out, o);
      }
    }
  }
#endif

  // For each level and corner c = 4·cx + 2·cy + cz in order, adds weight·row to the level's D
  // outputs (starting from zero), the weight being (tx·ty)·tz; corners of weight zero (the point
  // lies on the lattice plane of the other side) add nothing: +0 plus ±0 is +0, and finite sums
  // keep their bits, so their rows are not read. DC = D when known at compile time, else 0.
  template <int DC>
  __attribute__((always_inline)) inline void EncodeAll(const std::vector<Int3>& points,
                                                       float* out) {
    const int D = DC > 0 ? DC : D_;
    for (const Int3& m : points) {
      for (int l = 0; l < L_; ++l, out += D) {
        Level& lv = levels_[l];
        if (lv.aligned) {
          const float* row = LatticeRow(l, lv, m);
          for (int d = 0; d < D; ++d) out[d] = 0.f + row[d];
          continue;
        }
        const Axis& ax = lv.axis[0][size_t(m.x())];
        const Axis& ay = lv.axis[1][size_t(m.y())];
        const Axis& az = lv.axis[2][size_t(m.z())];
        const size_t cell = ax.offset + ay.offset + az.offset;
        float o[DC > 0 ? DC : 64];
        for (int d = 0; d < D; ++d) o[d] = 0.f;
        for (int c = 0; c < 8; ++c) {
          const float tx = ax.w[c >> 2 & 1], ty = ay.w[c >> 1 & 1], tz = az.w[c & 1];
          const float wc = tx * ty * tz;
          if (wc == 0.f) continue;
          const float* row = Row(lv, cell + lv.corner_offset[c]);
          for (int d = 0; d < D; ++d) o[d] += wc * row[d];
        }
        for (int d = 0; d < D; ++d) out[d] = o[d];
      }
    }
  }

  // An aligned level's row at grid point m (valid until the reader's next Get).
  const float* LatticeRow(int l, const Level& lv, const Int3& m) {
    if (const float* row = BoxRow(lv, m)) return row;
    return reader_.Get(l, Int3(lv.lattice[0][size_t(m.x())], lv.lattice[1][size_t(m.y())],
                               lv.lattice[2][size_t(m.z())]));
  }
  // An aligned level's row at grid point m in the live map's box, or null outside it.
  const float* BoxRow(const Level& lv, const Int3& m) const {
    const size_t x = size_t(m.x()), y = size_t(m.y()), z = size_t(m.z());
    if (!(lv.in_box[0][x] & lv.in_box[1][y] & lv.in_box[2][z])) return nullptr;
    return lv.features + (lv.slot_part[0][x] + lv.slot_part[1][y] + lv.slot_part[2][z]) * D_;
  }
  // Starts loading the aligned levels' rows of a point read soon: grid points lie apart in the
  // map's storage (at 0.2 m each row a cache line of its own), and reading them one after another
  // waited on memory more than the levels' sums took.
  void PrefetchAligned(const Int3& m) const {
    for (int l = 0; l < L_; ++l)
      if (levels_[l].aligned)
        if (const float* row = BoxRow(levels_[l], m)) __builtin_prefetch(row);
  }
  static constexpr size_t kPrefetchPoints = 16;

  const float* Row(Level& lv, size_t i) {
    float* row = lv.rows + i * D_;
    if (!lv.have[i]) [[unlikely]] {
      // The row's lattice point, from its index.
      const int dz = lv.dims.z(), dyz = lv.dims.y() * dz;
      const Int3 g(int(i / size_t(dyz)), int(i % size_t(dyz)) / dz, int(i % size_t(dz)));
      std::copy_n(reader_.Get(int(&lv - levels_), lv.lo + g), D_, row);
      lv.have[i] = 1;
    }
    return row;
  }

  const int L_, D_;
  bool any_aligned_ = false;  // a level read straight from the map (a coarse grid)
  FeatureReader& reader_;
  Level levels_[kMaxLevels];
};

}  // namespace rim::mesh_internal
