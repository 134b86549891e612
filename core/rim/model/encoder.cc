#include "rim/model/encoder.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "rim/base/row8.h"

namespace rim {

namespace {

// Corners and weights (first pass), then the weighted feature sums (second pass) of points
// [begin, end) at one level.
void EncodeRange(const LocalMap& map, int l, const float* xyz, int begin, int end,
                 LocalEncoding* enc, float* features) {
  const MapGeometry& geo = map.geometry();
  const int L = geo.levels(), D = geo.feature_dim();
  const LocalMap::Level& lv = map.level(l);
  const double inv_h = 1.0 / geo.voxel_m(l);
  for (int p = begin; p < end; ++p) {
    Int3 base;
    float f[3];
    for (int a = 0; a < 3; ++a) {
      const double u = double(xyz[3 * p + a]) * inv_h;
      const double b = std::floor(u);
      base[a] = int(b);
      f[a] = float(u - b);
    }
    int64_t* slots = &enc->slots[(size_t(p) * L + l) * 8];
    map.CellSlots(l, base, slots);
    float* w = &enc->weights[(size_t(p) * L + l) * 8];
    for (int c = 0; c < 8; ++c) {
      const int cx = c >> 2 & 1, cy = c >> 1 & 1, cz = c & 1;
      w[c] = (cx ? f[0] : 1.f - f[0]) * (cy ? f[1] : 1.f - f[1]) * (cz ? f[2] : 1.f - f[2]);
    }
  }
  // Second pass, once every point's corners are known: the feature rows are scattered over the
  // dense grid, so a later point's rows are requested while this one's are summed. With batches in
  // random order 8 points ahead took 4–8 % off the encode against 4, and 16 did no better; in cell
  // order (OrderBatchByCell), where neighbouring points share rows, 16 took another 4–6 % off.
  constexpr int kAhead = 16;
  for (int p = begin; p < end; ++p) {
    if (p + kAhead < end) {
      const int64_t* ahead = &enc->slots[(size_t(p + kAhead) * L + l) * 8];
      for (int c = 0; c < 8; ++c) __builtin_prefetch(lv.features(ahead[c]));
    }
    const int64_t* slots = &enc->slots[(size_t(p) * L + l) * 8];
    const float* w = &enc->weights[(size_t(p) * L + l) * 8];
    float* out = features + size_t(p) * L * D + size_t(l) * D;
    if (D == 8) {  // every preset: the sum stays in registers instead of going through `out`
      float acc[8] = {};
      for (int c = 0; c < 8; ++c) {
        const float* feat = lv.features(slots[c]);
        const float wc = w[c];
        for (int d = 0; d < 8; ++d) acc[d] += wc * feat[d];
      }
      std::copy_n(acc, 8, out);
      continue;
    }
    std::fill_n(out, D, 0.f);
    for (int c = 0; c < 8; ++c) {
      const float* feat = lv.features(slots[c]);
      for (int d = 0; d < D; ++d) out[d] += w[c] * feat[d];
    }
  }
}

}  // namespace

void EncodeLocal(const LocalMap& map, const float* xyz, int n, LocalEncoding* enc, float* features,
                 WorkerPool* pool) {
  const int L = map.geometry().levels();
  enc->points = n;
  enc->slots.resize(size_t(n) * L * 8);
  enc->weights.resize(size_t(n) * L * 8);
  // Every (level, chunk of points) pair writes its own entries: no two tasks share an output.
  // Four chunks per thread and level: the levels miss the cache unequally (the finest most), and
  // with one chunk per thread one thread idled at the region's end (encode −7 to −12 % a 512-ray
  // iteration, BENCHMARK.md).
  const int chunks = pool ? 4 * pool->threads() : 1;
  auto task = [&](int i) {
    const int l = i / chunks, c = i % chunks;
    EncodeRange(map, l, xyz, int(int64_t(n) * c / chunks), int(int64_t(n) * (c + 1) / chunks), enc,
                features);
  };
  if (pool) {
    pool->Run(L * chunks, task);
  } else {
    for (int i = 0; i < L; ++i) task(i);
  }
}

void SparseGradient::Reset(const LocalMap& map) { levels_.resize(map.geometry().levels()); }

void SparseGradient::BeginIteration(LocalMap* map) {
  stamp_ = map->NextScatterStamp();
  for (Level& lv : levels_) {
    lv.touched.clear();
  }
}

namespace {
constexpr int kPrefetchPoints = 4;
}  // namespace

void SparseGradient::Scatter(LocalMap* map, const LocalEncoding& enc, const float* grad_features,
                             WorkerPool* pool) {
  const int L = map->geometry().levels();
  // Levels have their own slots, rows and gradients: one task per level, in a fixed order
  // within each, so the result does not depend on the thread count.
  if (pool) {
    pool->Run(L, [&](int l) { ScatterLevel(map, enc, grad_features, l); });
  } else {
    for (int l = 0; l < L; ++l) ScatterLevel(map, enc, grad_features, l);
  }
}

void SparseGradient::ScatterLevel(LocalMap* map, const LocalEncoding& enc,
                                  const float* grad_features, int l) {
  const int L = map->geometry().levels(), D = map->geometry().feature_dim();
  LocalMap::Level& grid = map->level(l);
  Level& lv = levels_[l];
  // At most 8 new rows per point. Sized once for the largest batch seen and never shrunk, so
  // that a new row costs a D-float clear rather than a vector growth; rows beyond touched.size()
  // are stale.
  if (lv.grad.size() < size_t(enc.points) * 8 * D) lv.grad.resize(size_t(enc.points) * 8 * D);
  for (int p = 0; p < enc.points; ++p) {
    const float* g = grad_features + size_t(p) * L * D + size_t(l) * D;
    const int64_t* slots = &enc.slots[(size_t(p) * L + l) * 8];
    // The slots are scattered over the dense grid: ask for a later point's tags now so that
    // several cache misses are in flight at once instead of one after the other.
    if (p + kPrefetchPoints < enc.points) {
      const int64_t* ahead = &enc.slots[(size_t(p + kPrefetchPoints) * L + l) * 8];
      // Corners c and c + 1 differ in z only: neighbouring slots, one cache line.
      for (int c = 0; c < 8; c += 2) __builtin_prefetch(&grid.scatter_tag(ahead[c]), 1);
    }
    const float* w = &enc.weights[(size_t(p) * L + l) * 8];
    // The point's upstream gradient in registers: the rows below could alias it as far as the
    // compiler knows, and it would otherwise reload g and add one float at a time.
    float g8[8];
    if (D == 8) std::copy_n(g, 8, g8);
    for (int c = 0; c < 8; ++c) {
      const int64_t slot = slots[c];
      LocalMap::ScatterTag& tag = grid.scatter_tag(slot);
      const float wc = w[c];
      if (tag.stamp != stamp_) {
        // A new row is written, not read and added to: its line (last used an iteration ago)
        // need not arrive before the next corner can go on. 0 + x keeps the sums' bits (and a
        // -0 turned +0) as a cleared row would.
        tag.stamp = stamp_;
        const size_t row = lv.touched.size();
        tag.row = int32_t(row);
        lv.touched.push_back(slot);
        float* __restrict dst = &lv.grad[row * D];
        if (D == 8) {
          for (int d = 0; d < 8; ++d) dst[d] = 0.f + wc * g8[d];
        } else {
          for (int d = 0; d < D; ++d) dst[d] = 0.f + wc * g[d];
        }
        continue;
      }
      float* __restrict dst = &lv.grad[size_t(tag.row) * D];
      if (D == 8) {  // every preset: two 4-wide multiply-adds
        for (int d = 0; d < 8; ++d) dst[d] += wc * g8[d];
      } else {
        for (int d = 0; d < D; ++d) dst[d] += wc * g[d];
      }
    }
  }
}

FeatureReader::FeatureReader(const LocalMap& map, const SubmapStore& store)
    : map_(map),
      store_(store),
      zeros_(map.geometry().feature_dim(), 0.f),
      widened_(map.geometry().feature_dim()) {}

FeatureReader::Slot FeatureReader::Fetch(int level, const Int3& g,
                                         const SubmapStore::BlockAddress& a) {
  if (last_valid_[level] && last_origin_[level] == a.origin) return {last_block_[level], a.index};
  auto& cache = blocks_[level];
  auto it = cache.find(a.origin);
  if (it == cache.end()) {
    // Bounded: a batch spread over the whole map must not pin the whole store.
    if (cache.size() >= kMaxCachedBlocks) cache.clear();
    it = cache.emplace(a.origin, store_.ReadBlock(level, g)).first;
  }
  last_valid_[level] = true;
  last_origin_[level] = a.origin;
  last_block_[level] = it->second.get();
  return {it->second.get(), a.index};
}

const float* FeatureReader::Get(int level, const Int3& g) {
  if (map_.InBox(level, g)) {
    return map_.level(level).features(map_.Slot(level, g));
  }
  const Slot s = Fetch(level, g);
  if (s.block == nullptr) return zeros_.data();
  const size_t D = size_t(map_.geometry().feature_dim());
  DecodeRows8(&s.block->features[size_t(s.index) * Row8Bytes(int(D))], 1, int(D), widened_.data());
  return widened_.data();
}

uint8_t FeatureReader::ObservedBits(const Int3& g0) {
  if (map_.InBox(0, g0))
    return map_.level(0).flags_shared(map_.Slot(0, g0)) & LocalMap::kObservedBits;
  const Slot s = Fetch(0, g0);
  if (s.block == nullptr) return 0;
  return s.block->observed[size_t(s.index)] & LocalMap::kObservedBits;
}

void FeatureReader::Prefetch(const Vec3d& p_W) const {
  if (!map_.placed()) return;
  const MapGeometry& geo = map_.geometry();
  for (int l = 0; l < geo.levels(); ++l) {
    const double inv_h = 1.0 / geo.voxel_m(l);
    const IntBox box = map_.LatticeBox(l);
    Int3 base;
    for (int a = 0; a < 3; ++a) base[a] = int(std::floor(p_W[a] * inv_h));
    if ((base.array() < box.lo.array()).any() || (base.array() >= box.hi.array()).any()) continue;
    int64_t slots[8];
    map_.CellSlots(l, base, slots);
    // Corners c and c + 1 differ in z only: mostly one cache line.
    for (int c = 0; c < 8; c += 2) __builtin_prefetch(map_.level(l).features(slots[c]));
  }
}

// Encode's cell for D = 8: the sums and the Jacobian's three columns are kept as separate
// 8-float rows, which the compiler keeps in vector registers (the Jacobian's interleaved
// d-major layout made it add one float at a time), and written out once. Each element gets the
// same products added in the same corner order as the general loop, so the bits are the same.
void FeatureReader::EncodeCell8(const float f[3], float inv_h, const float* const* corner, int l,
                                const Int3& base, float* out, float* jac) {
  float acc[8] = {}, jx[8] = {}, jy[8] = {}, jz[8] = {};
  for (int c = 0; c < 8; ++c) {
    const int cx = c >> 2 & 1, cy = c >> 1 & 1, cz = c & 1;
    const float tx = cx ? f[0] : 1.f - f[0], ty = cy ? f[1] : 1.f - f[1],
                tz = cz ? f[2] : 1.f - f[2];
    const float* feat = corner ? corner[c] : Get(l, base + Int3(cx, cy, cz));
    float row[8];
    std::copy_n(feat, 8, row);
    const float wc = tx * ty * tz;
    for (int d = 0; d < 8; ++d) acc[d] += wc * row[d];
    if (!jac) continue;
    const float sx = (cx ? 1.f : -1.f) * inv_h, sy = (cy ? 1.f : -1.f) * inv_h,
                sz = (cz ? 1.f : -1.f) * inv_h;
    const float dwx = sx * ty * tz, dwy = tx * sy * tz, dwz = tx * ty * sz;
    for (int d = 0; d < 8; ++d) {
      jx[d] += dwx * row[d];
      jy[d] += dwy * row[d];
      jz[d] += dwz * row[d];
    }
  }
  std::copy_n(acc, 8, out);
  if (!jac) return;
  for (int d = 0; d < 8; ++d) {
    jac[d * 3 + 0] = jx[d];
    jac[d * 3 + 1] = jy[d];
    jac[d * 3 + 2] = jz[d];
  }
}

bool FeatureReader::StoreCorners8(int l, const Int3& base, const float** corner, float* rows) {
  if (map_.placed()) {
    // A corner in the box (closed: lattice points lo..hi) reads the live map: take this path
    // only when none is.
    const IntBox box = map_.LatticeBox(l);
    bool apart = false;
    for (int a = 0; a < 3; ++a) apart = apart || base[a] + 1 < box.lo[a] || base[a] > box.hi[a];
    if (!apart) return false;
  }
  // SubmapStore::Address axis by axis (sub-maps and blocks are boxes on the lattice): for each
  // axis, the block origin and the offset in the block of the cell's lower and upper corner.
  // A corner's block and index combine its three axes' choices, so a cell that spans blocks
  // (a third of them at block_size 8) costs a lookup per block it touches, not per corner.
  const int B = store_.block_size();
  const Int3 cells = map_.geometry().cells(l);
  int origin[3][2], in[3][2];
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k < 2; ++k) {
      const int g = base[a] + k;
      const int sub = FloorDiv(g, cells[a]) * cells[a];
      const int block = FloorDiv(g - sub, B);
      origin[a][k] = sub + block * B;
      in[a][k] = g - origin[a][k];
    }
  // Corners grouped by block, each block looked up once and its corners decoded at once (a
  // later lookup may start the block cache over).
  bool done[8] = {};
  for (int c = 0; c < 8; ++c) {
    if (done[c]) continue;
    const Int3 o(origin[0][c >> 2 & 1], origin[1][c >> 1 & 1], origin[2][c & 1]);
    const Slot s = Fetch(l, base + Int3(c >> 2 & 1, c >> 1 & 1, c & 1), {o, 0});
    for (int k = c; k < 8; ++k) {
      const int kx = k >> 2 & 1, ky = k >> 1 & 1, kz = k & 1;
      if (done[k] || !(Int3(origin[0][kx], origin[1][ky], origin[2][kz]) == o)) continue;
      done[k] = true;
      if (s.block == nullptr) {
        corner[k] = zeros_.data();
        continue;
      }
      const int index = (in[0][kx] * B + in[1][ky]) * B + in[2][kz];
      DecodeRows8(&s.block->features[size_t(index) * Row8Bytes(8)], 1, 8, rows + 8 * k);
      corner[k] = rows + 8 * k;
    }
  }
  return true;
}

