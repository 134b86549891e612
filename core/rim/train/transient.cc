#include "rim/train/transient.h"

#if defined(__x86_64__)
#include <immintrin.h>
#define RIM_TRANSIENT_AVX2 1
#endif

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <tuple>

namespace rim {
namespace {

constexpr float kPi = 3.14159265358979323846f;
constexpr float kInf = std::numeric_limits<float>::infinity();
// Window half-widths are capped (a point 0.3 m away with window_min_m 0.15 m would ask for ±67
// bins of 0.4°): wider than this the window only costs time.
constexpr int kMaxWindowBins = 16;

// atan(x) for |x| <= 1, within 2e-8 rad (Abramowitz and Stegun 4.4.49): a range image bins
// about 100k returns and as many buffered points a frame, where std::atan2 would cost more than
// the rest of the judgement.
inline float AtanUnit(float x) {
  const float x2 = x * x;
  float p = 0.0028662257f;
  p = p * x2 - 0.0161657367f;
  p = p * x2 + 0.0429096138f;
  p = p * x2 - 0.0752896400f;
  p = p * x2 + 0.1065626393f;
  p = p * x2 - 0.1420889944f;
  p = p * x2 + 0.1999355085f;
  p = p * x2 - 0.3333314528f;
  return x + x * x2 * p;
}

inline float FastAtan2(float y, float x) {
  const float ax = std::abs(x), ay = std::abs(y);
  if (ax == 0.f && ay == 0.f) return 0.f;
  float a = ay <= ax ? AtanUnit(ay / ax) : 0.5f * kPi - AtanUnit(ax / ay);
  if (x < 0.f) a = kPi - a;
  return y < 0.f ? -a : a;
}

#ifdef RIM_TRANSIENT_AVX2
// FastAtan2 of eight pairs: the same operations in the same order (products and sums rounded one
// by one: no fused multiply-add), so the same bits as the scalar function.
__attribute__((target("avx2"))) inline __m256 FastAtan2x8(__m256 y, __m256 x) {
  const __m256 sign = _mm256_set1_ps(-0.f), zero = _mm256_setzero_ps();
  const __m256 ax = _mm256_andnot_ps(sign, x), ay = _mm256_andnot_ps(sign, y);
  const __m256 le = _mm256_cmp_ps(ay, ax, _CMP_LE_OQ);
  const __m256 t = _mm256_div_ps(_mm256_blendv_ps(ax, ay, le), _mm256_blendv_ps(ay, ax, le));
  const __m256 t2 = _mm256_mul_ps(t, t);
  __m256 p = _mm256_set1_ps(0.0028662257f);
  p = _mm256_sub_ps(_mm256_mul_ps(p, t2), _mm256_set1_ps(0.0161657367f));
  p = _mm256_add_ps(_mm256_mul_ps(p, t2), _mm256_set1_ps(0.0429096138f));
  p = _mm256_sub_ps(_mm256_mul_ps(p, t2), _mm256_set1_ps(0.0752896400f));
  p = _mm256_add_ps(_mm256_mul_ps(p, t2), _mm256_set1_ps(0.1065626393f));
  p = _mm256_sub_ps(_mm256_mul_ps(p, t2), _mm256_set1_ps(0.1420889944f));
  p = _mm256_add_ps(_mm256_mul_ps(p, t2), _mm256_set1_ps(0.1999355085f));
  p = _mm256_sub_ps(_mm256_mul_ps(p, t2), _mm256_set1_ps(0.3333314528f));
  const __m256 u = _mm256_add_ps(t, _mm256_mul_ps(_mm256_mul_ps(t, t2), p));
  __m256 a = _mm256_blendv_ps(_mm256_sub_ps(_mm256_set1_ps(0.5f * kPi), u), u, le);
  a = _mm256_blendv_ps(a, _mm256_sub_ps(_mm256_set1_ps(kPi), a),
                       _mm256_cmp_ps(x, zero, _CMP_LT_OQ));
  a = _mm256_blendv_ps(a, _mm256_xor_ps(a, sign), _mm256_cmp_ps(y, zero, _CMP_LT_OQ));
  const __m256 both_zero =
      _mm256_and_ps(_mm256_cmp_ps(ax, zero, _CMP_EQ_OQ), _mm256_cmp_ps(ay, zero, _CMP_EQ_OQ));
  return _mm256_blendv_ps(a, zero, both_zero);
}
#endif

// int(std::floor(d)) for |d| < 2^31, without a call into the maths library (the baseline x86-64
// target has no rounding instruction).
inline int FloorToInt(double d) {
  const int i = int(d);
  return i - (d < double(i));
}

// 1 / v for every range v a range image holds (0.01 · centimetres, in float, as At() reads it),
// in double: a lookup instead of a division per bin of a judgement's window.
const double* InverseRanges() {
  static const std::vector<double> table = [] {
    std::vector<double> t(size_t(RangeImage::empty_cm()) + 1, 0.0);
    for (size_t cm = 1; cm < t.size(); ++cm) t[cm] = 1.0 / double(0.01f * float(cm));
    return t;
  }();
  return table.data();
}

}  // namespace

RangeImage::RangeImage(float bin_deg) {
  const float bin_rad = bin_deg * kPi / 180.f;
  inv_bin_rad_ = 1.f / bin_rad;
  na_ = int(std::ceil(2.f * kPi / bin_rad));
  ne_ = int(std::ceil(kPi / bin_rad));
}

void RangeImage::PlaceOf(const Vec3f& d, float* azimuth, float* elevation) const {
  const float az = FastAtan2(d.y(), d.x());
  const float el = FastAtan2(d.z(), std::sqrt(d.x() * d.x() + d.y() * d.y()));
  float a = (az + kPi) * inv_bin_rad_;
  if (a >= float(na_)) a -= float(na_);
  *azimuth = std::max(a, 0.f);
  *elevation = std::clamp((el + 0.5f * kPi) * inv_bin_rad_, 0.f, float(ne_) - 1e-3f);
}

#ifdef RIM_TRANSIENT_AVX2
__attribute__((target("avx2"))) void RangeImage::Place8Avx2(const Vec3f* p, float* range,
                                                            float* azimuth,
                                                            float* elevation) const {
  alignas(32) float xs[8], ys[8], zs[8];
  for (int l = 0; l < 8; ++l) {
    xs[l] = p[l].x();
    ys[l] = p[l].y();
    zs[l] = p[l].z();
  }
  const __m256 x = _mm256_load_ps(xs), y = _mm256_load_ps(ys), z = _mm256_load_ps(zs);
  const __m256 xy2 = _mm256_add_ps(_mm256_mul_ps(x, x), _mm256_mul_ps(y, y));
  _mm256_storeu_ps(range, _mm256_sqrt_ps(_mm256_add_ps(xy2, _mm256_mul_ps(z, z))));
  const __m256 az = FastAtan2x8(y, x), el = FastAtan2x8(z, _mm256_sqrt_ps(xy2));
  const __m256 inv = _mm256_set1_ps(inv_bin_rad_), na = _mm256_set1_ps(float(na_));
  __m256 a = _mm256_mul_ps(_mm256_add_ps(az, _mm256_set1_ps(kPi)), inv);
  a = _mm256_blendv_ps(a, _mm256_sub_ps(a, na), _mm256_cmp_ps(a, na, _CMP_GE_OQ));
  _mm256_storeu_ps(azimuth, _mm256_max_ps(a, _mm256_setzero_ps()));
  const __m256 e = _mm256_mul_ps(_mm256_add_ps(el, _mm256_set1_ps(0.5f * kPi)), inv);
  _mm256_storeu_ps(elevation, _mm256_min_ps(_mm256_max_ps(e, _mm256_setzero_ps()),
                                            _mm256_set1_ps(float(ne_) - 1e-3f)));
}
#endif

#ifdef RIM_TRANSIENT_AVX2
__attribute__((target("avx2"))) void RangeImage::Bin8Avx2(const Vec3f* p, float min_range_m,
                                                          float max_range_m, uint32_t* bins,
                                                          uint16_t* offsets, uint16_t* ranges_cm,
                                                          int* lo, int* hi) const {
  alignas(32) float rs[8], fas[8], fes[8];
  Place8Avx2(p, rs, fas, fes);
  const __m256 r = _mm256_load_ps(rs), fa = _mm256_load_ps(fas), fe = _mm256_load_ps(fes);
  // Binned: 0 < r <= max_range_m (false for NaN, as the scalar test).
  const __m256 binned = _mm256_and_ps(_mm256_cmp_ps(r, _mm256_setzero_ps(), _CMP_GT_OQ),
                                      _mm256_cmp_ps(r, _mm256_set1_ps(max_range_m), _CMP_LE_OQ));
  const __m256i a = _mm256_min_epi32(_mm256_cvttps_epi32(fa), _mm256_set1_epi32(na_ - 1));
  const __m256i e = _mm256_min_epi32(_mm256_cvttps_epi32(fe), _mm256_set1_epi32(ne_ - 1));
  const __m256i bin = _mm256_or_si256(_mm256_slli_epi32(e, 16), a);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(bins),
                      _mm256_blendv_epi8(_mm256_set1_epi32(-1), bin, _mm256_castps_si256(binned)));
  const __m256 k256 = _mm256_set1_ps(256.f);
  const __m256i max255 = _mm256_set1_epi32(255);
  const __m256i oe = _mm256_min_epi32(
      _mm256_cvttps_epi32(_mm256_mul_ps(_mm256_sub_ps(fe, _mm256_cvtepi32_ps(e)), k256)), max255);
  const __m256i oa = _mm256_min_epi32(
      _mm256_cvttps_epi32(_mm256_mul_ps(_mm256_sub_ps(fa, _mm256_cvtepi32_ps(a)), k256)), max255);
  const __m256i offset = _mm256_or_si256(_mm256_slli_epi32(oe, 8), oa);
  const __m256i cm = _mm256_andnot_si256(
      _mm256_castps_si256(_mm256_cmp_ps(r, _mm256_set1_ps(min_range_m), _CMP_LT_OQ)),
      _mm256_cvttps_epi32(_mm256_min_ps(_mm256_mul_ps(_mm256_set1_ps(100.f), r),
                                        _mm256_set1_ps(float(kEmpty - 1)))));
  // To 16 bits (every value fits): pack, then put the two halves side by side.
  _mm_storeu_si128(
      reinterpret_cast<__m128i*>(offsets),
      _mm256_castsi256_si128(_mm256_permute4x64_epi64(_mm256_packus_epi32(offset, offset), 0x08)));
  _mm_storeu_si128(
      reinterpret_cast<__m128i*>(ranges_cm),
      _mm256_castsi256_si128(_mm256_permute4x64_epi64(_mm256_packus_epi32(cm, cm), 0x08)));
  const int mask = _mm256_movemask_ps(binned);
  if (mask != 0) {
    alignas(32) int32_t es[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(es), e);
    for (int l = 0; l < 8; ++l) {
      if (!(mask >> l & 1)) continue;
      *lo = std::min(*lo, es[l]);
      *hi = std::max(*hi, es[l]);
    }
  }
}
#endif

