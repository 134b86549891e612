// The GPU path's kernels (kernels.h): the training iteration over the local map's dense grids,
// encoding, and SDF/gradient queries. One thread per point or row, except the gradient scatter
// (one per row, level and corner); the decoder's parameters sit in shared memory, where every
// thread of a warp reads the same word at once.
#include <cuda_runtime.h>

#include <cmath>
#include <cstdint>

#include "rim/gpu/kernels.h"

namespace rim::gpu {
namespace {

constexpr int kD = kFeatureDim;

__device__ __forceinline__ int PosModDev(int a, int m) {
  const int r = a % m;
  return r < 0 ? r + m : r;
}

// The cell of level `v` holding point p: the slots of its 8 corners (corner c at offset
// (c >> 2 & 1, c >> 1 & 1, c & 1), as LocalMap::CellSlots) and p's fractions in it, computed in
// double as the CPU encoder does. False when the cell is not in the box (or p is NaN).
__device__ __forceinline__ bool FindCell(const LevelView& v, const float p[3], int32_t slot[8],
                                         float f[3]) {
  int s0[3], s1[3];
#pragma unroll
  for (int a = 0; a < 3; ++a) {
    const double u = double(p[a]) * v.inv_h;
    const double b = floor(u);
    if (!(b >= double(v.lo[a]) && b < double(v.lo[a]) + double(v.cells[a]))) return false;
    f[a] = float(u - b);
    s0[a] = PosModDev(int(b), v.dims[a]);
    s1[a] = s0[a] + 1 == v.dims[a] ? 0 : s0[a] + 1;
  }
#pragma unroll
  for (int c = 0; c < 8; ++c)
    slot[c] = ((c & 4 ? s1[0] : s0[0]) * v.dims[1] + (c & 2 ? s1[1] : s0[1])) * v.dims[2] +
              (c & 1 ? s1[2] : s0[2]);
  return true;
}

__device__ __forceinline__ void TrilinearWeights(const float f[3], float w[8]) {
#pragma unroll
  for (int c = 0; c < 8; ++c) {
    const float tx = c & 4 ? f[0] : 1.f - f[0], ty = c & 2 ? f[1] : 1.f - f[1],
                tz = c & 1 ? f[2] : 1.f - f[2];
    w[c] = tx * ty * tz;
  }
}

// A feature row (8 floats, 32-byte aligned) in two 16-byte loads.
__device__ __forceinline__ void LoadRow(const float* features, int32_t slot, float row[8]) {
  const float4* q = reinterpret_cast<const float4*>(features + size_t(slot) * kD);
  const float4 a = __ldg(q), b = __ldg(q + 1);
  row[0] = a.x, row[1] = a.y, row[2] = a.z, row[3] = a.w;
  row[4] = b.x, row[5] = b.y, row[6] = b.z, row[7] = b.w;
}

// Encodes p at every level into x (levels·D); false when p is outside the box.
template <int L>
__device__ __forceinline__ bool EncodePoint(const Grids& g, const float p[3], float* x) {
#pragma unroll
  for (int l = 0; l < L; ++l) {
    int32_t slot[8];
    float f[3], w[8];
    if (!FindCell(g.level[l], p, slot, f)) return false;
    TrilinearWeights(f, w);
    float acc[kD] = {};
#pragma unroll
    for (int c = 0; c < 8; ++c) {
      float row[8];
      LoadRow(g.level[l].features, slot[c], row);
#pragma unroll
      for (int d = 0; d < kD; ++d) acc[d] += w[c] * row[d];
    }
#pragma unroll
    for (int d = 0; d < kD; ++d) x[l * kD + d] = acc[d];
  }
  return true;
}

// Decoder parameters into shared memory: W0 (H × F, row-major), b0 (H), w1 (H), b1.
template <int F, int H>
__device__ __forceinline__ void LoadParams(const float* params, float* sp) {
  constexpr int P = H * F + 2 * H + 1;
  for (int i = threadIdx.x; i < P; i += blockDim.x) sp[i] = params[i];
  __syncthreads();
}

// y = w1 · relu(W0 x + b0) + b1; h gets relu(W0 x + b0).
template <int F, int H>
__device__ __forceinline__ float MlpForward(const float* sp, const float* x, float* h) {
  const float* W0 = sp;
  const float* b0 = sp + H * F;
  const float* w1 = b0 + H;
  float y = w1[H];
#pragma unroll
  for (int k = 0; k < H; ++k) {
    float s = b0[k];
#pragma unroll
    for (int i = 0; i < F; ++i) s += W0[k * F + i] * x[i];
    h[k] = fmaxf(s, 0.f);
    y += w1[k] * h[k];
  }
  return y;
}

__device__ __forceinline__ float SigmoidDev(float x) {
  if (x >= 0.f) return 1.f / (1.f + expf(-x));
  const float e = expf(x);
  return e / (1.f + e);
}

__device__ __forceinline__ double WarpSum(double v) {
#pragma unroll
  for (int o = 16; o > 0; o >>= 1) v += __shfl_down_sync(0xffffffffu, v, o);
  return v;
}

// ---- training ----

// Every row's point must lie in the box at every level; the first that does not is reported.
__global__ void CheckPointsKernel(Grids g, int rows, const float* xyz, int32_t* error) {
  const int r = blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= rows) return;
  const float p[3] = {xyz[3 * r], xyz[3 * r + 1], xyz[3 * r + 2]};
  for (int l = 0; l < g.levels; ++l) {
    int32_t slot[8];
    float f[3];
    if (!FindCell(g.level[l], p, slot, f)) {
      atomicCAS(error, 0, r + 1);
      return;
    }
  }
}

// Forward: encode, decode, keep features and y; marks level 0's observed flags (Trainer's
// MarkObserved) for labelled rows.
template <int L, int H>
__global__ void __launch_bounds__(128) TrainForwardKernel(Grids g, TrainArgs a, TrainBuffers b) {
  constexpr int F = L * kD;
  __shared__ float sp[H * F + 2 * H + 1];
  LoadParams<F, H>(b.params, sp);
  const int r = blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= a.rows || *b.error != 0) return;
  const float p[3] = {b.xyz[3 * r], b.xyz[3 * r + 1], b.xyz[3 * r + 2]};
  float x[F], h[H];
  EncodePoint<L>(g, p, x);
#pragma unroll
  for (int i = 0; i < F; ++i) b.features[size_t(r) * F + i] = x[i];
  b.y[r] = MlpForward<F, H>(sp, x, h);
  if (r < a.labelled && g.flags0 != nullptr) {
    const float label = b.labels[r];
    uint32_t bits = 0;
    if (fabsf(label) < a.observed_band_m) {
      bits = 1u | 2u;  // kObserved | kHasData
    } else if (label > 0.f) {
      bits = 4u | 2u;  // kSeenFree | kHasData
    }
    if (bits != 0) {
      int32_t slot[8];
      float f[3];
      FindCell(g.level[0], p, slot, f);
      uint32_t* word = reinterpret_cast<uint32_t*>(g.flags0) + (slot[0] >> 2);
      atomicOr(word, bits << (8 * (slot[0] & 3)));
    }
  }
}