void FeatureReader::Encode(const Vec3d& p_W, float* features, float* jacobian) {
  const MapGeometry& geo = map_.geometry();
  const int L = geo.levels(), D = geo.feature_dim();
  for (int l = 0; l < L; ++l) {
    const double inv_h = 1.0 / geo.voxel_m(l);
    Int3 base;
    float f[3];
    for (int a = 0; a < 3; ++a) {
      const double u = p_W[a] * inv_h;
      const double b = std::floor(u);
      base[a] = int(b);
      f[a] = float(u - b);
    }
    float* out = features + size_t(l) * D;
    std::fill_n(out, D, 0.f);
    float* jac = jacobian ? jacobian + size_t(l) * D * 3 : nullptr;
    if (jac) std::fill_n(jac, D * 3, 0.f);
    // The 8 corner rows: from one CellSlots lookup when the whole cell is in the live box (the
    // common case for queries near the robot).
    const float* corner[8];
    const IntBox box = map_.LatticeBox(l);
    const bool inside = map_.placed() && (base.array() >= box.lo.array()).all() &&
                        (base.array() < box.hi.array()).all();
    if (inside) {
      int64_t slots[8];
      map_.CellSlots(l, base, slots);
      for (int c = 0; c < 8; ++c) corner[c] = map_.level(l).features(slots[c]);
    }
    if (D == 8) {  // every preset
      float rows[64];
      const bool whole = inside || StoreCorners8(l, base, corner, rows);
      EncodeCell8(f, float(inv_h), whole ? corner : nullptr, l, base, out, jac);
      continue;
    }
    for (int c = 0; c < 8; ++c) {
      const int cx = c >> 2 & 1, cy = c >> 1 & 1, cz = c & 1;
      const float tx = cx ? f[0] : 1.f - f[0], ty = cy ? f[1] : 1.f - f[1],
                  tz = cz ? f[2] : 1.f - f[2];
      // Otherwise each row comes from Get, valid only until the next call: used at once.
      const float* feat = inside ? corner[c] : Get(l, base + Int3(cx, cy, cz));
      const float wc = tx * ty * tz;
      for (int d = 0; d < D; ++d) out[d] += wc * feat[d];
      if (!jac) continue;
      // d w / d p_a: the derivative of the axis factor (±1/h) times the other two factors.
      const float sx = (cx ? 1.f : -1.f) * float(inv_h), sy = (cy ? 1.f : -1.f) * float(inv_h),
                  sz = (cz ? 1.f : -1.f) * float(inv_h);
      const float dw[3] = {sx * ty * tz, tx * sy * tz, tx * ty * sz};
      for (int d = 0; d < D; ++d)
        for (int a = 0; a < 3; ++a) jac[d * 3 + a] += dw[a] * feat[d];
    }
  }
}

}  // namespace rim