void RangeImage::Place8(const Vec3f* p, float* range, float* azimuth, float* elevation) const {
#ifdef RIM_TRANSIENT_AVX2
  static const bool avx2 = __builtin_cpu_supports("avx2");
  if (avx2) return Place8Avx2(p, range, azimuth, elevation);
#endif
  for (int l = 0; l < 8; ++l) {
    range[l] = p[l].norm();
    PlaceOf(p[l], &azimuth[l], &elevation[l]);
  }
}

void RangeImage::BinOf(const Vec3f& d, int* azimuth, int* elevation) const {
  const float az = FastAtan2(d.y(), d.x());                                     // (−π, π]
  const float el = FastAtan2(d.z(), std::sqrt(d.x() * d.x() + d.y() * d.y()));  // [−π/2, π/2]
  int a = int((az + kPi) * inv_bin_rad_);
  int e = int((el + 0.5f * kPi) * inv_bin_rad_);
  *azimuth = a >= na_ ? a - na_ : a;
  *elevation = std::clamp(e, 0, ne_ - 1);
}

void RangeImage::Fill(const std::vector<Vec3f>& points_S, float min_range_m, float max_range_m,
                      WorkerPool* pool, float fired_row_share, Scratch* external) {
  const size_t n = points_S.size();
  Scratch& own = external ? *external : scratch_;
  std::vector<uint32_t>& scratch = own.bins;
  std::vector<uint16_t>& scratch_offset = own.offsets;
  scratch.resize(n);
  scratch_offset.resize(n);
  // The bins (two arctangents a point, most of the cost) in pieces over the pool, eight points at
  // a time where the processor has AVX2 (the same bits either way).
  std::vector<uint16_t>& scratch_cm = own.ranges_cm;
  scratch_cm.resize(n);
  constexpr int kPieces = 4;
  int piece_lo[kPieces], piece_hi[kPieces];
#ifdef RIM_TRANSIENT_AVX2
  static const bool avx2 = __builtin_cpu_supports("avx2");
#endif
  auto piece = [&](int k) {
    int lo = ne_, hi = -1;
    const size_t end = n * size_t(k + 1) / kPieces;
    size_t i = n * size_t(k) / kPieces;
    // One point from its range and place: its bin, its place in it and its range in centimetres.
    auto bin = [&](size_t j, float r, float fa, float fe) {
      scratch[j] = ~0u;
      if (!(r > 0.f && r <= max_range_m)) return;
      const int a = std::min(int(fa), na_ - 1), e = std::min(int(fe), ne_ - 1);
      scratch[j] = uint32_t(e) << 16 | uint32_t(a);
      scratch_offset[j] = uint16_t(std::min(int((fe - float(e)) * 256.f), 255) << 8 |
                                   std::min(int((fa - float(a)) * 256.f), 255));
      scratch_cm[j] = r < min_range_m ? 0 : uint16_t(std::min(100.f * r, float(kEmpty - 1)));
      lo = std::min(lo, e);
      hi = std::max(hi, e);
    };
#ifdef RIM_TRANSIENT_AVX2
    if (avx2) {
      for (; i + 8 <= end; i += 8)
        Bin8Avx2(&points_S[i], min_range_m, max_range_m, &scratch[i], &scratch_offset[i],
                 &scratch_cm[i], &lo, &hi);
    }
#endif
    for (; i < end; ++i) {
      float fa = 0.f, fe = 0.f;
      const float r = points_S[i].norm();
      if (r > 0.f && r <= max_range_m) PlaceOf(points_S[i], &fa, &fe);
      bin(i, r, fa, fe);
    }
    piece_lo[k] = lo;
    piece_hi[k] = hi;
  };
  if (pool && n >= 4096) {
    pool->Run(kPieces, piece);
  } else {
    for (int k = 0; k < kPieces; ++k) piece(k);
  }
  const int lo = *std::min_element(piece_lo, piece_lo + kPieces);
  const int hi = *std::max_element(piece_hi, piece_hi + kPieces);
  first_row_ = lo;
  rows_ = std::max(0, hi - lo + 1);
  // kRowSlack bins past the last row: a window's row is read in eight-bin loads that may run
  // past its end (and past the image's), into bins that are then not used.
  range_cm_.resize(size_t(rows_) * na_ + kRowSlack);
  offset_.resize(size_t(rows_) * na_ + kRowSlack);
  std::fill(range_cm_.end() - kRowSlack, range_cm_.end(), kEmpty);
  std::fill(offset_.end() - kRowSlack, offset_.end(), uint16_t(0));
  // The nearest return per bin, the first of equals in the points' order, in bands of rows over
  // the pool: each band reads every point and writes only its own rows.
  constexpr int kBands = 2;
  auto band = [&](int k) {
    const int row_lo = rows_ * k / kBands, row_hi = rows_ * (k + 1) / kBands;
    std::fill(range_cm_.begin() + ptrdiff_t(row_lo) * na_,
              range_cm_.begin() + ptrdiff_t(row_hi) * na_, kEmpty);
    std::fill(offset_.begin() + ptrdiff_t(row_lo) * na_, offset_.begin() + ptrdiff_t(row_hi) * na_,
              uint16_t(0));
    const uint32_t e_lo = uint32_t(first_row_ + row_lo), e_hi = uint32_t(first_row_ + row_hi);
    for (size_t i = 0; i < n; ++i) {
      const uint32_t e = scratch[i] >> 16;  // 0xffff when not binned
      if (e < e_lo || e >= e_hi) continue;
      const uint16_t cm = scratch_cm[i];
      const size_t slot = size_t(e - uint32_t(first_row_)) * na_ + (scratch[i] & 0xffff);
      if (cm < range_cm_[slot]) {
        range_cm_[slot] = cm;
        offset_[slot] = scratch_offset[i];
      }
    }
  };
  if (pool && n >= 4096) {
    pool->Run(kBands, band);
  } else {
    for (int k = 0; k < kBands; ++k) band(k);
  }
  // Rows the sensor fired along: a spinning sensor's rings fill most of their row (a city scan's
  // fill 60-100 % of theirs); rows between its rings hold none.
  empty_range_m_ = max_range_m;
  fired_.assign(size_t(rows_), 0);
  blocked_.assign(size_t(rows_), 0);
  const int enough = std::max(1, int(std::ceil(fired_row_share * float(na_))));
  for (int row = 0; row < rows_; ++row) {
    const uint16_t* line = &range_cm_[size_t(row) * na_];
    fired_[size_t(row)] =
        std::count_if(line, line + na_, [](uint16_t v) { return v != kEmpty; }) >= enough;
    blocked_[size_t(row)] = std::find(line, line + na_, uint16_t(0)) != line + na_;
  }
}