// Loss terms and d loss / d y: BCE of the labelled rows (MlpTrainStep's stable form), the
// eikonal term of each group of 6 probes.
__global__ void LossKernel(TrainArgs a, TrainBuffers b) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  const int groups = a.eikonal_weight > 0.f ? (a.rows - a.labelled) / 6 : 0;
  double bce = 0, eik = 0;
  if (*b.error == 0) {
    if (i < a.labelled) {
      const float scale = -a.inv_sigma / float(a.labelled);
      const float s = -b.y[i] * a.inv_sigma;
      const float t = SigmoidDev(-b.labels[i] * a.inv_sigma);
      const float e = expf(-fabsf(s));
      bce = double(fmaxf(s, 0.f) - s * t + log1pf(e));
      const float sig = s >= 0.f ? 1.f / (1.f + e) : e / (1.f + e);
      b.dy[i] = (sig - t) * scale;
    } else if (i - a.labelled < groups) {
      const int base = a.labelled + 6 * (i - a.labelled);
      float grad[3];
#pragma unroll
      for (int k = 0; k < 3; ++k) grad[k] = (b.y[base + 2 * k] - b.y[base + 2 * k + 1]) * a.inv_2h;
      const float norm = sqrtf(grad[0] * grad[0] + grad[1] * grad[1] + grad[2] * grad[2]);
      eik = double(norm - 1.f) * double(norm - 1.f);
      const float coef =
          norm > 0.f ? a.eikonal_weight * 2.f * (norm - 1.f) / (norm * float(groups)) : 0.f;
#pragma unroll
      for (int k = 0; k < 3; ++k) {
        b.dy[base + 2 * k] = coef * grad[k] * a.inv_2h;
        b.dy[base + 2 * k + 1] = -(coef * grad[k] * a.inv_2h);
      }
    }
  }
  bce = WarpSum(bce);
  eik = WarpSum(eik);
  __shared__ double part[2][32];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
  if (lane == 0) {
    part[0][warp] = bce;
    part[1][warp] = eik;
  }
  __syncthreads();
  if (warp == 0) {
    const int warps = (blockDim.x + 31) >> 5;
    bce = lane < warps ? part[0][lane] : 0.0;
    eik = lane < warps ? part[1][lane] : 0.0;
    bce = WarpSum(bce);
    eik = WarpSum(eik);
    if (lane == 0) {
      if (bce != 0.0) atomicAdd(&b.sums[0], bce);
      if (eik != 0.0) atomicAdd(&b.sums[1], eik);
    }
  }
}