namespace {

// A judgement's window (JudgePlaced): p's range and place in the image, its window's half-widths
// in bins, and the thresholds.
struct WindowQuery {
  float r, fa, fe, cos_el, beyond, near2, bin_m2;
  int a0, e0, wa, we;
  bool empty_is_free;
};

// The sums of the plane fit: least squares of 1/range = t0 + t1·x + t2·y over a window's returns,
// x and y their angular offsets from the point in bins (azimuth scaled by cos(elevation)), in
// double.
struct PlaneSums {
  double s1 = 0, sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0, sz = 0, sxz = 0, syz = 0, szz = 0;
  // One return at (x, y) with z = 1/range.
  void Add(float x, float y, double z) {
    s1 += 1;
    sx += x;
    sy += y;
    sxx += double(x) * x;
    sxy += double(x) * y;
    syy += double(y) * y;
    sz += z;
    sxz += x * z;
    syz += y * z;
    szz += z * z;
  }
};

// What reading the window found: a verdict when a bin decided it (a blocked bin: kept; a return
// within `near` of p: something there; the first such bin in the window's order), else the sides
// of p that returns (or, along fired rows, empty bins) lie on, whether all of them end beyond p,
// and the plane's sums over its returns.
struct WindowScan {
  bool decided = false;
  Verdict verdict = Verdict::kKept;
  bool left = false, right = false, below = false, above = false, all_beyond = true;
  PlaneSums sums;
};

// The k-th offset of the window's order from its centre: 0, −1, +1, −2, +2, ...
inline int Outwards(int k) { return k & 1 ? -(k + 1) / 2 : k / 2; }

// The window's first k_end rows one bin at a time, from p's own bin outwards, row by row (0, −1,
// +1, ...) and so within each row: a static point the scan sees has a return about its range at
// or next to its own bin, and is let go after a look or two. Adds to *sums_out; true when a bin
// decided the verdict.
bool ScanRowsScalar(const RangeImage& image, const WindowQuery& q, int k_end, WindowScan* w,
                    PlaneSums* sums_out) {
  const int ne = image.elevation_bins(), na = image.azimuth_bins();
  const float empty_range = image.empty_range_m();
  const double* inv_range = InverseRanges();
  PlaneSums sums = *sums_out;  // a local (stores through `w` could alias the inverse ranges)
  for (int k = 0; k < k_end; ++k) {
    const int de = Outwards(k);
    const int e = q.e0 + de;
    if (e < 0 || e >= ne) continue;
    // A row without returns holds only empty bins, and the sensor did not fire along it.
    const uint16_t* ranges = image.RangeRow(e);
    if (ranges == nullptr) continue;
    const uint16_t* places = image.OffsetRow(e);
    const bool fired = q.empty_is_free && image.Fired(e);
    for (int j = 0; j <= 2 * q.wa; ++j) {
      const int da = Outwards(j);
      int a = q.a0 + da;
      if (a < 0) a += na;
      if (a >= na) a -= na;
      const uint16_t cm = ranges[a];
      if (cm == 0) {  // blocked near the sensor
        w->decided = true;
        w->verdict = Verdict::kKept;
        return true;
      }
      if (cm == RangeImage::empty_cm()) {
        // Nothing came back: evidence only along a row the sensor fired, and only for `all_beyond`.
        if (!fired) continue;
        w->all_beyond &= empty_range >= q.beyond;
        w->left |= da < 0;
        w->right |= da > 0;
        w->below |= de < 0;
        w->above |= de > 0;
        continue;
      }
      const float v = 0.01f * float(cm);  // AtWrapped's value
      const uint16_t o = places[a];       // OffsetAt's decoding
      const float oa = (float(o & 0xff) + 0.5f) * (1.f / 256.f);
      const float oe = (float(o >> 8) + 0.5f) * (1.f / 256.f);
      const float x = (float(q.a0 + da) + oa - q.fa) * q.cos_el, y = (float(e) + oe - q.fe);
      // Something still there: a return within `near` of p.
      const float dr = v - q.r;
      if (q.bin_m2 * (x * x + y * y) + dr * dr < q.near2) {
        w->decided = true;
        w->verdict = Verdict::kSomethingThere;
        return true;
      }
      w->all_beyond &= v >= q.beyond;
      w->left |= x < 0.f;
      w->right |= x > 0.f;
      w->below |= y < 0.f;
      w->above |= y > 0.f;
      sums.Add(x, y, inv_range[cm]);
    }
  }
  *sums_out = sums;
  return false;
}

// The whole window that way: the reference that ScanWindowAvx2 must equal.
void ScanWindowScalar(const RangeImage& image, const WindowQuery& q, WindowScan* w) {
  PlaneSums sums;
  if (!ScanRowsScalar(image, q, 2 * q.we + 1, w, &sums)) w->sums = sums;
}

#ifdef RIM_TRANSIENT_AVX2
// ScanWindowScalar with the rows after p's own eight bins at a time: the same verdict, flags and
// sums to the bit. The own row is read one bin at a time as ScanWindowScalar reads it (most
// judgements that end early end there). In the other rows each bin's values come from the same
// float operations (no fused multiply-add), a row's first deciding bin is found in the window's
// order, and the sums are added in that order. The rows are read where they lie in the image (a
// copy first made each load wait on the copy's stores). On the synthetic cities this saves about
// 0.5 ms of a frame's filter; on the sparse images of the campus scans it makes no difference
// beyond the host's noise (docs/perf-log.md, "Moving things: the window a row at a time").
__attribute__((target("avx2"))) void ScanWindowAvx2(const RangeImage& image, const WindowQuery& q,
                                                    WindowScan* w) {
  const int ne = image.elevation_bins(), na = image.azimuth_bins();
  const int n = 2 * q.wa + 1;  // bins a row, at most 2 · kMaxWindowBins + 1
  const int vectors = (n + 7) / 8;
  constexpr int kRow = 2 * kMaxWindowBins + 1, kPadded = (kRow + 7) / 8 * 8;
  alignas(32) uint16_t cms[kPadded] = {}, places[kPadded] = {};
  alignas(32) float xs[kPadded], ys[kPadded];
  // The row's bins in the window's order (indices into the row from its left end, −wa).
  int order[kRow];
  for (int j = 0; j < n; ++j) order[j] = q.wa + Outwards(j);
  const float empty_range = image.empty_range_m();
  const double* inv_range = InverseRanges();
  PlaneSums sums;  // a local (stores through `w` could alias the inverse ranges), kept at the end
  // p's own row one bin at a time, as ScanWindowScalar reads it: most judgements that end early
  // end there (a return at the point, or a blocked bin), after a bin or two, where a row of
  // vectors would read them all.
  if (ScanRowsScalar(image, q, 1, w, &sums)) return;
  const int a_left = q.a0 - q.wa;  // the unwrapped azimuth of the row's left end
  const bool wraps = a_left < 0 || a_left + n > na;
  const __m256i lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i empty16 = _mm256_set1_epi32(RangeImage::empty_cm()),
                zero_i = _mm256_setzero_si256();
  const __m256i byte = _mm256_set1_epi32(0xff);
  const __m256 zero = _mm256_setzero_ps(), half = _mm256_set1_ps(0.5f),
               inv256 = _mm256_set1_ps(1.f / 256.f), cm_to_m = _mm256_set1_ps(0.01f);
  const __m256 fa = _mm256_set1_ps(q.fa), fe = _mm256_set1_ps(q.fe),
               cos_el = _mm256_set1_ps(q.cos_el), r = _mm256_set1_ps(q.r),
               near2 = _mm256_set1_ps(q.near2), bin_m2 = _mm256_set1_ps(q.bin_m2),
               beyond = _mm256_set1_ps(q.beyond);
  // Sides and ends of the returns, lane-wise, reduced at the end.
  __m256 left = zero, right = zero, below = zero, above = zero, short_of = zero;
  bool empty_left = false, empty_right = false, empty_below = false, empty_above = false,
       empty_short = false;
  for (int k = 1; k <= 2 * q.we; ++k) {
    const int de = Outwards(k);
    const int e = q.e0 + de;
    if (e < 0 || e >= ne) continue;
    const uint16_t* row = image.RangeRow(e);
    if (row == nullptr) continue;
    const uint16_t* row_places = image.OffsetRow(e);
    // The row's bins: read in place (loads past the window's end land in the next bins, or in
    // the image's slack past its last row), or copied where the window wraps round the azimuth.
    const uint16_t* row_cms = row + a_left;
    const uint16_t* row_offsets = row_places + a_left;
    if (wraps) {
      row_cms = cms;
      row_offsets = places;
      for (int i = 0; i < n; ++i) {
        int a = a_left + i;
        if (a < 0) a += na;
        if (a >= na) a -= na;
        cms[i] = row[a];
        places[i] = row_places[a];
      }
    }
    const __m256 y_row = _mm256_set1_ps(float(e));
    uint64_t blocked_bits = 0, near_bits = 0, return_bits = 0, empty_bits = 0;  // a bit a bin
    for (int v = 0; v < vectors; ++v) {
      const __m256i index = _mm256_add_epi32(lanes, _mm256_set1_epi32(8 * v));
      const __m256i valid = _mm256_cmpgt_epi32(_mm256_set1_epi32(n), index);
      const __m256i cm =
          _mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(row_cms + 8 * v)));
      const __m256i o = _mm256_cvtepu16_epi32(
          _mm_loadu_si128(reinterpret_cast<const __m128i*>(row_offsets + 8 * v)));
      const __m256i empty = _mm256_and_si256(valid, _mm256_cmpeq_epi32(cm, empty16));
      const __m256i blocked = _mm256_and_si256(valid, _mm256_cmpeq_epi32(cm, zero_i));
      const __m256 ret =
          _mm256_castsi256_ps(_mm256_andnot_si256(_mm256_or_si256(empty, blocked), valid));
      const __m256 range = _mm256_mul_ps(cm_to_m, _mm256_cvtepi32_ps(cm));
      const __m256 oa =
          _mm256_mul_ps(_mm256_add_ps(_mm256_cvtepi32_ps(_mm256_and_si256(o, byte)), half), inv256);
      const __m256 oe =
          _mm256_mul_ps(_mm256_add_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32(o, 8)), half), inv256);
      const __m256 az = _mm256_cvtepi32_ps(_mm256_add_epi32(index, _mm256_set1_epi32(a_left)));
      const __m256 x = _mm256_mul_ps(_mm256_sub_ps(_mm256_add_ps(az, oa), fa), cos_el);
      const __m256 y = _mm256_sub_ps(_mm256_add_ps(y_row, oe), fe);
      const __m256 dr = _mm256_sub_ps(range, r);
      const __m256 d2 = _mm256_add_ps(
          _mm256_mul_ps(bin_m2, _mm256_add_ps(_mm256_mul_ps(x, x), _mm256_mul_ps(y, y))),
          _mm256_mul_ps(dr, dr));
      const __m256 near = _mm256_and_ps(ret, _mm256_cmp_ps(d2, near2, _CMP_LT_OQ));
      blocked_bits |= uint64_t(_mm256_movemask_ps(_mm256_castsi256_ps(blocked))) << (8 * v);
      near_bits |= uint64_t(_mm256_movemask_ps(near)) << (8 * v);
      return_bits |= uint64_t(_mm256_movemask_ps(ret)) << (8 * v);
      empty_bits |= uint64_t(_mm256_movemask_ps(_mm256_castsi256_ps(empty))) << (8 * v);
      left = _mm256_or_ps(left, _mm256_and_ps(ret, _mm256_cmp_ps(x, zero, _CMP_LT_OQ)));
      right = _mm256_or_ps(right, _mm256_and_ps(ret, _mm256_cmp_ps(x, zero, _CMP_GT_OQ)));
      below = _mm256_or_ps(below, _mm256_and_ps(ret, _mm256_cmp_ps(y, zero, _CMP_LT_OQ)));
      above = _mm256_or_ps(above, _mm256_and_ps(ret, _mm256_cmp_ps(y, zero, _CMP_GT_OQ)));
      // Not v >= beyond (no range is NaN).
      short_of =
          _mm256_or_ps(short_of, _mm256_and_ps(ret, _mm256_cmp_ps(range, beyond, _CMP_LT_OQ)));
      _mm256_store_ps(xs + 8 * v, x);
      _mm256_store_ps(ys + 8 * v, y);
    }
    if ((blocked_bits | near_bits) != 0) {
      // The row's first deciding bin in the window's order: the earlier rows had none.
      for (int j = 0; j < n; ++j) {
        const int i = order[j];
        if (blocked_bits >> i & 1) {
          w->decided = true;
          w->verdict = Verdict::kKept;
          return;
        }
        if (near_bits >> i & 1) {
          w->decided = true;
          w->verdict = Verdict::kSomethingThere;
          return;
        }
      }
    }
    if (empty_bits != 0 && q.empty_is_free && image.Fired(e)) {
      // Empty bins of a fired row: returns at the scan's range, on their side of p's column.
      empty_short |= !(empty_range >= q.beyond);
      empty_left |= (empty_bits & ((uint64_t(1) << q.wa) - 1)) != 0;
      empty_right |= (empty_bits >> (q.wa + 1)) != 0;
      empty_below |= de < 0;
      empty_above |= de > 0;
    }
    // The sums, in the window's order: the returns' indices first, without a branch a bin.
    int ret_order[kRow];
    int m = 0;
    for (int j = 0; j < n; ++j) {
      ret_order[m] = order[j];
      m += int(return_bits >> order[j] & 1);
    }
    for (int t = 0; t < m; ++t) {
      const int i = ret_order[t];
      sums.Add(xs[i], ys[i], inv_range[row_cms[i]]);
    }
  }
  // With the own row's, which ScanRowsScalar left in *w.
  w->left |= _mm256_movemask_ps(left) != 0 || empty_left;
  w->right |= _mm256_movemask_ps(right) != 0 || empty_right;
  w->below |= _mm256_movemask_ps(below) != 0 || empty_below;
  w->above |= _mm256_movemask_ps(above) != 0 || empty_above;
  w->all_beyond &= _mm256_movemask_ps(short_of) == 0 && !empty_short;
  w->sums = sums;
}
#endif