// Backward: through the decoder to the features, then into the corner rows of every level with
// atomic adds (a row's first touch this iteration appends it to the level's touched list); the
// decoder's gradient summed over the block's rows in shared memory, one atomic add per
// parameter and block.
template <int L, int H>
__host__ __device__ constexpr int BackwardRows() {
  return H >= 64 ? 32 : 64;
}

template <int L, int H>
__global__ void __launch_bounds__(BackwardRows<L, H>())
    TrainBackwardKernel(Grids g, TrainArgs a, TrainBuffers b) {
  constexpr int F = L * kD;
  constexpr int P = H * F + 2 * H + 1;
  constexpr int B = BackwardRows<L, H>();
  __shared__ float sp[P];
  __shared__ float s_gh[B][H], s_h[B][H], s_x[B][F + 1], s_dy[B];
  LoadParams<F, H>(b.params, sp);
  const float* W0 = sp;
  const float* b0 = sp + H * F;
  const float* w1 = b0 + H;
  const int t = threadIdx.x;
  const int r = blockIdx.x * B + t;
  const bool live = r < a.rows && *b.error == 0;
  float x[F];
  float dyr = 0.f;
  if (live) {
#pragma unroll
    for (int i = 0; i < F; ++i) x[i] = b.features[size_t(r) * F + i];
    dyr = b.dy[r];
  } else {
#pragma unroll
    for (int i = 0; i < F; ++i) x[i] = 0.f;
  }
#pragma unroll
  for (int k = 0; k < H; ++k) {
    float s = b0[k];
#pragma unroll
    for (int i = 0; i < F; ++i) s += W0[k * F + i] * x[i];
    const float hk = fmaxf(s, 0.f);
    s_h[t][k] = hk;
    s_gh[t][k] = hk > 0.f ? dyr * w1[k] : 0.f;
  }
  s_dy[t] = dyr;
#pragma unroll
  for (int i = 0; i < F; ++i) s_x[t][i] = x[i];
  // d loss / d features of the row, into its feature row (this thread alone reads and writes
  // it); ScatterKernel spreads it over the corner rows.
  if (live) {
    float dx[F];
#pragma unroll
    for (int i = 0; i < F; ++i) dx[i] = 0.f;
      // Not unrolled over k: unrolled, the compiler kept the forward loop's H·F weight loads live
      // for reuse here and spilled them.
#pragma unroll 1
    for (int k = 0; k < H; ++k) {
      const float gk = s_gh[t][k];
#pragma unroll
      for (int i = 0; i < F; ++i) dx[i] += gk * W0[k * F + i];
    }
#pragma unroll
    for (int i = 0; i < F; ++i) b.features[size_t(r) * F + i] = dx[i];
  }
  if (!a.train_decoder) return;
  __syncthreads();
  for (int j = t; j < P; j += B) {
    float s = 0.f;
    if (j < H * F) {
      const int k = j / F, i = j % F;
      for (int q = 0; q < B; ++q) s += s_gh[q][k] * s_x[q][i];
    } else if (j < H * F + H) {
      const int k = j - H * F;
      for (int q = 0; q < B; ++q) s += s_gh[q][k];
    } else if (j < H * F + 2 * H) {
      const int k = j - H * F - H;
      for (int q = 0; q < B; ++q) s += s_dy[q] * s_h[q][k];
    } else {
      for (int q = 0; q < B; ++q) s += s_dy[q];
    }
    if (s != 0.f) atomicAdd(&b.grad_params[j], s);
  }
}