// Judge, for p_S at range r and place (fa, fe) in the image (RangeImage::PlaceOf); `reference`: the
// window read one bin at a time (ScanWindowScalar) even where the processor has AVX2.
Verdict JudgePlaced(const RangeImage& image, const TransientConfig& c, const Vec3f& p_S, float r,
                    float fa, float fe, bool reference = false) {
  if (!(r >= c.min_range_m && r <= c.max_range_m)) return Verdict::kKept;
  const float beyond = r + c.margin_m + c.margin_per_m * r;
  const int a0 = int(fa), e0 = int(fe);
  // The window: so many bins, and at least window_min_m each side at the point's range (in
  // azimuth at its distance from the sensor's vertical axis).
  const float r_xy = std::max(std::sqrt(p_S.x() * p_S.x() + p_S.y() * p_S.y()), 0.1f);
  const float cos_el = r_xy / std::max(r, 1e-6f);
  const int wa = std::min(
      kMaxWindowBins, std::max(c.window_azimuth_bins, image.BinsSpanning(c.window_min_m / r_xy)));
  const int we = std::min(
      kMaxWindowBins, std::max(c.window_elevation_bins, image.BinsSpanning(c.window_min_m / r)));
  // A return this near p (in metres, squared): something is still there.
  const float bin_m = image.bin_rad() * r;
  const float near = c.near_m + c.near_bins * bin_m;
  const float near2 = near * near, bin_m2 = bin_m * bin_m;
  const int ne = image.elevation_bins(), na = image.azimuth_bins();
  // Hidden: the returns of p's own azimuth column just below, at and just above its elevation end
  // in front of it by the margin and twice the misfit a plane is allowed. No return of the window
  // can then be beyond p by the margin along p's own ray, nor can a plane that fits them pass
  // behind p: the verdict (kept) needs no more of the window. About a sixth of all judgements end
  // here (17-18 % on two cities), mostly deferred rays and departed points behind parked cars
  // and walls.
  if (we >= 1) {
    const float front = r - (beyond - r) - 2.f * (c.fit_rms_m + c.fit_rms_per_m * r);
    int in_front = 0;
    for (int e = e0 - 1; e <= e0 + 1 && e >= 0 && e < ne; ++e) {
      const float v = image.AtWrapped(a0, e);
      if (!(v > 0.f && v < front)) break;
      ++in_front;
    }
    if (in_front == 3) return Verdict::kKept;
  }
  // Outside the scan's rows: when p's own row and every row below it (or above it) hold no
  // returns, nothing below (above) p can be seen, its window never has returns on both sides in
  // elevation, and the verdict is kept, unless the window's scan below meets a return within
  // `near` of p (something there) or a blocked bin first. Without blocked bins in the window's
  // rows only the bins within `near` can decide it, and only they are read: the same verdict. These
  // are mostly points beside the sensor, below its lowest ring, whose windows are the widest.
  const int rows_lo = image.first_row(), rows_hi = rows_lo + image.rows() - 1;
  if (e0 < rows_lo || e0 > rows_hi) {
    bool blocked = false;
    for (int e = std::max(e0 - we, rows_lo); e <= std::min(e0 + we, rows_hi); ++e)
      blocked |= image.RowBlocked(e);
    if (!blocked) {
      // A return within `near` lies less than reach bins from p in both directions.
      const float reach = near / bin_m;
      const int de_max = std::min(we, int(std::ceil(reach)) + 1);
      const int da_max = std::min(wa, int(std::ceil(reach / std::max(cos_el, 1e-6f))) + 1);
      for (int e = std::max(e0 - de_max, rows_lo); e <= std::min(e0 + de_max, rows_hi); ++e) {
        const uint16_t* ranges = image.RangeRow(e);
        const uint16_t* places = image.OffsetRow(e);
        for (int da = -da_max; da <= da_max; ++da) {
          int a = a0 + da;
          if (a < 0) a += na;
          if (a >= na) a -= na;
          const uint16_t cm = ranges[a];
          if (cm == RangeImage::empty_cm()) continue;
          const float v = 0.01f * float(cm);
          const uint16_t o = places[a];
          const float oa = (float(o & 0xff) + 0.5f) * (1.f / 256.f);
          const float oe = (float(o >> 8) + 0.5f) * (1.f / 256.f);
          const float x = (float(a0 + da) + oa - fa) * cos_el, y = (float(e) + oe - fe);
          const float dr = v - r;
          if (bin_m2 * (x * x + y * y) + dr * dr < near2) return Verdict::kSomethingThere;
        }
      }
      return Verdict::kKept;
    }
  }
  // The rest of the window: a deciding bin, or the sides, ends and plane sums of its returns.
  const WindowQuery q{r, fa, fe, cos_el, beyond, near2, bin_m2, a0, e0, wa, we, c.empty_is_free};
  WindowScan w;
#ifdef RIM_TRANSIENT_AVX2
  static const bool avx2 = __builtin_cpu_supports("avx2");
  if (avx2 && !reference) {
    ScanWindowAvx2(image, q, &w);
  } else {
    ScanWindowScalar(image, q, &w);
  }
#else
  (void)reference;
  ScanWindowScalar(image, q, &w);
#endif
  if (w.decided) return w.verdict;
  const bool left = w.left, right = w.right, below = w.below, above = w.above;
  const bool all_beyond = w.all_beyond;
  const PlaneSums& f = w.sums;
  const double s1 = f.s1, sx = f.sx, sy = f.sy, sxx = f.sxx, sxy = f.sxy, syy = f.syy, sz = f.sz,
               sxz = f.sxz, syz = f.syz, szz = f.szz;
  if (!(left && right && below && above)) return Verdict::kKept;
  // Every return in the window ends clearly beyond p: seen through.
  if (all_beyond) return Verdict::kSeenThrough;
  if (!c.surface_fit || s1 < 8) return Verdict::kKept;
  // Some end before: p is seen through only if the scan's surface around its direction is one
  // plane (no depth edge in the window) that passes p by the margin. The normal equations, by
  // Cramer's rule.
  const double m00 = s1, m01 = sx, m02 = sy, m11 = sxx, m12 = sxy, m22 = syy;
  const double c00 = m11 * m22 - m12 * m12, c01 = m02 * m12 - m01 * m22,
               c02 = m01 * m12 - m02 * m11;
  const double det = m00 * c00 + m01 * c01 + m02 * c02;
  if (!(std::abs(det) > 1e-9 * s1 * s1 * s1)) return Verdict::kKept;
  const double c11 = m00 * m22 - m02 * m02, c12 = m01 * m02 - m00 * m12,
               c22 = m00 * m11 - m01 * m01;
  const double t0 = (c00 * sz + c01 * sxz + c02 * syz) / det;
  const double t1 = (c01 * sz + c11 * sxz + c12 * syz) / det;
  const double t2 = (c02 * sz + c12 * sxz + c22 * syz) / det;
  if (!(t0 > 0.0)) return Verdict::kKept;
  const double fitted_range = 1.0 / t0;
  if (fitted_range < beyond) return Verdict::kKept;
  // ... and by fit_normal_margin_m along the plane's normal: at a grazing angle a point a few
  // centimetres off the surface (range noise, a pose a little off) lies metres in front of it along
  // the ray. The plane's slope in range per radian, over the range, is the tangent of the angle
  // between the ray and the normal.
  const double slope = std::sqrt(t1 * t1 + t2 * t2) / t0 / double(image.bin_rad());
  if ((fitted_range - r) / std::sqrt(1.0 + slope * slope) < c.fit_normal_margin_m)
    return Verdict::kKept;
  // The fit's residual, in range: δ(1/v) ≈ δv / v², at about the fitted range.
  const double rss = std::max(0.0, szz - (t0 * sz + t1 * sxz + t2 * syz));
  const double rms_range = std::sqrt(rss / s1) * fitted_range * fitted_range;
  const double allowed = c.fit_rms_m + c.fit_rms_per_m * fitted_range;
  return rms_range <= allowed ? Verdict::kSeenThrough : Verdict::kKept;
}

// Evidence that adds up in busy places (TransientConfig::busy_drops): what this scan says of p_S
// (sensor frame) by the rays of the 3 × 3 bins about its direction that pass within busy_radius_m
// of it. kHit: one of them ends within
// the near distance of p (something is there); kPass: none does, and one ends beyond p by the
// margin; kNone otherwise (all of them end in front of p, or none passes that near, or p lies
// outside [min_range_m, busy_max_range_m]). A ray's place is its return's place in its bin.
enum class Pass : uint8_t { kNone, kPass, kHit };
Pass BusyPass(const RangeImage& image, const TransientConfig& c, const Vec3f& p_S) {
  const float r = p_S.norm();
  if (!(r >= c.min_range_m && r <= std::min(c.max_range_m, c.busy_max_range_m))) return Pass::kNone;
  float fa, fe;
  image.PlaceOf(p_S, &fa, &fe);
  const float beyond = r + c.margin_m + c.margin_per_m * r;
  const int a0 = int(fa), e0 = int(fe);
  const float r_xy = std::max(std::sqrt(p_S.x() * p_S.x() + p_S.y() * p_S.y()), 0.1f);
  const float cos_el = r_xy / std::max(r, 1e-6f);
  const float bin_m = image.bin_rad() * r;
  const float near = c.near_m + c.near_bins * bin_m;
  const float radius2 = c.busy_radius_m * c.busy_radius_m;
  // The rays of the 3 × 3 bins about p's direction (a bin is 3.5 cm across at 5 m, 7 cm at 10 m).
  constexpr int reach = 1;
  const int na = image.azimuth_bins(), ne = image.elevation_bins();
  bool pass = false, clean = true;
  for (int e = std::max(e0 - reach, 0); e <= std::min(e0 + reach, ne - 1); ++e) {
    const uint16_t* ranges = image.RangeRow(e);
    if (ranges == nullptr) continue;
    for (int da = -reach; da <= reach; ++da) {
      int a = a0 + da;
      if (a < 0) a += na;
      if (a >= na) a -= na;
      const uint16_t cm = ranges[a];
      if (cm == 0) return Pass::kNone;  // blocked near the sensor: nothing behind it is known
      float v, oa = 0.5f, oe = 0.5f;
      if (cm == RangeImage::empty_cm()) {
        // Nothing came back: a ray to the scan's range along a row the sensor fired (as the
        // rule reads it), no evidence elsewhere. Its place: the bin's centre.
        if (!c.empty_is_free || !image.Fired(e)) continue;
        v = image.empty_range_m();
      } else {
        v = 0.01f * float(cm);
        image.OffsetAt(a, e, &oa, &oe);
      }
      const float x = (float(a0 + da) + oa - fa) * cos_el * bin_m;
      const float y = (float(e) + oe - fe) * bin_m;
      const bool within = x * x + y * y <= radius2;
      if (within && std::abs(v - r) < near) return Pass::kHit;
      // A ray of these bins that ends in front of p: p may lie on a surface the rays graze (a
      // car's side seen along it), where the rays beside p run on along the surface.
      if (v < beyond) clean = false;
      pass |= within && v >= beyond;
    }
  }
  return pass && clean ? Pass::kPass : Pass::kNone;
}