// The slot and trilinear weight of corner c of p's cell at level v (FindCell and
// TrilinearWeights for one corner; p is in the box).
__device__ __forceinline__ void CornerOf(const LevelView& v, const float p[3], int c, int32_t* slot,
                                         float* w) {
  int s[3];
  float t[3];
#pragma unroll
  for (int a = 0; a < 3; ++a) {
    const double u = double(p[a]) * v.inv_h;
    const double b = floor(u);
    const float f = float(u - b);
    const int s0 = PosModDev(int(b), v.dims[a]);
    const bool up = (c >> (2 - a)) & 1;
    s[a] = up ? (s0 + 1 == v.dims[a] ? 0 : s0 + 1) : s0;
    t[a] = up ? f : 1.f - f;
  }
  *slot = (s[0] * v.dims[1] + s[1]) * v.dims[2] + s[2];
  *w = t[0] * t[1] * t[2];
}

// The feature gradient into the corner rows, one thread per (row, level, corner): every corner of
// every row is touched, as the CPU scatter does. A row's first touch this iteration appends it to
// the level's touched list; the warp's fresh rows of a level take their places with one atomic
// add on the level's counter.
template <int L>
__global__ void __launch_bounds__(256) ScatterKernel(Grids g, TrainArgs a, TrainBuffers b) {
  constexpr int F = L * kD;
  const int64_t idx = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  const int r = int(idx / F);
  const int l = int(idx % F) >> 3, c = int(idx % F) & 7;
  const bool live = r < a.rows && *b.error == 0;
  bool fresh = false;
  int32_t slot = 0;
  if (live) {
    const LevelView& v = g.level[l];
    const float p[3] = {b.xyz[3 * r], b.xyz[3 * r + 1], b.xyz[3 * r + 2]};
    float w;
    CornerOf(v, p, c, &slot, &w);
    fresh = atomicExch(&v.tags[slot], a.stamp) != a.stamp;
    const float4* d4 = reinterpret_cast<const float4*>(b.features + size_t(r) * F + l * kD);
    const float4 d0 = d4[0], d1 = d4[1];
    float* row = v.grad + size_t(slot) * kD;
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
    // Hopper adds four floats in one atomic: a quarter of the atomic operations, which bound
    // this kernel (8 scalar adds a corner took 75 µs of a 174 µs iteration on an H200).
    float4* row4 = reinterpret_cast<float4*>(row);
    atomicAdd(row4, make_float4(w * d0.x, w * d0.y, w * d0.z, w * d0.w));
    atomicAdd(row4 + 1, make_float4(w * d1.x, w * d1.y, w * d1.z, w * d1.w));
#else
    atomicAdd(row + 0, w * d0.x);
    atomicAdd(row + 1, w * d0.y);
    atomicAdd(row + 2, w * d0.z);
    atomicAdd(row + 3, w * d0.w);
    atomicAdd(row + 4, w * d1.x);
    atomicAdd(row + 5, w * d1.y);
    atomicAdd(row + 6, w * d1.z);
    atomicAdd(row + 7, w * d1.w);
#endif
  }
  const int lane = threadIdx.x & 31;
#pragma unroll
  for (int level = 0; level < L; ++level) {
    const bool mine = fresh && l == level;
    const unsigned lanes = __ballot_sync(0xffffffffu, mine);
    if (lanes == 0) continue;
    const int leader = __ffs(lanes) - 1;
    int base = 0;
    if (lane == leader) base = atomicAdd(&b.counts[level], __popc(lanes));
    base = __shfl_sync(0xffffffffu, base, leader);
    if (mine) g.level[level].touched[base + __popc(lanes & ((1u << lane) - 1u))] = slot;
  }
}

// Lazy Adam on one touched row, with its own step count.
__device__ __forceinline__ void AdamRow(const LevelView& v, const AdamArgs& h, int32_t slot) {
  const int step = ++v.steps[slot];
  // Bias corrections in double, as AdamBiasTable computes them.
  const double b1t = pow(double(h.beta1), step), b2t = pow(double(h.beta2), step);
  const float step_size = float(double(h.lr) / (1.0 - b1t));
  const float inv_sqrt_bc2 = float(1.0 / sqrt(1.0 - b2t));
  // Whole rows in 16-byte loads, all before the first store: element by element, the compiler
  // could not rule out that the four rows overlap and waited for each store before the next load.
  float4* p4 = reinterpret_cast<float4*>(v.features + size_t(slot) * kD);
  float4* m4 = reinterpret_cast<float4*>(v.adam_m + size_t(slot) * kD);
  float4* v4 = reinterpret_cast<float4*>(v.adam_v + size_t(slot) * kD);
  float4* g4 = reinterpret_cast<float4*>(v.grad + size_t(slot) * kD);
  float4 pr[2] = {p4[0], p4[1]}, mr[2] = {m4[0], m4[1]}, vr[2] = {v4[0], v4[1]},
         gr[2] = {g4[0], g4[1]};
  float* pp = reinterpret_cast<float*>(pr);
  float* mm = reinterpret_cast<float*>(mr);
  float* vv = reinterpret_cast<float*>(vr);
  const float* gg = reinterpret_cast<const float*>(gr);
#pragma unroll
  for (int d = 0; d < kD; ++d) {
    mm[d] = h.beta1 * mm[d] + (1.f - h.beta1) * gg[d];
    vv[d] = h.beta2 * vv[d] + (1.f - h.beta2) * gg[d] * gg[d];
    pp[d] -= step_size * mm[d] / (sqrtf(vv[d]) * inv_sqrt_bc2 + h.eps);
  }
  p4[0] = pr[0];
  p4[1] = pr[1];
  m4[0] = mr[0];
  m4[1] = mr[1];
  v4[0] = vr[0];
  v4[1] = vr[1];
  g4[0] = make_float4(0.f, 0.f, 0.f, 0.f);
  g4[1] = make_float4(0.f, 0.f, 0.f, 0.f);
}

__global__ void FeatureAdamKernel(Grids g, AdamArgs h, const int32_t* counts, const int32_t* error,
                                  int32_t* dirty_counts, uint32_t sync_stamp) {
  if (*error != 0) return;
  const int l = blockIdx.y;
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  const LevelView& v = g.level[l];
  const bool live = i < counts[l];
  const int32_t slot = live ? v.touched[i] : 0;
  if (live) AdamRow(v, h, slot);
  if (dirty_counts == nullptr) return;  // the same for the whole grid
  // A row's first update in the sync window lists it for the copy back to the host; the warp's
  // new rows take their places with one atomic add.
  const bool fresh = live && atomicExch(&v.sync_tags[slot], sync_stamp) != sync_stamp;
  const unsigned lanes = __ballot_sync(0xffffffffu, fresh);
  if (lanes == 0) return;
  const int lane = threadIdx.x & 31, leader = __ffs(lanes) - 1;
  int base = 0;
  if (lane == leader) base = atomicAdd(&dirty_counts[l], __popc(lanes));
  base = __shfl_sync(0xffffffffu, base, leader);
  if (fresh) v.dirty[base + __popc(lanes & ((1u << lane) - 1u))] = slot;
}

__global__ void ScatterRowsKernel(LevelView v, PackedRows rows, int n) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int32_t slot = rows.slots[i];
  for (int d = 0; d < kD; ++d) {
    v.features[size_t(slot) * kD + d] = rows.features[size_t(i) * kD + d];
    v.adam_m[size_t(slot) * kD + d] = rows.adam_m[size_t(i) * kD + d];
    v.adam_v[size_t(slot) * kD + d] = rows.adam_v[size_t(i) * kD + d];
  }
  v.steps[slot] = rows.steps[i];
}

__global__ void GatherRowsKernel(LevelView v, PackedRows rows, int n) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int32_t slot = rows.slots[i];
  for (int d = 0; d < kD; ++d) {
    rows.features[size_t(i) * kD + d] = v.features[size_t(slot) * kD + d];
    rows.adam_m[size_t(i) * kD + d] = v.adam_m[size_t(slot) * kD + d];
    rows.adam_v[size_t(i) * kD + d] = v.adam_v[size_t(slot) * kD + d];
  }
  rows.steps[i] = v.steps[slot];
}