// Judges the points i of [begin, end) for which want(i) holds, p_S(i) in the image's sensor frame,
// and hands each verdict to done(i, verdict): eight places at a time (RangeImage::Place8, the
// bits of PlaceOf and norm()). want is asked once for each i, in increasing order.
template <class Want, class PointAt, class Done>
void JudgeRange(const RangeImage& image, const TransientConfig& c, size_t begin, size_t end,
                Want want, PointAt p_S, Done done) {
  Vec3f p[8];
  size_t index[8];
  int m = 0;
  auto flush = [&] {
    float r[8], fa[8], fe[8];
    for (int l = m; l < 8; ++l) p[l] = p[0];  // a full batch
    image.Place8(p, r, fa, fe);
    for (int l = 0; l < m; ++l) done(index[l], JudgePlaced(image, c, p[l], r[l], fa[l], fe[l]));
    m = 0;
  };
  for (size_t i = begin; i < end; ++i) {
    if (!want(i)) continue;
    p[m] = p_S(i);
    index[m++] = i;
    if (m == 8) flush();
  }
  if (m > 0) flush();
}

// Calls judge(begin, end) on pieces that cover [0, n), over the pool when there are enough: a
// judgement costs 0.1-1 µs, so a thousand of them outweigh waking the workers. Pieces are handed
// out as threads finish them, and judgements differ in cost by a factor of ten (a return found at
// once, or a whole window and a plane fit): 32 pieces keep the threads finishing together, where
// 8 left one idle for a while (the stage about 0.5 ms shorter on seed 724).
void JudgeInPieces(size_t n, WorkerPool* pool,
                   const std::function<void(size_t begin, size_t end)>& judge) {
  constexpr int kPieces = 32;
  auto piece = [&](int k) { judge(n * size_t(k) / kPieces, n * size_t(k + 1) / kPieces); };
  if (pool && n >= 1024) {
    pool->Run(kPieces, piece);
  } else {
    for (int k = 0; k < kPieces; ++k) piece(k);
  }
}

// Where a scan was taken from, to judge world points against its image.
struct SensorView {
  const RangeImage& image;
  Eigen::Matrix3f R_SW;
  Vec3f sensor_W;
  SensorView(const RangeImage& image, const Eigen::Isometry3f& T_world_sensor)
      : image(image),
        R_SW(T_world_sensor.linear().transpose()),
        sensor_W(T_world_sensor.translation()) {}
  Vec3f ToSensor(const Vec3f& p_W) const { return R_SW * (p_W - sensor_W); }
};

// Sets drop[i] for the world points p_W(i), i in [0, n), that the scan saw through.
template <class PointAt>
void SeenThroughInPieces(const SensorView& view, const TransientConfig& c, size_t n,
                         WorkerPool* pool, PointAt p_W, uint8_t* drop) {
  JudgeInPieces(n, pool, [&](size_t begin, size_t end) {
    JudgeRange(
        view.image, c, begin, end, [](size_t) { return true; },
        [&](size_t i) { return view.ToSensor(p_W(i)); },
        [&](size_t i, Verdict v) { drop[i] = v == Verdict::kSeenThrough; });
  });
}

}  // namespace

Verdict Judge(const RangeImage& image, const TransientConfig& c, const Vec3f& p_S) {
  const float r = p_S.norm();
  if (!(r >= c.min_range_m && r <= c.max_range_m)) return Verdict::kKept;
  float fa, fe;
  image.PlaceOf(p_S, &fa, &fe);
  return JudgePlaced(image, c, p_S, r, fa, fe);
}

Verdict JudgeReference(const RangeImage& image, const TransientConfig& c, const Vec3f& p_S) {
  const float r = p_S.norm();
  if (!(r >= c.min_range_m && r <= c.max_range_m)) return Verdict::kKept;
  float fa, fe;
  image.PlaceOf(p_S, &fa, &fe);
  return JudgePlaced(image, c, p_S, r, fa, fe, /*reference=*/true);
}

bool SeenThrough(const RangeImage& image, const TransientConfig& c, const Vec3f& p_S) {
  return Judge(image, c, p_S) == Verdict::kSeenThrough;
}

void ClearedPoints::Add(const Vec3f& p_W, const Vec3f& dir_W, int64_t frame) {
  points_.push_back(p_W);
  dirs_.push_back(dir_W);
  frames_.push_back(frame);
}

void ClearedPoints::Expire(int64_t frame, int lifetime_frames, size_t max_points, const Vec3d& lo,
                           const Vec3d& hi) {
  const Eigen::Array3f l = lo.cast<float>().array(), h = hi.cast<float>().array();
  // Oldest first: beyond the bound the oldest go.
  const size_t over = points_.size() > max_points ? points_.size() - max_points : 0;
  size_t out = 0;
  for (size_t i = 0; i < points_.size(); ++i) {
    if (i < over || frames_[i] < frame - lifetime_frames) continue;
    if (!((points_[i].array() >= l).all() && (points_[i].array() < h).all())) continue;
    points_[out] = points_[i];
    dirs_[out] = dirs_[i];
    frames_[out] = frames_[i];
    ++out;
  }
  points_.resize(out);
  dirs_.resize(out);
  frames_.resize(out);
}

void ClearedPoints::Sample(int n, float band_m, float label_m, const Vec3f& lo, const Vec3f& hi,
                           FastRng* rng, SampleBatch* out) const {
  if (points_.empty() || n <= 0) return;
  const Eigen::Array3f l = lo.array(), h = hi.array();
  for (int k = 0; k < n; ++k) {
    const size_t i = size_t((*rng)() % points_.size());
    const float u = (float((*rng)() >> 40) * (1.f / float(1ull << 24)) * 2.f - 1.f) * band_m;
    const Vec3f q = points_[i] + u * dirs_[i];
    if (!((q.array() >= l).all() && (q.array() < h).all())) continue;
    out->xyz.insert(out->xyz.end(), {q.x(), q.y(), q.z()});
    out->labels.push_back(label_m);
  }
}

void ClearedPoints::Clear() {
  points_.clear();
  dirs_.clear();
  frames_.clear();
}

TransientFilter::TransientFilter(const TransientConfig& config)
    : config_(config), image_(config.bin_deg) {
  const int ring = config.past_frames * config.past_scans;
  past_.reserve(size_t(std::max(ring, 0)));
  for (int i = 0; i < ring; ++i) past_.push_back({RangeImage(config.bin_deg)});
}