__global__ void DecoderAdamKernel(AdamArgs h, float step_size, float inv_sqrt_bc2, int n,
                                  float* params, float* grad, float* m, float* v,
                                  const int32_t* error) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n || *error != 0) return;
  const float gd = grad[i];
  const float md = h.beta1 * m[i] + (1.f - h.beta1) * gd;
  const float vd = h.beta2 * v[i] + (1.f - h.beta2) * gd * gd;
  m[i] = md;
  v[i] = vd;
  params[i] -= step_size * md / (sqrtf(vd) * inv_sqrt_bc2 + h.eps);
  grad[i] = 0.f;
}

// ---- encoding and queries ----

template <int L>
__global__ void EncodeKernel(Grids g, const float* xyz, int n, float* features) {
  constexpr int F = L * kD;
  const int r = blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= n) return;
  const float p[3] = {xyz[3 * r], xyz[3 * r + 1], xyz[3 * r + 2]};
  float x[F];
  const bool inside = EncodePoint<L>(g, p, x);
#pragma unroll
  for (int i = 0; i < F; ++i) features[size_t(r) * F + i] = inside ? x[i] : NAN;
}

// The SDF and, with Grad, its gradient: d sdf / d p = Σ_i (d sdf / d x_i)(d x_i / d p), the
// encoding's derivative taken per corner weight as FeatureReader::Encode does.
template <int L, int H, bool Grad>
__global__ void __launch_bounds__(128) QueryKernel(Grids g, const float* params, const float* xyz,
                                                   int n, float* sdf, float* gradient) {
  constexpr int F = L * kD;
  __shared__ float sp[H * F + 2 * H + 1];
  LoadParams<F, H>(params, sp);
  const int r = blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= n) return;
  const float p[3] = {xyz[3 * r], xyz[3 * r + 1], xyz[3 * r + 2]};
  float x[F], jx[Grad ? F : 1], jy[Grad ? F : 1], jz[Grad ? F : 1];
  bool inside = true;
#pragma unroll
  for (int l = 0; l < L; ++l) {
    const LevelView& v = g.level[l];
    int32_t slot[8];
    float f[3];
    if (!FindCell(v, p, slot, f)) {
      inside = false;
      break;
    }
    const float inv_h = float(v.inv_h);
    float acc[kD] = {}, ax[kD] = {}, ay[kD] = {}, az[kD] = {};
#pragma unroll
    for (int c = 0; c < 8; ++c) {
      const float tx = c & 4 ? f[0] : 1.f - f[0], ty = c & 2 ? f[1] : 1.f - f[1],
                  tz = c & 1 ? f[2] : 1.f - f[2];
      float row[8];
      LoadRow(v.features, slot[c], row);
      const float wc = tx * ty * tz;
#pragma unroll
      for (int d = 0; d < kD; ++d) acc[d] += wc * row[d];
      if (Grad) {
        const float sx = (c & 4 ? 1.f : -1.f) * inv_h, sy = (c & 2 ? 1.f : -1.f) * inv_h,
                    sz = (c & 1 ? 1.f : -1.f) * inv_h;
        const float dwx = sx * ty * tz, dwy = tx * sy * tz, dwz = tx * ty * sz;
#pragma unroll
        for (int d = 0; d < kD; ++d) {
          ax[d] += dwx * row[d];
          ay[d] += dwy * row[d];
          az[d] += dwz * row[d];
        }
      }
    }
#pragma unroll
    for (int d = 0; d < kD; ++d) {
      x[l * kD + d] = acc[d];
      if (Grad) {
        jx[l * kD + d] = ax[d];
        jy[l * kD + d] = ay[d];
        jz[l * kD + d] = az[d];
      }
    }
  }
  if (!inside) {
    sdf[r] = NAN;
    if (Grad) gradient[3 * r] = gradient[3 * r + 1] = gradient[3 * r + 2] = NAN;
    return;
  }
  const float* W0 = sp;
  const float* b0 = sp + H * F;
  const float* w1 = b0 + H;
  float y = w1[H];
  float gx[Grad ? F : 1];
  if (Grad) {
#pragma unroll
    for (int i = 0; i < F; ++i) gx[i] = 0.f;
  }
#pragma unroll
  for (int k = 0; k < H; ++k) {
    float s = b0[k];
#pragma unroll
    for (int i = 0; i < F; ++i) s += W0[k * F + i] * x[i];
    if (s > 0.f) {
      y += w1[k] * s;
      if (Grad) {
#pragma unroll
        for (int i = 0; i < F; ++i) gx[i] += w1[k] * W0[k * F + i];
      }
    }
  }
  sdf[r] = y;
  if (Grad) {
    float d0 = 0.f, d1 = 0.f, d2 = 0.f;
#pragma unroll
    for (int i = 0; i < F; ++i) {
      d0 += gx[i] * jx[i];
      d1 += gx[i] * jy[i];
      d2 += gx[i] * jz[i];
    }
    gradient[3 * r] = d0;
    gradient[3 * r + 1] = d1;
    gradient[3 * r + 2] = d2;
  }
}

__device__ __forceinline__ uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

struct Box {
  double lo[3], hi[3];
};

__global__ void RandomPointsKernel(Box box, int n, uint64_t seed, float* xyz) {
  const int r = blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= n) return;
#pragma unroll
  for (int a = 0; a < 3; ++a) {
    const uint64_t bits = SplitMix64(seed ^ (uint64_t(r) * 3 + a) * 0xD1B54A32D192ED03ull);
    const double u = double(bits >> 11) * (1.0 / 9007199254740992.0);
    xyz[3 * r + a] = float(box.lo[a] + u * (box.hi[a] - box.lo[a]));
  }
}

int Blocks(int64_t n, int threads) { return int((n + threads - 1) / threads); }

}  // namespace

// Instantiated shapes: levels 2–4 × hidden 16, 32, 64 (every preset: 3 × 32).
#define RIM_GPU_SHAPES(CASE) \
  CASE(2, 16)                \
  CASE(2, 32)                \
  CASE(2, 64)                \
  CASE(3, 16)                \
  CASE(3, 32)                \
  CASE(3, 64)                \
  CASE(4, 16)                \
  CASE(4, 32)                \
  CASE(4, 64)

bool ShapeSupported(const MlpShape& s) {
#define RIM_GPU_CASE(L, H) \
  if (s.levels == L && s.hidden == H) return true;
  RIM_GPU_SHAPES(RIM_GPU_CASE)
#undef RIM_GPU_CASE
  return false;
}

int LaunchTrainBackward(const Grids& grids, const MlpShape& shape, const TrainArgs& args,
                        const TrainBuffers& buf, void* stream, void* const* marks) {
  cudaStream_t st = static_cast<cudaStream_t>(stream);
  if (args.rows <= 0) return int(cudaSuccess);
  auto mark = [&](int i) {
    if (marks != nullptr) cudaEventRecord(static_cast<cudaEvent_t>(marks[i]), st);
  };
  CheckPointsKernel<<<Blocks(args.rows, 256), 256, 0, st>>>(grids, args.rows, buf.xyz, buf.error);
  mark(0);
  bool launched = false;
#define RIM_GPU_CASE(L, H)                                                                        \
  if (shape.levels == L && shape.hidden == H) {                                                   \
    TrainForwardKernel<L, H><<<Blocks(args.rows, 128), 128, 0, st>>>(grids, args, buf);           \
    mark(1);                                                                                      \
    const int groups = args.eikonal_weight > 0.f ? (args.rows - args.labelled) / 6 : 0;           \
    if (args.labelled + groups > 0)                                                               \
      LossKernel<<<Blocks(int64_t(args.labelled) + groups, 256), 256, 0, st>>>(args, buf);        \
    mark(2);                                                                                      \
    constexpr int B = BackwardRows<L, H>();                                                       \
    TrainBackwardKernel<L, H><<<Blocks(args.rows, B), B, 0, st>>>(grids, args, buf);              \
    mark(3);                                                                                      \
    ScatterKernel<L><<<Blocks(int64_t(args.rows) * L * kD, 256), 256, 0, st>>>(grids, args, buf); \
    mark(4);                                                                                      \
    launched = true;                                                                              \
  }
  RIM_GPU_SHAPES(RIM_GPU_CASE)
#undef RIM_GPU_CASE
  if (!launched) return int(cudaErrorInvalidValue);
  return int(cudaGetLastError());
}