void TransientFilter::Apply(const std::vector<Vec3f>& points_S,
                            const Eigen::Isometry3f& T_world_sensor, float scan_min_range_m,
                            float scan_max_range_m, int64_t frame, PointBuffer* buffer,
                            DeferredPoints* deferred, LocalMap* map, std::mutex* aux_mu,
                            WorkerPool* pool) {
  // The last frame's image goes to the ring of earlier scans (its slot's oldest image is refilled
  // as this frame's).
  if (!past_.empty() && image_frame_ >= 0) {
    PastScan& slot = past_[size_t(image_frame_ % int64_t(past_.size()))];
    std::swap(slot.image, image_);
    slot.T_world_sensor = image_T_;
    slot.frame = image_frame_;
  }
  image_.Fill(points_S, scan_min_range_m, scan_max_range_m, pool, config_.fired_row_share,
              &fill_scratch_);
  image_T_ = T_world_sensor;
  image_frame_ = frame;
  const SensorView view(image_, T_world_sensor);
  const int period = config_.period_frames;

  // The buffer, judged over the pool, each judgement writing its own flag. Point i takes its turn
  // in the frames with i ≡ frame (mod period_frames); where nothing was dropped lately, in one of
  // those in quiet_turns (i ≡ frame mod period_frames · quiet_turns), and where things move,
  // every active_period_frames frames (i ≡ frame mod active_period_frames; by default
  // period_frames, so every turn).
  const std::vector<Vec3f>& points = buffer->points();
  const size_t n = points.size();
  drop_.assign(n, 0);
  const bool gate = BuildActiveMask(frame);
  std::vector<uint8_t>& passes = buffer->passes();
  // Busy places are judged in every frame within the reach of passes (busy_max_range_m); farther
  // ones keep the turns of places where things move.
  const float busy_reach = std::min(config_.busy_max_range_m, config_.max_range_m);
  const float busy_r2 = busy_reach * busy_reach;
  const size_t every = size_t(period) * (gate ? size_t(config_.quiet_turns) : 1);
  const size_t active_every =
      size_t(config_.active_period_frames > 0 ? config_.active_period_frames : period);
  const size_t phase_every = size_t(frame % int64_t(every));
  const size_t phase_active = size_t(frame % int64_t(active_every));
  std::atomic<int64_t> judged{0};
  JudgeInPieces(n, pool, [&](size_t begin, size_t end) {
    // i mod every and i mod active_every, kept as JudgeRange asks for each i in turn.
    size_t r = begin % every, ra = begin % active_every;
    int64_t mine = 0;
    JudgeRange(
        image_, config_, begin, end,
        [&](size_t i) {
          const bool want = r == phase_every ||
                            (gate && ra == phase_active && active_mask_.Has(points[i])) ||
                            (busy_on_ && (points[i] - view.sensor_W).squaredNorm() <= busy_r2 &&
                             busy_mask_.Has(points[i]));
          if (++r == every) r = 0;
          if (++ra == active_every) ra = 0;
          mine += want;
          return want;
        },
        [&](size_t i) { return view.ToSensor(points[i]); },
        [&](size_t i, Verdict v) {
          drop_[i] = v == Verdict::kSeenThrough;
          // In busy places, passes add up over frames (each point is one piece's: no race).
          if (!busy_on_ || v == Verdict::kSeenThrough || !busy_mask_.Has(points[i])) return;
          // (BusyPass reads kNone beyond busy_max_range_m.)
          const Pass pass = v == Verdict::kSomethingThere
                                ? Pass::kHit
                                : BusyPass(image_, config_, view.ToSensor(points[i]));
          uint8_t& count = passes[i];
          if (pass == Pass::kHit) {
            count = 0;
          } else if (pass == Pass::kPass) {
            if (count < 255) ++count;
            if (count >= config_.busy_passes) drop_[i] = 2;
          }
        });
    judged.fetch_add(mine, std::memory_order_relaxed);
  });
  const bool unmark = map != nullptr && map->placed();
  const int64_t departed_seen = unmark && config_.departed_frames > 0
                                    ? JudgeDeparted(points, frame, *map, T_world_sensor, pool)
                                    : 0;
  const int64_t dropped = DropFromBuffer(frame, 0, buffer, map, aux_mu);
  std::lock_guard<std::mutex> lock(*aux_mu);  // stats_ too: Mapper::Stats reads them under it
  stats_.judged += judged.load(std::memory_order_relaxed);
  stats_.departed_removed += departed_seen;
  stats_.buffer_removed += dropped;
  if (deferred) {
    stats_.deferred_removed += deferred->RemoveIf(
        view.sensor_W, config_.max_range_m, 2 * period, int(frame % (2 * period)),
        [&](const std::vector<Vec3f>& endpoints, std::vector<uint8_t>* drop) {
          SeenThroughInPieces(
              view, config_, endpoints.size(), pool, [&](size_t i) { return endpoints[i]; },
              drop->data());
        });
  }
}

void TransientFilter::NoteDrop(const Vec3f& p_W, int64_t frame) {
  if (config_.active_frames <= 0 || (config_.quiet_turns <= 1 && config_.busy_drops <= 0)) return;
  const float inv_cell = 1.f / config_.active_cell_m;
  Column& c =
      active_[ColumnKey(int(std::floor(p_W.x() * inv_cell)), int(std::floor(p_W.y() * inv_cell)))];
  if (frame - c.last > config_.active_frames) c.drops = 0;
  c.last = frame;
  ++c.drops;
}

bool TransientFilter::BuildActiveMask(int64_t frame) {
  busy_on_ = false;
  const bool quiet = config_.quiet_turns > 1, busy = config_.busy_drops > 0;
  if (config_.active_frames <= 0 || (!quiet && !busy)) return false;
  absl::erase_if(active_,
                 [&](const auto& kv) { return frame - kv.second.last > config_.active_frames; });
  ActiveMask& m = active_mask_;
  m.inv_cell = 1.f / config_.active_cell_m;
  m.nx = m.ny = 0;
  if (active_.empty()) return quiet;
  int lo_x = std::numeric_limits<int>::max(), lo_y = lo_x;
  int hi_x = std::numeric_limits<int>::min(), hi_y = hi_x;
  for (const auto& kv : active_) {
    const int cx = int32_t(uint32_t(kv.first >> 32)), cy = int32_t(uint32_t(kv.first));
    lo_x = std::min(lo_x, cx), hi_x = std::max(hi_x, cx);
    lo_y = std::min(lo_y, cy), hi_y = std::max(hi_y, cy);
  }
  const int64_t nx = int64_t(hi_x) - lo_x + 3, ny = int64_t(hi_y) - lo_y + 3;
  // Drops spread over more columns than a mask should hold (a tiny column over a wide map):
  // every point takes its turn this frame, and no place is busy.
  if (nx * ny > (int64_t(1) << 24)) return false;
  m.x0 = lo_x - 1, m.y0 = lo_y - 1, m.nx = int(nx), m.ny = int(ny);
  m.on.assign(size_t(nx * ny), 0);
  ActiveMask& b = busy_mask_;
  b.inv_cell = m.inv_cell;
  b.x0 = m.x0, b.y0 = m.y0, b.nx = m.nx, b.ny = m.ny;
  b.on.assign(busy ? size_t(nx * ny) : 0, 0);
  for (const auto& kv : active_) {
    const int x = int32_t(uint32_t(kv.first >> 32)) - m.x0, y = int32_t(uint32_t(kv.first)) - m.y0;
    const bool is_busy = busy && kv.second.drops >= config_.busy_drops;
    busy_on_ |= is_busy;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy) {
        const size_t k = size_t(x + dx) * size_t(ny) + size_t(y + dy);
        m.on[k] = 1;
        if (is_busy) b.on[k] = 1;
      }
  }
  // Without the quiet gate every point takes its turn; the active mask then serves the busy one.
  return quiet;
}

int64_t TransientFilter::DropFromBuffer(int64_t frame, size_t from, PointBuffer* buffer,
                                        LocalMap* map, std::mutex* aux_mu) {
  const std::vector<Vec3f>& points = buffer->points();
  const size_t n = points.size();
  std::vector<uint32_t> gone;
  int64_t busy = 0;
  const bool unmark = map != nullptr && map->placed();
  const double inv_leaf = unmark ? 1.0 / map->geometry().leaf_m() : 0.0;
  for (size_t i = from; i < n; ++i) {
    if (!drop_[i]) continue;
    gone.push_back(uint32_t(i));
    if (drop_[i] == 1) {
      NoteDrop(points[i], frame);
    } else {
      ++busy;
    }
    const Vec3f d = points[i] - buffer->origins()[i];
    const float len = d.norm();
    cleared_.Add(points[i], len > 0.f ? Vec3f(d / len) : Vec3f::UnitZ(), frame);
    if (!unmark) continue;
    const Int3 g(FloorToInt(points[i].x() * inv_leaf), FloorToInt(points[i].y() * inv_leaf),
                 FloorToInt(points[i].z() * inv_leaf));
    LocalMap::Level& lv = map->level(0);
    for (int k = 0; k < 27; ++k) {
      const Int3 v = g + Int3(k / 9 - 1, k / 3 % 3 - 1, k % 3 - 1);
      if (!map->InBox(0, v)) {
        // The box has just moved off it (the buffer lets such points go after this frame's
        // marking): the global map clears it, as for a departed point seen through.
        outside_cells_.push_back(v);
        continue;
      }
      // Readers load flags atomically under the shared lock (flags_shared): so are these writes.
      uint8_t* f = &lv.flags(map->Slot(0, v));
      __atomic_fetch_and(f, uint8_t(~LocalMap::kObserved), __ATOMIC_RELAXED);
      __atomic_fetch_or(f, uint8_t(LocalMap::kSeenFree), __ATOMIC_RELAXED);
    }
  }
  if (!gone.empty()) {
    std::lock_guard<std::mutex> lock(*aux_mu);
    buffer->Remove(gone);
    stats_.busy_removed += busy;
  }
  return int64_t(gone.size());
}

int64_t TransientFilter::JudgeNewest(int64_t frame, PointBuffer* buffer, LocalMap* map,
                                     std::mutex* aux_mu, WorkerPool* pool) {
  if (past_.empty()) return 0;
  const std::vector<Vec3f>& points = buffer->points();
  const size_t n = points.size(), first = n - buffer->newest();
  // Per newest point: 0 undecided, 1 seen through (dropped), 2 something was there in a nearer
  // earlier scan: it stood there then too (a static surface, or something that stopped), and the
  // older scans are not asked. Most points are settled by the first scan that sees them. Only
  // drop_[first, n) is read.
  drop_.resize(n);
  std::fill(drop_.begin() + std::ptrdiff_t(first), drop_.end(), uint8_t(0));
  std::vector<uint8_t>& state = drop_;
  int64_t judged = 0;
  for (int j = 1; j <= config_.past_scans; ++j) {
    const int64_t past_frame = frame - int64_t(j) * config_.past_frames;
    if (past_frame < 0) break;
    const PastScan& past = past_[size_t(past_frame % int64_t(past_.size()))];
    if (past.frame != past_frame) continue;  // not a scan judged by Apply (or not kept)
    const SensorView view(past.image, past.T_world_sensor);
    judged += std::count(state.begin() + std::ptrdiff_t(first), state.end(), uint8_t(0));
    JudgeInPieces(n - first, pool, [&](size_t begin, size_t end) {
      JudgeRange(
          past.image, config_, first + begin, first + end, [&](size_t i) { return state[i] == 0; },
          [&](size_t i) { return view.ToSensor(points[i]); },
          [&](size_t i, Verdict v) {
            state[i] = v == Verdict::kSeenThrough ? 1 : v == Verdict::kSomethingThere ? 2 : 0;
          });
    });
  }
  for (size_t i = first; i < n; ++i) state[i] = state[i] == 1;
  // They join the cleared points although nothing has learnt them: the feet that stay (within
  // the plane's normal margin of the road) are trained, and the free samples around the body
  // keep that bump low (without them, seed 612's planner read 10-15 cm too near there).
  const int64_t dropped = DropFromBuffer(frame, first, buffer, map, aux_mu);
  std::lock_guard<std::mutex> lock(*aux_mu);
  stats_.judged += judged;
  stats_.buffer_removed += dropped;
  stats_.past_removed += dropped;
  return dropped;
}

std::vector<Int3> TransientFilter::TakeOutsideCells() {
  std::vector<Int3> cells = std::move(outside_cells_);
  outside_cells_.clear();
  auto less = [](const Int3& a, const Int3& b) {
    return std::tie(a.x(), a.y(), a.z()) < std::tie(b.x(), b.y(), b.z());
  };
  std::sort(cells.begin(), cells.end(), less);
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  return cells;
}

int64_t TransientFilter::JudgeDeparted(const std::vector<Vec3f>& points, int64_t frame,
                                       const LocalMap& map, const Eigen::Isometry3f& T_world_sensor,
                                       WorkerPool* pool) {
  const double inv_leaf = 1.0 / map.geometry().leaf_m();
  auto voxel_of = [&](const Vec3f& p) {
    return Int3(FloorToInt(p.x() * inv_leaf), FloorToInt(p.y() * inv_leaf),
                FloorToInt(p.z() * inv_leaf));
  };
  auto pack = [](const Int3& g) {
    return (int64_t(g.x() & 0x1fffff) << 42) | (int64_t(g.y() & 0x1fffff) << 21) |
           int64_t(g.z() & 0x1fffff);
  };
  // The buffer's points outside the (new) box: RemoveOutside drops them after this frame's
  // marking. One per finest voxel is enough to judge the voxel by.
  const Eigen::Array3f lo = map.min_m().cast<float>().array(),
                       hi = map.max_m().cast<float>().array();
  const int turns = 2 * config_.period_frames;
  if (departed_.size() != size_t(turns)) departed_.resize(size_t(turns));
  // Each voxel once, by its first point (sorted by voxel). A voxel the box left in an earlier frame
  // has no points in the buffer now (the buffer takes only points inside the box), unless the box
  // came back to it; then it is judged twice, which costs a little and changes nothing. Found and
  // sorted in pieces over the pool, then merged.
  constexpr int kPieces = kFindPieces;
  auto same_voxel = [](const std::pair<int64_t, uint32_t>& a,
                       const std::pair<int64_t, uint32_t>& b) { return a.first == b.first; };
  std::vector<std::pair<int64_t, uint32_t>>* found = departed_found_;
  const float lx = lo.x(), ly = lo.y(), lz = lo.z(), hx = hi.x(), hy = hi.y(), hz = hi.z();
  auto find = [&](int k) {
    std::vector<std::pair<int64_t, uint32_t>>& out = found[k];
    out.clear();
    int64_t last = -1;  // the voxel of the last point looked up: a scan's neighbours share voxels
    const size_t end = points.size() * size_t(k + 1) / kPieces;
    for (size_t i = points.size() * size_t(k) / kPieces; i < end; ++i) {
      const float* q = points[i].data();
      // Inside the box (branch-free: nearly all are).
      if ((q[0] >= lx) & (q[0] < hx) & (q[1] >= ly) & (q[1] < hy) & (q[2] >= lz) & (q[2] < hz))
        continue;
      if (drop_[i]) continue;
      const int64_t v = pack(voxel_of(points[i]));
      if (v == last) continue;
      last = v;
      out.emplace_back(v, uint32_t(i));
    }
    // Sorted by voxel, each voxel once by its first point, on the pool's threads: what is left is
    // a merge.
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end(), same_voxel), out.end());
  };
  if (pool && points.size() >= 4096) {
    pool->Run(kPieces, find);
  } else {
    for (int k = 0; k < kPieces; ++k) find(k);
  }
  // The pieces merged (pairs are distinct: each point once), each voxel once by its first point.
  static_assert(kPieces == 4, "the merge below takes four pieces");
  std::vector<std::pair<int64_t, uint32_t>>& leaving = departed_leaving_;
  std::vector<std::pair<int64_t, uint32_t>>& halves = departed_merge_;
  halves.resize(found[0].size() + found[1].size() + found[2].size() + found[3].size());
  const auto mid = std::merge(found[0].begin(), found[0].end(), found[1].begin(), found[1].end(),
                              halves.begin());
  std::merge(found[2].begin(), found[2].end(), found[3].begin(), found[3].end(), mid);
  leaving.resize(halves.size());
  std::merge(halves.begin(), mid, mid, halves.end(), leaving.begin());
  leaving.erase(std::unique(leaving.begin(), leaving.end(), same_voxel), leaving.end());
  for (const auto& [v, i] : leaving) {
    departed_[size_t(v % turns)].points.push_back({points[i], frame, departed_order_++});
    ++departed_count_;
  }
  // Forget the oldest: past departed_frames, and beyond the bound, the oldest of all first. A
  // list keeps its head as an index and is compacted when half of it is spent.
  auto forget = [&](DepartedTurn& t) {
    ++t.head;
    --departed_count_;
  };
  for (DepartedTurn& t : departed_)
    while (t.size() > 0 && t.points[t.head].frame < frame - config_.departed_frames) forget(t);
  const size_t bound = size_t(config_.max_departed_points);
  while (departed_count_ > bound) {
    DepartedTurn* oldest = nullptr;
    for (DepartedTurn& t : departed_)
      if (t.size() > 0 && (!oldest || t.points[t.head].order < oldest->points[oldest->head].order))
        oldest = &t;
    forget(*oldest);
  }
  // Judged half as often as the buffer: what the box left behind no longer trains, so only
  // meshing and the distances wait for the verdict.
  DepartedTurn& turn = departed_[size_t(frame % turns)];
  const Departed* judged = turn.points.data() + turn.head;
  departed_drop_.assign(turn.size(), 0);
  SeenThroughInPieces(
      SensorView(image_, T_world_sensor), config_, turn.size(), pool,
      [&](size_t k) { return judged[k].p; }, departed_drop_.data());
  int64_t seen = 0;
  for (size_t k = 0; k < departed_drop_.size(); ++k) {
    if (!departed_drop_[k]) continue;
    const Departed& d = judged[k];
    // Its voxel and their neighbours, as the live map's unmarking does; those still in the box
    // are left to the buffer's own judgement.
    const Int3 g = voxel_of(d.p);
    for (int j = 0; j < 27; ++j) {
      const Int3 v = g + Int3(j / 9 - 1, j / 3 % 3 - 1, j % 3 - 1);
      if (!map.InBox(0, v)) outside_cells_.push_back(v);
    }
    ++seen;
  }
  if (seen > 0) {
    size_t out = turn.head;
    for (size_t k = 0; k < departed_drop_.size(); ++k)
      if (!departed_drop_[k]) turn.points[out++] = judged[k];
    turn.points.resize(out);
    departed_count_ -= size_t(seen);
  }
  for (DepartedTurn& t : departed_) {
    if (t.head > 0 && t.head >= t.points.size() / 2) {
      t.points.erase(t.points.begin(), t.points.begin() + std::ptrdiff_t(t.head));
      t.head = 0;
    }
  }
  return seen;
}

}  // namespace rim