int LaunchFeatureAdam(const Grids& grids, const AdamArgs& adam, const int32_t* counts, int max_rows,
                      const int32_t* error, int32_t* dirty_counts, uint32_t sync_stamp,
                      void* stream) {
  if (max_rows <= 0) return int(cudaSuccess);
  const dim3 blocks(Blocks(max_rows, 256), grids.levels);
  FeatureAdamKernel<<<blocks, 256, 0, static_cast<cudaStream_t>(stream)>>>(
      grids, adam, counts, error, dirty_counts, sync_stamp);
  return int(cudaGetLastError());
}

int LaunchScatterRows(const LevelView& level, const PackedRows& rows, int n, void* stream) {
  if (n <= 0) return int(cudaSuccess);
  ScatterRowsKernel<<<Blocks(n, 256), 256, 0, static_cast<cudaStream_t>(stream)>>>(level, rows, n);
  return int(cudaGetLastError());
}

int LaunchGatherRows(const LevelView& level, const PackedRows& rows, int n, void* stream) {
  if (n <= 0) return int(cudaSuccess);
  GatherRowsKernel<<<Blocks(n, 256), 256, 0, static_cast<cudaStream_t>(stream)>>>(level, rows, n);
  return int(cudaGetLastError());
}

int LaunchDecoderAdam(const AdamArgs& adam, float step_size, float inv_sqrt_bc2, int n,
                      float* params, float* grad, float* m, float* v, const int32_t* error,
                      void* stream) {
  if (n <= 0) return int(cudaSuccess);
  DecoderAdamKernel<<<Blocks(n, 256), 256, 0, static_cast<cudaStream_t>(stream)>>>(
      adam, step_size, inv_sqrt_bc2, n, params, grad, m, v, error);
  return int(cudaGetLastError());
}

int LaunchEncode(const Grids& grids, const float* xyz, int n, float* features, void* stream) {
  if (n <= 0) return int(cudaSuccess);
  cudaStream_t st = static_cast<cudaStream_t>(stream);
  switch (grids.levels) {
    case 2:
      EncodeKernel<2><<<Blocks(n, 128), 128, 0, st>>>(grids, xyz, n, features);
      break;
    case 3:
      EncodeKernel<3><<<Blocks(n, 128), 128, 0, st>>>(grids, xyz, n, features);
      break;
    case 4:
      EncodeKernel<4><<<Blocks(n, 128), 128, 0, st>>>(grids, xyz, n, features);
      break;
    default:
      return int(cudaErrorInvalidValue);
  }
  return int(cudaGetLastError());
}

int LaunchQuery(const Grids& grids, const MlpShape& shape, const float* params, const float* xyz,
                int n, float* sdf, float* gradient, void* stream) {
  if (n <= 0) return int(cudaSuccess);
  cudaStream_t st = static_cast<cudaStream_t>(stream);
  bool launched = false;
#define RIM_GPU_CASE(L, H)                                                        \
  if (shape.levels == L && shape.hidden == H) {                                   \
    if (gradient != nullptr) {                                                    \
      QueryKernel<L, H, true>                                                     \
          <<<Blocks(n, 128), 128, 0, st>>>(grids, params, xyz, n, sdf, gradient); \
    } else {                                                                      \
      QueryKernel<L, H, false>                                                    \
          <<<Blocks(n, 128), 128, 0, st>>>(grids, params, xyz, n, sdf, gradient); \
    }                                                                             \
    launched = true;                                                              \
  }
  RIM_GPU_SHAPES(RIM_GPU_CASE)
#undef RIM_GPU_CASE
  if (!launched) return int(cudaErrorInvalidValue);
  return int(cudaGetLastError());
}

int LaunchRandomPoints(const double lo[3], const double hi[3], int n, uint64_t seed, float* xyz,
                       void* stream) {
  if (n <= 0) return int(cudaSuccess);
  Box box;
  for (int a = 0; a < 3; ++a) {
    box.lo[a] = lo[a];
    box.hi[a] = hi[a];
  }
  RandomPointsKernel<<<Blocks(n, 256), 256, 0, static_cast<cudaStream_t>(stream)>>>(box, n, seed,
                                                                                    xyz);
  return int(cudaGetLastError());
}

}  // namespace rim::gpu
